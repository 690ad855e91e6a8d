"""The design study of a feed drive: the preload design's optimum, its Pareto fronts, the preload schedule and curves.

:func:`design_study` solves the design NLP (:mod:`piezopreload.design.preload`) for one
objective, traces the requested epsilon-constraint fronts, plans the least-friction preload
schedule (:mod:`piezopreload.design.schedule`) for a load profile on the optimum's screw, and
evaluates the curves a designer reads: rigidity and drag torque against preload, and the
first axial natural frequency along the travel at the bolts' preload and at full stack drive
(``docs/models.md``, the ball screw and the feed drive). :func:`check_screw` evaluates one
given (catalogue) screw. Results are objects with ``to_dict()`` (and ``plot()``).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.design import DesignRecord, DutyCasePoint, FrequencyCurve, Front, Optimum, PreloadCurve
from piezopreload.artifacts.schedule import LoadProfile, PreloadSchedule, ScheduleSpec
from piezopreload.core.artifacts import atomic_write_text
from piezopreload.core.errors import InputError
from piezopreload.core.progress import Bar, ProgressLike, say_of
from piezopreload.core.quantities import number, quantity
from piezopreload.core.tables import read_table
from piezopreload.design.preload import (
    OBJECTIVES,
    DesignNLP,
    DesignOptimum,
    DesignPoint,
    DesignSpec,
    HeatSpec,
    ParetoFront,
    RobustCost,
    optimise,
    pareto_front,
    robust_cost,
)
from piezopreload.design.schedule import example_profile, schedule_preload
from piezopreload.models.ballscrew import BallScrew, DutyCase, hiwin_loaded_nut_force, lift_off_load_N
from piezopreload.models.feed_drive import FeedDrive, PiezoPreload

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["DesignResult", "design_study", "plan_schedule", "read_profile", "check_screw", "ScrewCheck",
           "FRONT_COLUMNS", "design_spec_from_tables"]

#: the columns of a front's CSV
FRONT_COLUMNS = ("stiffness_N_per_um", "max_preload_N", "mean_drag_torque_Nm", "life_h", "contact_angle_deg", "ball_mm",
                 "conformity", "turns", "balls_per_turn", "bolt_preload_N")


def read_profile(path: str | Path) -> LoadProfile:
    """A load profile from a CSV of ``time_s,axial_load_N[,speed_rpm]``; errors name the file and line."""
    cols = read_table(path, ("time_s", "axial_load_N"), ("speed_rpm",), increasing="time_s")
    try:
        return LoadProfile(cols["time_s"], cols["axial_load_N"], cols.get("speed_rpm"))
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


@dataclass(frozen=True, eq=False)
class DesignResult:
    """A design study: ``optimum`` (a :class:`DesignOptimum`), ``fronts``, ``schedule`` and the curves.

    Parameters
    ----------
    spec : DesignSpec
        What was designed: the screw's ranges, the duty, the stacks, the objective.
    optimum : DesignOptimum
        The optimum: its point, its objective, the constraints that bind.
    fronts : list of ParetoFront
        The Pareto fronts of the study's pairs of objectives.
    schedule : PreloadSchedule
        The preload schedule of the machining cycle on the optimum's screw.
    profile : str
        The load profile's file, or ``example``.
    max_preload_N : float
        The stacks' reach on the optimum's screw: the top of its preload range (N).
    slew_N_per_s : float
        The fastest the stacks change the preload, at the bolts' preload (N/s).
    preload_curve : PreloadCurve
        Rigidity and drag torque of the optimum's double nut against the preload.
    natural_frequency : FrequencyCurve
        The first axial natural frequency along the travel.
    robust_cost : RobustCost or None
        Where the spec is robust (``DesignSpec.worst``): what the design gives up against the nominal design.
    """

    spec: DesignSpec
    optimum: DesignOptimum
    fronts: list[ParetoFront]
    schedule: PreloadSchedule
    profile: str  # the load profile's file, or "example"
    max_preload_N: float  # the stacks' reach on the optimum's screw
    slew_N_per_s: float
    preload_curve: PreloadCurve
    natural_frequency: FrequencyCurve
    robust_cost: RobustCost | None = None

    @property
    def point(self) -> Any:
        """The optimum's design point: the screw's geometry, preload, stiffness, drag and life."""
        return self.optimum.point

    def __repr__(self) -> str:
        p = self.optimum.point
        return (f"DesignResult({self.optimum.objective} optimum: {p.turns:.0f} turns x {p.balls_per_turn:.0f} balls of "
                f"{p.ball_mm:.3f} mm at {p.contact_angle_deg:.1f} deg, rigidity {p.stiffness_N_per_um:,.0f} N/um; "
                f"{len(self.fronts)} Pareto front(s); schedule saves {100 * self.schedule.saving_fraction:.0f} % of "
                f"the best constant preload's friction)")

    def _repr_html_(self) -> str:
        p = self.optimum.point
        rows = (("objective", self.optimum.objective), ("contact angle (deg)", f"{p.contact_angle_deg:.3g}"),
                ("balls", f"{p.turns:.0f} turns x {p.balls_per_turn:.0f} of {p.ball_mm:.4g} mm"),
                ("bolt / maximum preload (N)", f"{p.bolt_preload_N:,.0f} / {p.max_preload_N:,.0f}"),
                ("least rigidity (N/um)", f"{p.stiffness_N_per_um:,.0f}"), ("life (h)", f"{p.life_h:,.0f}"),
                ("binding", ", ".join(self.optimum.binding) or "none"),
                ("Pareto fronts", ", ".join(f.pair for f in self.fronts) or "none"),
                ("schedule: friction saved", f"{100 * self.schedule.saving_fraction:.0f} %"))
        body = "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)
        return f"<p><b>Ball-screw preload design</b></p><table>{body}</table>"

    def record(self, inputs: dict[str, Any] | None = None) -> DesignRecord:
        """The design artifact's record (:class:`~piezopreload.artifacts.design.DesignRecord`): the optimum, every
        front's points, the schedule with its samples, the curves; ``inputs`` the hashes it came from.

        Parameters
        ----------
        inputs : dict or None
            The hashes of the files the design came from, by name (None: none).

        Returns
        -------
        DesignRecord
            The record the design artifact is written from.
        """
        o = self.optimum
        return DesignRecord(
            optimum=Optimum(o.objective, o.point, tuple(o.binding), tuple(dict(t) for t in o.tried), o.solve_s,
                            o.nlp_solves),
            fronts=tuple(Front(f.pair, f.x_name, f.y_name, np.asarray(f.x, float), np.asarray(f.y, float),
                               tuple(f.points), f.solve_s, f.nlp_solves) for f in self.fronts),
            schedule=self.schedule, preload_curve=self.preload_curve, natural_frequency=self.natural_frequency,
            profile=self.profile, units={"force": "N", "length": "mm", "stiffness": "N/um", "torque": "N m",
                                         "life": "h", "energy": self.schedule.energy_units},
            inputs=dict(inputs or {}))

    def to_dict(self) -> dict[str, Any]:
        """The design artifact's body (:meth:`record`'s).

        Returns
        -------
        dict
            The design artifact's document, without its envelope (the record's :meth:`~DesignRecord.to_dict`).
        """
        return self.record().to_dict()

    def save(self, path: str | Path, inputs: dict[str, Any]) -> list[Path]:
        """Write the design artifact to ``path`` and each front's CSV beside it; returns the paths written.

        Parameters
        ----------
        path : str or Path
            The design artifact's file (``design.json``); the fronts' CSV files are written beside it as
            ``<stem>.pareto-<pair>.csv``.
        inputs : dict
            The hashes of the files the design came from, by name.

        Returns
        -------
        list of Path
            The artifact's path first, then each front's CSV.
        """
        path = self.record(inputs).save(path)
        written = [path]
        for front in self.fronts:
            csv = path.with_name(f"{path.stem}.pareto-{front.pair.replace(':', '-')}.csv")
            buf = io.StringIO()
            buf.write(f"# Pareto front {front.pair}: {front.x_name} swept, {front.y_name} optimised\n")
            # a point's growth is not one of its fields: the front's y is its own column (the shift's largest growth)
            growth = front.y_name == "growth"
            buf.write(",".join(FRONT_COLUMNS + (("growth_max_um",) if growth else ())) + "\n")
            for p, y in zip(front.points, front.y):
                d = p.to_dict()
                buf.write(",".join([f"{d[c]:.6g}" for c in FRONT_COLUMNS] + ([f"{y:.6g}"] if growth else [])) + "\n")
            atomic_write_text(csv, buf.getvalue())
            written.append(csv)
        return written

    def plot(self) -> Figure:
        """The Pareto fronts (optimum marked), rigidity against preload, and the schedule: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            A row of Pareto fronts with the optimum starred, the optimum's rigidity against preload, and the axial load
            with the scheduled and the best constant preload against time.
        """
        from matplotlib.figure import Figure

        n = len(self.fronts)
        fig = Figure(figsize=(4.0 * max(n, 2), 7.5), layout="constrained")
        grid = fig.add_gridspec(3, max(n, 2))
        p = self.optimum.point
        for j, front in enumerate(self.fronts):
            ax = fig.add_subplot(grid[0, j])
            front.draw(ax)
            y = {"preload": p.max_preload_N, "drag": p.mean_drag_torque_Nm, "life": p.life_h}.get(front.y_name)
            if y is not None:  # a point's growth is not one of its fields
                ax.plot([p.stiffness_N_per_um], [y], "*", ms=10, color="k", label="optimum")
            ax.legend(fontsize="small")
        self.optimum.draw(fig.add_subplot(grid[1, :]))
        load, preload = fig.add_subplot(grid[2, :]), None
        preload = load.twinx()
        t = self.schedule.profile.time_s
        load.plot(t, self.schedule.profile.axial_load_N, color="0.5", lw=0.8)
        load.set(xlabel="time (s)", ylabel="axial load (N)")
        preload.plot(t, self.schedule.preload_N, color="C0", label="schedule")
        preload.axhline(self.schedule.constant_preload_N, color="C1", ls="--", label="best constant")
        preload.set_ylabel("preload (N)")
        preload.legend(fontsize="small")
        return fig


def design_study(spec: DesignSpec, objective: str, pairs: list[str] | tuple[str, ...], points: int, *,
                 profile: LoadProfile | None = None, profile_name: str = "example", stiffness_min_N_per_um: float = 0.0,
                 deflection_max_um: float = math.inf, lift_off_margin: float | None = None,
                 progress: ProgressLike | None = None,
                 bar: Bar | None = None, optimum: DesignOptimum | None = None,
                 growth: Callable[[DesignPoint], float] | None = None) -> DesignResult:
    """Optimum for ``objective``, the fronts of ``pairs`` (``points`` each) and the schedule for ``profile``.

    The schedule keeps the rigidity above ``stiffness_min_N_per_um`` and the deflection
    ``|F_a| / rigidity`` below ``deflection_max_um`` (the machining cycle of
    :func:`~piezopreload.design.schedule.example_profile` when ``profile`` is None).
    ``progress`` gets messages, ``bar`` (points done, points in all) over the fronts. ``optimum``:
    the optimum for ``objective`` already solved on ``spec`` (it is not solved again). ``growth``: a design
    point's growth over a shift, the y of a ``stiffness:growth`` front
    (:func:`~piezopreload.design.thermal.duty_growth_um` with the study's ``[thermal]`` table).
    """
    say = say_of(progress) or (lambda _msg: None)
    nlp = DesignNLP(spec) if optimum is None or pairs else None
    if optimum is not None and optimum.objective != objective:
        raise InputError(f"design_study: the optimum given is for {optimum.objective!r}, not {objective!r}")
    result = optimise(spec, objective, nlp) if optimum is None else optimum
    p = result.point
    say(f"optimum ({objective}{', robust' if spec.worst is not None else ''}): {p.turns:.0f} turns x "
        f"{p.balls_per_turn:.0f} balls of {quantity(p.ball_mm, 'mm', 4)}, contact angle "
        f"{quantity(p.contact_angle_deg, 'deg')}, conformity {number(p.conformity)}, preload "
        f"{number(p.bolt_preload_N, 'N')} to {quantity(p.max_preload_N, 'N')}")
    cost = None
    if spec.worst is not None and objective in OBJECTIVES:  # the nominal design beside it: what robustness costs
        cost = robust_cost(spec, optimise(replace(spec, worst=None), objective), result)
        say(f"robust design: {cost.sentence()}")
    fronts = []
    for j, pair in enumerate(pairs):
        if bar is not None:
            report = lambda i, n, j=j: bar(j * n + i, len(pairs) * n)  # noqa: E731
        else:
            report = lambda i, n, pair=pair: say(f"front {pair}: {i}/{n}") if i in (n // 2, n) else None  # noqa: E731
        fronts.append(pareto_front(spec, pair, points, nlp, bar=report, growth=growth))

    # ---- the schedule on the optimum's screw -------------------------------------------------
    schedule, max_preload, slew = plan_schedule(spec, p, profile, profile_name=profile_name,
                                                stiffness_min_N_per_um=stiffness_min_N_per_um,
                                                deflection_max_um=deflection_max_um, lift_off_margin=lift_off_margin)
    say(f"schedule: {number(100 * schedule.saving_fraction, '%', 2)} % less friction energy than the best constant "
        f"preload ({quantity(schedule.constant_preload_N, 'N')})")
    return DesignResult(spec, result, fronts, schedule, profile_name if profile is not None else "example", max_preload,
                        slew, preload_curve(spec, result), natural_frequency(spec, result), cost)


def plan_schedule(spec: DesignSpec, point: DesignPoint, profile: LoadProfile | None = None, *,
                  profile_name: str = "example", stiffness_min_N_per_um: float = 0.0,
                  deflection_max_um: float = math.inf, lift_off_margin: float | None = None,
                  preload_margin_N: float = 0.0) -> tuple[PreloadSchedule, float, float]:
    """The least-friction schedule on the screw of ``point`` (the machining cycle when ``profile`` is None),
    with the stacks' reach and preload slew it was planned for: ``(schedule, max_preload_N, slew_N_per_s)``."""
    screw = spec.screw(point)
    max_preload = spec.actuator.max_preload_N(screw, point.bolt_preload_N)
    slew = spec.actuator.preload_slew_N_per_s(screw, point.bolt_preload_N, point.bolt_preload_N)
    try:
        sspec = ScheduleSpec(bolt_preload_N=point.bolt_preload_N, max_preload_N=max_preload, slew_N_per_s=slew,
                             stiffness_min_N_per_um=stiffness_min_N_per_um, deflection_max_um=deflection_max_um,
                             lift_off_margin=spec.lift_off_margin if lift_off_margin is None else lift_off_margin,
                             preload_margin_N=preload_margin_N, in_machine_factor=spec.rigidity_in_machine_factor)
        schedule = schedule_preload(screw, profile if profile is not None else example_profile(), sspec)
    except ValueError as exc:
        raise InputError(f"{profile_name if profile is not None else 'the example load profile'}: {exc}") from None
    return schedule, max_preload, slew


def preload_curve(spec: DesignSpec, optimum: DesignOptimum, n: int = 121) -> PreloadCurve:
    """Rigidity and drag torque of the optimum's double nut from a quarter of the bolts' preload to 1.5 F_hi,
    with each duty case at its preload."""
    p, screw = optimum.point, spec.screw(optimum.point)
    preloads = np.linspace(0.25 * p.bolt_preload_N, 1.5 * p.max_preload_N, n)
    return PreloadCurve(
        preload_N=preloads, rigidity_N_per_um=np.asarray(screw.rigidity_N_per_um(preloads), float),
        drag_torque_Nm=np.asarray(screw.drag_torque_Nm(preloads), float),
        cases=tuple(DutyCasePoint(float(case.axial_load_N), float(f_case),
                                  float(screw.rigidity_N_per_um(f_case, case.axial_load_N)))
                    for case, f_case in zip(spec.duty, p.case_preload_N)),
        bolt_preload_N=float(p.bolt_preload_N), max_preload_N=float(p.max_preload_N))


def natural_frequency(spec: DesignSpec, optimum: DesignOptimum, n: int = 41) -> FrequencyCurve:
    """The first axial natural frequency along the travel, at the bolts' preload and at full stack drive."""
    p, screw = optimum.point, spec.screw(optimum.point)
    positions = np.linspace(*spec.feed_drive.travel_mm, n)
    return FrequencyCurve(
        position_mm=positions,
        bolt_preload_Hz=np.asarray(spec.feed_drive.natural_frequency_Hz(screw, p.bolt_preload_N, positions), float),
        max_preload_Hz=np.asarray(spec.feed_drive.natural_frequency_Hz(screw, p.max_preload_N, positions), float))


@dataclass(frozen=True)
class ScrewCheck:
    """One double-nut screw at one preload and one axial load (:func:`check_screw`): its ratings and where they come
    from, the preload (and as a share of C_dyn), the rigidity with and without the load, the nuts' loads (and the
    HIWIN formula's), the lift-off, the contact's peak pressure and static safety, the drag and its heat, the life
    (None at standstill)."""

    screw: BallScrew
    c_dyn_N: float
    c_dyn_source: str
    c0_N: float
    c0_source: str
    preload_N: float
    preload_fraction_of_c_dyn: float
    axial_load_N: float
    rigidity_N_per_um: float
    rigidity_no_load_N_per_um: float
    contact_rigidity_N_per_um: float
    deflection_um: float
    loaded_nut_N: float
    unloaded_nut_N: float
    loaded_nut_hiwin_N: float
    lift_off_load_N: float
    lifted_off: bool
    peak_pressure_MPa: float
    ball_load_N: float
    static_safety: float
    drag_torque_Nm: float
    drag_coefficient: float
    drag_heat_W: float
    speed_rpm: float
    life_revolutions: float | None
    life_h: float | None

    def to_dict(self) -> dict[str, Any]:
        """What ``ballscrew --json`` prints: the screw's geometry, then every figure above."""
        s = self.screw
        screw = {"nominal_diameter_mm": s.nominal_diameter_mm, "lead_mm": s.lead_mm, "ball_mm": s.ball_mm,
                 "turns": s.turns, "contact_angle_deg": s.contact_angle_deg, "conformity_screw": s.conformity_screw,
                 "conformity_nut": s.conformity_nut, "balls_per_turn": s.balls_on_turn,
                 "balls_per_nut": s.balls_per_nut, "helix_angle_deg": math.degrees(s.helix_rad),
                 "root_diameter_mm": s.root_diameter_mm}
        return {"screw": screw, **{f.name: getattr(self, f.name) for f in fields(self) if f.name != "screw"}}


def check_screw(screw: BallScrew, preload_N: float | None = None, preload_fraction: float = 0.1,
                axial_load_N: float = 0.0, speed_rpm: float = 1000.0) -> ScrewCheck:
    """Everything a user checks of one screw at one preload and one axial load.

    The preload is ``preload_N``, or ``preload_fraction`` of the dynamic rating C_dyn.
    """
    c_dyn = screw.dynamic_rating_N
    if preload_N is None:
        if not 0 < preload_fraction <= 0.2:
            raise InputError(f"preload_fraction: must be in (0, 0.2] of C_dyn, got {preload_fraction}")
        preload_N = preload_fraction * c_dyn
    if not (math.isfinite(preload_N) and preload_N > 0):
        raise InputError(f"preload_N: must be a finite number > 0, got {preload_N}")
    if not math.isfinite(axial_load_N):
        raise InputError(f"axial_load_N: must be finite, got {axial_load_N}")
    loads = screw.nut_loads(preload_N, axial_load_N)
    contact = screw.contact(loads.loaded_nut_N)
    life = screw.life(preload_N, [DutyCase(axial_load_N, speed_rpm, 1.0)]) if speed_rpm > 0 else None
    return ScrewCheck(
        screw=screw, c_dyn_N=c_dyn, c_dyn_source="catalogue" if screw.c_dyn_N is not None else "estimate",
        c0_N=screw.static_rating_N, c0_source="catalogue" if screw.c0_N is not None else "Hertz at 4200 MPa",
        preload_N=float(preload_N), preload_fraction_of_c_dyn=float(preload_N / c_dyn),
        axial_load_N=float(axial_load_N), rigidity_N_per_um=float(loads.rigidity_N_per_um),
        rigidity_no_load_N_per_um=float(screw.rigidity_N_per_um(preload_N)),
        contact_rigidity_N_per_um=float(loads.contact_stiffness_N_per_um), deflection_um=float(loads.deflection_um),
        loaded_nut_N=float(loads.loaded_nut_N), unloaded_nut_N=float(loads.unloaded_nut_N),
        loaded_nut_hiwin_N=float(hiwin_loaded_nut_force(preload_N, axial_load_N)),
        lift_off_load_N=float(lift_off_load_N(preload_N)), lifted_off=bool(loads.lifted_off),
        peak_pressure_MPa=float(contact.peak_pressure_MPa), ball_load_N=float(contact.ball_load_N),
        static_safety=float(screw.static_rating_N / max(float(loads.loaded_nut_N), 1e-12)),
        drag_torque_Nm=float(screw.drag_torque_Nm(preload_N)), drag_coefficient=screw.drag_K,
        drag_heat_W=float(screw.drag_torque_Nm(preload_N) * speed_rpm * 2 * math.pi / 60),
        speed_rpm=float(speed_rpm), life_revolutions=None if life is None else life.revolutions,
        life_h=None if life is None else life.hours)


def design_spec_from_tables(t: dict[str, Any], fail: Callable[[str, str], Exception]) -> DesignSpec:
    """A study's design tables (``ballscrew``, ``design``, ``feed_drive``, ``duty``, and ``thermal`` where given:
    :mod:`piezopreload.design.tables`' records, each key checked on its own; ``feed_drive`` and ``duty`` None for
    the defaults) as a :class:`DesignSpec`. The rules between tables are checked here; ``fail(key path, message)``
    makes the error naming the file and line."""
    b, d, fd, duty = t["ballscrew"], t["design"], t["feed_drive"], t["duty"]
    kwargs: dict[str, Any] = {k: getattr(b, k) for k in ("nominal_diameter_mm", "lead_mm", "load_sharing",
                                                          "contact_angle_deg", "ball_mm", "conformity", "turns",
                                                          "rigidity_in_machine_factor")}
    kwargs["turns"] = tuple(int(x) for x in b.turns)
    if fd is not None:
        kwargs["feed_drive"] = FeedDrive(table_mass_kg=fd.table_mass_kg, screw_length_mm=fd.screw_length_mm,
                                         bearing_stiffness_N_per_um=fd.bearing_stiffness_N_per_um,
                                         travel_mm=fd.travel_mm, mounting=fd.mounting)
    cases = None if duty is None else duty.cases()
    if cases is not None:
        kwargs["duty"] = tuple(DutyCase(a, n, s) for a, n, s in cases)
    largest = max(abs(c.axial_load_N) for c in kwargs.get("duty", DesignSpec().duty))
    if d.axial_load_max_N < largest:
        raise fail("design.axial_load_max_N", f"must be at least the duty cycle's largest axial load ({largest:g} N), "
                                              f"got {d.axial_load_max_N:g}")
    names = {f.name for f in fields(DesignSpec)}
    kwargs.update({k: v for k, v in d.to_dict().items() if k in names})
    thermal = t.get("thermal")
    if thermal is not None:  # how a stiffness:growth front counts the nut's heat
        try:
            seals = thermal.seal_torque(b.nominal_diameter_mm, b.lead_mm)
        except InputError as exc:
            raise fail("thermal.seal_torque_Nm", f"is not set and {exc}") from None
        kwargs["heat"] = HeatSpec(thermal.heat_model, thermal.lubricant_vg, seals, thermal.contact_temperature_C,
                                  thermal.contact_calibration)
    kwargs["actuator"] = PiezoPreload(drive_V=d.stack_drive_V, amp_current_limit_A=d.amp_current_limit_A)
    if d.robust:  # the worst case of the assumptions' ranges (design/sensitivity.py's table)
        from piezopreload.design.sensitivity import worst_case

        kwargs["worst"] = worst_case()
    try:
        return DesignSpec(**kwargs)
    except ValueError as exc:  # every key was checked alone and with the others above: a rule this code misses
        raise fail("design", f"and the tables it is made with do not make a design specification: {exc}") from None
