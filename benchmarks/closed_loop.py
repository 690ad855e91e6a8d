"""Closed-loop simulation speed: the compiled loop against the numpy loop, one plant and a batch.

The paper's rig (studies/paper2021.toml) at its 1 kHz sample rate, feedforward (40-operator
inverse P-I) + PID on the 25 -> 60 N step, 10 simulated seconds. "Ours" is the compiled loop
(the one loop step as C, a C loop over time and plants); the peer is the numpy loop
(``engine="numpy"``, the fall-back), measured in the same run on the same noise:

* one plant: ``single_compiled_vs_numpy_ratio`` (target <= 0.02);
* a batch of 200 plants with varied amplifier, coupling, hysteresis and creep:
  ``batch_compiled_vs_numpy_ratio`` (target <= 0.25).

Beside them, nanoseconds per sample (``single_ns_per_step``, ``batch_ns_per_plant_step``)
and the compiled controller step alone run by the same C loop (``controller_step_ns``: the
part of a sample the controller costs, a floor for the loop on this machine), and called
once per sample from Python through ctypes as the rig executor does
(``controller_step_ctypes_ns``). The build happens before the timing (the cache is warm).
The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import time
import timeit

import numpy as np

from piezopreload.core import native
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller
from piezopreload.rig.compiled import controller_step
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward

BATCH, SIM_S = 200, 10.0
SPREAD = {"amp_bandwidth_Hz": 0.2, "amp_current_limit_A": 0.2, "coupling_stiffness_N_per_um": 0.1,
          "bw_alpha": 0.1, "creep_per_decade": 0.3}


def best_of(fn, repeats: int) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def controller_alone(controller: Controller, n: int) -> tuple[float, float]:
    """ns per sample of the compiled controller step: in a C loop, and called through ctypes."""
    from piezopreload.models.controller import controller_functions

    model = controller.model
    _, fn = controller_functions(model, prefix="pp_bench_controller")
    import casadi as ca

    x, p, sp, pv = ca.SX.sym("x", model.state.size), ca.SX.sym("p", model.params.size), ca.SX.sym("sp"), ca.SX.sym("pv")
    u, _, _, _, _, x_next = fn(x, sp, pv, p)
    step = ca.Function("pp_bench_controller_loop", [x, p, sp, pv], [x_next, u])
    runner = native.StepRunner(step, "pp_bench_controller")
    rng = np.random.default_rng(0)
    sp_s = 60.0 + 30.0 * np.sin(np.arange(n) * 2e-3)  # the setpoint moves: the P-I operators work every sample
    pv_s = sp_s - 0.5 + 0.25 * rng.standard_normal(n)
    x0 = controller.state_vector(controller.initial_state(sp_s[0], pv_s[0], 0.0))
    loop_s, _ = best_of(lambda: runner(controller.parameter_vector(), x0, [sp_s, pv_s], 1), 5)
    step_c = controller_step(controller)
    step_c.start(float(sp_s[0]), float(pv_s[0]), 0.0)
    pairs = list(zip(sp_s.tolist(), pv_s.tolist()))

    def calls() -> None:
        f = step_c.step
        for s, y in pairs:
            f(s, y)

    per_call = min(timeit.repeat(calls, number=1, repeat=3)) / n
    return loop_s / n * 1e9, per_call * 1e9


def main() -> None:
    if not native.enabled():
        raise SystemExit("no working C compiler here (or PIEZOPRELOAD_ENGINE=numpy): nothing compiled to time")
    study = load_study(paper_study())
    rig = Rig(study.plant)
    ff = identify_feedforward(study.plant, study.feedforward, check_range_N=None).model
    controller = Controller(study.controller, rig.dt_s, ff.inverse())
    ref = Reference.step(25.0, 60.0, 0.5, SIM_S)
    batch = Rig(study.plant.vary(BATCH, SPREAD, seed=0))
    n = int(round(SIM_S / rig.dt_s)) + 1
    simulate(rig, controller, Reference.step(25.0, 60.0, 0.01, 0.02), engine="c")  # build (or load) first

    single_c, run_c = best_of(lambda: simulate(rig, controller, ref, seed=0, engine="c"), 5)
    single_np, run_np = best_of(lambda: simulate(rig, controller, ref, seed=0, engine="numpy"), 1)
    batch_c, bat_c = best_of(lambda: simulate(batch, controller, ref, seed=0, engine="c"), 3)
    batch_np, bat_np = best_of(lambda: simulate(batch, controller, ref, seed=0, engine="numpy"), 1)
    diff = max(float(np.max(np.abs(run_c.force_N - run_np.force_N))),  # type: ignore[attr-defined]
               float(np.max(np.abs(bat_c.force_N - bat_np.force_N))))  # type: ignore[attr-defined]
    ctrl_ns, ctrl_ctypes_ns = controller_alone(controller, n)
    figures = {
        "sample_rate_Hz": 1.0 / rig.dt_s, "simulated_s": SIM_S, "samples": n, "batch": BATCH,
        "single_compiled_s": single_c, "single_numpy_s": single_np,
        "single_compiled_vs_numpy_ratio": single_c / single_np,
        "batch_compiled_s": batch_c, "batch_numpy_s": batch_np,
        "batch_compiled_vs_numpy_ratio": batch_c / batch_np,
        "single_ns_per_step": single_c / n * 1e9,
        "batch_ns_per_plant_step": batch_c / (n * BATCH) * 1e9,
        "numpy_single_ns_per_step": single_np / n * 1e9,
        "numpy_batch_ns_per_plant_step": batch_np / (n * BATCH) * 1e9,
        "controller_step_ns": ctrl_ns, "controller_step_ctypes_ns": ctrl_ctypes_ns,
        "single_simulated_s_per_wall_s": SIM_S / single_c,
        "max_abs_diff_compiled_numpy_N": diff,
    }
    print(f"one plant, {SIM_S:g} s at 1 kHz: compiled {single_c * 1e3:.1f} ms, numpy {single_np:.2f} s "
          f"-> ratio {figures['single_compiled_vs_numpy_ratio']:.4f} (target <= 0.02)")
    print(f"{BATCH} plants: compiled {batch_c:.2f} s, numpy {batch_np:.2f} s "
          f"-> ratio {figures['batch_compiled_vs_numpy_ratio']:.3f} (target <= 0.25)")
    print(f"ns per sample: one plant {figures['single_ns_per_step']:.0f}, per plant in the batch "
          f"{figures['batch_ns_per_plant_step']:.0f}; the controller step alone {ctrl_ns:.0f} in C, "
          f"{ctrl_ctypes_ns:.0f} through ctypes; compiled and numpy differ by at most {diff:.1e} N")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
