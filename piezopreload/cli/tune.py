"""``tune`` and ``validate``: PID gains around the compensated plant, and their Monte Carlo verdict."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import (
    check_monte_carlo,
    fmt,
    json_flag,
    monte_carlo_arguments,
    print_validation_summary,
    say,
    study_arguments,
    study_of,
)
from piezopreload.core.errors import InputError
from piezopreload.core.quantities import number, quantity

if TYPE_CHECKING:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.artifacts.tuning import MinimumTimeBound, TrackingFloor, TuningResult
    from piezopreload.artifacts.validation import ValidationResult


def register_tune(sub: Any) -> None:
    """tune the PID (CasADi), validate it by Monte Carlo, write the gain set"""
    p = sub.add_parser(
        "tune",
        description=(
            "Tune Kc, Ti, Td, the derivative filter and the setpoint weight around the study's "
            "P-I-compensated rig (CasADi + IPOPT, several plant variants, Ms and noise bounds), compare "
            "with the study's [controller] gains and SIMC's, compute the minimum-time bound, validate the tuned gains "
            "on a Monte Carlo set of nonlinear rigs, and write a gain-set artifact: 'validated' if every "
            "plant met every criterion, else 'candidate'."))
    study_arguments(p)
    p.add_argument("--out", default="gains.json", metavar="gains.json",
                   help="the gain-set artifact (default gains.json)")
    monte_carlo_arguments(p)
    json_flag(p)
    p.set_defaults(run=_cmd_tune, show=_print_tune)


@dataclass(frozen=True)
class TuneWritten:
    """``tune``'s result: the tuning, the gain set its validation made (written to ``out``) and the time taken;
    ``to_dict()`` is what ``tune --json`` prints: the tuned row with the feedforward as the headline, the bounds,
    the comparison table and the verdict."""

    tuned: TuningResult
    gain_set: GainSet
    out: str
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        t, gain_set = self.tuned, self.gain_set
        row, start = t.row("tuned"), t.row("study")
        record = t.to_dict()
        return {
            "settling_s": row.settling_s, "settling_measured_s": row.settling_measured_s,
            "overshoot_N": row.overshoot_N, "tracking_rms_N": row.tracking_rms_N,
            "tracking_rms_after_change_N": row.tracking_rms_after_change_N,
            "study_tracking_rms_N": start.tracking_rms_N,
            "study_tracking_rms_after_change_N": start.tracking_rms_after_change_N,
            "lower_bound_settling_s": t.minimum_time.settling_s, "lower_bound_tracking_rms_N": t.tracking_floor.rms_N,
            "out": self.out, "status": gain_set.status, "content_sha256": gain_set.content_sha256,
            "gains": record["gains"], "simc": record["simc_baseline"], "form": t.solve.form,
            "tuning": {k: v for k, v in record["tuning"].items() if k != "spec"}, "table": record["table"],
            "active_bounds": record["active_bounds"], "published": record.get("published"),
            "minimum_time": record["minimum_time"], "tracking_improvement": t.tracking_improvement,
            "tracking_floor": record["tracking_floor"],
            "validation": None if gain_set.validation is None else gain_set.validation.to_dict(),
            "seconds": self.seconds,
            "gain_schedule": None if t.solve.schedule is None else t.solve.schedule.to_dict(),  # entries, choice
        }


def _cmd_tune(args: argparse.Namespace) -> TuneWritten:
    t0 = time.perf_counter()
    check_monte_carlo(args)
    study = study_of(args)
    feedforward = study.identify_feedforward(say)
    tuned = study.tune(feedforward, seed=args.seed, progress=say)
    gain_set = study.validate(tuned, feedforward, plants=args.plants, seed=args.seed, workers=args.workers,
                              scheduler=args.scheduler, progress=say).save(args.out)
    return TuneWritten(tuned, gain_set, str(args.out), time.perf_counter() - t0)


def _print_tune(w: TuneWritten) -> None:
    t = w.tuned
    g, b = t.gains, t.simc_baseline
    print(f"tuned gains ({t.solve.form}): Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s, "
          f"Tf {g.Tf_s:.4g} s, b {g.b:.3g} (LabVIEW: Ti {g.labview()['Ti_min']:.4g} min, "
          f"Td {g.labview()['Td_min']:.4g} min); Ms {t.solve.ms:.2f}")
    for bound in t.active_bounds:
        print(f"  on its bound: {bound.gain} at its {bound.side} bound ({bound.bound:.4g}): {bound.note}")
    print(f"SIMC baseline: Kc {b.Kc:.4g} V/N, Ti {b.Ti_s:.4g} s")
    print("the study's step and trajectory on the nominal rig:")
    print(f"  {'gains':8s}{'FF':>4s}{'settling':>10s}{'overshoot':>11s}{'track RMS':>11s}"
          f"{'RMS >0.1 s':>12s}{'peak V':>8s}")
    for r in t.table:
        print(f"  {r.gains:8s}{'yes' if r.feedforward else 'no':>4s}{fmt(r.settling_s, ' s'):>10s}"
              f"{r.overshoot_N:9.2f} N{r.tracking_rms_N:9.2f} N{r.tracking_rms_after_change_N:10.2f} N"
              f"{r.peak_command_V:8.1f}")
    _print_bounds(t.minimum_time, t.tracking_floor, t.row("tuned").settling_s)
    v = w.gain_set.validation
    if v is not None:
        print(f"validation on {v.n_plants} plants ({v.workers}, {v.seconds:.0f} s): "
              f"{'PASSED' if v.passed else 'FAILED'} ({len(v.failures)} failures)")
        print_validation_summary(v)
    print(f"wrote {w.out} ({w.gain_set.status}, content hash {(w.gain_set.content_sha256 or '')[:12]}...)")


def _print_bounds(mt: MinimumTimeBound, tf: TrackingFloor, settling_s: float | None) -> None:
    """The minimum-time bound beside the tuned settling, and the tracking floor beside the tuned RMS."""
    if mt.settling_s is None:
        print(f"minimum-time bound: none ({mt.reason})")
    elif settling_s is None:
        print(f"minimum-time bound: {quantity(mt.settling_s, 's')}; the tuned step does not settle in the band")
    else:
        print(f"minimum-time bound: {quantity(mt.settling_s, 's')} beside the tuned settling of the true force "
              f"{quantity(settling_s, 's')} ({number(mt.tuned_over_bound_ratio or 0.0)} times it)")
    ratio = "" if tf.tuned_over_floor_ratio is None else f"; tuned / floor = {tf.tuned_over_floor_ratio:.2f}"
    print(f"tracking RMS floor of any causal controller (slew {quantity(tf.rate_N_per_s, 'N/s')} at best): "
          f"{quantity(tf.rms_N, 'N')}{ratio}")


def register_validate(sub: Any) -> None:
    """validate a gain set again by Monte Carlo on the nonlinear rig"""
    p = sub.add_parser(
        "validate",
        description=(
            "Run a gain set's gains and feedforward on a new Monte Carlo set of nonlinear rigs drawn around "
            "the plant it names, against the criteria it names, and report worst case and percentiles. "
            "With --out, write the gain set with this validation: 'validated' only if every plant met "
            "every criterion."))
    p.add_argument("gains", metavar="gains.json", help="a gain-set artifact written by 'piezopreload tune'")
    monte_carlo_arguments(p)
    p.add_argument("--seed", type=int, help="seed of the Monte Carlo set (default: the gain set's)")
    p.add_argument("--out", metavar="gains.json", help="write the gain set with this validation here")
    json_flag(p)
    p.set_defaults(run=_cmd_validate, show=_print_validate)


@dataclass(frozen=True)
class ValidateWritten:
    """``validate``'s result: the gain set's file, the Monte Carlo set (plants, seed), the validation and the gain set
    it made (written to ``out`` where given)."""

    gains: str
    plants: int
    seed: int
    result: ValidationResult
    after: GainSet
    out: str | None

    def to_dict(self) -> dict[str, Any]:
        return {"gains": self.gains, "validated": self.result.passed, "status": self.after.status,
                "plants": self.plants, "seed": self.seed, **self.result.headline(),
                "validation": self.result.to_dict(), "out": self.out, "content_sha256": self.after.content_sha256}


def _cmd_validate(args: argparse.Namespace) -> ValidateWritten:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.tuning.verdict import validate_gain_set

    check_monte_carlo(args)
    before = GainSet.load(args.gains)
    plants = args.plants or (before.validation.n_plants if before.validation is not None else 200)
    seed = int(before.inputs.get("seed", 0)) if args.seed is None else args.seed
    say(f"validating {args.gains} on {plants} plants ...")
    try:
        after, result = validate_gain_set(before, n_plants=plants, seed=seed, workers=args.workers,
                                          scheduler=args.scheduler, bar=lambda i, n: say(f"  chunk {i}/{n}"),
                                          inputs={"revalidated_from_sha256": before.content_sha256})
    except InputError as exc:
        raise InputError(f"{args.gains}: {exc}") from exc
    if args.out is not None:
        after = after.save(args.out)
    return ValidateWritten(args.gains, plants, seed, result, after, args.out)


def _print_validate(w: ValidateWritten) -> None:
    v = w.result
    print(f"validation of {w.gains} on {w.plants} plants (seed {w.seed}, "
          f"{v.workers}, {v.seconds:.0f} s): {'PASSED' if v.passed else 'FAILED'} "
          f"({len(v.failures)} failures)")
    print_validation_summary(v)
    for f in v.failures[:10]:
        print(f"  plant {f.plant}: {f.metric} {fmt(f.value)} > {f.limit:g}")
    if w.out:
        print(f"wrote {w.out} ({w.after.status}, content hash {(w.after.content_sha256 or '')[:12]}...)")
