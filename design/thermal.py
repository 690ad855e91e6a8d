"""What the preload schedule buys in microns: the heat, the temperature and the screw's growth over a shift.

The physics is :mod:`piezopreload.models.thermal`; here it meets the design and the controlled system.
For one machining cycle as the axis runs it (:class:`CycleLoad`: the preload, the screw's speed and the
axial load per sample) :func:`cycle_sources` finds the heat (the nut's friction heat under either model, the
support bearings') and where it enters: the nut runs out over its stroke and back once per cycle (its
revolutions laid out in the cycle's order, :func:`nut_centre_m`), its heat shared between the screw under its
loaded turns and its own body. Averaged over the cycle, that heat and the screw's film coefficient drive the
slow model of the axis (:meth:`CycleSources.shift`, exact at any time): the shift of repeated cycles from a
cold axis.

:func:`thermal_budget` does this for the preload the force loop achieved along the schedule (the system run's
last cycle) and for the design's best constant preload, and makes the error budget at each of the table's
positions at the end of each hour: the elastic deflection under the worst cut of the cycle (the double nut's
at the planned preload and the screw with its bearings from the table's position:
:meth:`~piezopreload.models.feed_drive.FeedDrive.screw_side_stiffness_N_per_um`), the thermal growth there
(in a semi-closed loop; none with a linear scale) and the force loop's tracking error's share (the largest
deflection the achieved preload adds over the planned one; none for a constant preload, held within the
sensor's noise). Sums of magnitudes: a worst case, not a prediction of one part's error.

Every one of the schedule's requirements grows with the preload at each sample, and so do the heat (either
model) and the growth: the least-friction schedule (:func:`~piezopreload.design.schedule.schedule_preload`,
the pointwise least feasible preload) is also the least-heat and the least-growth schedule. Designing the
schedule against the budget instead of the friction energy changes its objective's value, not the plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts.requirements import Requirement, Sense
from piezopreload.artifacts.thermal import PreloadCase, PreloadDrift, ThermalCase, ThermalRecord
from piezopreload.core.errors import InputError
from piezopreload.design.system import SystemRun
from piezopreload.design.tables import ThermalTable
from piezopreload.models.ballscrew import BallScrew
from piezopreload.models.feed_drive import FeedDrive, Mounting
from piezopreload.models.thermal import (
    EXPANSION_PER_K,
    STEEL_HEAT_CAPACITY_J_PER_M3K,
    AxisModel,
    Feedback,
    FineMarch,
    Network,
    ScrewBody,
    ThermalMounting,
    bearing_torque_Nm,
    end_force_N,
    growth_m,
    held_force_N,
    nut_coverage,
    pair_lift_off_N,
    pipe_film_W_per_m2K,
    shaft_film_W_per_m2K,
    spacer_drift_N_per_K,
    viscosity_m2_s,
)

__all__ = ["CycleLoad", "CycleSources", "ThermalBudget", "axis_model", "cycle_sources", "nut_centre_m",
           "shift_hours", "thermal_budget", "schedule_requirements",
           "ShiftBasis", "shift_basis", "mounting_of", "duty_cycle", "duty_growth_um", "POSITIONS"]

Array = NDArray[np.float64]
#: the table's positions the budget is read at, evenly over the travel
POSITIONS = 37
#: the grid the shift's largest figures are read on (s)
_GRID_S = 300.0
_STEEL_SPECIFIC_HEAT = 460.0  # J/kg K


@dataclass(frozen=True, eq=False)
class CycleLoad:
    """One machining cycle as the axis runs it, one row per sample: its duration (s), the preload (N), the screw's
    speed (rpm) and the axial load (N); the cycle repeats."""

    duration_s: Array
    preload_N: Array
    speed_rpm: Array
    axial_load_N: Array

    def __post_init__(self) -> None:
        n = np.asarray(self.duration_s).size
        for name in ("duration_s", "preload_N", "speed_rpm", "axial_load_N"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise InputError(f"CycleLoad.{name} must hold one finite number per sample ({n}).")
            object.__setattr__(self, name, value)
        if n == 0 or np.any(self.duration_s <= 0) or np.any(self.preload_N <= 0):
            raise InputError("CycleLoad needs samples with durations > 0 and preloads > 0.")

    @property
    def period_s(self) -> float:
        return float(np.sum(self.duration_s))

    def mean(self, x: Any) -> Any:
        """The cycle's time mean of ``x`` (one value, or one row, per sample). A summation over the samples rather
        than a BLAS product: on a shared machine a threaded BLAS call on these tall arrays takes tens of times
        longer, and the sensitivity study makes many of them."""
        return np.einsum("i,i...->...", self.duration_s, np.asarray(x, float)) / self.period_s

    @classmethod
    def on_profile(cls, time_s: Any, preload_N: Any, speed_rpm: Any, axial_load_N: Any) -> CycleLoad:
        """A cycle on a load profile's samples: each sample lasts until the next one, the last as long as the one
        before (the cycle's period is the profile's span and one sample, as the force loop repeats it)."""
        t = np.asarray(time_s, float)
        gaps = np.diff(t)
        return cls(np.concatenate([gaps, gaps[-1:]]), np.broadcast_to(np.asarray(preload_N, float), t.shape),
                   speed_rpm, axial_load_N)


def mounting_of(table: ThermalTable, drive: FeedDrive) -> ThermalMounting:
    """The mounting the growth is computed for: the table's, or the axis' (fixed-supported floats: fixed-free)."""
    if table.mounting is not None:
        return table.mounting
    return ThermalMounting.FIXED_FREE if drive.mounting is Mounting.FIXED_SUPPORTED else ThermalMounting.FIXED_FIXED


def _zones(screw: BallScrew, table: ThermalTable) -> tuple[tuple[float, float], tuple[float, float]]:
    """The double nut's loaded turns around its centre: (offset, length) m, either side of the spacer."""
    nut = 1e-3 * screw.nut_length_mm
    offset = 0.5 * (nut + 1e-3 * table.spacer_length_mm)
    return ((-offset, nut), (offset, nut))


def axis_model(screw: BallScrew, drive: FeedDrive, table: ThermalTable) -> AxisModel:
    """The axis' network: the screw between its bearings (its nominal diameter's surface, its root's section, the
    table's bore), the double nut and spacer as a steel ring (the nut's outer diameter over the screw's), its
    flange."""
    bore = 0.0 if table.bore_mm is None else 1e-3 * table.bore_mm
    if bore >= 1e-3 * screw.root_diameter_mm:
        raise InputError(f"[thermal] bore_mm = {table.bore_mm:g} must be below the screw's root diameter "
                         f"({screw.root_diameter_mm:.1f} mm)")
    body = ScrewBody(1e-3 * drive.screw_length_mm, 1e-3 * screw.nominal_diameter_mm, 1e-3 * screw.root_diameter_mm,
                     bore)
    length = 2e-3 * screw.nut_length_mm + 1e-3 * table.spacer_length_mm
    outer, inner = 1e-3 * screw.nut_outer_diameter, 1e-3 * screw.nominal_diameter_mm
    coolant = 0.0 if table.coolant_flow_l_per_min is None else pipe_film_W_per_m2K(table.coolant_flow_l_per_min,
                                                                                      bore)
    return AxisModel(body, table.volumes, (table.bearing_W_per_K, table.bearing_W_per_K),
                     nut_capacity_J_per_K=STEEL_HEAT_CAPACITY_J_PER_M3K * 0.25 * math.pi * (outer ** 2 - inner ** 2)
                     * length, nut_area_m2=math.pi * outer * length,
                     flange_capacity_J_per_K=table.flange_mass_kg * _STEEL_SPECIFIC_HEAT,
                     nut_flange_W_per_K=table.nut_flange_W_per_K, flange_table_W_per_K=table.flange_table_W_per_K,
                     coolant_W_per_m2K=coolant)


def nut_centre_m(cycle: CycleLoad, stroke_mm: tuple[float, float]) -> Array:
    """The nut's centre (m from bearing A) at each sample's middle: out over the stroke and back once per cycle,
    at a pace proportional to the screw's speed (the cycle's revolutions laid out in their order)."""
    travel = np.abs(cycle.speed_rpm) * cycle.duration_s
    total = float(np.sum(travel))
    if total <= 0:
        return np.full(cycle.duration_s.size, 1e-3 * stroke_mm[0])
    s = (np.cumsum(travel) - 0.5 * travel) / total
    return 1e-3 * (stroke_mm[0] + (stroke_mm[1] - stroke_mm[0]) * (1.0 - np.abs(1.0 - 2.0 * s)))


@dataclass(frozen=True, eq=False)
class CycleSources:
    """Where a cycle's heat enters the axis, per sample: the nut's friction heat (W; its seals' part apart too), each
    end bearing's heat
    (W, all of it; its share enters the screw at the end face, :meth:`AxisModel.face_share`), the nut's coverage
    of the screw's volumes (rows sum to 1), the screw's film (W/m^2 K); with the model, the cycle and the table's
    shares, and the coolant's constant heat per node (W)."""

    model: AxisModel
    cycle: CycleLoad
    nut_W: Array  # the seals' heat included
    seal_W: Array  # the seals' part of it
    bearing_W: Array  # (samples, 2): ends A and B
    coverage: Array
    film_W_per_m2K: Array
    nut_share: float
    bearing_share: float
    coolant_W: Array
    free_W_per_m2K: float

    def heat_W(self) -> Array:
        """Each sample's heat per node (samples x nodes)."""
        n = self.model.volumes
        q = np.zeros((self.nut_W.size, self.model.size))
        q[:, :n] = self.nut_share * self.nut_W[:, None] * self.coverage
        q[:, n] = (1.0 - self.nut_share) * self.nut_W
        q[:, 0] += self.bearing_share * self.model.face_share(0) * self.bearing_W[:, 0]
        q[:, n - 1] += self.bearing_share * self.model.face_share(1) * self.bearing_W[:, 1]
        return q + self.coolant_W[None, :]

    def mean_heat_W(self) -> Array:
        """The cycle's mean heat per node (what drives the slow model)."""
        n = self.model.volumes
        c = self.cycle
        q = np.zeros(self.model.size)
        q[:n] = self.nut_share * c.mean(self.nut_W[:, None] * self.coverage)
        q[n] = (1.0 - self.nut_share) * c.mean(self.nut_W)
        q[0] += self.bearing_share * self.model.face_share(0) * c.mean(self.bearing_W[:, 0])
        q[n - 1] += self.bearing_share * self.model.face_share(1) * c.mean(self.bearing_W[:, 1])
        return q + self.coolant_W

    def network(self) -> Network:
        """The slow model: the network at the cycle's mean film."""
        return self.model.network(float(self.cycle.mean(self.film_W_per_m2K)), self.free_W_per_m2K)

    def shift(self, times_s: Any) -> Array:
        """Every node's rise at ``times_s`` (rows) from a cold axis, the cycle repeated (the slow model, exact)."""
        return self.network().response(self.mean_heat_W(), times_s)

    def fine(self, step_s: float) -> FineMarch:
        """The same axis stepped through the cycle in steps of about ``step_s`` (whole samples each): each step's
        heat and film the mean of its samples'."""
        c = self.cycle
        steps = max(1, int(round(c.period_s / step_s)))
        groups = np.array_split(np.arange(c.duration_s.size), steps)
        q, h = self.heat_W(), self.film_W_per_m2K
        dt = np.array([c.duration_s[g].sum() for g in groups])
        heat = np.array([c.duration_s[g] @ q[g] for g in groups]) / dt[:, None]
        film = np.array([c.duration_s[g] @ h[g] for g in groups]) / dt
        return FineMarch(self.model, heat, film, dt, self.free_W_per_m2K)


def cycle_sources(screw: BallScrew, drive: FeedDrive, table: ThermalTable, cycle: CycleLoad, *,
                  heat_model: str | None = None, model: AxisModel | None = None,
                  coverage: Array | None = None) -> CycleSources:
    """The cycle's heat and where it enters (module docstring), under ``heat_model`` (default: the table's).
    ``coverage``: the nut's coverage of the screw's volumes per sample where the caller has it (it depends on the
    cycle, the nut's and the spacer's lengths, the stroke and the volumes alone)."""
    heat_model = heat_model or table.heat_model
    model = model or axis_model(screw, drive, table)
    stroke = table.stroke_mm or drive.travel_mm
    seals = table.seal_torque(screw.nominal_diameter_mm, screw.lead_mm)
    nut = screw.friction_heat_W(cycle.preload_N, cycle.speed_rpm, model=heat_model, lubricant_vg=table.lubricant_vg,
                                seal_torque_Nm=seals, temperature_C=table.contact_temperature_C,
                                contact_calibration=table.contact_calibration)
    dm = table.bearing_dm_mm or screw.nominal_diameter_mm + 10.0
    nu = 1e6 * float(viscosity_m2_s(table.lubricant_vg, table.contact_temperature_C))
    omega = np.abs(cycle.speed_rpm) * math.pi / 30.0
    far_preload = 0.0 if mounting_of(table, drive) is ThermalMounting.FIXED_FREE else table.bearing_preload_N
    bearing = np.stack([bearing_torque_Nm(cycle.speed_rpm, nu, dm, load, table.bearing_f0, table.bearing_f1) * omega
                        for load in (table.bearing_preload_N, far_preload)], axis=1)
    coolant = model.coolant_W_per_K() * ((table.coolant_C if table.coolant_C is not None else table.ambient_C)
                                        - table.ambient_C)
    free = table.convection_factor * table.free_convection_W_per_m2K
    film = table.convection_factor * shaft_film_W_per_m2K(omega, model.screw.outer_diameter_m, table.ambient_C,
                                                          table.free_convection_W_per_m2K)
    return CycleSources(model, cycle, np.asarray(nut, float), seals * omega, bearing,
                        nut_coverage(model, nut_centre_m(cycle, stroke), _zones(screw, table)) if coverage is None
                        else coverage, film,
                        table.nut_heat_share, table.bearing_heat_share, coolant, free)


def shift_hours(shift_h: float) -> Array:
    """The times the budget records (h): 5, 10, 20 and 30 minutes into the warm-up (those within the shift), the end
    of each hour, and the shift's end."""
    whole = np.arange(1.0, math.floor(shift_h) + 1.0)
    early = np.array([1 / 12, 1 / 6, 1 / 3, 0.5])
    times = np.concatenate([early[early < shift_h], whole])
    return times if math.isclose(shift_h, times[-1]) else np.append(times, shift_h)


@dataclass(frozen=True)
class _Mechanics:
    """What turns the screw's rises into growth at the table's positions: the mounting and its numbers."""

    mounting: ThermalMounting
    EA_N: float
    bearing_N_per_m: float
    bearing_preload_N: float
    pretension_K: float
    positions_m: Array
    dx_m: float

    def _ends(self) -> dict[str, float]:
        return {"EA_N": self.EA_N, "bearing_N_per_m": self.bearing_N_per_m, "bearing_preload_N": self.bearing_preload_N,
                "pretension_K": self.pretension_K}

    def force_N(self, rise_screw: Array) -> Array:
        """The force the held ends take up from the growth, for each row of screw rises."""
        return held_force_N(rise_screw, self.dx_m, self.mounting, **self._ends())

    def end_N(self, rise_screw: Array) -> Array:
        """The force on each end's bearing pair (the pretension included), for each row of screw rises."""
        return end_force_N(rise_screw, self.dx_m, self.mounting, **self._ends())

    @property
    def lift_off_N(self) -> float:
        """The end pairs' lift-off (0: ends not held, or no pair preload)."""
        return 0.0 if self.mounting is ThermalMounting.FIXED_FREE else pair_lift_off_N(self.bearing_preload_N)

    def growth_um(self, rise_screw: Array) -> Array:
        """The growth (um) at the table's positions for each row of screw rises."""
        faces = growth_m(rise_screw, self.dx_m, self.mounting, **self._ends())
        x = np.arange(faces.shape[-1]) * self.dx_m
        return 1e6 * np.stack([np.interp(self.positions_m, x, row) for row in np.atleast_2d(faces)])


def _mechanics(screw: BallScrew, drive: FeedDrive, table: ThermalTable, model: AxisModel,
               positions_mm: Array) -> _Mechanics:
    area = 0.25 * math.pi * (1e-3 * screw.root_diameter_mm) ** 2
    return _Mechanics(mounting_of(table, drive), screw.material.E_MPa * 1e6 * area,
                      drive.bearing_stiffness_N_per_um * 1e6, table.bearing_preload_N, table.pretension_K,
                      1e-3 * positions_mm, model.dx_m)


def _grid(times_h: Array) -> Array:
    """The shift's five-minute grid with the recorded times in it (s)."""
    return np.union1d(np.arange(0.0, times_h[-1] * 3600.0, _GRID_S)[1:], times_h * 3600.0)


def _elastic_um(screw: BallScrew, drive: FeedDrive, preload_N: Array, load_N: Array, positions_mm: Array) -> Array:
    """The largest deflection (um) at each table position under the cycle's cuts: the double nut's at its preload
    and the screw with its bearings from that position."""
    cut = np.abs(load_N) > 0
    if not cut.any():
        return np.zeros(positions_mm.size)
    nut = np.abs(screw.nut_loads(preload_N[cut], load_N[cut]).deflection_um)
    side = drive.screw_side_stiffness_N_per_um(screw.root_diameter_mm, positions_mm)
    return np.max(nut[:, None] + np.abs(load_N[cut])[:, None] / np.asarray(side)[None, :], axis=0)


@dataclass(frozen=True, eq=False)
class ThermalBudget:
    """A shift's thermal budget: its record (the system artifact's ``thermal``) and its requirements' verdicts."""

    record: ThermalRecord
    requirements: tuple[Requirement, ...]
    sources: dict[str, CycleSources]


def _budget_um(elastic: Array, tracking: float, growth: Array, semi_closed: bool) -> Array:
    """The error budget (um) per grid time and table position: the deflection under the worst cut, the force loop's
    share, and the growth where the position loop does not see it (a semi-closed loop)."""
    return elastic[None, :] + tracking + (np.abs(growth) if semi_closed else np.zeros_like(growth))


def _case(sources: CycleSources, other: CycleSources, mech: _Mechanics, elastic: Array, tracking: float,
          semi_closed: bool, times_h: Array) -> tuple[ThermalCase, Array, Array]:
    """One preload's shift: the case, and its nut-over-screw rises and times on the grid."""
    n = sources.model.volumes
    grid = _grid(times_h)
    rises, other_rises = sources.shift(grid), other.shift(grid)
    at = np.searchsorted(grid, times_h * 3600.0)
    growth, other_growth = mech.growth_um(rises[:, :n]), mech.growth_um(other_rises[:, :n])
    under = rises[:, :n] @ sources.cycle.mean(sources.coverage)
    nut_over = rises[:, n] - under
    budget = _budget_um(elastic, tracking, growth, semi_closed)
    c = sources.cycle
    hottest = np.unravel_index(int(np.argmax(rises[:, :n])), (rises.shape[0], n))[1]
    case = ThermalCase(
        heat_mean_W=float(c.mean(sources.nut_W)), heat_mean_other_W=float(c.mean(other.nut_W)),
        seal_heat_mean_W=float(c.mean(sources.seal_W)),
        bearing_heat_mean_W=float(np.sum(c.mean(sources.bearing_W))), preload_mean_N=float(c.mean(c.preload_N)),
        temperature_rise_max_K=float(np.max(rises[:, :n])),
        rise_max_at_mm=1e3 * float(sources.model.centres_m[hottest]),
        temperature_rise_max_other_K=float(np.max(other_rises[:, :n])),
        nut_rise_max_K=float(np.max(rises[:, n])), nut_over_screw_end_K=float(nut_over[-1]),
        end_force_max_N=float(np.max(np.abs(mech.force_N(rises[:, :n])))),
        bearing_force_max_N=float(np.max(np.abs(mech.end_N(np.vstack([np.zeros(n), rises[:, :n]]))))),
        growth_max_um=float(np.max(np.abs(growth))),
        growth_max_other_um=float(np.max(np.abs(other_growth))), positioning_error_max_um=float(np.max(budget)),
        tracking_um=float(tracking), times_h=times_h, rise_along_K=rises[at, :n], nut_rise_K=rises[at, n],
        nut_over_screw_K=nut_over[at], growth_um=growth[at], elastic_um=elastic, budget_um=budget[at])
    return case, nut_over, grid


def _last_cycle(run: SystemRun) -> tuple[CycleLoad, Array, Array]:
    """The system run's last cycle: the achieved preload as a cycle, and its planned preload and load per sample."""
    f, r, prof = run.evaluation.frame, run.run, run.schedule.profile
    if prof.speed_rpm is None:
        raise InputError("[thermal] needs the load profile's speed_rpm column: the heat is the drag times the "
                         "screw's speed")
    dt = float(r.t_s[1] - r.t_s[0])
    period = (r.reference.duration_s - run.pre_cycle.duration_s) / run.cycles
    last = r.t_s >= run.pre_cycle.duration_s + (run.cycles - 1) * period - 0.5 * dt
    speed = np.interp(f.t_cycle[last], prof.time_s, prof.speed_rpm)
    cycle = CycleLoad(np.full(int(last.sum()), dt), np.maximum(f.achieved[last], 1e-3), speed, f.load[last])
    return cycle, np.maximum(f.planned[last], 1e-3), f.load[last]


def _drift(run: SystemRun, table: ThermalTable, constant_over: Array, schedule_over: Array,
           command_range_V: tuple[float, float]) -> PreloadDrift:
    """The passive nut's drift at the best constant preload (the nut law, and its tangent extrapolated for
    comparison) and the stacks' room to hold the schedule's."""
    screw, plant = run.plant.screw, run.plant
    spacer = screw.nut_length_mm + table.spacer_length_mm  # between the two nuts' loaded turns' middles
    constant = run.design_schedule.constant_preload_N
    per_K = float(spacer_drift_N_per_K(screw.nut_stiffness_N_per_um(constant), spacer,
                                       plant.sleeve_stiffness_N_per_um))
    j = int(np.argmax(np.abs(schedule_over)))
    stroke = EXPANSION_PER_K * spacer * 1e3 * float(schedule_over[j])  # um the spacer's gap grows
    needed = -stroke / (plant.rig.stack.nominal_travel_um / 100.0)  # the stacks give it back: less voltage
    cycles = run.run.t_s >= run.pre_cycle.duration_s
    volts = run.run.voltage_V[cycles]
    headroom = command_range_V[1] - float(np.max(volts)) if needed > 0 else float(np.min(volts)) - command_range_V[0]
    k = int(np.argmax(np.abs(constant_over)))
    mismatch = EXPANSION_PER_K * spacer * 1e3 * float(constant_over[k])  # um: the nut warmer presses the nuts
    left = float(screw.spacer_preload_N(constant, mismatch, plant.sleeve_stiffness_N_per_um))
    return PreloadDrift(spacer, per_K, left - float(constant), left, per_K * float(constant_over[k]), float(constant),
                        abs(stroke), needed, headroom)


def _pair(x: Any) -> tuple[float, float]:
    return float(x[0]), float(x[1])


def _cause(record: ThermalRecord) -> str:
    """What drives the schedule's growth, in words: the heat by source and the mounting's share."""
    s = record.schedule
    held = ""
    if record.mounting is ThermalMounting.PRETENSIONED:
        held = f"; the {record.pretension_K:g} K pretension relieved, the ends held by their bearing pairs"
    elif record.mounting is ThermalMounting.FIXED_FIXED:
        held = "; the ends held by their bearing pairs"
    return (f"the schedule's heat: {record.heat_words(s)}; the screw up to {s.temperature_rise_max_K:.1f} K "
            f"{record.place(s.rise_max_at_mm)}{held}")


def _requirements(table: ThermalTable, record: ThermalRecord) -> tuple[Requirement, ...]:
    """The shift's limits as requirements; a growth or positioning error over its limit names what drives it."""
    s = record.schedule
    return _limits(table, s.growth_max_um, s.positioning_error_max_um, _cause(record))


def _limits(table: ThermalTable, growth_max_um: float, positioning_error_max_um: float,
            cause: str = "") -> tuple[Requirement, ...]:
    """The shift's limits as requirements on the schedule's largest growth and positioning error; one over its limit
    names what drives it (``cause``, where given)."""
    out = []
    for value, limit, name, source in (
            (growth_max_um, table.thermal_growth_max_um, "thermal growth at the table over the shift",
             "[thermal] thermal_growth_max_um"),
            (positioning_error_max_um, table.positioning_error_max_um,
             "positioning error over the shift (deflection, growth, tracking)", "[thermal] positioning_error_max_um")):
        if limit is None:
            continue
        out.append(Requirement(name if value <= limit or not cause else f"{name} ({cause})", value, limit, "um",
                               Sense.AT_MOST, source))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ShiftBasis:
    """What the schedule's shift is computed from that neither the heat nor the film settings change, for one
    double nut and the table's geometry (its stroke, spacer and volumes): the last cycle as the loop achieved it,
    the table's positions, the elastic deflection at the planned preload per position (um), the force loop's
    tracking share of it (um) and the nut's coverage of the screw's volumes per sample."""

    cycle: CycleLoad
    positions_mm: Array
    elastic_um: Array
    tracking_um: float
    coverage: Array


def shift_basis(run: SystemRun, drive: FeedDrive, table: ThermalTable, screw: BallScrew | None = None) -> ShiftBasis:
    """The :class:`ShiftBasis` of the system run ``run`` on ``drive`` with ``table``'s geometry for the double nut
    ``screw`` (default: the run's)."""
    screw = run.plant.screw if screw is None else screw
    achieved, planned, load = _last_cycle(run)
    positions = np.linspace(drive.travel_mm[0], drive.travel_mm[1], POSITIONS)
    elastic_planned = _elastic_um(screw, drive, planned, load, positions)
    tracking = float(np.max(np.maximum(_elastic_um(screw, drive, achieved.preload_N, load, positions)
                                       - elastic_planned, 0.0)))
    coverage = nut_coverage(axis_model(screw, drive, table), nut_centre_m(achieved, table.stroke_mm or drive.travel_mm),
                            _zones(screw, table))
    return ShiftBasis(achieved, positions, elastic_planned, tracking, coverage)


def schedule_requirements(run: SystemRun, drive: FeedDrive, table: ThermalTable, *, screw: BallScrew | None = None,
                          basis: ShiftBasis | None = None) -> tuple[Requirement, ...]:
    """The thermal requirements' verdicts of the schedule's shift alone (:func:`thermal_budget`'s, without the
    constant preload and the other heat model): what :mod:`piezopreload.design.sensitivity` evaluates under each
    assumption. ``screw``: another double nut judged on the same achieved preload (default: the run's); ``basis``:
    its :func:`shift_basis`, where the caller has it."""
    screw = run.plant.screw if screw is None else screw
    basis = shift_basis(run, drive, table, screw) if basis is None else basis
    model = axis_model(screw, drive, table)
    mech = _mechanics(screw, drive, table, model, basis.positions_mm)
    sources = cycle_sources(screw, drive, table, basis.cycle, model=model, coverage=basis.coverage)
    growth = mech.growth_um(sources.shift(_grid(shift_hours(table.shift_h)))[:, :model.volumes])  # as _case has it
    budget = _budget_um(basis.elastic_um, basis.tracking_um, growth, table.feedback is Feedback.SEMI_CLOSED)
    return _limits(table, float(np.max(np.abs(growth))), float(np.max(budget)))


def thermal_budget(run: SystemRun, drive: FeedDrive, table: ThermalTable, *,
                   command_range_V: tuple[float, float]) -> ThermalBudget:
    """The shift's thermal budget of the system run ``run`` on the axis ``drive`` (module docstring).

    ``command_range_V``: the force loop's command limits (the drift's check).
    """
    screw = run.plant.screw
    basis = shift_basis(run, drive, table, screw)
    achieved, positions = basis.cycle, basis.positions_mm
    elastic_planned, tracking = basis.elastic_um, basis.tracking_um
    model = axis_model(screw, drive, table)
    mech = _mechanics(screw, drive, table, model, positions)
    other_model = table.heat_model.other
    design = run.design_schedule
    prof = design.profile
    constant = CycleLoad.on_profile(prof.time_s, design.constant_preload_N, prof.speed_rpm, prof.axial_load_N)
    travel = drive.travel_mm
    mounting = mech.mounting
    times = shift_hours(table.shift_h)
    semi = table.feedback is Feedback.SEMI_CLOSED
    sources: dict[str, CycleSources] = {}
    cases, over = {}, {}
    schedule, best = PreloadCase.SCHEDULE, PreloadCase.CONSTANT
    for name, cycle, elastic, share in ((schedule, achieved, elastic_planned, tracking), (best, constant, None, 0.0)):
        sources[name] = cycle_sources(screw, drive, table, cycle, model=model,
                                      coverage=basis.coverage if name is schedule else None)
        other = cycle_sources(screw, drive, table, cycle, heat_model=other_model, model=model,
                              coverage=sources[name].coverage)
        if elastic is None:
            elastic = _elastic_um(screw, drive, cycle.preload_N, cycle.axial_load_N, positions)
        cases[name], over[name], _ = _case(sources[name], other, mech, elastic, share, semi, times)
    film = float(achieved.mean(sources[schedule].film_W_per_m2K))
    record = ThermalRecord(
        table.heat_model, other_model, table.lubricant_vg, table.sealed,
        table.seal_torque(screw.nominal_diameter_mm, screw.lead_mm), table.nut_heat_share, table.convection_factor,
        mounting, table.pretension_K, mech.lift_off_N, table.feedback, table.shift_h, _pair(table.stroke_mm or travel),
        1e3 * model.centres_m, positions, film, model.screw.time_constant_s(film), cases[schedule], cases[best],
        _drift(run, table, over[best], over[schedule], command_range_V))
    return ThermalBudget(record, _requirements(table, record), sources)


def duty_cycle(spec: Any, point: Any, samples_per_case: int = 100, period_s: float = 60.0) -> CycleLoad:
    """A design's duty cycle as a machining cycle: each case (:class:`~piezopreload.models.ballscrew.DutyCase`) its
    share of ``period_s`` at its preload of the design ``point``, its speed and its load, in
    ``samples_per_case`` samples (so the nut sweeps its stroke)."""
    total = sum(c.time_share for c in spec.duty)
    rows = [(c.time_share / total * period_s / samples_per_case, f, c.speed_rpm, c.axial_load_N)
            for c, f in zip(spec.duty, point.case_preload_N) for _ in range(samples_per_case)]
    return CycleLoad(*(np.array(col) for col in zip(*rows)))


def duty_growth_um(spec: Any, point: Any, table: ThermalTable) -> float:
    """The largest growth at the table over the shift of a design ``point`` (on
    :class:`~piezopreload.design.preload.DesignSpec` ``spec``) running its duty cycle (:func:`duty_cycle`): the y
    of a ``stiffness:growth`` Pareto front."""
    screw, drive = spec.screw(point), spec.feed_drive
    model = axis_model(screw, drive, table)
    sources = cycle_sources(screw, drive, table, duty_cycle(spec, point), model=model)
    rises = sources.shift(_grid(shift_hours(table.shift_h)))
    mech = _mechanics(screw, drive, table, model, np.linspace(drive.travel_mm[0], drive.travel_mm[1], POSITIONS))
    return float(np.max(np.abs(mech.growth_um(rises[:, :model.volumes]))))
