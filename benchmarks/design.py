"""The ball-screw design NLP: CasADi + IPOPT against scipy's SLSQP, and the cost of a front.

* The same design problem (the paper study's [ballscrew], [feed_drive], [duty] and [design]
  tables, objective "stiffness", integers fixed at the optimum's turns and balls per turn so
  both solvers see one continuous NLP), from the same start: CasADi/IPOPT with exact
  derivatives from AD against ``scipy.optimize.minimize(method="SLSQP")`` with
  finite-difference gradients of the same formulas evaluated in numpy. Each is timed as the
  median of several runs; ``nlp_time_ratio`` is ours over the peer's.
* A 50-point stiffness:drag front (epsilon-constraint, warm-started) against one solve, in
  two forms: with the integers fixed as above (one NLP per point) against one NLP; and the
  mixed-integer front (relaxation and integer neighbours at every point) against one
  mixed-integer design solve (``optimise``).
* The same mixed-integer front with every warm solve left to IPOPT (``DesignNLP(warm=
  "ipopt")``, the reference the tests hold the SQP path to): its time, and the largest
  difference between the two fronts.

The last line printed is one JSON object.
"""

from __future__ import annotations

import json
import statistics
import time

import numpy as np
from scipy.optimize import minimize

from piezopreload.design.preload import WEIGHTS, DesignNLP, optimise, pareto_front
from piezopreload.study import load_study

REPEATS = 7
POINTS = 50


def _median_time(fn, repeats: int = REPEATS):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    spec = load_study().design_spec
    if spec is None:
        raise SystemExit("the default study has no [design] table to benchmark")
    nlp = DesignNLP(spec)
    best = optimise(spec, "stiffness", nlp)
    ints = (int(best.point.turns), int(best.point.balls_per_turn))
    lbx, ubx = nlp.bounds(ints)
    y0 = np.clip(nlp.initial_guess(), lbx, ubx)
    weights = WEIGHTS["stiffness"]

    ours_s, ours = _median_time(lambda: nlp.solve(weights, y0, integers=ints))
    f, g = nlp.numpy_functions(weights)
    bounds = [(lo, None if np.isinf(hi) else hi) for lo, hi in zip(lbx, ubx)]
    # scipy-stubs type a constraint dict's fun as scalar-valued; SLSQP takes a vector of inequalities
    peer_s, peer = _median_time(lambda: minimize(  # type: ignore[call-overload]
        f, y0, method="SLSQP", bounds=bounds, constraints=[{"type": "ineq", "fun": lambda y: -g(y)}],
        options={"maxiter": 500, "ftol": 1e-10}))
    print(f"one NLP: CasADi/IPOPT {1e3 * ours_s:.2f} ms, objective {ours.f:.10f} ({ours.status}); "
          f"SLSQP + finite differences {1e3 * peer_s:.2f} ms, objective {peer.fun:.10f} ({peer.message}, "
          f"{peer.nfev} evaluations); max constraint violation {max(0.0, float(np.max(g(peer.x)))):.1e}", flush=True)

    # ---- fronts --------------------------------------------------------------------------
    def fixed_front():
        k_lo = optimise(spec, "drag", nlp).point.stiffness_N_per_um
        eps = np.linspace(k_lo, (1.0 - 1e-6) * best.point.stiffness_N_per_um, POINTS)  # pareto_front's span
        start = nlp.solve(WEIGHTS["drag"], y0, integers=ints)
        y, lam, ok = start.y, start.lam_g, 0
        for k in eps:
            s = nlp.solve(WEIGHTS["drag"], y, lam_g0=lam, integers=ints, stiffness_min=float(k))
            y, lam = s.y, s.lam_g
            ok += s.success and s.feasible
        return ok

    fixed_s, fixed_ok = _median_time(fixed_front, 3)
    design_s, _ = _median_time(lambda: optimise(spec, "stiffness", nlp))
    mixed_s, front = _median_time(lambda: pareto_front(spec, "stiffness:drag", POINTS, nlp), 3)
    reference = DesignNLP(spec, warm="ipopt")
    ipopt_s, ipopt_front = _median_time(lambda: pareto_front(spec, "stiffness:drag", POINTS, reference), 3)
    same_integers = [(p.turns, p.balls_per_turn) for p in front.points] == [
        (p.turns, p.balls_per_turn) for p in ipopt_front.points]
    same_points = len(front.points) == len(ipopt_front.points)  # a point either path failed would differ here
    dx = float(np.max(np.abs(front.x / ipopt_front.x - 1.0))) if same_points else None
    dy = float(np.max(np.abs(front.y / ipopt_front.y - 1.0))) if same_points else None
    print(f"front of {POINTS} points, integers fixed: {fixed_s:.3f} s ({fixed_ok} solved) = "
          f"{fixed_s / ours_s:.1f} x one NLP", flush=True)
    print(f"front of {POINTS} points, mixed-integer: {mixed_s:.3f} s ({len(front.points)} points, "
          f"{front.nlp_solves} solver runs) = {mixed_s / design_s:.1f} x one design solve "
          f"({1e3 * design_s:.1f} ms)", flush=True)
    print(f"the same front with IPOPT for every warm solve: {ipopt_s:.3f} s; same integers at every point: "
          f"{same_integers}; largest relative difference: "
          + (f"stiffness {dx:.1e}, drag {dy:.1e}" if same_points else
             f"none, the fronts have {len(front.points)} and {len(ipopt_front.points)} points"), flush=True)
    print(json.dumps({
        "nlp_casadi_s": ours_s, "nlp_slsqp_s": peer_s, "nlp_time_ratio": ours_s / peer_s,
        "objective_casadi": ours.f, "objective_slsqp": float(peer.fun),
        "objective_gap": float(peer.fun - ours.f),
        "front_points": POINTS, "front_fixed_integers_s": fixed_s, "front_fixed_vs_one_nlp_ratio": fixed_s / ours_s,
        "design_solve_s": design_s, "front_mixed_integer_s": mixed_s,
        "front_mixed_vs_one_design_ratio": mixed_s / design_s, "front_mixed_nlp_solves": front.nlp_solves,
        "front_ipopt_warm_s": ipopt_s, "front_sqp_vs_ipopt_warm_time_ratio": mixed_s / ipopt_s,
        "front_same_integers": same_integers, "front_max_rel_diff_stiffness": dx, "front_max_rel_diff_drag": dy,
    }))


if __name__ == "__main__":
    main()
