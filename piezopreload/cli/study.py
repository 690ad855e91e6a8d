"""``run`` (the one-command study), ``report``, ``simulate`` and ``reproduce``."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import (
    fmt,
    json_flag,
    study_arguments,
    study_of,
)
from piezopreload.core.errors import InputError
from piezopreload.core.quantities import number

if TYPE_CHECKING:
    from piezopreload.outcome import RunSummary, StudyResult
    from piezopreload.results import StudyReproduction, StudyRun
    from piezopreload.sweep import SweepReport


# --------------------------------------------------------------------------------------
# run (the one-command study) and report
# --------------------------------------------------------------------------------------
def register_run(sub: Any) -> None:
    """run a whole study: design, plant, identify, tune, validate, compare, learn, system, export, rig, report"""
    p = sub.add_parser(
        "run",
        description=(
            "Take a study file through its stages: the ball-screw preload design, the designed system as the plant "
            "(where the study's [plant] says so), the feedforward's P-I identification, PID tuning, Monte Carlo "
            "validation, the closed-loop comparison, learning on each margin pass of the design's schedule, the "
            "controlled preload along that schedule, gain export, a run on the rig executor (the simulated rig by "
            "default) and the PDF report. Each stage writes "
            "its artifacts into the output folder and records its inputs' hashes in pipeline.json; a stage whose "
            "inputs have not changed is not run again. Without STUDY, the machine axis (studies/machine_axis.toml); "
            "the paper's study is studies/paper2021.toml."),
        epilog=("exit codes: 0 done, every requirement met; 1 internal failure; 2 bad input or a stage that failed "
                "(named); 3 the rig run stopped by an interlock; 4 the study ran but missed a requirement (each one "
                "is printed, and listed under summary.requirements_missed with --json)"))
    p.add_argument("study", nargs="?", metavar="STUDY.toml",
                   help="study file (default: the machine axis, machine_axis.toml)")
    p.add_argument("--out", default="piezopreload-out", metavar="DIR",
                   help="output folder (default ./piezopreload-out)")
    p.add_argument("--force", action="store_true", help="run every stage again, changed or not")
    p.add_argument("--overwrite", action="store_true",
                   help="where --out holds another study's outputs, remove them first (without it such a folder is "
                        "refused: one folder never mixes two studies)")
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    json_flag(p)
    p.set_defaults(run=_cmd_run, show=_print_run)


def _cmd_run(args: argparse.Namespace) -> StudyResult:
    from piezopreload.progress import Progress
    from piezopreload.study import load_study

    return load_study(args.study).run(args.out, force=args.force, progress=Progress(quiet=args.quiet),
                                      overwrite=args.overwrite)


def _print_run(s: StudyResult) -> None:
    for st in s.stages:
        state = f"ran in {st.seconds:.1f} s" if st.ran else st.status
        print(f"  {st.stage:9s} {state}")
    if s.gain_set:
        print(f"gain set: {s.gain_set} (content hash {(s.gain_set_sha256 or '')[:12]}..., the SHA-256 of its "
              "fields, not of the file)")
    if s.rig_log:
        print(f"rig run log: {s.rig_log}")
    if s.report:
        print(f"report: {s.report}")
    print(f"outputs: {s.out}")
    _print_verdict(s.summary)


def _print_verdict(summary: RunSummary) -> None:
    """Every requirement with its margin, the least (the design's own constraints apart), the missed ones and the
    verdict's robustness over the modelling assumptions."""
    from piezopreload.artifacts.requirements import own_constraints  # not at import: --help loads no floor

    met, checked = summary.requirements_met, summary.requirements
    if met is None:
        return
    print("requirements (the margin as a share of the limit; achieved against required; the key that sets it):")
    width = max(len(r.figures()) for r in checked)
    for r in checked:
        print(f"  {r.line(r.key, width)}")
    least = summary.least_margin
    if met:
        print(f"every requirement met; the least margin: {number(least.margin_pct or 0.0, '%')} % ({least.name})"
              if least else "every requirement met")
        for r in own_constraints(checked):
            print(f"  apart from {r.name}, {number(r.margin_pct or 0.0, '%')} %: a bound the design is built to "
                  "sit on")
    else:
        print(f"{len(summary.missed)} requirement{'s' if len(summary.missed) != 1 else ''} missed:")
        for r in summary.missed:
            print(f"  missed: {r.sentence()}")
    if summary.headline.sensitivity is not None:
        print(f"robustness: {summary.headline.sensitivity.sentence()}")


def register_report(sub: Any) -> None:
    """render a study's (or a sweep's) PDF report again from its artifacts"""
    p = sub.add_parser(
        "report",
        description=("Draw the figures and typeset report.pdf again from the artifacts in a study's output folder "
                     "(written by 'piezopreload run'), or a sweep's report from a sweep's folder (written by "
                     "'piezopreload sweep'); nothing else is computed."))
    p.add_argument("dir", metavar="DIR", help="a study's output folder, or a sweep's")
    p.add_argument("--template", metavar="REPORT.typ",
                   help="typeset this Typst template instead of the shipped one "
                        "(start from a copy of DIR/report/report.typ)")
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    json_flag(p)
    p.set_defaults(run=_cmd_report, show=lambda s: print(f"report: {s.report}"))


def _cmd_report(args: argparse.Namespace) -> StudyResult | SweepReport:
    from piezopreload.pipeline import rerender_report
    from piezopreload.progress import Progress
    from piezopreload.sweep import is_sweep_folder, rerender_sweep_report

    if is_sweep_folder(args.dir):  # a sweep's folder (piezopreload sweep): the sweep's report
        return rerender_sweep_report(args.dir, progress=Progress(quiet=args.quiet), template=args.template)
    return rerender_report(args.dir, progress=Progress(quiet=args.quiet), template=args.template)


# --------------------------------------------------------------------------------------
# simulate and reproduce
# --------------------------------------------------------------------------------------
def register_simulate(sub: Any) -> None:
    """simulate a controller on the study's plant"""
    from piezopreload.artifacts.gainset import REFERENCES
    from piezopreload.tuning.calibrate import CONTROLLERS

    p = sub.add_parser(
        "simulate",
        description=(
            "Simulate the PID alone or the inverse-P-I feedforward plus PID on the study's plant, simulated "
            "(truth hysteresis, creep, amplifier, sensor noise and quantisation, one-sample delay), over the "
            "study's step or trajectory, and print rise, peak and settling time, overshoot and tracking "
            "errors, beside the study's published values where it declares them ([published])."))
    study_arguments(p)
    p.add_argument("--controller", choices=CONTROLLERS, default="ff+pid", help="default: ff+pid")
    p.add_argument("--reference", choices=REFERENCES, default="step",
                   help="the study's [reference.step] or [reference.trajectory] (default: step)")
    p.add_argument("--gains", metavar="gains.json", help="a gain-set artifact (default: the study's gains)")
    p.add_argument("--feedforward", metavar="model.json",
                   help="an identified hysteresis-model artifact to invert (default: identify one from a "
                        "simulated loop measurement of the rig, as the paper did)")
    p.add_argument("--out", metavar="run.csv", help="write the simulated samples as CSV")
    json_flag(p)
    p.set_defaults(run=_cmd_simulate, show=_print_simulate)


@dataclass(frozen=True)
class Simulated:
    """``simulate``'s result: the run (what ran: ``run.info``), the time taken, and the CSV written (``out``)."""

    run: StudyRun
    seconds: float
    out: str | None

    def to_dict(self) -> dict[str, Any]:
        return {**self.run.to_dict(), "seconds": self.seconds, "out": self.out}


def _cmd_simulate(args: argparse.Namespace) -> Simulated:
    from dataclasses import replace

    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.core.artifacts import package_version
    from piezopreload.core.tables import write_csv
    from piezopreload.tuning.feedforward import FeedforwardInfo, IdentifiedFeedforward

    t0 = time.perf_counter()
    gains = None if args.gains is None else GainSet.load(args.gains)
    study = study_of(args, gains)
    ff = None
    if args.controller == "ff+pid":  # the study's feedforward (or the file's), as the paper identified its own
        ff = IdentifiedFeedforward.load(args.feedforward) if args.feedforward else study.identify_feedforward()
    run = study.simulate(gains, controller=args.controller, reference=args.reference, feedforward=ff, seed=args.seed)
    info = run.info
    if gains is not None:  # the files, as the user named them
        info = replace(info, gains_source=args.gains)
    if args.feedforward and ff is not None:
        info = replace(info, feedforward=FeedforwardInfo(args.feedforward, ff.model.kind, ff.model.n_operators))
    run = replace(run, info=info)
    if args.out is not None:
        write_csv(args.out, run.columns(), f"piezopreload {package_version()} simulate: study {study.name} "
                                           f"({study.sha256[:12]}), controller {args.controller}, reference "
                                           f"{args.reference}, seed {run.seed}")
    return Simulated(run, time.perf_counter() - t0, args.out)


def _print_simulate(s: Simulated) -> None:
    run, info = s.run, s.run.info
    g, ff, published = info.gains, info.feedforward, info.published
    print(f"study       {info.study.name} ({info.study.path})")
    print(f"controller  {info.controller}: Kc {g.Kc:g} V/N, Ti {g.Ti_s:g} s, Td {g.Td_s:g} s "
          f"(LabVIEW: Ti {g.labview()['Ti_min']:.4g} min, Td {g.labview()['Td_min']:.4g} min); "
          f"output {g.u_min_V:g}..{g.u_max_V:g} V")
    if ff:
        print(f"feedforward {ff.model} P-I, {ff.operators} operators, {ff.source}")
    levels = " -> ".join(f"{x:g}" for x in run.reference.levels_N)
    print(f"reference   {info.reference}: {levels} N; band {run.band_N:g} N on the {run.signal} signal, "
          f"seed {run.seed}")
    print(f"  {'':22s}{'simulated':>11s}" + ("" if published is None else f"{'published':>11s}"))
    numbers = run.numbers()
    keys = [("rise_s", "rise time (s)"), ("peak_s", "peak time (s)"), ("settling_s", "settling time (s)"),
            ("overshoot_N", "overshoot (N)")]
    if "tracking_rms_N" in numbers:
        keys += [("tracking_rms_N", "tracking RMS (N)"), ("tracking_max_N", "tracking max (N)")]
    for key, label in keys:
        beside = "" if published is None or key not in published else f"{fmt(published[key]):>11s}"
        print(f"  {label:22s}{fmt(numbers[key]):>11s}{beside}")
    if published is not None:
        print(f"published: {published['source']}")
    print(f"peak command {numbers['peak_command_V']:.1f} V; {run.t_s.size} samples at "
          f"{1e3 * info.sample_period_s:g} ms")
    if s.out:
        print(f"wrote       {s.out}")


def register_reproduce(sub: Any) -> None:
    """a study's published step numbers beside the simulation's"""
    p = sub.add_parser(
        "reproduce",
        description=("Run the study's step on its plant with the PID alone and with the P-I feedforward, and print "
                     "rise, peak and settling time beside the published ones the study declares ([published]; the "
                     "paper's study has the paper's, Sections 4.2-4.3). A study without published numbers is refused."))
    study_arguments(p)
    p.add_argument("--repeats", type=int, default=1, metavar="N",
                   help="run the step N times with independent sensor noise and report the median "
                        "and range of each number (default 1: the study's seed alone)")
    json_flag(p)
    p.set_defaults(run=_cmd_reproduce, show=_print_reproduce)


def _cmd_reproduce(args: argparse.Namespace) -> StudyReproduction:
    if args.repeats < 1:
        raise InputError(f"--repeats: must be >= 1, got {args.repeats}")
    return study_of(args).reproduce(seed=args.seed, repeats=args.repeats)


def _print_reproduce(s: StudyReproduction) -> None:
    g = s.gains
    step = " -> ".join(f"{x:g}" for x in s.step_levels_N)
    print(f"study {s.study.name} ({s.study.path}): step {step} N, band {s.band_N:g} N, "
          f"gains Kc {g.Kc:g}, Ti {g.Ti_s:g} s, Td {g.Td_s:g} s ([controller] read as {s.read_as})")
    print(f"published: {s.published}")
    print(f"feedforward fit to the simulated loop: RMS {s.feedforward_fit['rms_pct']:.2f} %, "
          f"max {s.feedforward_fit['max_pct']:.2f} % of span")
    what = "simulated" if s.repeats == 1 else f"median of {s.repeats}"
    print(f"  {'controller':12s}{'metric':14s}{'published':>10s}{what:>14s}{'ratio':>8s}  within 25 %"
          + ("" if s.repeats == 1 else "  range"))
    for r in s.rows:
        ratio = "n/a" if r.ratio is None else f"{r.ratio:.2f}"
        spread = "" if s.repeats == 1 else f"  {fmt(r.range[0])}-{fmt(r.range[1])}"
        print(f"  {r.controller:12s}{r.metric:14s}{r.paper:10.2f}{fmt(r.simulated):>14s}{ratio:>8s}"
              f"  {'yes' if r.within_25pct else 'NO ':11s}{spread}")
