"""Co-design against the sequential answer, and the literature problems it is checked on.

* The co-design test problems of Herber and Allison (J. Mech. Des. 141(1):011402, 2019, doi:10.1115/1.4040705;
  TP1-TP3, :mod:`piezopreload.design.codesign_problems`), each solved simultaneously and nested:
  ``literature_objective_ratio`` is the ratio of found to published optimum farthest from 1 over all of them.
* The default study's nested co-design (:func:`piezopreload.codesign.codesign`, the weights the study states)
  beside its sequential answer, both validated by the same Monte Carlo: ``codesign_vs_sequential_objective_ratio``
  (<= 1 by construction) and ``codesign_vs_sequential_time_ratio`` (the whole co-design, the sequential start
  included, over the sequential design and tuning; the sequential tuning here is the robust set, not the gain
  schedule ``piezopreload run`` also tunes, so the ratio is the stricter one).
* The two fronts of thermal growth (the design's duty-cycle estimate) against the tracking RMS at the study's Ms:
  the sequential front is the design's ``stiffness:growth`` front (the design alone trading rigidity for heat),
  each point then tuned; the co-designed front is the non-dominated set of those points and every pair the
  co-design scored. ``front_dominates``: every sequential point is weakly dominated by a co-designed one (true by
  that construction: the co-design starts from the sequential answer); ``front_strictly_dominated`` counts the
  sequential points a co-designed pair beats in both.

Run: ``python benchmarks/codesign.py [--budget N] [--plants N] [--front N]``. The last line printed is one JSON
object.
"""

from __future__ import annotations

import argparse
import json
import time

from piezopreload.codesign import Candidate, codesign, evaluate_design
from piezopreload.design import codesign_problems as cp
from piezopreload.design.preload import pareto_front
from piezopreload.design.thermal import duty_growth_um
from piezopreload.study import load_study


def literature() -> dict:
    rows = {}
    for name, solve, args in (("TP1", cp.solve_tp1, ()), ("TP2 (1,1,2)", cp.solve_tp2, (cp.TP2(1.0, 1.0, 2.0),)),
                              ("TP2 (2,0,-1)", cp.solve_tp2, (cp.TP2(2.0, 0.0, -1.0),)),
                              ("TP3", cp.solve_tp3, ())):
        for strategy in cp.STRATEGIES:
            sol = solve(strategy, *args)
            rows[f"{name} {strategy}"] = {"plant": sol.plant, "objective": sol.objective,
                                          "published": sol.published_objective, "ratio": sol.objective_ratio,
                                          "solves": sol.solves, "time_s": sol.time_s, "success": sol.success}
            print(f"{name:13s} {strategy:12s} plant {sol.plant:.6g}  objective {sol.objective:.8g}  published "
                  f"{sol.published_objective:.8g}  ratio {sol.objective_ratio:.6f}  ({sol.solves} NLP solves, "
                  f"{sol.time_s:.2f} s)")
    worst = max(rows.values(), key=lambda r: abs(r["ratio"] - 1.0))
    return {"rows": rows, "worst_ratio": worst["ratio"]}


def _point(c: Candidate) -> tuple[float, float]:
    """(growth um, tracking RMS N), to 6 significant digits (the tuning's own tolerance is coarser)."""
    return float(f"{c.growth_um:.6g}"), float(f"{c.tracking_rms_N:.6g}")


def _dominates(a: tuple[float, float], b: tuple[float, float], strict: bool = False) -> bool:
    """``a`` no worse than ``b`` in both (``strict``: better in both); points are compared as rounded."""
    if strict:
        return a[0] < b[0] and a[1] < b[1]
    return a[0] <= b[0] and a[1] <= b[1]


def _nondominated(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The points no other point dominates (no worse in both, better in one), each once."""
    unique = sorted(set(points))
    return [p for p in unique if not any(_dominates(q, p) and q != p for q in unique)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=9, help="the co-design's inner solves (default 9)")
    ap.add_argument("--plants", type=int, help="Monte Carlo plants (default: the study's)")
    ap.add_argument("--front", type=int, default=4, help="points of the sequential front (default 4)")
    args = ap.parse_args()

    lit = literature()
    study = load_study()
    t0 = time.perf_counter()
    r = codesign(study, budget=args.budget, validate_plants=args.plants, progress=print)
    print(f"co-design of the default study: {time.perf_counter() - t0:.1f} s; {r!r}")
    print(f"  changed: {'; '.join(r.changed()) or 'nothing'}; coupling: {r.coupling()}")
    for row in r.bought():
        print(f"  {row['term']:9s} sequential {row['sequential']:.4g}  co-designed {row['codesigned']:.4g} "
              f"{row['unit']} (weight {row['weight']:g})")
    for row in r.requirements():
        print(f"  {row['requirement']:45s} limit {row['limit']}  sequential {row.get('sequential')}  "
              f"co-designed {row.get('codesigned')}")

    # ---- the two fronts: thermal growth against tracking RMS at the study's Ms ---------------------------
    spec, table = study.design_spec, study.thermal
    if spec is None or table is None:
        raise SystemExit("the default study has lost its design or [thermal] tables: the fronts need both")
    front = pareto_front(spec, "stiffness:growth", args.front, growth=lambda p: duty_growth_um(spec, p, table))
    sequential_front = []
    for p in front.points:
        c = evaluate_design(study, p, start=r.sequential.gains)
        if c.feasible:
            sequential_front.append(_point(c))
        why = "" if c.feasible else " " + c.why
        print(f"  sequential front: rigidity {p.stiffness_N_per_um:.0f} N/um, contact angle {p.contact_angle_deg:.1f} "
              f"deg: growth {c.growth_um:.1f} um, tracking RMS {c.tracking_rms_N:.2f} N{why}")
    sequential_front.append(_point(r.sequential))
    codesigned_front = _nondominated(sequential_front + [_point(c) for c in r.candidates])
    dominates = all(any(_dominates(q, p) for q in codesigned_front) for p in sequential_front)
    strictly = sum(any(_dominates(_point(c), p, strict=True) for c in r.candidates) for p in sequential_front)
    shown = [(round(a, 1), round(b, 2)) for a, b in sorted(sequential_front)]
    print(f"  sequential front (growth um, tracking N): {shown}")
    print(f"  co-designed front: {[(round(a, 1), round(b, 2)) for a, b in codesigned_front]}")
    tracking_only = r.sequential.tracking_rms_N
    best_tracking = min(c.tracking_rms_N for c in r.candidates)
    print(f"  the controller's share: the best tracking RMS over the pairs scored {best_tracking:.2f} N against the "
          f"sequential {tracking_only:.2f} N (a tracking-only objective's ratio {best_tracking / tracking_only:.3f})")

    print(json.dumps({
        "codesign_vs_sequential_objective_ratio": r.objective_ratio,
        "front_dominates": bool(dominates),
        "literature_objective_ratio": lit["worst_ratio"],
        "codesign_vs_sequential_time_ratio": r.time_ratio,
        "front_strictly_dominated": int(strictly),
        "front_points": {"sequential": len(sequential_front), "codesigned": len(codesigned_front)},
        "tracking_only_ratio": best_tracking / tracking_only,
        "strategy": r.strategy,
        "weights": r.weights.to_dict(),
        "changed": r.changed(),
        "coupling": r.coupling().split(":")[0],
        "validated": r.to_dict()["validated"],
        "inner_solves": r.evaluations,
        "sequential_s": r.sequential_s,
        "codesign_s": r.codesign_s,
    }, allow_nan=False))


if __name__ == "__main__":
    main()
