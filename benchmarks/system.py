"""The whole system on the machine axis: the schedule's requirements from the first cut, and the gain schedule's limits.

Runs a study (default: the machine axis with ``[schedule] stiffness_min_N_per_um = 1000``, where the
requirement binds over most of the cycle, from the first cut on) into a temporary folder and reads
its typed artifacts:

* the system stage: every requirement's verdict and margin, the passes, the pre-cycle's time, the
  tracking in % of the schedule's range, the local margins (largest, share of the samples that
  carry one), the friction energy per cycle achieved, planned and of the design's best constant
  preload, and ``friction_local_over_uniform_margin_ratio``: the planned friction energy of the
  last pass's schedule (local margins) over that of the same schedule with its largest margin
  everywhere (a constant added to the whole schedule), planned in the same run;
* the tune stage: the gain schedule's choice and, at every level, the Monte Carlo worst-case
  overshoot of the robust set and of the schedule against the limit.

``--stiffness`` sets the requirement (0: the study's own). The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.registry import read_artifact
from piezopreload.artifacts.system import SystemRecord
from piezopreload.design.schedule import schedule_preload
from piezopreload.pipeline import run_study
from piezopreload.progress import Progress
from piezopreload.study import load_study


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", help="study file (default: the machine axis)")
    parser.add_argument("--stiffness", type=float, default=1000.0,
                        help="[schedule] stiffness_min_N_per_um (default 1000; 0: the study's own)")
    args = parser.parse_args()
    study = load_study(args.study)
    if args.stiffness > 0:
        study = study.replace(schedule={"stiffness_min_N_per_um": args.stiffness})
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        t0 = time.perf_counter()
        run_study(study, out, progress=Progress(stream=io.StringIO()))
        seconds = time.perf_counter() - t0
        system = SystemRecord.load(out / "system" / "system.json")
        design = DesignRecord.load(out / "design" / "design.json")
        tuning = read_artifact(out / "tuning.json", "tuning")["tuning"].get("schedule")
    n, plan, m = system.numbers, design.schedule, system.schedule.margin_N
    assert study.design_spec is not None, f"{study.name} has no design"
    screw = study.design_spec.screw(design.point)
    uniform = schedule_preload(screw, plan.profile, replace(plan.spec, preload_margin_N=float(m.max())))
    result = {
        "study": study.name, "stiffness_min_N_per_um": plan.spec.stiffness_min_N_per_um, "run_s": seconds,
        "load_average": os.getloadavg()[0], "requirements_met": system.requirements_met,
        "requirements": {r.name: {"value": r.value, "limit": r.limit, "margin": r.margin, "met": r.met}
                         for r in system.requirements},
        "bounds": [b.sentence() for b in system.bounds], "passes": len(system.passes),
        "pre_cycle_s": system.pre_cycle.duration_s, "pre_cycle_ramp_s": system.pre_cycle.ramp_s,
        "cycle_start_error_N": n.cycle_start_error_N,
        "tracking_rms_N": n.tracking_rms_N, "tracking_rms_pct_of_range": n.tracking_rms_pct_of_range,
        "local_margin_max_N": float(m.max()), "local_margin_share_of_samples": float(np.mean(m > 0)),
        "friction_energy_per_cycle": n.friction_energy_per_cycle,
        "planned_friction_energy_per_cycle": n.planned_friction_energy_per_cycle,
        "design_plan_friction_energy": plan.friction_energy_J, "constant_preload_N": plan.constant_preload_N,
        "constant_friction_energy": plan.constant_friction_energy_J,
        "friction_saved_fraction": n.friction_saved_fraction,
        "friction_local_over_uniform_margin_ratio": float(
            system.schedule.friction_energy / uniform.friction_energy_J),
        "energy_units": n.energy_units,
    }
    if tuning is not None:
        result["gain_schedule"] = {
            "choice": tuning["choice"], "overshoot_limit_N": tuning["limits"]["overshoot_N"],
            "levels": {f"{r['level_N']:g}": {"robust_overshoot_N": r["robust"]["overshoot_N"],
                                             "schedule_overshoot_N": r["scheduled"]["overshoot_N"],
                                             "robust_passed": r["robust"]["passed"],
                                             "schedule_passed": r["scheduled"]["passed"], "b": r["entry"]["b"]}
                       for r in tuning["levels"]}}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
