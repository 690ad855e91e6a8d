"""The ``piezopreload`` command line: a thin layer over the Python API.

Every subcommand parses its arguments, calls the API, and prints a human table or, with
``--json``, one JSON object on stdout (the result's ``to_dict()``). It exits 0 on success, 2
on bad input with one ``error: ...`` line on stderr, 1 on an internal failure; ``rig run``
and ``rig serve`` exit 3 when an interlock or a signal stopped the run. Set
``PIEZOPRELOAD_DEBUG=1`` to see the traceback of an internal failure. Each subcommand has one
``register_*`` function beside its handler and printer; :data:`COMMANDS` lists them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from piezopreload import __version__
from piezopreload.core.errors import InputError, InternalError, PiezopreloadError
from piezopreload.core.tables import parse_columns, read_record, write_csv
from piezopreload.data import SHIPPED_COLUMNS, shipped_data
from piezopreload.design.preload import OBJECTIVES, PARETO_PAIRS
from piezopreload.design.study import check_screw
from piezopreload.models.ballscrew import BallScrew
from piezopreload.models.gainset import EXPORT_FORMATS, REFERENCES, GainSet
from piezopreload.rig import DEFAULT_ENDPOINT as DEFAULT_RIG_ENDPOINT
from piezopreload.study import PAPER_STUDY, load_study
from piezopreload.tuning.calibrate import CONTROLLERS
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.holdout import Window, identify_record
from piezopreload.tuning.identify import MODELS
from piezopreload.tuning.learning import METHODS

EXIT_OK, EXIT_INTERNAL, EXIT_INPUT = 0, 1, 2
PASSWORD_ENV = "PIEZOPRELOAD_RIG_PASSWORD"


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments as one ``error: ...`` line with exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InputError(f"{self.prog}: {message} (see --help)")


def _integer(low: int, what: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be {what}, got {value}")
        return value
    return parse


_positive_int, _nonnegative_int = _integer(1, "a positive integer"), _integer(0, "an integer >= 0")


def _nonnegative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _time_constants(text: str) -> list[float]:
    """``'0.01,0.1,1'`` -> positive, increasing time constants in s."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0 < x < float("inf") for x in values) or any(b <= a for a, b in zip(values, values[1:])):
        raise argparse.ArgumentTypeError(f"'{text}' is not a list of positive, increasing times in s (example: 0.01,0.1,1)")
    return values


def _window(text: str | None, option: str) -> Window | None:
    """``'4:7'`` -> ``Window(4, 7)``; bad text raises :class:`InputError` naming ``option``."""
    if text is None:
        return None
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        t0, t1 = float(a), float(b)
    except ValueError:
        raise InputError(f"{option}: '{text}' is not T0:T1 in seconds (example: {option} 4:7)") from None
    try:
        return Window(t0, t1)
    except ValueError:
        raise InputError(f"{option}: '{text}' must have finite T0 < T1") from None


def _fmt(x: float | None, unit: str = "") -> str:
    return "-" if x is None else f"{x:.3f}{unit}"


def _json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print the results as one JSON object")


def _study_arguments(p: argparse.ArgumentParser, seed: bool = True) -> None:
    p.add_argument("--study", metavar="STUDY.toml", help="study file (default: the paper's, paper2021.toml)")
    if seed:
        p.add_argument("--seed", type=_nonnegative_int, help="noise seed (default: the study's)")


def _study(args: argparse.Namespace) -> Any:
    # the single-step commands work on a study's plant (its [rig], or its design's: Study.plant_study): the paper's unless named
    return load_study(args.study or PAPER_STUDY)


# --------------------------------------------------------------------------------------
# run (the one-command study) and report
# --------------------------------------------------------------------------------------
def register_run(sub: Any) -> None:
    p = sub.add_parser(
        "run", help="run a whole study: design, plant, identify, tune, validate, compare, system, export, rig, report",
        description=(
            "Take a study file through its stages: the ball-screw preload design, the designed system as the plant "
            "(where the study's [plant] says so), the feedforward's P-I identification, PID tuning, Monte Carlo "
            "validation, the closed-loop comparison, the controlled preload along the design's schedule, gain "
            "export, a run on the rig executor (the simulated rig by default) and the PDF report. Each stage writes "
            "its artifacts into the output folder and records its inputs' hashes in pipeline.json; a stage whose "
            "inputs have not changed is not run again. Without STUDY, the machine axis (studies/machine_axis.toml); "
            "the paper's study is studies/paper2021.toml."),
        epilog=("exit codes: 0 done, 1 internal failure, 2 bad input or a stage that failed (named), 3 the rig run "
                "stopped by an interlock"))
    p.add_argument("study", nargs="?", metavar="STUDY.toml", help="study file (default: the machine axis, machine_axis.toml)")
    p.add_argument("--out", default="piezopreload-out", metavar="DIR", help="output folder (default ./piezopreload-out)")
    p.add_argument("--force", action="store_true", help="run every stage again, changed or not")
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    _json_flag(p)
    p.set_defaults(run=_cmd_run, show=_print_run)


def _cmd_run(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.progress import Progress

    return load_study(args.study).run(args.out, force=args.force, progress=Progress(quiet=args.quiet))


def _print_run(s: dict[str, Any]) -> None:
    for st in s["stages"]:
        state = f"ran in {st['seconds']:.1f} s" if st["ran"] else st["status"]
        print(f"  {st['stage']:9s} {state}")
    if s["gain_set"]:
        print(f"gain set: {s['gain_set']} (sha256 {(s['gain_set_sha256'] or '')[:12]}...)")
    if s["rig_log"]:
        print(f"rig run log: {s['rig_log']}")
    if s["report"]:
        print(f"report: {s['report']}")
    print(f"outputs: {s['out']}")


def register_report(sub: Any) -> None:
    p = sub.add_parser(
        "report", help="render a study's PDF report again from its artifacts",
        description=("Draw the figures and typeset report.pdf again from the artifacts in a study's output folder "
                     "(written by 'piezopreload run'); nothing else is computed."))
    p.add_argument("dir", metavar="DIR", help="a study's output folder")
    p.add_argument("--template", metavar="REPORT.typ",
                   help="typeset this Typst template instead of the shipped one (start from a copy of DIR/report/report.typ)")
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    _json_flag(p)
    p.set_defaults(run=_cmd_report, show=lambda s: print(f"report: {s['report']}"))


def _cmd_report(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.pipeline import rerender_report
    from piezopreload.progress import Progress

    return rerender_report(args.dir, progress=Progress(quiet=args.quiet), template=args.template)


# --------------------------------------------------------------------------------------
# identify
# --------------------------------------------------------------------------------------
def register_identify(sub: Any) -> None:
    p = sub.add_parser(
        "identify", help="identify a P-I hysteresis model from a measured record",
        description=(
            "Identify the weights of a Prandtl-Ishlinskii hysteresis model from a measured "
            "input/output record as a constrained QP (cvxpy + Clarabel), and report train and test "
            "errors in % of the output span beside a straight line and the paper's own method. "
            "Without DATA, the measured piezo record shipped with the package is used."),
        epilog=(
            "CSV: comma separated; lines starting with # are comments. With a header the columns are "
            "found by name (time_s, voltage_V and one output such as force_N or displacement_um); "
            "otherwise give --no-header --columns time=1,input=3:voltage_V,output=2:displacement_um "
            "(0-based indices, optional name with unit after ':')."))
    p.add_argument("data", nargs="?", metavar="DATA.csv", help="measured record (default: the shipped one)")
    p.add_argument("--columns", help="where time, input and output are: time=I,input=J,output=K")
    p.add_argument("--no-header", action="store_true", help="the file has no header line")
    p.add_argument("--model", choices=[*MODELS, *(m + "+creep" for m in MODELS)], default="classical",
                   help="classical: eq. (15); paper-asymmetric: eq. (18); modified: Kuhnen's model "
                        "with dead-zone output operators and an exact inverse (default: classical); "
                        "'+creep' as --creep")
    p.add_argument("--creep", action="store_true",
                   help="add creep (first-order lags on the input) identified in the same QP; the output also "
                        "gives the test error of the model refitted without creep")
    p.add_argument("--creep-time-constants", metavar="TAU,...", type=_time_constants,
                   help="the creep lags' time constants in s, increasing (default: one per decade from 0.01 s "
                        "to the record's length)")
    p.add_argument("--operators", type=_positive_int, default=40, help="number of play operators (default 40)")
    p.add_argument("--train", metavar="T0:T1", help="training window in s (default: first 70 %% of the record)")
    p.add_argument("--test", metavar="T0:T1", help="test window in s (default: after the training window)")
    p.add_argument("--ridge", type=_nonnegative_float, default=0.0, help="ridge weight on the scaled weights (default 0)")
    p.add_argument("--out", metavar="model.json", help="write the identified model as an artifact")
    _json_flag(p)
    p.set_defaults(run=_cmd_identify, show=_print_identify)


def _cmd_identify(args: argparse.Namespace) -> dict[str, Any]:
    if args.data is None:
        path, columns, header = shipped_data(), parse_columns(SHIPPED_COLUMNS), False
    else:
        path, header = args.data, not args.no_header
        columns = parse_columns(args.columns) if args.columns else None
    fit = identify_record(read_record(path, columns=columns, header=header), model=args.model,
                          operators=args.operators, train=_window(args.train, "--train"),
                          test=_window(args.test, "--test"), ridge=args.ridge, creep=args.creep,
                          creep_time_constants_s=args.creep_time_constants)
    return {**fit.to_dict(), "out": None if args.out is None else str(fit.save(args.out))}


def _print_identify(s: dict[str, Any]) -> None:
    d, sv = s["data"], s["solver"]
    unit = s["output_unit"] or "output units"
    print(f"data      {d['path']} ({d['samples']} samples; input {d['input']}, output {d['output']})")
    print(f"model     {s['model']}, {s['operators']} play operators, "
          f"{'invertible' if s['invertible'] else 'not invertible'}")
    print(f"solver    {sv['name']}: {sv['status']}{', active set polished' if sv['polished'] else ''}; "
          f"QP {1e3 * sv['qp_seconds']:.1f} ms, whole fit {1e3 * sv['fit_seconds']:.0f} ms")
    print(f"errors in % of the output span ({s['output_span']:.4g} {unit}):")
    print(f"  {'':40s}{'RMS':>8s}{'max':>8s}")
    rows = [(f"train {s['train']['window_s'][0]:g}-{s['train']['window_s'][1]:g} s", s["train"]),
            (f"test  {s['test']['window_s'][0]:g}-{s['test']['window_s'][1]:g} s", s["test"]),
            ("test, best straight line", s["line_test"])]
    if s["paper_method_test"] is not None:
        rows.append(("test, the paper's method (eq. 17)", s["paper_method_test"]))
    if s.get("without_creep"):
        rows.append((f"test, {s['without_creep']['model']} without creep", s["without_creep"]["test"]))
    for label, e in rows:
        print(f"  {label:40s}{e['rms_pct']:8.3f}{e['max_pct']:8.3f}")
    if s.get("paper_method_note"):
        print(f"  the paper's method (eq. 17) could not run: {s['paper_method_note']}")
    for c in [s["creep"]] if s.get("creep") else []:
        print("creep     " + ", ".join(f"{w:.4g} at {tau:g} s" for tau, w in zip(c["time_constants_s"], c["weights"]))
              + f" ({unit} per input unit); without creep: refitted, not zeroed")
    if s["out"]:
        print(f"wrote     {s['out']}")


# --------------------------------------------------------------------------------------
# simulate and reproduce
# --------------------------------------------------------------------------------------
def register_simulate(sub: Any) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a controller on the reference rig",
        description=(
            "Simulate the PID alone or the inverse-P-I feedforward plus PID on the study's simulated rig "
            "(truth hysteresis, creep, amplifier, sensor noise and quantisation, one-sample delay) over the "
            "paper's step or trajectory, and print rise, peak and settling time, overshoot and tracking "
            "errors beside the paper's values."))
    _study_arguments(p)
    p.add_argument("--controller", choices=CONTROLLERS, default="ff+pid", help="default: ff+pid")
    p.add_argument("--reference", choices=REFERENCES, default="step",
                   help="step: 25 -> 60 N; trajectory: 60-80-100-80-60 N (default: step)")
    p.add_argument("--gains", metavar="gains.json", help="a gain-set artifact (default: the study's gains)")
    p.add_argument("--feedforward", metavar="model.json",
                   help="an identified hysteresis-model artifact to invert (default: identify one from a "
                        "simulated loop measurement of the rig, as the paper did)")
    p.add_argument("--out", metavar="run.csv", help="write the simulated samples as CSV")
    _json_flag(p)
    p.set_defaults(run=_cmd_simulate, show=_print_simulate)


def _cmd_simulate(args: argparse.Namespace) -> dict[str, Any]:
    t0 = time.perf_counter()
    study = _study(args)
    gains = None if args.gains is None else GainSet.load(args.gains)
    ff = None
    if args.controller == "ff+pid":  # the study's feedforward (or the file's), as the paper identified its own
        ff = IdentifiedFeedforward.load(args.feedforward) if args.feedforward else study.identify_feedforward()
    run = study.simulate(gains, controller=args.controller, reference=args.reference, feedforward=ff, seed=args.seed)
    s = run.to_dict()
    if gains is not None:
        s["gains"]["source"] = args.gains
    if args.feedforward and ff is not None:
        s["feedforward"] = {"source": args.feedforward, "model": ff.model.kind, "operators": ff.model.n_operators}
    if args.out is not None:
        write_csv(args.out, run.columns(), f"piezopreload {__version__} simulate: study {study.name} "
                                           f"({study.sha256[:12]}), controller {args.controller}, reference "
                                           f"{args.reference}, seed {run.seed}")
    return {**s, "seconds": time.perf_counter() - t0, "out": args.out}


def _print_simulate(s: dict[str, Any]) -> None:
    g, ff = s["gains"], s["feedforward"]
    print(f"study       {s['study']['name']} ({s['study']['path']})")
    print(f"controller  {s['controller']}: Kc {g['Kc_V_per_N']:g} V/N, Ti {g['Ti_s']:g} s, Td {g['Td_s']:g} s "
          f"(LabVIEW: Ti {g['labview']['Ti_min']:.4g} min, Td {g['labview']['Td_min']:.4g} min); "
          f"output {g['u_min_V']:g}..{g['u_max_V']:g} V")
    if ff:
        print(f"feedforward {ff['model']} P-I, {ff['operators']} operators, {ff['source']}")
    levels = " -> ".join(f"{x:g}" for x in s["reference_levels_N"])
    print(f"reference   {s['reference']}: {levels} N; band {s['band_N']:g} N on the {s['signal']} signal, "
          f"seed {s['seed']}")
    print(f"  {'':22s}{'simulated':>11s}{'paper':>9s}")
    keys = [("rise_s", "rise time (s)"), ("peak_s", "peak time (s)"), ("settling_s", "settling time (s)"),
            ("overshoot_N", "overshoot (N)")]
    if "tracking_rms_N" in s:
        keys += [("tracking_rms_N", "tracking RMS (N)"), ("tracking_max_N", "tracking max (N)")]
    for key, label in keys:
        print(f"  {label:22s}{_fmt(s[key]):>11s}{_fmt(s['paper'][key]):>9s}")
    print(f"peak command {s['peak_command_V']:.1f} V; {s['samples']} samples at {1e3 * s['sample_period_s']:g} ms")
    if s["out"]:
        print(f"wrote       {s['out']}")


def register_reproduce(sub: Any) -> None:
    p = sub.add_parser(
        "reproduce", help="the paper's six step numbers beside the simulation's",
        description=("Run the paper's 25 -> 60 N step on the study's rig with the PID alone and with the P-I "
                     "feedforward, and print rise, peak and settling time beside the paper's (Sections 4.2-4.3)."))
    _study_arguments(p)
    p.add_argument("--repeats", type=int, default=1, metavar="N",
                   help="run the step N times with independent sensor noise and report the median "
                        "and range of each number (default 1: the study's seed alone)")
    _json_flag(p)
    p.set_defaults(run=_cmd_reproduce, show=_print_reproduce)


def _cmd_reproduce(args: argparse.Namespace) -> dict[str, Any]:
    if args.repeats < 1:
        raise InputError(f"--repeats: must be >= 1, got {args.repeats}")
    return _study(args).reproduce(seed=args.seed, repeats=args.repeats)


def _print_reproduce(s: dict[str, Any]) -> None:
    g = s["gains"]
    print(f"study {s['study']['name']} ({s['study']['path']}): step 25 -> 60 N, band {s['band_N']:g} N, "
          f"gains Kc {g['Kc_V_per_N']:g}, Ti {g['Ti_s']:g} s, Td {g['Td_s']:g} s (paper's values read as {g['read_as']})")
    print(f"feedforward fit to the simulated loop: RMS {s['feedforward_fit']['rms_pct']:.2f} %, "
          f"max {s['feedforward_fit']['max_pct']:.2f} % of span")
    what = "simulated" if s["repeats"] == 1 else f"median of {s['repeats']}"
    print(f"  {'controller':12s}{'metric':14s}{'paper':>8s}{what:>14s}{'ratio':>8s}  within 25 %"
          + ("" if s["repeats"] == 1 else "  range"))
    for r in s["rows"]:
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
        spread = "" if s["repeats"] == 1 else f"  {_fmt(r['range'][0])}-{_fmt(r['range'][1])}"
        print(f"  {r['controller']:12s}{r['metric']:14s}{r['paper']:8.2f}{_fmt(r['simulated']):>14s}{ratio:>8s}"
              f"  {'yes' if r['within_25pct'] else 'NO ':11s}{spread}")


# --------------------------------------------------------------------------------------
# tune, validate, export
# --------------------------------------------------------------------------------------
def _monte_carlo_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plants", type=int, metavar="N",
                   help="Monte Carlo plants (default: the study's [validation] plants, or the gain set's; 200)")
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: the CPU count)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the Monte Carlo on this Dask cluster")


def _check_monte_carlo(args: argparse.Namespace) -> None:
    if args.plants is not None and args.plants < 1:
        raise InputError(f"--plants: must be >= 1, got {args.plants}")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers: must be >= 1, got {args.workers}")
    if args.scheduler is not None and not args.scheduler.startswith("tcp://"):
        raise InputError(f"--scheduler: '{args.scheduler}' is not a Dask scheduler address tcp://HOST:PORT")


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _print_validation_summary(v: dict[str, Any]) -> None:
    for key, row in v["summary"].items():
        print(f"  {key:22s} worst {_fmt(row['worst'])}  p95 {_fmt(row['p95'])}  median {_fmt(row['p50'])}")


def register_tune(sub: Any) -> None:
    p = sub.add_parser(
        "tune", help="tune the PID (CasADi), validate it by Monte Carlo, write the gain set",
        description=(
            "Tune Kc, Ti, Td, the derivative filter and the setpoint weight around the study's "
            "P-I-compensated rig (CasADi + IPOPT, several plant variants, Ms and noise bounds), compare "
            "with the paper's and SIMC's gains, compute the minimum-time bound, validate the tuned gains "
            "on a Monte Carlo set of nonlinear rigs, and write a gain-set artifact: 'validated' if every "
            "plant met every criterion, else 'candidate'."))
    _study_arguments(p)
    p.add_argument("--out", default="gains.json", metavar="gains.json", help="the gain-set artifact (default gains.json)")
    _monte_carlo_arguments(p)
    _json_flag(p)
    p.set_defaults(run=_cmd_tune, show=_print_tune)


def _cmd_tune(args: argparse.Namespace) -> dict[str, Any]:
    t0 = time.perf_counter()
    _check_monte_carlo(args)
    study = _study(args)
    tuned = study.tune(study.identify_feedforward(_say), seed=args.seed, progress=_say)
    gain_set = tuned.validate(args.plants, args.seed, workers=args.workers, scheduler=args.scheduler,
                              progress=_say).save(args.out)
    return tuned.summary(gain_set, str(args.out), time.perf_counter() - t0)


def _print_tune(s: dict[str, Any]) -> None:
    g, b = s["gains"], s["simc"]
    print(f"tuned gains: Kc {g['Kc_V_per_N']:.4g} V/N, Ti {g['Ti_s']:.4g} s, Td {g['Td_s']:.4g} s, "
          f"Tf {g['Tf_s']:.4g} s, b {g['b']:.3g} (LabVIEW: Ti {g['labview']['Ti_min']:.4g} min, "
          f"Td {g['labview']['Td_min']:.4g} min); Ms {s['tuning']['ms']:.2f}")
    print(f"SIMC baseline: Kc {b['Kc_V_per_N']:.4g} V/N, Ti {b['Ti_s']:.4g} s")
    print("step 25 -> 60 N and trajectory 60-80-100-80-60 N on the nominal rig:")
    print(f"  {'gains':8s}{'FF':>4s}{'settling':>10s}{'overshoot':>11s}{'track RMS':>11s}{'RMS >0.1 s':>12s}{'peak V':>8s}")
    for r in s["table"]:
        print(f"  {r['gains']:8s}{'yes' if r['feedforward'] else 'no':>4s}{_fmt(r['settling_s'], ' s'):>10s}"
              f"{r['overshoot_N']:9.2f} N{r['tracking_rms_N']:9.2f} N{r['tracking_rms_after_change_N']:10.2f} N"
              f"{r['peak_command_V']:8.1f}")
    print(f"paper (FF + PID): settling {s['paper']['ff+pid']['settling_s']} s")
    mt, tf = s["minimum_time"], s["tracking_floor"]
    ratio = "-" if mt["tuned_over_bound_ratio"] is None else f"{mt['tuned_over_bound_ratio']:.2f}"
    print(f"minimum-time bound: {mt['settling_s']:.3f} s; tuned settling / bound = {ratio}")
    print(f"tracking RMS floor of any causal controller (slew {tf['rate_N_per_s']:.0f} N/s at best): "
          f"{tf['rms_N']:.2f} N; tuned / floor = {tf['tuned_over_floor_ratio']:.2f}")
    v = s["validation"]
    print(f"validation on {v['n_plants']} plants ({v['workers']}, {v['seconds']:.0f} s): "
          f"{'PASSED' if v['passed'] else 'FAILED'} ({v['n_failures']} failures)")
    _print_validation_summary(v)
    print(f"wrote {s['out']} ({s['status']}, sha256 {s['content_sha256'][:12]}...)")


def register_learn(sub: Any) -> None:
    p = sub.add_parser(
        "learn", help="preview and iterative learning control over a repeated reference",
        description=(
            "Learn a feedforward correction cycle by cycle (Q-filtered P-type ILC, or norm-optimal ILC as a QP with "
            "the voltage and slew limits) on the study's rig, with the reference read ahead by --preview-s. Prints "
            "the error per iteration, the causal and the preview floor; writes the learned signal (a content-hashed "
            "artifact tied to the gain set and the reference) that 'rig run --learned' plays back. With --from-run "
            "LOG --learned FILE it makes one learning update from a rig run of FILE instead."))
    _study_arguments(p)
    p.add_argument("--gains", metavar="gains.json", help="a gain set (default: the study's [controller] gains)")
    p.add_argument("--reference", default="trajectory", metavar="step|trajectory|schedule|FILE.csv",
                   help="the repeated reference (default trajectory)")
    p.add_argument("--iterations", type=_nonnegative_int, default=10, help="learning updates (default 10)")
    p.add_argument("--preview-s", type=_nonnegative_float, help="preview horizon (default: delay + lag + slew time)")
    p.add_argument("--method", choices=METHODS, default="p-type", help="the learning law (default p-type)")
    p.add_argument("--plants", type=_positive_int, help="learn on N Monte Carlo plants and report the worst")
    p.add_argument("--out", metavar="DIR", help="write learned.json (and learning.png) here")
    p.add_argument("--from-run", metavar="LOG.csv", help="a rig run log of --learned FILE: one learning update")
    p.add_argument("--learned", metavar="FILE", help="the learned signal the run played (with --from-run)")
    _json_flag(p)
    p.set_defaults(run=_cmd_learn, show=_print_learn)


def _cmd_learn(args: argparse.Namespace) -> dict[str, Any]:
    from pathlib import Path

    from piezopreload.models.learned import LearnedSignal
    from piezopreload.rig.runlog import read_run_log
    from piezopreload.rig.session import reference_for
    from piezopreload.tuning.learning import learn_from_log

    gain_set = None if args.gains is None else GainSet.load(args.gains)
    out = Path(args.out) if args.out else None
    if args.from_run or args.learned:
        if not (args.from_run and args.learned and gain_set is not None):
            raise InputError("learn --from-run LOG needs --learned FILE (the signal the run played) and --gains FILE")
        new = learn_from_log(LearnedSignal.load(args.learned), read_run_log(args.from_run), gain_set, args.learned)
        path = (out or Path(args.learned).parent) / "learned.json"
        saved = new.save(path)
        return {"from_run": args.from_run, "iteration": saved.iteration, "history": saved.history,
                "out": str(path), "content_sha256": saved.content_sha256}
    study = _study(args)
    reference: Any = args.reference
    if reference not in (*study.references, "schedule"):
        reference = reference_for(reference, gain_set or GainSet(gains=study.gains), "--reference")[0]
    result = study.learn(gain_set, reference=reference, iterations=args.iterations, preview_s=args.preview_s,
                         method=args.method, plants=args.plants, seed=args.seed, progress=_say)
    summary = result.to_dict()
    if out is not None:
        summary.update(result.save(out, None if gain_set is None else gain_set.content_sha256,
                                   {"study": study.path, "study_sha256": study.sha256, "gains": args.gains}))
    return summary


def _print_learn(s: dict[str, Any]) -> None:
    if "from_run" in s:
        print(f"one learning update from {s['from_run']}: iteration {s['iteration']}; wrote {s['out']}")
        return
    print(f"{s['method']} learning, preview {s['preview_s'] * 1e3:.0f} ms"
          + (f", worst of {s['plants']} plants" if s["plants"] else "") + ":")
    for h in s["history"]:
        worst = {k: max(v) if isinstance(v, list) else v for k, v in h.items()}
        print(f"  iteration {h['iteration']:2d}: RMS {worst['tracking_rms_N']:.3f} N, outside 0.1 s after jumps "
              f"{worst['tracking_rms_after_change_N']:.3f} N")
    print(f"best: {s['tracking_rms_N']:.3f} N ({s['tracking_rms_pct_of_range']:.2f} % of the range), "
          f"{s['tracking_rms_after_change_N']:.3f} N outside 0.1 s after jumps; "
          f"{'converged' if s['converged'] else 'NOT converged'}")
    print(f"floors: causal {s['causal_floor_N']:.3f} N, with this preview {s['preview_floor_N']:.3f} N")
    if s.get("out"):
        print(f"wrote {s['out']}")


def register_validate(sub: Any) -> None:
    p = sub.add_parser(
        "validate", help="validate a gain set again by Monte Carlo on the nonlinear rig",
        description=(
            "Run a gain set's gains and feedforward on a new Monte Carlo set of nonlinear rigs drawn around "
            "the plant it names, against the criteria it names, and report worst case and percentiles. "
            "With --out, write the gain set with this validation: 'validated' only if every plant met "
            "every criterion."))
    p.add_argument("gains", metavar="gains.json", help="a gain-set artifact written by 'piezopreload tune'")
    _monte_carlo_arguments(p)
    p.add_argument("--seed", type=int, help="seed of the Monte Carlo set (default: the gain set's)")
    p.add_argument("--out", metavar="gains.json", help="write the gain set with this validation here")
    _json_flag(p)
    p.set_defaults(run=_cmd_validate, show=_print_validate)


def _cmd_validate(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.tuning.verdict import validate_gain_set

    _check_monte_carlo(args)
    before = GainSet.load(args.gains)
    stored = (before.validation or {}).get("n_plants")
    plants = args.plants or (stored if isinstance(stored, int) and stored >= 1 else 200)
    seed = int(before.inputs.get("seed", 0)) if args.seed is None else args.seed
    _say(f"validating {args.gains} on {plants} plants ...")
    try:
        after, result = validate_gain_set(before, n_plants=plants, seed=seed, workers=args.workers,
                                          scheduler=args.scheduler, progress=lambda i, n: _say(f"  chunk {i}/{n}"),
                                          inputs={"revalidated_from_sha256": before.content_sha256})
    except InputError as exc:
        raise InputError(f"{args.gains}: {exc}") from exc
    if args.out is not None:
        after = after.save(args.out)
    return {"gains": args.gains, "validated": result.passed, "status": after.status, "plants": plants, "seed": seed,
            **result.headline(), "validation": result.to_dict(), "out": args.out, "content_sha256": after.content_sha256}


def _print_validate(s: dict[str, Any]) -> None:
    v = s["validation"]
    print(f"validation of {s['gains']} on {s['plants']} plants (seed {s['seed']}, {v['workers']}, {v['seconds']:.0f} s): "
          f"{'PASSED' if s['validated'] else 'FAILED'} ({v['n_failures']} failures)")
    _print_validation_summary(v)
    for f in v["failures"][:10]:
        print(f"  plant {f['plant']}: {f['metric']} {_fmt(f['value'])} > {f['limit']:g}")
    if s["out"]:
        print(f"wrote {s['out']} ({s['status']}, sha256 {s['content_sha256'][:12]}...)")


def register_export(sub: Any) -> None:
    p = sub.add_parser(
        "export", help="export a validated gain set for a controller",
        description=(
            "Write a validated gain set in a controller's units: json (SI, controller form stated), "
            "labview (Kc, Ti and Td in minutes), plc (Kp, Tn, Tv in seconds), c-header (constants), "
            "casadi-c (the whole controller step, feedforward and PID with its state, as C code generated by CasADi). "
            "A candidate or a gain set whose content hash does not match is refused."))
    p.add_argument("gains", metavar="gains.json", help="a gain-set artifact written by 'piezopreload tune'")
    p.add_argument("--format", required=True, choices=list(EXPORT_FORMATS))
    p.add_argument("--out", metavar="PATH", help="file to write (default: standard output)")
    _json_flag(p)
    p.set_defaults(run=_cmd_export, show=_print_export)


def _cmd_export(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.core.artifacts import atomic_write_text
    from piezopreload.rig.export import export_text

    gain_set = GainSet.load(args.gains)
    try:
        text = export_text(gain_set, args.format)
    except InputError as exc:
        raise InputError(f"{args.gains}: {exc}") from exc
    if args.out:
        atomic_write_text(args.out, text)
    return {"gains": args.gains, "format": args.format, "out": args.out, "content_sha256": gain_set.content_sha256,
            "text": None if args.out else text}


def _print_export(s: dict[str, Any]) -> None:
    if s["out"]:
        print(f"wrote {s['out']} ({s['format']}) from {s['gains']}")
    else:
        print(s["text"], end="")


# --------------------------------------------------------------------------------------
# ballscrew and design
# --------------------------------------------------------------------------------------
def register_ballscrew(sub: Any) -> None:
    p = sub.add_parser(
        "ballscrew", help="evaluate one double-nut ball screw: ratings, rigidity, load sharing, drag, life",
        description=(
            "Evaluate a given (catalogue) double-nut ball screw at a preload and an axial load: C_dyn and C_0 "
            "(estimated from the geometry unless given), rigidity, deflection, the nuts' loads and lift-off, "
            "peak contact pressure, drag torque and life. Check a catalogue screw before optimising."))
    p.add_argument("--nominal-diameter-mm", type=float, required=True)
    p.add_argument("--lead-mm", type=float, required=True)
    p.add_argument("--ball-mm", type=float, required=True)
    p.add_argument("--turns", type=float, required=True, help="loaded turns per nut")
    p.add_argument("--contact-angle-deg", type=float, default=45.0, help="default 45")
    p.add_argument("--conformity", type=float, default=0.55, help="groove radius / ball diameter (default 0.55)")
    p.add_argument("--pitch-diameter-mm", type=float, help="default: the nominal diameter")
    p.add_argument("--preload-N", type=float, help="the preload (default: --preload-fraction of C_dyn)")
    p.add_argument("--preload-fraction", type=float, help="preload as a fraction of C_dyn (default 0.1)")
    p.add_argument("--axial-load-N", type=float, default=0.0, help="axial load on the nut (default 0)")
    p.add_argument("--speed-rpm", type=_nonnegative_float, default=1000.0, help="for life in hours and heat (default 1000)")
    p.add_argument("--c-dyn-N", type=float, help="catalogue dynamic load rating (default: estimated)")
    p.add_argument("--c0-N", type=float, help="catalogue static load rating (default: Hertz at 4,200 MPa)")
    _json_flag(p)
    p.set_defaults(run=_cmd_ballscrew, show=_print_ballscrew)


def _cmd_ballscrew(args: argparse.Namespace) -> dict[str, Any]:
    if args.preload_N is not None and args.preload_fraction is not None:
        raise InputError("give --preload-N or --preload-fraction, not both")
    try:
        screw = BallScrew(
            nominal_diameter_mm=args.nominal_diameter_mm, lead_mm=args.lead_mm, ball_mm=args.ball_mm,
            turns=args.turns, contact_angle_deg=args.contact_angle_deg, conformity_screw=args.conformity,
            conformity_nut=args.conformity, pitch_diameter_mm=args.pitch_diameter_mm, c_dyn_N=args.c_dyn_N,
            c0_N=args.c0_N)
    except ValueError as exc:
        raise InputError(f"the screw is not valid: {exc}") from exc
    try:
        return check_screw(screw, args.preload_N, 0.1 if args.preload_fraction is None else args.preload_fraction,
                           args.axial_load_N, args.speed_rpm)
    except InputError as exc:  # name the option, as the user typed it
        option, _, rest = str(exc).partition(":")
        raise InputError(f"--{option.replace('_', '-')}:{rest}") from exc


def _print_ballscrew(r: dict[str, Any]) -> None:
    s = r["screw"]
    print(f"screw       {s['nominal_diameter_mm']:g} x {s['lead_mm']:g} mm, ball {s['ball_mm']:g} mm, "
          f"{s['turns']:g} turns x {s['balls_per_turn']} balls, contact angle {s['contact_angle_deg']:g} deg, "
          f"helix {s['helix_angle_deg']:.2f} deg")
    print(f"ratings     C_dyn {r['c_dyn_N']:.0f} N ({r['c_dyn_source']}), C_0 {r['c0_N']:.0f} N ({r['c0_source']})")
    print(f"preload     {r['preload_N']:.0f} N = {r['preload_fraction_of_c_dyn']:.3f} C_dyn; lift-off at "
          f"{r['lift_off_load_N']:.0f} N axial")
    print(f"rigidity    {r['rigidity_N_per_um']:.0f} N/um at {r['axial_load_N']:g} N axial "
          f"({r['rigidity_no_load_N_per_um']:.0f} N/um without load)")
    print(f"load        nuts carry {r['loaded_nut_N']:.0f} / {r['unloaded_nut_N']:.0f} N (HIWIN formula "
          f"{r['loaded_nut_hiwin_N']:.0f} N), deflection {r['deflection_um']:.2f} um"
          + ("; THE UNLOADED NUT HAS LIFTED OFF" if r["lifted_off"] else ""))
    print(f"contact     peak pressure {r['peak_pressure_MPa']:.0f} MPa (limit 4200), static safety "
          f"{r['static_safety']:.1f}")
    print(f"drag        {r['drag_torque_Nm']:.3f} N m (K_p {r['drag_coefficient']:.3f}), {r['drag_heat_W']:.1f} W at "
          f"{r['speed_rpm']:g} rpm")
    if r["life_h"] is not None:
        print(f"life        L10 {r['life_revolutions']:.3g} rev = {r['life_h']:.0f} h at {r['speed_rpm']:g} rpm")


def register_design(sub: Any) -> None:
    p = sub.add_parser(
        "design", help="design the preloaded ball screw (CasADi): optimum, Pareto fronts, preload schedule",
        description=(
            "Solve the study's ball-screw preload design (contact angle, ball size, conformity, turns and balls "
            "per turn, bolt preload and piezo preload range) for one objective, trace the Pareto fronts by the "
            "epsilon-constraint method, and plan the least-friction preload schedule for a load profile against "
            "the best constant preload. Infeasible requests name the constraints that cannot be met."))
    _study_arguments(p, seed=False)
    p.add_argument("--objective", choices=OBJECTIVES, help="default: the study's [design] objective")
    p.add_argument("--pareto", choices=PARETO_PAIRS, help="trace this front only (default: the study's list)")
    p.add_argument("--points", type=int, help="points per front (default: the study's, 50)")
    p.add_argument("--schedule", metavar="LOADS.csv",
                   help="load profile: time_s, axial_load_N[, speed_rpm] (default: the study's, or a machining cycle)")
    p.add_argument("--out", default="piezopreload-out/design.json", metavar="design.json",
                   help="the design artifact; each front's CSV is written beside it (default piezopreload-out/design.json)")
    _json_flag(p)
    p.set_defaults(run=_cmd_design, show=_print_design)


def _cmd_design(args: argparse.Namespace) -> dict[str, Any]:
    if args.points is not None and not 2 <= args.points <= 500:
        raise InputError(f"--points: must be in 2..500, got {args.points}")
    study = _study(args)
    result = study.design(objective=args.objective, pareto=None if args.pareto is None else [args.pareto],
                          points=args.points, schedule=args.schedule, progress=None if args.json else _say)
    written = result.save(args.out, {"study": study.path, "study_sha256": study.sha256})
    return {"study": {"path": study.path, "sha256": study.sha256}, **result.summary(),
            "written": [str(p) for p in written]}


def _print_design(r: dict[str, Any]) -> None:
    p = r["optimum"]
    print(f"study       {r['study']['path']}")
    print(f"optimum     objective {r['objective']}: {p['turns']:.0f} turns x {p['balls_per_turn']:.0f} balls of "
          f"{p['ball_mm']:.3f} mm, contact angle {p['contact_angle_deg']:.1f} deg, conformity {p['conformity']:.3f}")
    print(f"  preload   bolts {p['bolt_preload_N']:.0f} N, stacks up to {p['max_preload_N']:.0f} N; per duty case "
          + ", ".join(f"{f:.0f}" for f in p["case_preload_N"]) + " N")
    print(f"  achieves  rigidity {p['stiffness_N_per_um']:.0f} N/um (least over the duty cases; "
          f"{p['rigidity_at_max_preload_N_per_um']:.0f} at F_hi), mean drag {p['mean_drag_torque_Nm']:.3f} N m, "
          f"life {p['life_h']:.0f} h, first axial mode >= {p['frequency_min_Hz']:.0f} Hz")
    print(f"  ratings   C_dyn {p['c_dyn_N']:.0f} N (estimate), C_0 {p['c0_N']:.0f} N; peak pressure "
          f"{p['peak_pressure_MPa']:.0f} MPa; stack stroke used {p['stack_stroke_used_um']:.1f} um")
    print(f"  binding   {', '.join(r['binding']) or 'none'}")
    for f in r["fronts"]:
        y = next(k for k in f if k not in ("pair", "points", "solve_s", "nlp_solves", "stiffness_N_per_um"))
        print(f"front       {f['pair']}: {f['points']} points, rigidity {f['stiffness_N_per_um'][0]:.0f}-"
              f"{f['stiffness_N_per_um'][1]:.0f} N/um, {y} {f[y][0]:.4g}-{f[y][1]:.4g}, {f['solve_s']:.2f} s")
    s = r["schedule"]
    print(f"schedule    {s['samples']} samples: preload {s['preload_min_N']:.0f}-{s['preload_max_N']:.0f} N against a "
          f"best constant {s['constant_preload_N']:.0f} N; friction {s['friction_energy']:.4g} against "
          f"{s['constant_friction_energy']:.4g} {s['energy_units']} ({s['saving_fraction']:.0%} saved)")
    for path in r["written"]:
        print(f"wrote       {path}")


# --------------------------------------------------------------------------------------
# rig run / serve / push
# --------------------------------------------------------------------------------------
def _key_values(pairs: list[str] | None, option: str) -> dict[str, str]:
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise InputError(f"{option} '{pair}': expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def _rig_common(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.rig.backends import parse_fault

    return {"backend": args.backend, "backend_options": _key_values(args.backend_option, "--backend-option"),
            "reference": args.reference or "step", "log_dir": args.log_dir, "seed": args.seed,
            "faults": [parse_fault(f) for f in args.inject or []], "loop": args.loop,
            "safety": {"force_max_N": args.force_max_N, "ramp_s": args.ramp_s, "missed_streak": args.missed_streak}}


def _quiet_asyncua() -> None:
    import logging

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


def _password(args: argparse.Namespace, required: bool) -> str | None:
    password = os.environ.get(PASSWORD_ENV)
    if password is None and required:
        if sys.stdin.isatty():
            import getpass

            return getpass.getpass(f"password for {args.user}: ")
        raise InputError(f"--user {args.user}: set the password in the environment variable {PASSWORD_ENV} "
                         "(it is never taken on the command line, where other users could read it)")
    return password


def _rig_arguments(p: argparse.ArgumentParser) -> None:
    from piezopreload.rig.backends import FAULT_KINDS

    p.add_argument("gains", metavar="gains.json", help="a validated gain set (candidates and tampered files are refused)")
    p.add_argument("--backend", default="sim", help="sim (the simulated rig, default) or an installed hardware plug-in")
    p.add_argument("--backend-option", action="append", metavar="KEY=VALUE", help="passed to the backend (repeatable)")
    p.add_argument("--reference", metavar="|".join(REFERENCES) + "|FILE.csv",
                   help="the paper's step or trajectory as the gain set stores them, or a CSV of time_s,force_N "
                        "(default step; with --learned the signal's own)")
    p.add_argument("--log-dir", default="runs", metavar="DIR", help="where the run log goes (default runs/)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated rig (default 0)")
    p.add_argument("--force-max-N", type=float, help="interlock: highest force (default 150 N)")
    p.add_argument("--ramp-s", type=float, help="interlock: time to ramp the voltage down on a stop (default 0.5 s)")
    p.add_argument("--missed-streak", type=_positive_int,
                   help="interlock: missed deadlines in a row that stop the run (default 5 on the native loop, 50 on "
                        "the Python loop)")
    p.add_argument("--loop", choices=("auto", "native", "python"), default="auto",
                   help="the fixed-rate loop: native (a C thread; the simulated rig or a C-ABI library backend), "
                        "python (the interpreter; any backend), auto (native where it can run, default)")
    p.add_argument("--inject", action="append", metavar="KIND@T_S[=VALUE][/DURATION_S]",
                   help="fire drill: inject a fault into the backend at T_S (repeatable); KIND: "
                        + "; ".join(f"{k}: {v}" for k, v in FAULT_KINDS.items()))
    _json_flag(p)


def register_rig(sub: Any) -> None:
    rig = sub.add_parser("rig", help="run, serve and push gains on the rig executor",
                         description="The rig executor: a validated gain set at a fixed rate against a backend, "
                                     "behind interlocks, with a run log; served over OPC UA; gains pushed to it.")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="run|serve|push", parser_class=_Parser, required=True)
    p = rig_sub.add_parser(
        "run", help="run a validated gain set on a backend",
        description=(
            "Run the controller step (inverse-P-I feedforward + PID) of a validated gain set at its fixed rate with "
            "absolute deadlines, against the simulated rig (default) or a hardware backend, behind the interlocks "
            "(voltage clamp and slew limit; force, sensor NaN/stale/range, missed deadlines, SIGINT/SIGTERM, "
            "exceptions: each ramps the voltage down, disarms and exits 3). Writes the run log (CSV + JSON sidecar) "
            "and prints the step metrics and the loop's timing."),
        epilog="exit codes: 0 completed, 1 internal failure, 2 bad input, 3 stopped by an interlock or a signal")
    _rig_arguments(p)
    p.add_argument("--rate", type=float, metavar="HZ", help="the loop's rate; must be the gain set's (default: it)")
    p.add_argument("--learned", metavar="FILE", help="play back a learned signal ('piezopreload learn --out'): its "
                   "plan as the setpoint, its ff_extra_V added to the feedforward; its reference unless --reference")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--realtime", action="store_true", help="pace the loop in real time (default)")
    mode.add_argument("--fast", action="store_true", help="run the cycles back to back (simulated backend)")
    p.set_defaults(run=_cmd_rig_run, show=_print_rig_run)

    p = rig_sub.add_parser(
        "serve", help="run in real time and serve the rig over OPC UA",
        description=(
            "Run a validated gain set in real time like 'rig run' (the reference's last level held after its end) and "
            "serve it over OPC UA: CtrlP, CtrlTi, CtrlTd (LADS names), the gain set's and the feedforward's hashes, "
            "setpoint, force, voltage, state, last event, and the method PushGainSet. Ends on SIGINT/SIGTERM (exit 3) "
            "or after --duration (exit 0)."),
        epilog=f"The password of --user is read from ${PASSWORD_ENV}.")
    _rig_arguments(p)
    p.add_argument("--endpoint", default=DEFAULT_RIG_ENDPOINT, help=f"default {DEFAULT_RIG_ENDPOINT} (loopback)")
    p.add_argument("--user", metavar="NAME", help=f"the user allowed to push; password in ${PASSWORD_ENV}")
    p.add_argument("--certificate", metavar="CERT", help="the server's certificate: enables Basic256Sha256 SignAndEncrypt only")
    p.add_argument("--private-key", metavar="KEY", help="the server certificate's private key")
    p.add_argument("--duration", type=float, metavar="S", help="serve this long, then ramp down and exit 0")
    p.set_defaults(run=_cmd_rig_serve, show=_print_rig_run)

    p = rig_sub.add_parser(
        "push", help="push a validated gain set to a serving rig",
        description=("Push a validated gain set to 'rig serve' through the OPC UA method PushGainSet; the executor "
                     "checks it again and switches bumplessly between two cycles. Candidates, tampered files, wrong "
                     "passwords and refused calls exit 2 with the reason."),
        epilog=f"The password of --user is read from ${PASSWORD_ENV} (or asked for on a terminal).")
    p.add_argument("gains", metavar="gains.json", help="a validated gain set")
    p.add_argument("--endpoint", default=DEFAULT_RIG_ENDPOINT, help=f"default {DEFAULT_RIG_ENDPOINT}")
    p.add_argument("--user", metavar="NAME", help=f"user name; password in ${PASSWORD_ENV}")
    p.add_argument("--certificate", metavar="CERT", help="the client's certificate (Basic256Sha256 SignAndEncrypt)")
    p.add_argument("--private-key", metavar="KEY", help="the client certificate's private key")
    p.add_argument("--server-certificate", metavar="CERT", help="the server's certificate, to trust it")
    _json_flag(p)
    p.set_defaults(run=_cmd_rig_push, show=_print_rig_push)


def _cmd_rig_run(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.rig import session

    common = _rig_common(args)
    if args.learned and args.reference is None:
        common["reference"] = None  # the learned signal's own
    return session.run(args.gains, rate_Hz=args.rate, realtime=not args.fast, learned=args.learned, **common).to_dict()


def _cmd_rig_serve(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.rig import session

    _quiet_asyncua()
    if args.user is None:
        raise InputError("rig serve: give --user NAME (password in $" + PASSWORD_ENV + "); anonymous sessions are refused")
    users = {args.user: _password(args, True)}
    if args.certificate is None:
        _say("warning: no --certificate: passwords cross the network unencrypted; keep the endpoint on loopback")
    return session.serve(args.gains, endpoint=args.endpoint, users=users, certificate=args.certificate,
                         private_key=args.private_key, duration_s=args.duration, say=_say, **_rig_common(args)).to_dict()


def _cmd_rig_push(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.rig import session

    _quiet_asyncua()
    password = _password(args, args.user is not None) if args.user else None
    return session.push(args.gains, endpoint=args.endpoint, username=args.user, password=password,
                        certificate=args.certificate, private_key=args.private_key,
                        server_certificate=args.server_certificate)


def _print_rig_run(s: dict[str, Any]) -> None:
    m, t = s["metrics"], s["timing"]
    print(f"{s['status']}: {s['cycles']} cycles at {s['rate_Hz']:g} Hz on '{s['backend']}' "
          f"({'real time' if s['realtime'] else 'as fast as possible'}), controller step in {s['controller_step']}, "
          f"{s.get('loop') or 'python'} loop")
    if s["trip"]:
        print(f"stopped by interlock '{s['trip']['cause']}' at t = {s['trip']['t_s']:.3f} s: {s['trip']['detail']}")
    if "settling_s" in m:
        print(f"step: rise {_fmt(m['rise_s'], ' s')}, peak {_fmt(m['peak_s'], ' s')}, settling {_fmt(m['settling_s'], ' s')}, "
              f"overshoot {_fmt(m['overshoot_N'], ' N')}; tracking RMS {m['tracking_rms_N']:.3g} N")
    if t["realtime"]:
        print(f"timing: {t['missed_deadlines']} missed deadlines, lateness p99 {t['lateness_p99_s'] * 1e6:.0f} us, "
              f"max {t['lateness_max_s'] * 1e3:.2f} ms, {t.get('lost_samples', 0)} samples lost"
              + (f"; {t['sched_fifo']}; {t['memory_locked']}" if "sched_fifo" in t else ""))
    for p in s.get("pushes", []):
        print(f"push by {p['user']}: {'accepted' if p['accepted'] else 'refused'} "
              f"{p.get('gain_set_sha256', '')[:12]} {p.get('reason', '')}")
    print(f"run log: {s['log_csv']} and {s['log_json']}")


def _print_rig_push(s: dict[str, Any]) -> None:
    p = s["server_parameters"]
    print(f"{s['endpoint']}: {s['message']}")
    print(f"the server now runs {s['server_gain_set_sha256'][:12]}: CtrlP {p['CtrlP']:.6g} V/N, "
          f"CtrlTi {p['CtrlTi']:.6g} s, CtrlTd {p['CtrlTd']:.6g} s")


# --------------------------------------------------------------------------------------
# the parser
# --------------------------------------------------------------------------------------
#: one register function per subcommand, in the order ``--help`` lists them
COMMANDS: tuple[Callable[[Any], None], ...] = (
    register_run, register_report, register_identify, register_simulate, register_reproduce, register_tune,
    register_learn, register_validate, register_ballscrew, register_design, register_export, register_rig,
)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="piezopreload",
                     description="Design and tuning studies for feed drives whose ball-screw preload is set by piezo stacks.")
    parser.add_argument("--version", action="version", version=f"piezopreload {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for register in COMMANDS:
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return EXIT_INPUT
        result = args.run(args)
    except PiezopreloadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return int(getattr(exc, "exit_code", EXIT_INTERNAL if isinstance(exc, InternalError) else EXIT_INPUT))
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal failure: one line, the traceback on request
        if os.environ.get("PIEZOPRELOAD_DEBUG"):
            traceback.print_exc()
        print(f"error: internal failure: {type(exc).__name__}: {exc} "
              "(set PIEZOPRELOAD_DEBUG=1 for the traceback)", file=sys.stderr)
        return EXIT_INTERNAL
    if args.json:
        print(json.dumps(result, allow_nan=False))
    else:
        args.show(result)
    return int(result.get("exit_code", EXIT_OK))


if __name__ == "__main__":
    sys.exit(main())
