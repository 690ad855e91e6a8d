"""``sweep``: a study at every point of a grid of values of its keys (:mod:`piezopreload.sweep`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import json_flag, positive_int
from piezopreload.core.errors import InputError

if TYPE_CHECKING:
    from piezopreload.sweep import SweepResult


def register_sweep(sub: Any) -> None:
    """run a study at every point of a grid of values of its keys: one row per point, a report"""
    from piezopreload.artifacts.requirements import EXIT_REQUIREMENT_MISSED
    from piezopreload.artifacts.sweep import DEFAULT_SWEEP_OUT, EXIT_POINT_FAILED

    p = sub.add_parser(
        "sweep",
        description=(
            "Run STUDY through every stage of 'piezopreload run' once per point of a grid (or a zip) of values of its "
            "keys, each point into its own folder OUT/points/pNNN/. Each point is the study with its values, checked "
            "as a study file is; stages two points share (the same inputs and code) are computed once, and a sweep "
            "run again resumes where it stopped. The points run on local worker processes or on a Dask cluster. "
            "Writes OUT/sweep.json and OUT/sweep.csv (one row per point: its values, status and headline figures) "
            "and the sweep's report OUT/report.pdf ('piezopreload report OUT' typesets it again)."),
        epilog=(f"example: piezopreload sweep studies/paper2021.toml --vary tuning.ms_max=1.4,1.6,1.8 --vary "
                f"validation.plants=50,200 --workers 2. Exit codes: 0 every point done, 1 internal failure, 2 bad "
                f"input, {EXIT_REQUIREMENT_MISSED} every point ran but one missed a requirement of its study (its row "
                f"names it), {EXIT_POINT_FAILED} a point failed (its row has the error)"))
    p.add_argument("study", metavar="STUDY", help="a study file, or a shipped study's name (paper2021, machine_axis)")
    p.add_argument("--vary", action="append", required=True, metavar="TABLE.KEY=V1,V2,...",
                   help="a key of the study and its values (repeat for more keys); "
                        "a nested key as reference.step.final_N")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--grid", dest="mode", action="store_const", const="grid",
                     help="every combination of the values (the default)")
    how.add_argument("--zip", dest="mode", action="store_const", const="zip",
                     help="the i-th values of every key together (each key as many values)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, metavar="N",
                       help="local worker processes, one point each at a time (default: one per CPU; "
                            "1: one after another here)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run the points on this Dask cluster (the dask extra; "
                            "the folders on a file system the workers share)")
    p.add_argument("--out", default=DEFAULT_SWEEP_OUT, metavar="DIR",
                   help=f"the sweep's folder (default ./{DEFAULT_SWEEP_OUT})")
    p.add_argument("--force", action="store_true", help="run every stage of every point again (shared ones once)")
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    json_flag(p)
    p.set_defaults(run=_cmd_sweep, show=_print_sweep, mode="grid")


def _cmd_sweep(args: argparse.Namespace) -> SweepResult:
    from piezopreload.progress import Progress
    from piezopreload.study import load_study
    from piezopreload.sweep import parse_vary

    vary: dict[str, list[Any]] = {}
    for text in args.vary:
        key, values = parse_vary(text)
        if key in vary:
            raise InputError(f"--vary {key}: given twice; give each key once with all its values")
        vary[key] = values
    study = load_study(args.study)
    result = study.sweep(vary, mode=args.mode, out=args.out, workers=args.workers, scheduler=args.scheduler,
                         force=args.force, progress=Progress(quiet=args.quiet), where="--vary")
    return result


def _print_sweep(result: SweepResult) -> None:
    from piezopreload.sweep import ROWS

    print(repr(result))
    print(f"rows: {result.out / ROWS}")
    if (result.out / "report.pdf").is_file():
        print(f"report: {result.out / 'report.pdf'}")
