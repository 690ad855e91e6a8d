"""Tuning and validation wall time on the paper's rig.

* The PID tuning (CasADi + IPOPT, five plant variants, the paper's step and trajectory), the same
  NLP twice: with the loop and its derivatives compiled (ours) and evaluated in CasADi's virtual
  machine (the peer, ``engine="plain"``), same run. ``tune_compiled_vs_plain_ratio`` (target
  <= 0.25) times the solves with the library already built; the build, into an empty build
  cache of this run's own, is ``compile_s`` (and ``tune_compiled_first_s`` the solve with it).
  ``tune_gains_max_rel_diff`` (target <= 1e-4) compares the two sets of gains.
* A 200-plant Monte Carlo validation of the tuned gains in this process (one worker) and on 2
  local worker processes: ``validation_2_workers_vs_1_worker_ratio`` (0.5 would be a perfect
  split on this 2-core machine); the results must be identical.
* The minimum-time bound (:func:`piezopreload.tuning.bounds.minimum_time`) on the paper's rig and
  on the default study's designed plant (the machine axis: designed first, not timed):
  ``minimum_time_paper_s`` and ``minimum_time_designed_s`` the wall time (target: a few seconds),
  ``minimum_time_designed_bound_s`` the bound itself.

The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import os
import tempfile
import time

from piezopreload.core import native
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.bounds import minimum_time
from piezopreload.tuning.feedforward import identify_feedforward
from piezopreload.tuning.pid import tune_pid
from piezopreload.tuning.validate import executor, validate

N_PLANTS = 200


def main() -> None:
    cache = tempfile.TemporaryDirectory()
    os.environ["XDG_CACHE_HOME"] = cache.name  # an empty build cache: the first compiled tuning builds
    study = load_study(paper_study())
    ff = identify_feedforward(study.plant, study.feedforward, check_range_N=None).model
    spec = study.tuning

    t0 = time.perf_counter()
    first = tune_pid(study.plant, ff.inverse(), spec, engine="compiled")
    first_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled = tune_pid(study.plant, ff.inverse(), spec, engine="compiled")
    compiled_s = time.perf_counter() - t0
    print(f"tuning, compiled: {compiled_s:.1f} s ({compiled.status}, {compiled.iterations} IPOPT iterations); "
          f"the first, building the library, {first_s:.1f} s of which {first.compile_s:.1f} s compiling", flush=True)
    t0 = time.perf_counter()
    plain = tune_pid(study.plant, ff.inverse(), spec, engine="plain")
    plain_s = time.perf_counter() - t0
    print(f"tuning, plain: {plain_s:.1f} s ({plain.status}, {plain.iterations} IPOPT iterations)", flush=True)
    rel = max(abs(getattr(compiled.found(), k) - getattr(plain.found(), k)) / abs(getattr(plain.found(), k))
              for k in ("Kc", "Ti_s", "Td_s", "Tf_s", "b"))

    seed = study.seed if study.validation.seed is None else study.validation.seed
    seconds, results = {}, {}
    for workers in (1, 2):
        with executor(workers) as (pool, name):
            t0 = time.perf_counter()
            results[workers] = validate(compiled.found(), ff, study.plant, study.validation, pool=pool,
                                        pool_name=name, n_plants=N_PLANTS, seed=seed, step=study.references["step"],
                                        trajectory=study.references["trajectory"])
            seconds[workers] = time.perf_counter() - t0
        print(f"validation of {N_PLANTS} plants on {name}: {seconds[workers]:.1f} s", flush=True)
    same = all((results[1].metrics[k] == results[2].metrics[k]).all() for k in results[1].metrics)
    bounds = {}
    for name, s in (("paper", study), ("designed", load_study())):
        step = s.references["step"]
        t0 = time.perf_counter()
        b = minimum_time(s.plant, initial_N=float(step.levels_N[0]), final_N=float(step.levels_N[1]), band_N=s.band_N,
                         u_min_V=s.tuning.u_min_V, u_max_V=s.tuning.u_max_V)
        bounds[name] = (time.perf_counter() - t0, b.settling_s)
        print(f"minimum-time bound, {name}: {b.settling_s:.4g} s in {bounds[name][0]:.2f} s", flush=True)
    figures = {
        "tune_compiled_s": compiled_s, "tune_plain_s": plain_s, "tune_compiled_vs_plain_ratio": compiled_s / plain_s,
        "tune_gains_max_rel_diff": rel, "compile_s": first.compile_s, "tune_compiled_first_s": first_s,
        "tuning_iterations": compiled.iterations, "tuning_iterations_plain": plain.iterations,
        "tuning_status": compiled.status, "builds": native.build_stats()["builds"],
        "validation_plants": N_PLANTS, "validation_1_worker_s": seconds[1], "validation_2_workers_s": seconds[2],
        "validation_2_workers_vs_1_worker_ratio": seconds[2] / seconds[1],
        "validation_results_identical": bool(same), "validated": results[1].passed,
        "minimum_time_paper_s": bounds["paper"][0], "minimum_time_paper_bound_s": bounds["paper"][1],
        "minimum_time_designed_s": bounds["designed"][0], "minimum_time_designed_bound_s": bounds["designed"][1],
        "loadavg_1min": os.getloadavg()[0],
    }
    print(f"compiled over plain {figures['tune_compiled_vs_plain_ratio']:.3f} (target <= 0.25), gains within "
          f"{rel:.1e} (target <= 1e-4); 2 workers take {figures['validation_2_workers_vs_1_worker_ratio']:.2f} of "
          f"one worker's time (results identical: {same})")
    print(json.dumps(figures))
    cache.cleanup()


if __name__ == "__main__":
    main()
