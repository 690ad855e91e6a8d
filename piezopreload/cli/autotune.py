"""``autotune``: a PI or PID for the user's own loop (a transfer function, a measured frequency or step response)."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import json_flag, nonnegative_float, say
from piezopreload.core.errors import InputError

if TYPE_CHECKING:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.tuning.autotune_result import AutotuneResult
    from piezopreload.tuning.plantfit import FittedPlant


def _coefficients(text: str, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"--tf: the {what} '{text}' is not comma-separated numbers "
                         "(example: --tf 30/0.005,1)") from None
    return values


def _positive(text: str) -> float:
    value = nonnegative_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _grid(text: str) -> Any:
    """``--grid LO:HI:N``: ``N`` log-spaced frequencies from ``LO`` to ``HI`` rad/s."""
    import numpy as np

    parts = text.split(":")
    try:
        lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
    except (ValueError, IndexError):
        raise argparse.ArgumentTypeError(f"'{text}' is not LO:HI:N (example: 0.01:100:400, rad/s)") from None
    if len(parts) != 3 or not (0 < lo < hi < float("inf")) or n < 8:
        raise argparse.ArgumentTypeError(f"'{text}' needs 0 < LO < HI (rad/s) and N >= 8 points")
    return np.logspace(np.log10(lo), np.log10(hi), n)


def register_autotune(sub: Any) -> None:
    """tune a PI or PID for your own loop under Ms, Mt and Mks bounds"""
    p = sub.add_parser(
        "autotune",
        description=(
            "Tune a PI, or a PID with its derivative filter, for a linear plant given as a transfer function, a "
            "measured frequency response or a measured step response (fitted first or second order with dead time), "
            "with an exact input delay: the largest integral gain (IE) or the least IAE of a load step at the plant "
            "input, subject to abs(S) <= Ms, abs(T) <= Mt, abs(KS) <= Mks on a frequency grid chosen from the plant "
            "and a stable closed loop (analytic starts from the stabilising set, then an SQP with exact derivatives). "
            "The bounds hold on the continuous loop, or with --loop sampled on the loop as it runs at --Ts (zero-order "
            "hold, the controller step). With --u-min/--u-max and no --Mks, abs(KS) is bounded by the actuator's span "
            "per measured unit (a default the result names). With --out, write a gain set 'piezopreload export' "
            "writes for LabVIEW, PLCs and C."),
        epilog=(
            "--tf NUM/DEN: coefficients in descending powers of s (of z with --dt), e.g. --tf 30/0.005,1 for "
            "30/(0.005 s + 1). --frd: a CSV with omega_rad_per_s (or frequency_Hz) and magnitude, phase_deg (or real, "
            "imag). --step: a CSV of time_s, the input (input_* or voltage_*) and the output."))
    plant = p.add_mutually_exclusive_group(required=True)
    plant.add_argument("--tf", metavar="NUM/DEN", help="the plant's transfer function")
    plant.add_argument("--frd", metavar="FILE.csv", help="a measured frequency response")
    plant.add_argument("--step", metavar="FILE.csv", help="a measured step response, fitted with dead time")
    p.add_argument("--dt", type=_positive, metavar="S", help="--tf is discrete with this sample period (s)")
    p.add_argument("--delay-s", type=nonnegative_float, default=0.0, metavar="L", help="input delay in s (default 0)")
    p.add_argument("--Ms", type=float, required=True,
                   help="the largest sensitivity magnitude, abs(S) (> 1; 1.4 is common)")
    p.add_argument("--Mt", type=float, help="the largest complementary sensitivity magnitude, abs(T)")
    p.add_argument("--Mks", type=float,
                   help="the largest abs(KS), the controller's output per unit of measurement noise")
    p.add_argument("--metric", choices=("IE", "IAE"), default="IE", help="IE: largest ki (default); IAE: least IAE")
    p.add_argument("--form", choices=("PI", "PID"), default="PID", help="the controller (default PID)")
    p.add_argument("--filter-order", choices=("1", "2", "auto"), default=None,
                   help="a PID's filter: 1 on the derivative (default, the form the exports run), 2 on the whole "
                        "controller, auto: the one of larger ki")
    p.add_argument("--Ts", type=_positive, metavar="S",
                   help="the controller's sample period (the filter's floor, the gain set's period)")
    p.add_argument("--loop", choices=("continuous", "sampled"),
                   help="the loop the bounds hold on: continuous (default), or sampled at --Ts as it runs")
    p.add_argument("--grid", type=_grid, metavar="LO:HI:N",
                   help="the design grid: N log-spaced frequencies from LO to HI rad/s (default: from the plant)")
    p.add_argument("--order", type=int, choices=(1, 2), help="--step: the fitted model's order (default: the better)")
    p.add_argument("--out", metavar="gains.json", help="write the gain set (needs --Ts or a discrete plant, --u-min, "
                                                        "--u-max)")
    p.add_argument("--u-min", type=float, metavar="V",
                   help="the controller's lowest output (the gain set's; with --u-max the default Mks)")
    p.add_argument("--u-max", type=float, metavar="V",
                   help="the controller's highest output (the gain set's; with --u-min the default Mks)")
    json_flag(p)
    p.set_defaults(run=_cmd_autotune, show=_print_autotune)


def _filter_order(text: str | None, form: str) -> int | str | None:
    """``--filter-order``: None (the form's default), 1, 2 or "auto"; a PI has none."""
    if text is None:
        return None
    if form == "PI":
        raise InputError("--filter-order belongs to a PID (--form PID); a PI has no filter")
    return text if text == "auto" else int(text)


def _plant(args: argparse.Namespace) -> tuple[Any, float, FittedPlant | None]:
    """The plant, its delay and (for --step) the fit's record."""
    import control

    from piezopreload.tuning.plantfit import fit_plant, read_frequency_response

    if args.tf is not None:
        num, sep, den = args.tf.partition("/")
        if not sep:
            raise InputError(f"--tf: '{args.tf}' is not NUM/DEN (example: --tf 30/0.005,1)")
        n, d = _coefficients(num, "numerator"), _coefficients(den, "denominator")
        for what, c in (("numerator", n), ("denominator", d)):
            if not all(map(math.isfinite, c)):
                raise InputError(f"--tf: the {what} has a coefficient that is not finite")
            if not any(c):
                given = (num if what == "numerator" else den)[:40]
                raise InputError(f"--tf: the {what} is zero ('{given}'); expected a nonzero polynomial (example: "
                                 "--tf 30/0.005,1)")
        return control.tf(n, d, 0 if args.dt is None else args.dt), args.delay_s, None
    if args.dt is not None:
        raise InputError("--dt belongs to --tf (a discrete transfer function); a measured response carries its own")
    if args.frd is not None:
        return read_frequency_response(args.frd), args.delay_s, None
    fit = fit_plant(args.step, order=args.order or "auto")
    say(repr(fit))
    return fit.transfer_function(), fit.delay_s + args.delay_s, fit


@dataclass(frozen=True)
class Autotuned:
    """``autotune``'s result: the tuning, the fit of a measured step response (None: the plant was given), and the gain
    set written with where (None: none); ``--json`` prints the tuning's ``to_dict()`` with the rest beside it."""

    result: AutotuneResult
    fit: FittedPlant | None
    gain_set: GainSet | None = None
    out: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {**self.result.to_dict(), "fit": None if self.fit is None else self.fit.to_dict(),
                               "out": self.out}
        if self.gain_set is not None:
            record = self.gain_set.tuning or {}  # an autotuned set always carries its tuning record
            out.update(status=self.gain_set.status, content_sha256=self.gain_set.content_sha256,
                       status_reason=record.get("status_reason"), sampled_loop_check=record.get("sampled_loop_check"))
        return out


def _cmd_autotune(args: argparse.Namespace) -> Autotuned:
    from piezopreload.tuning.autotune import autotune

    if args.order is not None and args.step is None:
        raise InputError("--order belongs to --step (the fitted model's order)")
    if args.out is not None and (args.u_min is None or args.u_max is None):
        raise InputError("--out writes a gain set, which needs the controller's output range: give --u-min and --u-max")
    if (args.u_min is None) != (args.u_max is None):
        raise InputError("--u-min and --u-max go together (the actuator's range); give both or neither")
    if args.loop == "sampled" and args.Ts is None and args.dt is None:
        raise InputError("--loop sampled holds the bounds on the loop as it runs at a sample period: give --Ts")
    if args.out is not None and args.Ts is None and args.dt is None:
        raise InputError("--out writes a gain set, which runs at a sample period: give --Ts (or a discrete --tf with "
                         "--dt)")
    plant, delay, fit = _plant(args)
    result = autotune(plant, Ms=args.Ms, Mt=args.Mt, Mks=args.Mks, metric=args.metric, form=args.form, Ts=args.Ts,
                      loop=args.loop, u_min=args.u_min, u_max=args.u_max, delay_s=delay, w=args.grid,
                      filter_order=_filter_order(args.filter_order, args.form))
    if args.out is None:
        return Autotuned(result, fit)
    return Autotuned(result, fit, result.to_gain_set(name="autotune").save(args.out), args.out)


def _print_autotune(tuned: Autotuned) -> None:
    s = tuned.to_dict()
    mg, b = s["margins"], s["bounds"]
    kind = s["form"] if s["form"] == "PI" or s["kd"] == 0 else f"PID, filter order {s['filter_order']}"
    at = "" if s["Ts_s"] is None else f", runs at Ts {s['Ts_s']:g} s"
    print(f"{kind}{at}: kp {s['kp']:.5g}, ki {s['ki']:.5g}, kd {s['kd']:.5g}, Tf {s['Tf_s']:.5g} s "
          "(C = (kp + ki/s + kd s) F(s))")
    if "gains" in s:
        g = s["gains"]
        print(f"ideal/ISA: Kc {g['Kc']:.5g}, Ti {g['Ti_s']:.5g} s, Td {g['Td_s']:.5g} s, Tf {g['Tf_s']:.5g} s"
              + (" (the measurement through the second-order filter)" if g.get("filter_order") == 2 else ""))
    print(f"the bounds hold on {s['bounds_hold_on']}")
    what = f"IE {s['ie']:.5g}" + ("" if s["iae"] is None else f", IAE {s['iae']:.5g}")
    print("unit load step at the plant input: "
          f"{what} (tuned for the {'largest ki' if s['metric'] == 'IE' else 'least IAE'})")
    bounds = {k: f" (bound {b[k]:g}{', a default' if k in s['defaults'] else ''})" for k in b}
    print("reached: " + ", ".join(f"{k} {mg[k]:.4g}{bounds.get(k, '')}" for k in ("Ms", "Mt", "Mks")))
    gm = "inf" if mg["gain_margin"] is None else f"{mg['gain_margin']:.3g}"
    pm = "-" if mg["phase_margin_deg"] is None else f"{mg['phase_margin_deg']:.1f} deg"
    dm = "-" if mg["delay_margin_s"] is None else f"{mg['delay_margin_s']:.4g} s"
    print(f"gain margin {gm}, phase margin {pm}, delay margin {dm}; "
          f"closed loop {'stable' if s['stable'] else 'UNSTABLE'}")
    for name, d in s["defaults"].items():
        print(f"  default {name} {d['value']:.4g}: {d['reason']}")
    for bound in s["active_bounds"]:
        print(f"  on its bound: {bound['gain']} at its {bound['side']} bound ({bound['bound']:.4g}): {bound['note']}")
    for sentence in s["leans_on"]:
        print(f"  leans on a bound you did not set: {sentence}")
    for name, over in s["over_by"].items():
        print(f"  {name} is over its bound by {over:.3%} on the check grid (the refinement aims at 0.01 %, the "
              "tolerance is 0.5 %)")
    print(f"{len(s['starts'])} starts, {s['iterations']} {s['solver']} iterations, {s['refinements']} grid "
          f"refinements, {s['seconds'] * 1e3:.0f} ms")
    if s["out"]:
        c = s["sampled_loop_check"]
        print(f"wrote {s['out']} ({s['status']}, content hash {s['content_sha256'][:12]}...): "
              f"at Ts {c['sample_period_s']:g} s "
              + ", ".join(f"{k} {v:.4g}" for k, v in c["achieved"].items())
              + f", {'stable' if c['stable'] else 'UNSTABLE'}; {s['status_reason']}")
