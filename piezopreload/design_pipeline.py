"""The design half of a study: one screw evaluated, the design optimum, fronts and schedule.

``piezopreload ballscrew`` evaluates a given (catalogue) screw; ``piezopreload design`` reads
the study's [ballscrew], [feed_drive], [duty], [design] and [schedule] tables, solves the
design NLP, traces the Pareto fronts, plans the preload schedule for the load profile, and
writes a ``design`` artifact with a CSV per front beside it.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.core.artifacts import atomic_write_text, write_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.tables import read_table
from piezopreload.design.preload import (
    OBJECTIVES,
    PARETO_PAIRS,
    DesignInfeasible,
    DesignNLP,
    DesignSpec,
    optimise,
    pareto_front,
)
from piezopreload.design.schedule import LoadProfile, ScheduleSpec, example_profile, schedule_preload
from piezopreload.models.ballscrew import BallScrew, DutyCase, hiwin_loaded_nut_force, lift_off_load_N
from piezopreload.models.feed_drive import FeedDrive, PiezoPreload
from piezopreload.study import StudyText, read_study_text

__all__ = ["evaluate_ballscrew", "design_spec_from_study", "design_study"]


def evaluate_ballscrew(screw: BallScrew, preload_N: float | None, preload_fraction: float | None,
                       axial_load_N: float, speed_rpm: float) -> dict[str, Any]:
    """Everything a user checks of one screw at one preload and one axial load."""
    c_dyn = screw.dynamic_rating_N
    if preload_N is None:
        fraction = 0.1 if preload_fraction is None else preload_fraction
        if not 0 < fraction <= 0.2:
            raise InputError(f"--preload-fraction: must be in (0, 0.2] of C_dyn, got {fraction}")
        preload_N = fraction * c_dyn
    if not (math.isfinite(preload_N) and preload_N > 0):
        raise InputError(f"--preload-N: must be a finite number > 0, got {preload_N}")
    if not math.isfinite(axial_load_N):
        raise InputError(f"--axial-load-N: must be finite, got {axial_load_N}")
    loads = screw.nut_loads(preload_N, axial_load_N)
    contact = screw.contact(loads.loaded_nut_N)
    life = screw.life(preload_N, [DutyCase(axial_load_N, speed_rpm, 1.0)]) if speed_rpm > 0 else None
    return {
        "screw": {"nominal_diameter_mm": screw.nominal_diameter_mm, "lead_mm": screw.lead_mm, "ball_mm": screw.ball_mm,
                  "turns": screw.turns, "contact_angle_deg": screw.contact_angle_deg,
                  "conformity_screw": screw.conformity_screw, "conformity_nut": screw.conformity_nut,
                  "balls_per_turn": screw.balls_on_turn, "balls_per_nut": screw.balls_per_nut,
                  "helix_angle_deg": math.degrees(screw.helix_rad), "root_diameter_mm": screw.root_diameter_mm},
        "c_dyn_N": c_dyn, "c_dyn_source": "catalogue" if screw.c_dyn_N is not None else "estimate",
        "c0_N": screw.static_rating_N, "c0_source": "catalogue" if screw.c0_N is not None else "Hertz at 4200 MPa",
        "preload_N": float(preload_N), "preload_fraction_of_c_dyn": float(preload_N / c_dyn),
        "axial_load_N": float(axial_load_N),
        "rigidity_N_per_um": float(loads.rigidity_N_per_um),
        "rigidity_no_load_N_per_um": float(screw.rigidity_N_per_um(preload_N)),
        "contact_rigidity_N_per_um": float(loads.contact_stiffness_N_per_um),
        "deflection_um": float(loads.deflection_um),
        "loaded_nut_N": float(loads.loaded_nut_N), "unloaded_nut_N": float(loads.unloaded_nut_N),
        "loaded_nut_hiwin_N": float(hiwin_loaded_nut_force(preload_N, axial_load_N)),
        "lift_off_load_N": float(lift_off_load_N(preload_N)), "lifted_off": bool(loads.lifted_off),
        "peak_pressure_MPa": float(contact.peak_pressure_MPa), "ball_load_N": float(contact.ball_load_N),
        "static_safety": float(screw.static_rating_N / max(float(loads.loaded_nut_N), 1e-12)),
        "drag_torque_Nm": float(screw.drag_torque_Nm(preload_N)), "drag_coefficient": screw.drag_K,
        "drag_heat_W": float(screw.drag_torque_Nm(preload_N) * speed_rpm * 2 * math.pi / 60),
        "speed_rpm": float(speed_rpm),
        "life_revolutions": None if life is None else life.revolutions,
        "life_h": None if life is None else life.hours,
    }


def _pair_list(values: list[float], n: int, key: str, st: StudyText) -> list[float]:
    if len(values) != n:
        raise st.fail(key, f"must have {n} values (low, high), got {values!r}")
    return [float(v) for v in values]


def design_spec_from_study(st: StudyText) -> tuple[DesignSpec, dict[str, Any]]:
    """The study's design tables as a :class:`DesignSpec` and the run's options."""
    data = st.data
    if "ballscrew" not in data:
        raise InputError(f"{st.path}: the study has no [ballscrew] table; the design needs the screw's nominal "
                         f"diameter and lead (see studies/paper2021.toml)")
    b, fd, duty, d = data["ballscrew"], data.get("feed_drive", {}), data.get("duty", {}), data.get("design", {})
    kwargs: dict[str, Any] = {}
    for key in ("nominal_diameter_mm", "lead_mm", "load_sharing"):
        if key in b:
            kwargs[key] = float(b[key])
    for key in ("contact_angle_deg", "ball_mm", "conformity"):
        if key in b:
            kwargs[key] = tuple(_pair_list(b[key], 2, f"ballscrew.{key}", st))
    if "turns" in b:
        lo, hi = _pair_list(b["turns"], 2, "ballscrew.turns", st)
        if lo != int(lo) or hi != int(hi):
            raise st.fail("ballscrew.turns", f"must be two integers, got {b['turns']!r}")
        kwargs["turns"] = (int(lo), int(hi))
    if fd:
        try:
            defaults = DesignSpec().feed_drive
            kwargs["feed_drive"] = FeedDrive(
                table_mass_kg=float(fd.get("table_mass_kg", defaults.table_mass_kg)),
                screw_length_mm=float(fd.get("screw_length_mm", defaults.screw_length_mm)),
                bearing_stiffness_N_per_um=float(fd.get("bearing_stiffness_N_per_um", defaults.bearing_stiffness_N_per_um)),
                travel_mm=tuple(_pair_list(fd["travel_mm"], 2, "feed_drive.travel_mm", st)) if "travel_mm" in fd
                else defaults.travel_mm,
                mounting=fd.get("mounting", defaults.mounting))
        except ValueError as exc:
            raise st.fail("feed_drive", f"is not valid: {exc}") from None
    if duty:
        lists = [duty.get(k) for k in ("axial_load_N", "speed_rpm", "time_share")]
        if any(v is None for v in lists) or len({len(v) for v in lists}) != 1 or not lists[0]:
            raise st.fail("duty", "needs axial_load_N, speed_rpm and time_share as lists of equal, non-zero length")
        try:
            kwargs["duty"] = tuple(DutyCase(float(a), float(n), float(s)) for a, n, s in zip(*lists))
        except ValueError as exc:
            raise st.fail("duty", f"is not valid: {exc}") from None
    names = {f.name for f in fields(DesignSpec)}
    for key, value in d.items():
        if key in names:
            kwargs[key] = float(value)
    try:
        kwargs["actuator"] = PiezoPreload(drive_V=float(d.get("stack_drive_V", 100.0)),
                                          amp_current_limit_A=float(d.get("amp_current_limit_A", 0.1)))
        spec = DesignSpec(**kwargs)
    except ValueError as exc:
        table = "design" if "DesignSpec" in str(exc) or "PiezoPreload" in str(exc) else "ballscrew"
        raise st.fail(table, f"is not valid: {exc}") from None
    objective = d.get("objective", "stiffness")
    if objective not in OBJECTIVES:
        raise st.fail("design.objective", f"must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    pareto = d.get("pareto", list(PARETO_PAIRS))
    for pair in pareto:
        if pair not in PARETO_PAIRS:
            raise st.fail("design.pareto", f"has {pair!r}; expected some of {', '.join(PARETO_PAIRS)}")
    points = int(d.get("pareto_points", 50))
    if not 2 <= points <= 500:
        raise st.fail("design.pareto_points", f"must be in 2..500, got {points}")
    sched = data.get("schedule", {})
    options = {"objective": objective, "pareto": list(pareto), "points": points, "schedule": dict(sched)}
    return spec, options


def _read_profile(path: str | Path) -> LoadProfile:
    cols = read_table(path, ("time_s", "axial_load_N"), ("speed_rpm",), increasing="time_s")
    try:
        return LoadProfile(cols["time_s"], cols["axial_load_N"], cols.get("speed_rpm"))
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


def _front_csv(front: Any) -> str:
    buf = io.StringIO()
    buf.write(f"# Pareto front {front.pair}: {front.x_name} swept, {front.y_name} optimised\n")
    cols = ["stiffness_N_per_um", "max_preload_N", "mean_drag_torque_Nm", "life_h", "contact_angle_deg", "ball_mm",
            "conformity", "turns", "balls_per_turn", "bolt_preload_N"]
    buf.write(",".join(cols) + "\n")
    for p in front.points:
        d = p.as_dict()
        buf.write(",".join(f"{d[c]:.6g}" for c in cols) + "\n")
    return buf.getvalue()


def design_study(path: str | Path, objective: str | None = None, pareto: list[str] | None = None,
                 points: int | None = None, schedule_csv: str | None = None, out: str | Path | None = None,
                 progress: Callable[[str], None] | None = None,
                 bar: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Optimum, fronts and schedule of a study's design; writes ``out`` and the fronts' CSVs.

    ``progress`` gets messages; ``bar``, if given, gets (points done, points in all) over the fronts.
    """
    st = read_study_text(path)
    spec, options = design_spec_from_study(st)
    objective = objective or options["objective"]
    pairs = options["pareto"] if pareto is None else pareto
    n_points = options["points"] if points is None else points
    say = progress or (lambda _msg: None)
    nlp = DesignNLP(spec)
    try:
        result = optimise(spec, objective, nlp)
    except DesignInfeasible as exc:
        raise InputError(f"{st.path}: {exc}") from None
    p = result.point
    say(f"optimum ({objective}): {p.turns:.0f} turns x {p.balls_per_turn:.0f} balls of {p.ball_mm:.3f} mm, "
        f"contact angle {p.contact_angle_deg:.1f} deg, preload {p.bolt_preload_N:.0f}-{p.max_preload_N:.0f} N")
    fronts = []
    for j, pair in enumerate(pairs):
        if bar is not None:
            report = lambda i, n, j=j: bar(j * n + i, len(pairs) * n)  # noqa: E731
        else:
            report = lambda i, n, pair=pair: say(f"front {pair}: {i}/{n}") if i in (n // 2, n) else None  # noqa: E731
        fronts.append(pareto_front(spec, pair, n_points, nlp, progress=report))

    # ---- the schedule on the optimum's screw -------------------------------------------------
    sched_opts = options["schedule"]
    profile_path = schedule_csv or sched_opts.get("profile")
    if profile_path is not None and schedule_csv is None:
        profile_path = str(Path(st.path).parent / profile_path)
    profile = _read_profile(profile_path) if profile_path else example_profile()
    screw = spec.screw(p)
    max_preload = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    slew = spec.actuator.preload_slew_N_per_s(screw, p.bolt_preload_N, p.bolt_preload_N)
    try:
        sspec = ScheduleSpec(bolt_preload_N=p.bolt_preload_N, max_preload_N=max_preload, slew_N_per_s=slew,
                             stiffness_min_N_per_um=float(sched_opts.get("stiffness_min_N_per_um", 0.0)),
                             deflection_max_um=float(sched_opts.get("deflection_max_um", math.inf)),
                             lift_off_margin=float(sched_opts.get("lift_off_margin", spec.lift_off_margin)))
        schedule = schedule_preload(screw, profile, sspec)
    except ValueError as exc:
        raise InputError(f"{profile_path or 'the example load profile'}: {exc}") from None
    say(f"schedule: {schedule.saving_fraction:.0%} less friction energy than the best constant preload "
        f"({schedule.constant_preload_N:.0f} N)")
    positions = np.linspace(*spec.feed_drive.travel_mm, 41)
    freq = {
        "position_mm": positions.tolist(),
        "bolt_preload_Hz": spec.feed_drive.natural_frequency_Hz(screw, p.bolt_preload_N, positions).tolist(),
        "max_preload_Hz": spec.feed_drive.natural_frequency_Hz(screw, p.max_preload_N, positions).tolist(),
    }
    preloads = np.linspace(0.25 * p.bolt_preload_N, 1.5 * p.max_preload_N, 121)
    curve = {
        "preload_N": preloads.tolist(),
        "rigidity_N_per_um": np.asarray(screw.rigidity_N_per_um(preloads), float).tolist(),
        "drag_torque_Nm": np.asarray(screw.drag_torque_Nm(preloads), float).tolist(),
        "cases": [{"axial_load_N": case.axial_load_N, "preload_N": float(f_case),
                   "rigidity_N_per_um": float(screw.rigidity_N_per_um(f_case, case.axial_load_N))}
                  for case, f_case in zip(spec.duty, p.case_preload_N)],
        "bolt_preload_N": p.bolt_preload_N, "max_preload_N": p.max_preload_N,
    }
    body = {
        "preload_curve": curve,
        "inputs": {"study": st.path, "study_sha256": st.sha256, "profile": str(profile_path) if profile_path else "example"},
        "units": {"force": "N", "length": "mm", "stiffness": "N/um", "torque": "N m", "life": "h", "energy": schedule.energy_units},
        "optimum": result.as_dict(),
        "fronts": [f.as_dict() for f in fronts],
        "schedule": {**schedule.as_dict(), "time_s": profile.time_s.tolist(), "axial_load_N": profile.axial_load_N.tolist(),
                     "preload_N": schedule.preload_N.tolist(), "max_preload_N": max_preload, "slew_N_per_s": slew},
        "natural_frequency": freq,
    }
    written: list[str] = []
    if out is not None:
        out = Path(out)
        write_artifact(out, "design", body)
        written.append(str(out))
        for front in fronts:
            csv = out.with_name(f"{out.stem}.pareto-{front.pair.replace(':', '-')}.csv")
            atomic_write_text(csv, _front_csv(front))
            written.append(str(csv))
    return {
        "study": {"path": st.path, "sha256": st.sha256},
        "objective": objective,
        "optimum": result.point.as_dict(),
        "binding": result.binding,
        "integer_candidates": result.tried,
        "solve_s": result.solve_s,
        "fronts": [{"pair": f.pair, "points": len(f.points), "solve_s": f.solve_s, "nlp_solves": f.nlp_solves,
                    "stiffness_N_per_um": [float(f.x.min()), float(f.x.max())],
                    f.y_name: [float(f.y.min()), float(f.y.max())]} for f in fronts],
        "schedule": {**schedule.as_dict(), "max_preload_N": max_preload, "slew_N_per_s": slew},
        "written": written,
    }
