"""``ballscrew`` and ``design``: one double-nut screw checked, and the preload design study."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import (
    json_flag,
    nonnegative_float,
    say,
    study_arguments,
    study_of,
)
from piezopreload.core.errors import InputError

if TYPE_CHECKING:
    from piezopreload.design.study import DesignResult, ScrewCheck


# --------------------------------------------------------------------------------------
# ballscrew and design
# --------------------------------------------------------------------------------------
def register_ballscrew(sub: Any) -> None:
    """evaluate one double-nut ball screw: ratings, rigidity, load sharing, drag, life"""
    p = sub.add_parser(
        "ballscrew",
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
    p.add_argument("--speed-rpm", type=nonnegative_float, default=1000.0,
                   help="for life in hours and heat (default 1000)")
    p.add_argument("--c-dyn-N", type=float, help="catalogue dynamic load rating (default: estimated)")
    p.add_argument("--c0-N", type=float, help="catalogue static load rating (default: Hertz at 4,200 MPa)")
    json_flag(p)
    p.set_defaults(run=_cmd_ballscrew, show=_print_ballscrew)


def _cmd_ballscrew(args: argparse.Namespace) -> ScrewCheck:
    from piezopreload.design.study import check_screw
    from piezopreload.models.ballscrew import BallScrew

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


def _print_ballscrew(r: ScrewCheck) -> None:
    s = r.screw
    print(f"screw       {s.nominal_diameter_mm:g} x {s.lead_mm:g} mm, ball {s.ball_mm:g} mm, "
          f"{s.turns:g} turns x {s.balls_on_turn} balls, contact angle {s.contact_angle_deg:g} deg, "
          f"helix {math.degrees(s.helix_rad):.2f} deg")
    print(f"ratings     C_dyn {r.c_dyn_N:.0f} N ({r.c_dyn_source}), C_0 {r.c0_N:.0f} N ({r.c0_source})")
    print(f"preload     {r.preload_N:.0f} N = {r.preload_fraction_of_c_dyn:.3f} C_dyn; lift-off at "
          f"{r.lift_off_load_N:.0f} N axial")
    print(f"rigidity    {r.rigidity_N_per_um:.0f} N/um at {r.axial_load_N:g} N axial "
          f"({r.rigidity_no_load_N_per_um:.0f} N/um without load)")
    print(f"load        nuts carry {r.loaded_nut_N:.0f} / {r.unloaded_nut_N:.0f} N (HIWIN formula "
          f"{r.loaded_nut_hiwin_N:.0f} N), deflection {r.deflection_um:.2f} um"
          + ("; THE UNLOADED NUT HAS LIFTED OFF" if r.lifted_off else ""))
    print(f"contact     peak pressure {r.peak_pressure_MPa:.0f} MPa (limit 4200), static safety "
          f"{r.static_safety:.1f}")
    print(f"drag        {r.drag_torque_Nm:.3f} N m (K_p {r.drag_coefficient:.3f}), {r.drag_heat_W:.1f} W at "
          f"{r.speed_rpm:g} rpm")
    if r.life_h is not None:
        print(f"life        L10 {r.life_revolutions:.3g} rev = {r.life_h:.0f} h at {r.speed_rpm:g} rpm")


def register_design(sub: Any) -> None:
    """design the preloaded ball screw (CasADi): optimum, Pareto fronts, preload schedule"""
    from piezopreload.design.preload import OBJECTIVES, PARETO_PAIRS

    p = sub.add_parser(
        "design",
        description=(
            "Solve the study's ball-screw preload design (contact angle, ball size, conformity, turns and balls "
            "per turn, bolt preload and piezo preload range) for one objective, trace the Pareto fronts by the "
            "epsilon-constraint method, and plan the least-friction preload schedule for a load profile against "
            "the best constant preload. Infeasible requests name the constraints that cannot be met."))
    study_arguments(p, seed=False)
    p.add_argument("--objective", choices=[o.value for o in OBJECTIVES], help="default: the study's [design] objective")
    p.add_argument("--pareto", choices=PARETO_PAIRS, help="trace this front only (default: the study's list)")
    p.add_argument("--points", type=int, help="points per front (default: the study's, 50)")
    p.add_argument("--schedule", metavar="LOADS.csv",
                   help="load profile: time_s, axial_load_N[, speed_rpm] (default: the study's, or a machining cycle)")
    p.add_argument("--out", default="piezopreload-out/design.json", metavar="design.json",
                   help="the design artifact; each front's CSV is written beside it "
                        "(default piezopreload-out/design.json)")
    json_flag(p)
    p.set_defaults(run=_cmd_design, show=_print_design)


@dataclass(frozen=True)
class DesignWritten:
    """``design``'s result: the study it solved, the design and the files written (the artifact, each front's CSV);
    ``to_dict()`` is what ``design --json`` prints: the optimum, each front's span, the schedule's numbers."""

    study_path: str
    study_sha256: str
    result: DesignResult
    written: tuple[Path, ...]

    def to_dict(self) -> dict[str, Any]:
        o = self.result.optimum
        fronts = [{"pair": f.pair, "points": len(f.points), "solve_s": f.solve_s, "nlp_solves": f.nlp_solves,
                   "stiffness_N_per_um": [float(f.x.min()), float(f.x.max())],
                   f.y_name: [float(f.y.min()), float(f.y.max())]} for f in self.result.fronts]
        return {"study": {"path": self.study_path, "sha256": self.study_sha256}, "objective": o.objective,
                "optimum": o.point.to_dict(), "binding": o.binding, "integer_candidates": o.tried,
                "solve_s": o.solve_s, "fronts": fronts, "schedule": self.result.schedule.summary().to_dict(),
                "written": [str(p) for p in self.written]}


def _cmd_design(args: argparse.Namespace) -> DesignWritten:
    if args.points is not None and not 2 <= args.points <= 500:
        raise InputError(f"--points: must be in 2..500, got {args.points}")
    study = study_of(args)
    result = study.design(objective=args.objective, pareto=None if args.pareto is None else [args.pareto],
                          points=args.points, schedule=args.schedule, progress=None if args.json else say)
    written = result.save(args.out, {"study": study.path, "study_sha256": study.sha256})
    return DesignWritten(study.path, study.sha256, result, tuple(written))


def _print_design(w: DesignWritten) -> None:
    o, s = w.result.optimum, w.result.schedule
    p = o.point
    print(f"study       {w.study_path}")
    print(f"optimum     objective {o.objective}: {p.turns:.0f} turns x {p.balls_per_turn:.0f} balls of "
          f"{p.ball_mm:.3f} mm, contact angle {p.contact_angle_deg:.1f} deg, conformity {p.conformity:.3f}")
    print(f"  preload   bolts {p.bolt_preload_N:.0f} N, stacks up to {p.max_preload_N:.0f} N; per duty case "
          + ", ".join(f"{f:.0f}" for f in p.case_preload_N) + " N")
    print(f"  achieves  rigidity {p.stiffness_N_per_um:.0f} N/um (least over the duty cases; "
          f"{p.rigidity_at_max_preload_N_per_um:.0f} at F_hi), mean drag {p.mean_drag_torque_Nm:.3f} N m, "
          f"life {p.life_h:.0f} h, first axial mode >= {p.frequency_min_Hz:.0f} Hz")
    print(f"  ratings   C_dyn {p.c_dyn_N:.0f} N (estimate), C_0 {p.c0_N:.0f} N; peak pressure "
          f"{p.peak_pressure_MPa:.0f} MPa; stack stroke used {p.stack_stroke_used_um:.1f} um")
    print(f"  binding   {', '.join(o.binding) or 'none'}")
    for f in w.result.fronts:
        print(f"front       {f.pair}: {len(f.points)} points, rigidity {float(f.x.min()):.0f}-"
              f"{float(f.x.max()):.0f} N/um, {f.y_name} {float(f.y.min()):.4g}-{float(f.y.max()):.4g}, "
              f"{f.solve_s:.2f} s")
    print(f"schedule    {s.preload_N.size} samples: preload {float(s.preload_N.min()):.0f}-"
          f"{float(s.preload_N.max()):.0f} N against a best constant {s.constant_preload_N:.0f} N; friction "
          f"{s.friction_energy_J:.4g} against {s.constant_friction_energy_J:.4g} {s.energy_units} "
          f"({s.saving_fraction:.0%} saved)")
    for path in w.written:
        print(f"wrote       {path}")
