"""``codesign``: the preload design and its controller chosen together, beside the sequential answer."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import json_flag, nonnegative_float, say
from piezopreload.core.errors import InputError

if TYPE_CHECKING:
    from piezopreload.codesign import CodesignResult


def register_codesign(sub: Any) -> None:
    """co-design the preload system and its controller, against the sequential answer"""
    p = sub.add_parser(
        "codesign",
        description=(
            "Solve the study's design and then tune its controller (the sequential answer, as 'run' does), then "
            "choose the design's plant-shaping variables (a rigidity floor along the design's least-heat front, the "
            "contact angle, the conformity), the PID gains (the gain schedule's entries where the study tunes "
            "them) and the feedforward's preview lead along the preload schedule together, "
            "nested: the design outside, the design NLP and the tuning inside (Ms inside the tuning, the whole-range "
            "tracking RMS and the settling time as constraints), started from the sequential answer so it is never "
            "worse. Both are validated by the same Monte Carlo; the result gives, for each requirement and the "
            "objective, the sequential against the co-designed figure, and which coupling bought the difference."),
        epilog="Exit codes: 0 ok; 2 bad input, or a study whose design no controller makes meet its limits (the "
               "binding pair named); 1 an internal failure.")
    p.add_argument("study", nargs="?", metavar="STUDY.toml",
                   help="study file, or a shipped study's name (default: the machine axis, machine_axis.toml)")
    p.add_argument("--growth", type=nonnegative_float, metavar="W",
                   help="weight on the screw's thermal growth over the shift (needs [thermal])")
    p.add_argument("--friction", type=nonnegative_float, metavar="W",
                   help="weight on the schedule's friction energy per cycle")
    p.add_argument("--tracking", type=nonnegative_float, metavar="W",
                   help="weight on the tracking RMS along the preload schedule")
    p.add_argument("--voltage", type=nonnegative_float, metavar="W",
                   help="weight on the stacks' peak command (a weight not given is 0 where another is given; with "
                        "none given: growth and tracking 1 where the study has [thermal], else friction and tracking)")
    p.add_argument("--budget", type=int, default=9, metavar="N", help="most inner solves of the outer search "
                                                                      "(default 9)")
    form = p.add_mutually_exclusive_group()
    form.add_argument("--schedule", dest="controller", action="store_const", const=True, default=None,
                      help="compare with the gain schedule's entries ([tuning] schedule_levels, at least 2) as "
                           "decisions of the inner problem, each tuned at Ms over its window (default: as the "
                           "study's tune stage makes it: the entries where [tuning] schedule_levels >= 2, else one "
                           "robust set)")
    form.add_argument("--robust-set", dest="controller", action="store_const", const=False,
                      help="compare with one robust PID set, even where the study tunes a gain schedule (one tuning "
                           "per inner problem; the words then say the study runs the schedule)")
    p.add_argument("--plants", type=int, metavar="N",
                   help="Monte Carlo plants for each answer (default: the study's [validation] plants; 0: none)")
    json_flag(p)
    p.set_defaults(run=_cmd_codesign, show=_print_codesign)


def _cmd_codesign(args: argparse.Namespace) -> CodesignResult:
    from piezopreload.codesign import CodesignWeights, codesign
    from piezopreload.study import load_study

    if args.budget < 0:
        raise InputError(f"--budget: must be >= 0, got {args.budget}")
    if args.plants is not None and args.plants < 0:
        raise InputError(f"--plants: must be >= 0, got {args.plants}")
    study = load_study(args.study, progress=say)
    given = (args.growth, args.friction, args.tracking, args.voltage)
    weights = None if all(w is None for w in given) else CodesignWeights(*(0.0 if w is None else w for w in given))
    return codesign(study, weights, budget=args.budget, validate_plants=args.plants, schedule=args.controller,
                    progress=say)


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    return f"{x:.4g}"


def _print_codesign(r: CodesignResult) -> None:
    print(f"co-design of {r.study} ({r.strategy}: the design outside, the tuning inside; {r.evaluations} inner solves)")
    print(f"  strategy: {r.strategy_why}")
    print(f"  objective: sequential {r.objective_sequential:.4f}, co-designed {r.objective_codesigned:.4f} "
          f"(ratio {r.objective_ratio:.4f})")
    if not r.sequential.feasible:
        print(f"  the sequential answer misses the study: {r.sequential.why}")
    print(f"  time: sequential {r.sequential_s:.1f} s, co-design {r.codesign_s:.1f} s more "
          f"({r.time_ratio:.1f} times the sequential)")
    print(f"  changed: {'; '.join(r.changed()) or 'nothing (the sequential design is kept)'}")
    print(f"  controller: {r.controller_words()}")
    print(f"  feedforward: {r.feedforward_words()}")
    print(f"  coupling: {r.coupling()}")
    print(f"  {'term':10s} {'sequential':>12s} {'co-designed':>12s}  unit")
    for row in r.bought():
        print(f"  {row['term']:10s} {row['sequential']:12.4g} {row['codesigned']:12.4g}  {row['unit']}")
    # the figures first, the requirement's words last: the words run long, the columns stay aligned
    print(f"  {'limit':>9s} {'sequential':>11s} {'co-designed':>11s}  requirement")
    for row in r.requirements():
        print(f"  {_fmt(row['limit']):>9s} {_fmt(row.get('sequential')):>11s} {_fmt(row.get('codesigned')):>11s}  "
              f"{row['requirement'] + (' (' + row['unit'] + ')' if row['unit'] else '')}")
