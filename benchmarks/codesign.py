"""Co-design against the sequential answer, and the literature problems it is checked on.

* The co-design test problems of Herber and Allison (J. Mech. Des. 141(1):011402, 2019, doi:10.1115/1.4040705;
  TP1-TP3, :mod:`piezopreload.design.codesign_problems`), each solved simultaneously and nested:
  ``literature_objective_ratio`` is the ratio of found to published optimum farthest from 1 over all of them.
* The default study's nested co-design (:func:`piezopreload.codesign.codesign`, the weights the study states)
  beside its sequential answer, both validated by the same Monte Carlo: ``codesign_vs_sequential_objective_ratio``
  (<= 1 by construction) and ``codesign_vs_sequential_time_ratio`` (the whole co-design, the sequential start
  included, over the sequential design and tuning). Both answers are compared with the controller the study's tune
  stage makes (``schedule_inside``: the gain schedule's entries as inner decisions where ``[tuning] schedule_levels``
  is at least 2); the feedforward's preview lead along the schedule is the inner problem's too
  (``feedforward_lead_s``, what it bought in ``feedforward``).
* The two fronts of thermal growth (the design's duty-cycle estimate) against the tracking RMS at the study's Ms
  (:func:`piezopreload.codesign.codesign_fronts`), each a sweep: the sequential one the design alone along its
  ``stiffness:growth`` front, each point then tuned; the co-designed one the co-design at ``--front`` weights of the
  growth against the tracking. ``front_dominates``: every sequential point is weakly dominated by a co-designed
  one at the same Ms (:meth:`~piezopreload.artifacts.codesign.CodesignRecord.front_dominates`, computed from the two
  sweeps: false where a sequential point beats every co-designed one in growth or tracking);
  ``front_strictly_dominated`` counts the sequential points a co-designed pair beats in both.
* Where the coupling is strong: the study co-designed again at a tighter settling limit (``--settling``, default
  0.2 s), at a stiffer rigidity requirement on the schedule (``--stiffness``, ``[schedule] stiffness_min_N_per_um``,
  default 1000 N/um against the study's 300: the rigidity, not the lift-off bound, then sets the schedule's levels)
  and at a hotter duty (``--hotter``, the duty's speeds times 1.5 by default), each with both answers through the same
  Monte Carlo plants, requirement by requirement, and its two fronts (``--case-front`` points each;
  ``strong_coupling``).

* Less of the controller inside: the default study co-designed with the one robust set asked for
  (``--robust N`` inner solves; ``robust_set``), the comparison the co-design made by default before it followed the
  study's controller.

Run: ``python benchmarks/codesign.py [--budget N] [--plants N] [--front N] [--settling S] [--stiffness K] [--hotter F]
[--case-front N] [--case-budget N] [--no-cases] [--robust N]``. The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

from piezopreload.artifacts.codesign import nondominated
from piezopreload.codesign import codesign, codesign_fronts, codesign_record
from piezopreload.design import codesign_problems as cp
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


def print_terms(r) -> None:
    """Each objective term and each requirement of a co-design, sequential beside co-designed."""
    for row in r.bought():
        print(f"  {row['term']:9s} sequential {row['sequential']:.4g}  co-designed {row['codesigned']:.4g} "
              f"{row['unit']} (weight {row['weight']:g})")
    for row in r.requirements():
        print(f"  {row['requirement']:45s} limit {row['limit']}  sequential {row.get('sequential')}  "
              f"co-designed {row.get('codesigned')}")


def coupling_case(words: str, variant, args) -> dict:
    """The study co-designed again at ``variant``: both answers through the same Monte Carlo plants, requirement by
    requirement, what changed and bought it, and the two fronts (``--case-front`` points each)."""
    t0 = time.perf_counter()
    rs = codesign(variant, budget=args.budget, validate_plants=args.plants, progress=print)
    print(f"  {words}: {rs!r} ({time.perf_counter() - t0:.1f} s)")
    if not rs.sequential.feasible:
        print(f"  the sequential answer misses it on the nominal plant: {rs.sequential.why}")
    print(f"  changed: {'; '.join(rs.changed()) or 'nothing'}; coupling: {rs.coupling()}")
    print_terms(rs)
    out = {"case": words, "objective_ratio": rs.objective_ratio, "time_ratio": rs.time_ratio,
           "sequential_meets_nominal": rs.sequential.feasible, "changed": rs.changed(),
           "coupling": rs.coupling().split(":")[0], "bought": rs.bought(),
           "requirements": [{k: v for k, v in row.items()} for row in rs.requirements()],
           "validated": rs.to_dict()["validated"], "fronts": None}
    if args.case_front >= 2 and variant.thermal is not None:
        rec = codesign_record(variant, rs, codesign_fronts(variant, rs, points=args.case_front,
                                                           budget=args.case_budget, progress=print))
        fronts = {}
        for name, points in (("sequential", rec.sequential_front), ("codesigned", rec.codesigned_front)):
            fronts[name] = [(round(p.growth_um, 2), round(p.tracking_rms_N, 2)) for p in nondominated(points)]
            print(f"  {words}: {name} front (growth um, tracking N along the schedule), non-dominated of "
                  f"{len(points)}: {fronts[name]}")
        out["fronts"] = {**fronts, "front_dominates": bool(rec.front_dominates()),
                         "strictly_dominated": int(rec.strictly_dominated())}
        verdict = "is nowhere worse" if rec.front_dominates() else "is somewhere worse"
        print(f"  {words}: the co-designed front {verdict}; it beats {rec.strictly_dominated()} of "
              f"{len(rec.sequential_front)} sequential points in both")
    return out


def cases_of(study, args) -> dict:
    """The coupling cases asked for: a tighter settling limit, a stiffer rigidity, a hotter duty (none: --no-cases)."""
    cases: dict[str, tuple] = {}
    if args.no_cases:
        print("  the coupling cases left out (--no-cases)")
        return cases
    if args.settling is not None:
        cases["settling"] = (f"settling at most {args.settling:g} s",
                             study.replace(validation={"settling_max_s": args.settling}))
    if args.stiffness is not None:
        cases["stiffness"] = (f"the schedule's rigidity at least {args.stiffness:g} N/um",
                              study.replace(schedule={"stiffness_min_N_per_um": args.stiffness}))
    if args.hotter is not None and study.duty is not None:
        speeds = [args.hotter * float(v) for v in study.given["duty"]["speed_rpm"]]
        cases["hotter"] = (f"the duty's speeds times {args.hotter:g} ({', '.join(f'{v:g}' for v in speeds)} rpm)",
                           study.replace(duty={"speed_rpm": speeds}))
    return cases


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=9, help="the co-design's inner solves (default 9)")
    ap.add_argument("--plants", type=int, help="Monte Carlo plants (default: the study's)")
    ap.add_argument("--front", type=int, default=3, help="points of each front's sweep (default 3)")
    ap.add_argument("--robust", type=int, default=2, metavar="N",
                    help="also co-design with the one robust set asked for (schedule=False), N inner solves after the "
                         "start (no fronts; reported apart; default 2, 0: not run)")
    ap.add_argument("--settling", type=float, default=0.2,
                    help="a tighter settling limit (s) both answers are co-designed and validated at (default 0.2)")
    ap.add_argument("--stiffness", type=float, default=1000.0,
                    help="a stiffer rigidity requirement on the schedule, [schedule] stiffness_min_N_per_um (N/um; "
                         "default 1000)")
    ap.add_argument("--hotter", type=float, default=1.5,
                    help="a hotter duty: the duty's speeds times this (default 1.5)")
    ap.add_argument("--case-front", type=int, default=2,
                    help="points of each front's sweep in the coupling cases (default 2; 0: no fronts there)")
    ap.add_argument("--no-cases", action="store_true",
                    help="leave the three coupling cases out (each is a co-design of its own with its fronts)")
    ap.add_argument("--case-budget", type=int, default=3,
                    help="inner solves of each co-designed front weight's search in the coupling cases (default 3)")
    args = ap.parse_args()

    lit = literature()
    study = load_study()
    t0 = time.perf_counter()
    r = codesign(study, budget=args.budget, validate_plants=args.plants, progress=print)
    print(f"co-design of the default study: {time.perf_counter() - t0:.1f} s; {r!r}")
    print(f"  changed: {'; '.join(r.changed()) or 'nothing'}; coupling: {r.coupling()}")
    print(f"  controller: {r.controller_words()}")
    print(f"  feedforward: {r.feedforward_words()}")
    print_terms(r)

    # ---- the two fronts: thermal growth against tracking RMS at the study's Ms ---------------------------
    if study.design_spec is None or study.thermal is None:
        raise SystemExit("the default study has lost its design or [thermal] tables: the fronts need both")
    t_front = time.perf_counter()
    fronts = codesign_fronts(study, r, points=args.front, progress=print)
    rec = codesign_record(study, r, fronts)
    dominates, strictly = rec.front_dominates(), rec.strictly_dominated()
    for name, points in (("sequential", rec.sequential_front), ("co-designed", rec.codesigned_front)):
        front = [(round(p.growth_um, 2), round(p.tracking_rms_N, 2)) for p in nondominated(points)]
        print(f"  {name} front (growth um, tracking N), non-dominated of {len(points)} swept: {front}")
    print(f"  fronts: {time.perf_counter() - t_front:.1f} s; the co-designed front "
          f"{'is nowhere worse' if dominates else 'is somewhere worse'} at Ms <= {rec.ms_max:g}; it beats "
          f"{strictly} of {len(rec.sequential_front)} sequential points in both")
    tracking_only = r.sequential.cycle_tracking_rms_N  # the fronts' tracking: along the preload schedule
    best_tracking = min(p.tracking_rms_N for p in rec.codesigned_front if p.feasible)
    print(f"  the controller's share: the best tracking RMS on the co-designed front {best_tracking:.2f} N against "
          f"the sequential {tracking_only:.2f} N (ratio {best_tracking / tracking_only:.3f})")

    # ---- where the coupling is strong: a tighter settling limit, a stiffer rigidity, a hotter duty ------------------
    strong = {name: coupling_case(words, variant, args) for name, (words, variant) in cases_of(study, args).items()}

    # ---- less of the controller inside: the one robust set asked for -------------------------------------------
    robust = None
    if args.robust > 0:
        t_robust = time.perf_counter()
        rc = codesign(study, budget=args.robust, validate_plants=args.plants, schedule=False, progress=print)
        print(f"  with the one robust set asked for ({time.perf_counter() - t_robust:.1f} s): {rc!r}")
        print(f"  controller: {rc.controller_words()}")
        for row in rc.requirements():
            print(f"  {row['requirement']:45s} limit {row['limit']}  sequential {row.get('sequential')}  "
                  f"co-designed {row.get('codesigned')}")
        robust = {"objective_ratio": rc.objective_ratio, "time_ratio": rc.time_ratio, "changed": rc.changed(),
                  "controller": rc.controller_words(), "sequential_controller": rc.sequential.controller,
                  "tracking_rms_N": {"sequential": rc.sequential.cycle_tracking_rms_N,
                                     "codesigned": rc.codesigned.cycle_tracking_rms_N},
                  "validated": rc.to_dict()["validated"]}

    print(json.dumps({
        "codesign_vs_sequential_objective_ratio": r.objective_ratio,
        "front_dominates": bool(dominates),
        "literature_objective_ratio": lit["worst_ratio"],
        "codesign_vs_sequential_time_ratio": r.time_ratio,
        "front_strictly_dominated": int(strictly),
        "front_points": {"sequential": len(rec.sequential_front), "codesigned": len(rec.codesigned_front)},
        "front_nondominated": {"sequential": len(nondominated(rec.sequential_front)),
                               "codesigned": len(nondominated(rec.codesigned_front))},
        "strong_coupling": strong,
        "schedule_inside": r.schedule,
        "controller": r.controller_words(),
        "feedforward_lead_s": r.codesigned.ff_lead_s,
        "feedforward": r.codesigned.to_dict()["feedforward"],
        "robust_set": robust,
        "tracking_only_ratio": best_tracking / tracking_only,
        "strategy_why": r.strategy_why,
        "strategy": r.strategy,
        "weights": r.weights.to_dict(),
        "changed": r.changed(),
        "coupling": r.coupling().split(":")[0],
        "validated": r.to_dict()["validated"],
        "requirements": r.requirements(),
        "inner_solves": r.evaluations,
        "sequential_s": r.sequential_s,
        "codesign_s": r.codesign_s,
    }, allow_nan=False))


if __name__ == "__main__":
    main()
