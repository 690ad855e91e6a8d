"""Tuning and validation wall time on the paper's rig.

* the PID tuning (CasADi + IPOPT, five plant variants, the paper's step and trajectory);
* a 200-plant Monte Carlo validation of the tuned gains in this process (one worker);
* the same validation on 2 local worker processes; the ratio is ours (2 workers) over the
  peer (1 worker): 0.5 would be a perfect split on this 2-core machine.

The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import time

from piezopreload.models.actuator import Rig
from piezopreload.study import default_study, load_study
from piezopreload.tuning.calibrate import identify_feedforward
from piezopreload.tuning.pid import TuningSpec, tune_pid
from piezopreload.tuning.validate import Criteria, executor, validate

N_PLANTS = 200


def main() -> None:
    study = load_study(default_study())
    ff, _ = identify_feedforward(Rig(study.rig), study.excitation)
    t0 = time.perf_counter()
    tuning = tune_pid(study.rig, ff.inverse(), TuningSpec(band_N=study.band_N))
    tune_s = time.perf_counter() - t0
    print(f"tuning: {tune_s:.1f} s ({tuning.status}, {tuning.iterations} IPOPT iterations)", flush=True)

    criteria = Criteria(band_N=study.band_N)
    kw = dict(n_plants=N_PLANTS, seed=study.seed, step=study.references["step"],
              trajectory=study.references["trajectory"])
    seconds = {}
    results = {}
    for workers in (1, 2):
        with executor(workers) as (pool, name):
            t0 = time.perf_counter()
            results[workers] = validate(tuning.gains, ff, study.rig, criteria, pool=pool, pool_name=name, **kw)
            seconds[workers] = time.perf_counter() - t0
        print(f"validation of {N_PLANTS} plants on {name}: {seconds[workers]:.1f} s", flush=True)
    same = all((results[1].metrics[k] == results[2].metrics[k]).all() for k in results[1].metrics)
    figures = {
        "tuning_s": tune_s,
        "tuning_iterations": tuning.iterations,
        "tuning_status": tuning.status,
        "validation_plants": N_PLANTS,
        "validation_1_worker_s": seconds[1],
        "validation_2_workers_s": seconds[2],
        "validation_2_workers_vs_1_worker_ratio": seconds[2] / seconds[1],
        "validation_results_identical": bool(same),
        "validated": results[1].passed,
    }
    print(f"2 workers take {figures['validation_2_workers_vs_1_worker_ratio']:.2f} of one worker's time "
          f"(results identical: {same})")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
