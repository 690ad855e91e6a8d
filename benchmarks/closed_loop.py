"""Closed-loop simulation speed: one plant at a time against a batch of 1,000 plants at once.

The paper's rig (studies/paper2021.toml) at its 1 kHz sample rate, feedforward + PID on the
25 -> 60 N step. "Ours" is the batch: 1,000 plants with varied amplifier, coupling stiffness,
hysteresis and creep simulated in one call; the "peer" is the same simulation of one plant,
which is what a loop over plants costs per plant. Both are reported as simulated seconds per
wall-clock second (per plant for the batch). The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import time

import numpy as np

from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller
from piezopreload.study import default_study, load_study
from piezopreload.tuning.calibrate import identify_feedforward

BATCH, SIM_S, REPEATS = 1000, 2.0, 3
SPREAD = {"amp_bandwidth_Hz": 0.2, "amp_current_limit_A": 0.2, "coupling_stiffness_N_per_um": 0.1,
          "bw_alpha": 0.1, "creep_per_decade": 0.3}


def best_of(fn) -> float:
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.min(times))


def main() -> None:
    study = load_study(default_study())
    rig = Rig(study.rig)
    ff, _ = identify_feedforward(rig, study.excitation)
    controller = Controller(study.gains, rig.dt_s, ff.inverse())
    ref = Reference.step(25.0, 60.0, 0.1, SIM_S)
    batch = Rig(study.rig.vary(BATCH, SPREAD, seed=0))

    single_s = best_of(lambda: simulate(rig, controller, ref, seed=0))
    batch_s = best_of(lambda: simulate(batch, controller, ref, seed=0))
    per_plant_single = single_s
    per_plant_batch = batch_s / BATCH
    figures = {
        "sample_rate_Hz": 1.0 / rig.dt_s,
        "simulated_s": SIM_S,
        "batch": BATCH,
        "single_wall_s": single_s,
        "batch_wall_s": batch_s,
        "single_sim_s_per_wall_s": SIM_S / per_plant_single,
        "batch_sim_s_per_wall_s_per_plant": SIM_S / per_plant_batch,
        "batch_speedup_per_plant": per_plant_single / per_plant_batch,
        "batch_vs_single_time_per_plant_ratio": per_plant_batch / per_plant_single,
    }
    print(f"one plant:     {SIM_S:g} s simulated in {single_s:.3f} s -> {figures['single_sim_s_per_wall_s']:.1f} "
          "simulated s per wall s")
    print(f"{BATCH} plants:  {SIM_S:g} s simulated in {batch_s:.3f} s -> "
          f"{figures['batch_sim_s_per_wall_s_per_plant']:.0f} simulated s per wall s per plant")
    print(f"batch is {figures['batch_speedup_per_plant']:.0f}x faster per plant (target >= 50x)")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
