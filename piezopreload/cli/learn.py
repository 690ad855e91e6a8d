"""``learn``: preview and iterative learning control over a repeated reference."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import (
    json_flag,
    nonnegative_float,
    nonnegative_int,
    positive_int,
    say,
    study_arguments,
    study_of,
)
from piezopreload.core.errors import InputError

if TYPE_CHECKING:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.schedule import ScheduleLearning
    from piezopreload.tuning.learning import LearnedWritten, LearningResult


def register_learn(sub: Any) -> None:
    """preview and iterative learning control over a repeated reference"""
    from piezopreload.tuning.ilc import METHODS

    p = sub.add_parser(
        "learn",
        description=(
            "Learn a feedforward correction trial by trial (each trial one run of the repeated reference, a machining "
            "cycle on a machine) on the study's rig, with the reference read ahead by --preview-s: norm-optimal ILC "
            "(the default; a sparse QP where the voltage or slew limits bind) or Q-filtered P-type ILC (the model-free "
            "option). Learning stops when another trial no longer pays. Prints the error per trial, the causal and the "
            "preview floor; writes the learned signal (a content-hashed artifact tied to the gain set and the "
            "reference) that 'rig run --learned' plays back. With --from-run LOG --learned FILE it makes one learning "
            "update from a rig run of FILE instead."))
    study_arguments(p)
    p.add_argument("--gains", metavar="gains.json", help="a gain set (default: the study's [controller] gains)")
    p.add_argument("--reference", default="trajectory", metavar="step|trajectory|schedule|FILE.csv",
                   help="the repeated reference (default trajectory; schedule: the design's preload schedule of a "
                        "study whose plant is its design, each margin pass learned on its own reference)")
    p.add_argument("--iterations", type=nonnegative_int,
                   help="the most learning trials after trial 0 (default: the study's [learning] iterations, else 6; "
                        "fewer where more no longer pay)")
    p.add_argument("--preview-s", type=nonnegative_float,
                   help="preview horizon (default: the study's [learning] preview_s, else delay + lag + slew time)")
    p.add_argument("--after-change-weight", type=nonnegative_float, default=0.0, metavar="W",
                   help="place each planned change to least (whole-trajectory error + W x the error outside 0.1 s "
                        "after the changes); 0, the default, for the least whole-trajectory error")
    p.add_argument("--method", choices=[m.value for m in METHODS],
                   help=f"the learning law (default: the study's [learning] method, else {METHODS[0]})")
    p.add_argument("--plants", type=positive_int, help="learn on N Monte Carlo plants and report the worst")
    p.add_argument("--out", metavar="DIR", help="write learned.json (and learning.png) here")
    p.add_argument("--from-run", metavar="LOG.csv", help="a rig run log of --learned FILE: one learning update")
    p.add_argument("--learned", metavar="FILE", help="the learned signal the run played (with --from-run)")
    json_flag(p)
    p.set_defaults(run=_cmd_learn, show=_print_learn)


@dataclass(frozen=True)
class RunLearned:
    """``learn --from-run``'s result: the run log learned from, the new signal's iteration and history, where it was
    written and its content hash."""

    from_run: str
    iteration: int
    history: list[dict[str, Any]]
    out: str
    content_sha256: str | None

    def to_dict(self) -> dict[str, Any]:
        return {"from_run": self.from_run, "iteration": self.iteration, "history": self.history, "out": self.out,
                "content_sha256": self.content_sha256}


@dataclass(frozen=True)
class Learned:
    """``learn``'s result: the learning, the reference as given and where it was written (None: nowhere);
    ``--json`` prints the learning's ``to_dict()`` with the reference and the files beside it."""

    result: LearningResult | ScheduleLearning
    reference: str
    written: LearnedWritten | None

    def to_dict(self) -> dict[str, Any]:
        return {**self.result.to_dict(), "reference": self.reference,
                **({} if self.written is None else self.written.to_dict())}


def _from_run(args: argparse.Namespace, gain_set: GainSet | None) -> RunLearned:
    from pathlib import Path

    from piezopreload.artifacts.learned import LearnedSignal
    from piezopreload.rig.runlog import read_run_log
    from piezopreload.tuning.learning import learn_from_log

    if not (args.from_run and args.learned and gain_set is not None):
        raise InputError("learn --from-run LOG needs --learned FILE (the signal the run played) and --gains FILE")
    new = learn_from_log(LearnedSignal.load(args.learned), read_run_log(args.from_run), gain_set, args.learned)
    path = (Path(args.out) if args.out else Path(args.learned).parent) / "learned.json"
    saved = new.save(path)
    return RunLearned(args.from_run, saved.iteration, saved.history, str(path), saved.content_sha256)


def _cmd_learn(args: argparse.Namespace) -> Learned | RunLearned:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.rig.session import reference_for

    gain_set = None if args.gains is None else GainSet.load(args.gains)
    if args.from_run or args.learned:
        return _from_run(args, gain_set)
    study = study_of(args, gain_set)
    reference: Any = args.reference
    if reference not in (*study.reference.references(), "schedule"):
        reference = reference_for(reference, gain_set or GainSet(gains=study.controller), "--reference")[0]
    if reference == "schedule":  # along the preload schedule, each margin pass on its own reference
        if args.plants is not None:
            raise InputError("--plants: the schedule is learned on the designed plant itself (each margin pass); "
                             "leave --plants out, or learn on a reference over Monte Carlo plants")
        result: Any = study.learn_schedule(gain_set, iterations=args.iterations, preview_s=args.preview_s,
                                           method=args.method, seed=args.seed, progress=say)
    else:
        result = study.learn(gain_set, reference=reference, iterations=args.iterations, preview_s=args.preview_s,
                             method=args.method, plants=args.plants, seed=args.seed,
                             after_change_weight=args.after_change_weight, progress=say)
    written = None
    if args.out is not None:
        written = result.save(args.out, None if gain_set is None else gain_set.content_sha256,
                              {"study": study.path, "study_sha256": study.sha256, "gains": args.gains,
                               "reference": args.reference})
    return Learned(result, args.reference, written)


def _print_learn(learned: Learned | RunLearned) -> None:
    if isinstance(learned, RunLearned):
        print(f"one learning update from {learned.from_run}: iteration {learned.iteration}; wrote {learned.out}")
        return
    s = learned.to_dict()
    print(f"{s['method']} learning on {s['reference']}, preview {s['preview_s'] * 1e3:.0f} ms"
          + (f", worst of {s['plants']} plants" if s["plants"] else "") + ":")
    for h in s["history"]:
        worst = {k: max(v) if isinstance(v, list) else v for k, v in h.items()}
        print(f"  trial {h['iteration']:2d}: RMS {worst['tracking_rms_N']:.3f} N, outside 0.1 s after jumps "
              f"{worst['tracking_rms_after_change_N']:.3f} N")
    reasons = sorted(set(s["stop_reason"]))
    print(f"{s['trials']} learning trials after trial 0 (stopped: {', '.join(reasons)}); within 1.1 x the best error "
          f"from trial {s['trials_to_within_1p1']}")
    print(f"best: {s['tracking_rms_N']:.3f} N ({s['tracking_rms_pct_of_range']:.2f} % of the range), "
          f"{s['tracking_rms_after_change_N']:.3f} N outside 0.1 s after jumps; "
          f"{'converged' if s['converged'] else 'NOT converged'}"
          + (f" ({s['converged_plants']} of {s['plants']} plants)" if s["plants"] else ""))
    print(f"floors: causal {s['causal_floor_N']:.3f} N, with this preview {s['preview_floor_N']:.3f} N; noise "
          f"{s['noise_floor_N']:.3f} N (two runs of one signal differ by that much, RMS)")
    if s.get("out"):
        print(f"wrote {s['out']}")
