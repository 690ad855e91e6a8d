"""The whole system: the controlled preload follows the design's schedule, and what the axis gets while cutting.

The design's least-friction schedule (:mod:`piezopreload.design.schedule`) is the planned
preload ``F_p(t)`` of a machining cycle. The stacks' share of it, ``F_p(t) - F_i``, is the force
loop's reference (piecewise linear through the schedule's samples, repeated for the cycles
the machine runs); the loop (the tuned gains with the inverse-P-I feedforward, a
:class:`~piezopreload.models.controller.Controller`) runs it on the designed plant
(:mod:`piezopreload.design.plant`).

**The start of the cycle is part of the plan.** The stacks rest at 0 V when the machine is
switched on; the schedule's first level is not 0. Before the first cut a pre-cycle
(:class:`~piezopreload.artifacts.system.PreCycle`) brings them to it: a ramp at the slew
limit, then a hold for the loop to settle (the validated settling time by default). The cycles
begin after it, so no requirement is judged on a start-up transient and no margin answers one.

From the true force over the cycles the run gives (:class:`~piezopreload.artifacts.system.TrackingNumbers`):

* the tracking error, RMS and worst, also in % of the schedule's range;
* the axial rigidity the double nut has in the machine (its table figure times the in-machine
  factor, ``ScheduleSpec.in_machine_factor``) at the achieved preload under each sample's cutting
  load (:meth:`BallScrew.nut_loads`) against the requirement the schedule was planned for,
  the achieved preload against the lift-off bound with the schedule's margin
  (``lift_off_margin |F_a| / 2^(3/2)``), and the nut axial deflection under the cutting load; these are the
  requirements, as verdicts (:func:`requirements_of`). The one or two whose rows bind the design's schedule
  (:attr:`PreloadSchedule.binding <piezopreload.artifacts.schedule.PreloadSchedule.binding>`: the lift-off row
  where the plan sits on its bound, the rigidity row where the plan sits on the rigidity it needs) are the design's
  own constraints (``basis="design"``): the schedule is built to sit on them, so their margin in the run is the
  loop's error, not what the physics grants. Given the design, the physical lift-off by the nut law over the
  Monte Carlo plants is one more, and :func:`margin_basis` says what each margin rests on;
* the friction energy of the achieved preload, and the fraction it saves against the design's
  best constant preload (the design's number, not computed again).

**Local margins.** The schedule keeps its requirements at the planned preload; the loop lags it.
Where the achieved preload misses a requirement, the shortfall below the least preload that
sample's requirements need (``PreloadSchedule.needed_N``) is the margin the loop needs there:
the schedule is planned again with that margin (times ``margin_factor``, and over the fraction of
the previous pass's added margin the loop turned into preload there) at those samples, over the
loop's lag before them and a short plateau around them (:func:`folded_shortfall`), held over the
whole stretch of the cycle where a requirement binds the plan around them (:func:`binding_stretches`,
:func:`held_over_stretches`), every other sample keeping its least-friction preload
(:func:`local_margins`), and the loop runs it again: at most ``passes`` times. Inside a stretch
where a requirement binds, the next pass's plan is the last one raised by one constant, so the
loop's error there (its transients and its noise) is the one the margin was taken from. A margin
that stepped up and down inside the stretch would change the loop's reference where the
requirement binds: the loop's transient after each step (a learned loop's too, in a pass's first
trials after the plan changed), and the noise extremes of a learned loop, which fall elsewhere in
every pass, would fall short next to the margin, and the passes would chase their own steps.
Where the stacks' reach cannot give the margin, or the passes end first,
:class:`~piezopreload.artifacts.system.ScheduleBound` says which requirement is stopped, where, and
by how much.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.requirements import AtBound, OffBounds, Requirement, Sense
from piezopreload.artifacts.schedule import LIFT_OFF_KEY, RIGIDITY_KEY, PreloadSchedule, ScheduleSpec
from piezopreload.artifacts.sensitivity import SensitivityRecord
from piezopreload.artifacts.summaries import SystemSummary
from piezopreload.artifacts.system import (
    MarginBasis,
    MarginPass,
    PlannedSchedule,
    PreCycle,
    ScheduleBound,
    SystemRecord,
    SystemSeries,
    TrackingNumbers,
)
from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.core.progress import ProgressLike, say_of
from piezopreload.core.tables import write_csv
from piezopreload.design.schedule import least_preload, schedule_preload
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.ballscrew import LIFT_OFF_RATIO, BallScrew
from piezopreload.models.closedloop import ClosedLoopRun, Interpolation, Reference, simulate
from piezopreload.models.controller import Controller

if TYPE_CHECKING:  # the thermal budget reads a system run; the plots name their type
    from matplotlib.figure import Figure

    from piezopreload.design.preload import DesignSpec
    from piezopreload.design.thermal import ThermalBudget

__all__ = ["PRE_CYCLE_REST_S", "RIGIDITY_VERDICT", "LIFT_OFF_BOUND_VERDICT", "OWN_CONSTRAINT", "LIFT_OFF_LAW",
           "ROUND_OFF",
           "margin_basis", "off_bounds_screw", "SystemRun", "Evaluation", "pre_cycle_for",
           "schedule_reference", "track_schedule", "evaluate_tracking", "requirements_of", "folded_shortfall",
           "frame_under", "binding_stretches", "held_over_stretches", "local_margins"]


#: the pre-cycle's rest before its ramp (s): the loop starts bumplessly on its first sample's feedforward, so a
#: learned feedforward that leads the ramp needs samples before it
PRE_CYCLE_REST_S = 0.05
#: a requirement counts as met within this fraction of its limit: the floating-point round-off of the preload's way
#: through the stacks' share and the load's interpolation (1e-13 of it in practice), far below any sensor's resolution
ROUND_OFF = 1e-9
#: the rigidity's verdict: at the sample where the rigidity is least against its requirement (the requirement
#: follows the load: the least rigidity itself may fall where little is required)
RIGIDITY_VERDICT = "rigidity while cutting, where least against its requirement"
#: the lift-off bound's verdict: the achieved preload against ``lift_off_margin |F_a| / 2^(3/2)``
LIFT_OFF_BOUND_VERDICT = "preload against the schedule's lift-off bound while cutting"
#: what a verdict's name carries where its row binds the design's schedule (``basis="design"``)
OWN_CONSTRAINT = " (the design's own constraint)"
#: the law the physical lift-off is judged by: the model's own, not the catalogues' 2^(3/2) rule
LIFT_OFF_LAW = ("the nut law's lift-off load rho(sigma) F_p (the exact two-nut solution with the nut body, "
                "BallScrew.lift_off_load_N; the catalogues' 2^(3/2) F_p is the Hertz-only nut's)")
#: the longest lag of the loop behind its reference the margins look back over (s)
_LAG_MAX_S = 0.25
#: a local margin holds this long either side of the shortfall it answers (s): one load ramp of the machining cycle
_HOLD_S = 0.05


def pre_cycle_for(plant: DesignedPlant, schedule: PreloadSchedule, contact_N: float = 0.0,
                  settle_s: float = 0.5) -> PreCycle:
    """The pre-cycle of ``schedule`` on ``plant``: :data:`PRE_CYCLE_REST_S` at rest, a ramp to the stacks' share of
    the first level at the schedule's slew limit, then ``settle_s`` held (rounded up to a whole sample of the loop, so
    the cycles start on one)."""
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise InputError(f"settle_s: must be finite and >= 0, got {settle_s!r}")
    level = max(float(plant.stack_force_N(schedule.preload_N[0])), contact_N)
    slew = float(schedule.spec.slew_N_per_s)
    ramp = max(level, 0.0) / slew
    dt = float(plant.rig.sample_period_s)
    total = math.ceil((PRE_CYCLE_REST_S + ramp + settle_s) / dt - 1e-9) * dt
    return PreCycle(level_N=level, slew_N_per_s=slew, ramp_s=ramp, settle_s=max(total - ramp - PRE_CYCLE_REST_S, 0.0),
                    rest_s=PRE_CYCLE_REST_S)


def schedule_reference(plant: DesignedPlant, schedule: PreloadSchedule, cycles: int = 1, contact_N: float = 0.0,
                       pre_cycle: PreCycle | None = None) -> Reference:
    """The force loop's reference: the stacks' share of the scheduled preload (less the bolts'), piecewise
    linear through the schedule's samples, ``cycles`` times in a row, after the ``pre_cycle`` (none: the
    cycles start at once, from rest).

    ``contact_N``: the least force the stacks keep on the nuts (they are not bonded to them: where the
    schedule asks for the bolts' preload alone, the stacks still push this much).
    """
    if not (np.isfinite(contact_N) and contact_N >= 0):
        raise InputError(f"contact_N: must be finite and >= 0, got {contact_N!r}")
    t = np.asarray(schedule.profile.time_s, float)
    t = t - t[0]
    dt = float(t[-1] - t[-2])
    share = np.maximum(plant.stack_force_N(schedule.preload_N), contact_N)
    cycle = Reference.ramps(t, share, float(t[-1] + dt)).repeat(cycles)
    if pre_cycle is None or pre_cycle.duration_s <= 0:
        return cycle
    rest, ramp = pre_cycle.rest_s, pre_cycle.ramp_s
    head_t = [0.0] + ([rest] if rest > 0 else []) + ([rest + ramp] if ramp > 0 else [])
    head_f = [0.0] * (len(head_t) - (ramp > 0)) + ([share[0]] if ramp > 0 else [])
    return Reference(np.concatenate([head_t, cycle.times_s + pre_cycle.duration_s]),
                     np.concatenate([head_f, cycle.levels_N]), cycle.duration_s + pre_cycle.duration_s,
                     Interpolation.LINEAR)


@dataclass(frozen=True, eq=False)
class _Frame:
    """One run's samples as the requirements see them: the time into the cycle, the load, the preloads planned and
    achieved, the rigidity and its requirement, the lift-off bound, the deflection; ``cycle``: after the pre-cycle,
    ``cutting``: in a cycle and under load."""

    t_cycle: Array
    cycle: NDArray[np.bool_]
    cutting: NDArray[np.bool_]
    load: Array
    planned: Array
    achieved: Array
    required: Array
    rigidity: Array
    planned_rigidity: Array
    deflection: Array
    lift_bound: Array
    weight: Array


def _frame(plant: DesignedPlant, schedule: PreloadSchedule, run: ClosedLoopRun, cycles: int, pre_s: float) -> _Frame:
    prof, screw = schedule.profile, plant.screw
    dt = float(run.t_s[1] - run.t_s[0])
    cycle = run.t_s >= pre_s - 0.5 * dt
    period = (run.reference.duration_s - pre_s) / cycles
    t_cycle = np.where(cycle, np.mod(run.t_s - pre_s + 0.5 * dt, period) - 0.5 * dt, 0.0) + float(prof.time_s[0])
    load = np.where(cycle, np.interp(t_cycle, prof.time_s, prof.axial_load_N), 0.0)
    planned, achieved = plant.preload_N(run.reference_N), plant.preload_N(run.force_N)
    speed = np.ones_like(t_cycle) if prof.speed_rpm is None else np.interp(t_cycle, prof.time_s, prof.speed_rpm) * (
        2.0 * np.pi / 60.0)
    return _Frame(
        t_cycle=t_cycle, cycle=cycle, cutting=cycle & (np.abs(load) > 0), load=load, planned=planned,
        achieved=achieved, **_mechanics(screw, schedule.spec, planned, achieved, load),
        weight=np.where(cycle, float(screw.drag_torque_Nm(1.0)) * speed * dt, 0.0))


class _Mechanics(TypedDict):
    """The frame's columns the double nut and the requirements set."""

    required: Array
    rigidity: Array
    planned_rigidity: Array
    deflection: Array
    lift_bound: Array


def _mechanics(screw: BallScrew, spec: ScheduleSpec, planned: Array, achieved: Array, load: Array) -> _Mechanics:
    """The frame's columns the double nut and the requirements set: the requirement, the rigidity at the achieved
    and the planned preload, the deflection, the lift-off bound."""
    loads = screw.nut_loads(np.maximum(achieved, 1e-3), load)
    factor = spec.rigidity_factor  # the nut's table rigidity -> its rigidity mounted in the machine
    return _Mechanics(
        required=spec.required_stiffness(load), rigidity=factor * np.asarray(loads.rigidity_N_per_um, float),
        planned_rigidity=factor * np.asarray(screw.rigidity_N_per_um(np.maximum(planned, 1e-3), load), float),
        deflection=np.asarray(loads.deflection_um, float) / factor,
        lift_bound=spec.lift_off_bound_N(load))


def frame_under(frame: _Frame, screw: BallScrew, spec: ScheduleSpec) -> _Frame:
    """The same run's frame (the same achieved and planned preloads under the same loads) judged with another double
    nut ``screw`` and another schedule specification ``spec``: what a modelling assumption changes (design/
    sensitivity.py)."""
    return dc_replace(frame, **_mechanics(screw, spec, frame.planned, frame.achieved, frame.load))


def _verdict(name: str, value: float, limit: float, unit: str, sense: Sense, source: str, key: str) -> Requirement:
    """A requirement, its value within :data:`ROUND_OFF` of the limit taken as the limit (met with nothing to spare)."""
    value = limit if abs(value - limit) <= ROUND_OFF * abs(limit) else value
    return Requirement(name, float(value), float(limit), unit, sense, source, key)


def requirements_of(frame: _Frame, schedule: PreloadSchedule,
                    own: Collection[str] | None = None) -> tuple[Requirement, ...]:
    """The schedule's requirements as verdicts on the achieved preload while cutting: the rigidity (at the sample
    where it is least against its requirement), the deflection (where the study limits it) and the lift-off bound
    (at the sample where the preload is least against it).

    ``own``: the keys of the requirements whose rows bind the design's schedule (default: ``schedule.binding``,
    :attr:`~piezopreload.artifacts.schedule.PreloadSchedule.binding`); each of those is the design's own
    constraint (``basis="design"``, its name ending in :data:`OWN_CONSTRAINT`)."""
    own = schedule.binding if own is None else tuple(own)
    spec, c = schedule.spec, frame.cutting
    ratio = np.where(c, frame.rigidity / frame.required, np.inf)
    k = int(np.argmin(ratio))
    by_deflection = frame.required[k] > spec.stiffness_min_N_per_um
    out = [_verdict(RIGIDITY_VERDICT, frame.rigidity[k], frame.required[k], "N/um", Sense.AT_LEAST,
                    "[schedule] deflection_max_um (|F_a| / deflection_max_um)" if by_deflection
                    else "[schedule] stiffness_min_N_per_um", RIGIDITY_KEY)]
    if math.isfinite(spec.deflection_max_um):
        out.append(_verdict("nut axial deflection while cutting", float(np.max(np.abs(frame.deflection[c]))),
                            spec.deflection_max_um, "um", Sense.AT_MOST, "[schedule] deflection_max_um",
                            "schedule.deflection_max_um"))
    lift = np.where(c, frame.achieved / np.maximum(frame.lift_bound, 1e-9), np.inf)
    j = int(np.argmin(lift))
    out.append(_verdict(LIFT_OFF_BOUND_VERDICT, frame.achieved[j], frame.lift_bound[j], "N", Sense.AT_LEAST,
                        "[schedule] lift_off_margin (lift_off_margin |F_a| / 2^(3/2))", LIFT_OFF_KEY))
    return tuple(dc_replace(r, name=r.name + OWN_CONSTRAINT, basis="design") if r.key in own else r for r in out)


def _needed_at(schedule: PreloadSchedule, t_cycle: Array) -> tuple[Array, NDArray[np.intp]]:
    """The least preload the requirements need between the profile's samples (the larger of the two around each
    time: the load is linear between them) and the index of the sample before."""
    prof_t = schedule.profile.time_s
    j = np.clip(np.searchsorted(prof_t, t_cycle, side="right") - 1, 0, prof_t.size - 2)
    return np.maximum(schedule.needed_N[j], schedule.needed_N[j + 1]), j


def _shortfall(frame: _Frame, schedule: PreloadSchedule, screw: Any) -> Array:
    """Where the achieved preload misses a requirement: how far it lies below the least preload that sample's load
    needs (:func:`~piezopreload.design.schedule.least_preload`, at least 1 N); 0 elsewhere."""
    missed = frame.cutting & ((frame.rigidity < frame.required * (1.0 - ROUND_OFF))
                              | (frame.achieved < frame.lift_bound * (1.0 - ROUND_OFF)))
    out = np.zeros_like(frame.achieved)
    need = least_preload(screw, schedule.spec, frame.load[missed])
    out[missed] = np.maximum(need - frame.achieved[missed], 1.0)
    return out


def _lag_samples(run: ClosedLoopRun, cycle: NDArray[np.bool_], most: int) -> int:
    """The loop's lag behind its reference over the cycles, in samples: the shift that best aligns them."""
    r, y = run.reference_N[cycle], run.force_N[cycle]
    errors = [float(np.mean((r[: r.size - d] - y[d:]) ** 2)) for d in range(min(most, r.size // 2) + 1)]
    return int(np.argmin(errors))


def _window_max(x: Array, before: int, after: int) -> Array:
    """Each sample's largest value of ``x`` from ``before`` samples before it to ``after`` samples after it."""
    out = x.copy()
    for d in range(1, after + 1):
        out[:-d] = np.maximum(out[:-d], x[d:])
    for d in range(1, before + 1):
        out[d:] = np.maximum(out[d:], x[:-d])
    return out


def folded_shortfall(schedule: PreloadSchedule, frame: _Frame, shortfall: Array, lag: int, hold: int) -> Array:
    """The shortfall on the profile's samples: at each sample the largest of the loop's samples around it, over the
    loop's ``lag`` before the shortfall (the plan must be higher that early for the lagging loop to arrive in time)
    and ``hold`` samples either side (a plateau the loop can follow rather than one pass's noise, sample by sample);
    over every cycle. Zero where the loop met every requirement, with that window around."""
    wanted = _window_max(shortfall, hold, lag + hold)
    _, j = _needed_at(schedule, frame.t_cycle)
    out = np.zeros(schedule.profile.time_s.size)
    on = wanted > 0
    np.maximum.at(out, j[on], wanted[on])
    np.maximum.at(out, j[on] + 1, wanted[on])
    return out


def binding_stretches(schedule: PreloadSchedule) -> list[tuple[int, int]]:
    """The stretches ``[a, b)`` of the profile's samples where a requirement binds the plan: under load (or next to
    a sample under load: the loop is judged between them, on the plan interpolated), the need above the bolts' preload,
    and the planned preload less its margin at that need (within :data:`ROUND_OFF`; a ramp of the load, where the plan
    follows the need, included). Between them the plan stands above every requirement (at the bolts' preload, on a slew
    cone, or without load)."""
    spec, need = schedule.spec, schedule.needed_N
    held = schedule.preload_N - schedule.margin_N <= need * (1.0 + ROUND_OFF)
    cut = schedule.profile.cutting
    judged = cut | np.concatenate([cut[1:], [False]]) | np.concatenate([[False], cut[:-1]])  # the loop between them
    binds = judged & (need > spec.bolt_preload_N * (1.0 + ROUND_OFF)) & held
    edges = np.flatnonzero(np.diff(np.concatenate([[0], binds.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def held_over_stretches(folded: Array, stretches: list[tuple[int, int]]) -> Array:
    """``folded`` (per profile sample) with each of ``stretches`` at its largest value over the stretch: a margin
    that holds through the stretch where its requirement binds, with no step inside it."""
    out = np.array(folded, float)
    for a, b in stretches:
        out[a:b] = np.max(out[a:b])
    return out


def local_margins(schedule: PreloadSchedule, folded: Array, factor: float, response: Array | None = None) -> Array:
    """The local margins of the next pass on the profile's samples: this pass's (less the spec's uniform one) plus
    ``factor`` times the folded shortfall (:func:`folded_shortfall`) over ``response``, how much of a margin added the
    pass before the loop turned into preload there (between 1/4 and 1; 1 where no margin was added yet): a loop that
    delivers half of a raise gets twice the raise."""
    gain = factor / (1.0 if response is None else np.clip(response, 0.25, 1.0))
    return schedule.margin_N - schedule.spec.preload_margin_N + gain * folded


def _response(before: Array, after: Array, added: Array) -> Array:
    """Per profile sample, the fraction of the margin ``added`` the loop turned into preload: the shortfall's fall
    ``before - after`` over it (1 where nothing was added)."""
    return np.where(added > 0, (before - after) / np.where(added > 0, added, 1.0), 1.0)


def _numbers(frame: _Frame, schedule: PreloadSchedule, run: ClosedLoopRun, cycles: int, constant_energy: float,
             shortfall: Array) -> TrackingNumbers:
    c, cut = frame.cycle, frame.cutting
    error = (run.reference_N - run.force_N)[c]
    span = float(np.ptp(frame.planned[c])) or 1.0
    ratio = np.where(cut, frame.rigidity / frame.required, np.inf)
    k = int(np.argmin(ratio))  # where the rigidity is least against its requirement
    m = int(np.argmin(np.where(cut, frame.rigidity, np.inf)))  # where the rigidity itself is least
    dt = float(run.t_s[1] - run.t_s[0])
    achieved_energy = float(np.dot(frame.weight, frame.achieved)) / cycles
    spec = schedule.spec
    return TrackingNumbers(
        tracking_rms_N=float(np.sqrt(np.mean(error**2))), tracking_max_N=float(np.max(np.abs(error))),
        tracking_rms_pct_of_range=float(100.0 * np.sqrt(np.mean(error**2)) / span), schedule_range_N=span,
        rigidity_min_cutting_N_per_um=float(frame.rigidity[m]),
        rigidity_required_at_min_N_per_um=float(frame.required[m]), rigidity_min_t_s=float(run.t_s[m]),
        rigidity_ratio_min=float(ratio[k]), rigidity_at_worst_ratio_N_per_um=float(frame.rigidity[k]),
        rigidity_required_at_worst_ratio_N_per_um=float(frame.required[k]), rigidity_worst_t_s=float(run.t_s[k]),
        rigidity_below_requirement_s=float(np.sum(cut & (frame.rigidity < frame.required * (1.0 - ROUND_OFF))) * dt),
        deflection_max_um=float(np.max(np.abs(frame.deflection[cut]))),
        deflection_limit_um=None if math.isinf(spec.deflection_max_um) else float(spec.deflection_max_um),
        lift_off_ratio_min=float(np.min(frame.achieved[cut] / np.maximum(frame.lift_bound[cut], 1e-9))),
        lift_off_margin=float(spec.lift_off_margin), preload_shortfall_max_N=float(np.max(shortfall)),
        friction_energy_per_cycle=achieved_energy,
        planned_friction_energy_per_cycle=float(np.dot(frame.weight, frame.planned)) / cycles,
        friction_saved_fraction=1.0 - achieved_energy / constant_energy, energy_units=schedule.energy_units,
        peak_voltage_V=float(np.max(run.voltage_V)), cycle_start_error_N=float(abs(error[0])))


@dataclass(frozen=True, eq=False)
class Evaluation:
    """One run over a schedule judged: its numbers, its requirements as verdicts, the shortfall per sample."""

    frame: _Frame
    numbers: TrackingNumbers
    requirements: tuple[Requirement, ...]
    shortfall: Array

    @property
    def met(self) -> bool:
        return all(r.met for r in self.requirements)


def evaluate_tracking(plant: DesignedPlant, schedule: PreloadSchedule, run: ClosedLoopRun, cycles: int, *,
                      pre_cycle_s: float = 0.0, constant_energy: float | None = None,
                      own: Collection[str] | None = None) -> Evaluation:
    """Judge one run over the schedule (module docstring): tracking, rigidity, deflection, lift-off, energy.

    ``pre_cycle_s``: the pre-cycle before the first cut (left out). ``constant_energy``: the best
    constant preload's friction energy per cycle the saving is read against (default: the
    schedule's own record of it, the design's). ``own``: the keys of the design's own constraints
    (:func:`requirements_of`; default: those whose rows bind ``schedule``).
    """
    frame = _frame(plant, schedule, run, cycles, pre_cycle_s)
    if not frame.cutting.any():
        raise InputError("the load profile has no sample under load: the schedule's requirements have nothing to judge")
    energy = schedule.constant_friction_energy_J if constant_energy is None else constant_energy
    shortfall = _shortfall(frame, schedule, plant.screw)
    return Evaluation(frame, _numbers(frame, schedule, run, cycles, energy, shortfall),
                      requirements_of(frame, schedule, own), shortfall)


@dataclass(frozen=True, eq=False)
class SystemRun:
    """The controlled preload over the schedule's cycles (module docstring): the last pass's run and schedule, its
    evaluation, every pass's record, the pre-cycle and the bounds; ``design_schedule`` the schedule it started from
    (the design's: its best constant preload is the one the saving is read against).

    Parameters
    ----------
    schedule : PreloadSchedule
        The last pass's schedule, the one the loop ran.
    design_schedule : PreloadSchedule
        The design's schedule it started from.
    plant : DesignedPlant
        The designed plant the loop ran on.
    cycles : int
        The machining cycles run.
    run : ClosedLoopRun
        The last pass's closed-loop run.
    pre_cycle : PreCycle
        The rest and the ramp before the first cut.
    evaluation : Evaluation
        The last pass's run judged: its numbers, its requirements as verdicts, its shortfall per sample.
    passes : tuple of MarginPass
        Every pass's record, in order.
    bounds : tuple of ScheduleBound
        What stops a requirement the passes could not meet (none: nothing).
    thermal : ThermalBudget or None
        The shift's heat, temperature and growth (None: the study has no thermal model).
    basis : MarginBasis or None
        What the margins rest on (:func:`margin_basis`; None: the run was not given the design).
    physical_lift_off : Requirement or None
        The nut law's lift-off load against the cutting load, the worst over the plants (:func:`margin_basis`).
    sensitivity : SensitivityRecord or None
        The verdicts under the modelling assumptions' ranges (None: not studied).
    """

    schedule: PreloadSchedule
    design_schedule: PreloadSchedule
    plant: DesignedPlant
    cycles: int
    run: ClosedLoopRun
    pre_cycle: PreCycle
    evaluation: Evaluation
    passes: tuple[MarginPass, ...]
    bounds: tuple[ScheduleBound, ...] = ()
    thermal: ThermalBudget | None = None  # the shift's heat, temperature and growth (design/thermal.py)
    basis: MarginBasis | None = None  # what the margins rest on (margin_basis), where the run was given the design
    physical_lift_off: Requirement | None = None  # the nut law's lift-off against the load (margin_basis)
    sensitivity: SensitivityRecord | None = None  # the verdicts under the assumptions' ranges (design/sensitivity.py)

    @property
    def numbers(self) -> TrackingNumbers:
        """The run's figures over the schedule's cycles: tracking error, least rigidity, deflection, friction
        energy, peak voltage."""
        return self.evaluation.numbers

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        """Every requirement the run is judged against: the evaluation's, the nut law's lift-off over the plants where
        it
        was checked, and the thermal ones where the study has a ``[thermal]`` table.
        """
        return (self.evaluation.requirements + (() if self.physical_lift_off is None else (self.physical_lift_off,))
                + (() if self.thermal is None else self.thermal.requirements))

    @property
    def requirements_met(self) -> bool:
        """Whether every one of :attr:`requirements` is met."""
        return all(r.met for r in self.requirements)

    @property
    def margin_N(self) -> float:
        """The largest margin the last pass's schedule leaves the loop (local: ``schedule.margin_N`` per sample)."""
        return float(np.max(self.schedule.margin_N))

    def record(self, inputs: dict[str, Any] | None = None, every: int = 10) -> SystemRecord:
        """The system artifact's record (:class:`~piezopreload.artifacts.system.SystemRecord`), the series every
        ``every``-th sample.

        Parameters
        ----------
        inputs : dict or None
            The hashes of the files the run came from, by name (None: none).
        every : int
            The series' decimation: every ``every``-th sample is kept.

        Returns
        -------
        SystemRecord
            The record the system artifact is written from.
        """
        f, s, sl = self.evaluation.frame, self.schedule, slice(None, None, every)
        series = SystemSeries(self.run.t_s[sl], f.planned[sl], f.achieved[sl], f.load[sl], f.rigidity[sl],
                              f.required[sl], f.planned_rigidity[sl], f.deflection[sl], self.run.voltage_V[sl],
                              f.cutting[sl])
        plan = PlannedSchedule(s.profile.time_s, s.preload_N, s.margin_N, s.margin_short_N, s.friction_energy_J,
                               s.energy_units, s.status)
        return SystemRecord(self.numbers, self.requirements, self.bounds, self.pre_cycle, self.passes, plan, series,
                            self.cycles, dict(inputs or {}), None if self.thermal is None else self.thermal.record,
                            self.basis, self.sensitivity)

    def summary(self) -> SystemSummary:
        """The run's numbers, verdicts, pre-cycle, passes and thermal figures (no series).

        Returns
        -------
        SystemSummary
            The figures of :meth:`record` without the series.
        """
        return SystemSummary.of(self.record())

    def save(self, folder: str | Path, inputs: dict[str, Any]) -> dict[str, Path]:
        """Write ``system.json`` (kind ``system``, :meth:`record`) and ``reference.csv`` (the loop's reference at its
        rate, ``time_s,force_N``, the pre-cycle first: what the rig executor plays) into ``folder``.

        Parameters
        ----------
        folder : str or Path
            The folder the two files are written into.
        inputs : dict
            The hashes of the files the run came from, by name.

        Returns
        -------
        dict of str to Path
            ``system``: the artifact's path; ``reference``: the reference CSV's.
        """
        folder = Path(folder)
        paths = {"system": self.record(inputs).save(folder / "system.json"), "reference": folder / "reference.csv"}
        write_csv(paths["reference"], {"time_s": self.run.t_s, "force_N": self.run.reference_N},
                  f"the stacks' share of the preload schedule (less the bolts' {self.plant.bolt_preload_N:.1f} N): a "
                  f"{self.pre_cycle.duration_s:.3f} s pre-cycle to the first level, then {self.cycles} cycles; "
                  f"local margins up to {self.margin_N:.1f} N")
        return paths

    def plot(self) -> Figure:
        """Planned against achieved preload, rigidity against the requirement, deflection: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            Three axes against time: planned and achieved preload (N), the pre-cycle's end dotted; achieved and required
            rigidity while cutting (N/um); the axial deflection (um).
        """
        from matplotlib.figure import Figure

        f, t = self.evaluation.frame, self.run.t_s
        fig = Figure(figsize=(7.0, 7.0), layout="constrained")
        ax = fig.subplots(3, 1, sharex=True)
        ax[0].plot(t, f.planned, color="k", lw=1.0, label="planned")
        ax[0].plot(t, f.achieved, color="C0", lw=0.8, label="achieved (true force)")
        ax[0].axvline(self.pre_cycle.duration_s, color="0.6", ls=":", lw=0.8)
        ax[0].set_ylabel("preload (N)")
        ax[0].legend(fontsize="small")
        ax[1].plot(t, np.where(f.cutting, f.rigidity, np.nan), color="C0", lw=0.8, label="achieved")
        ax[1].plot(t, np.where(f.cutting, f.required, np.nan), ":", color="k", label="required")
        ax[1].set_ylabel("rigidity (N/um)")
        ax[1].legend(fontsize="small")
        ax[2].plot(t, f.deflection, color="C2", lw=0.8)
        ax[2].set(xlabel="time (s)", ylabel="axial deflection (um)")
        return fig


def _bounds(schedule: PreloadSchedule, ev: Evaluation, wanted: Array) -> tuple[ScheduleBound, ...]:
    """Why the last pass still misses a requirement: at the worst sample, the margin the next pass would want
    beyond the stacks' reach (``reach``), or within it (the passes ran out)."""
    if ev.met:
        return ()
    f = ev.frame
    reach = schedule.spec.max_preload_N
    margin = schedule.spec.preload_margin_N + wanted
    short = schedule.needed_N + margin - reach
    k = int(np.argmax(ev.shortfall))
    rigidity_missed = f.rigidity[k] < f.required[k]
    name = RIGIDITY_VERDICT if rigidity_missed else "preload against the lift-off bound"
    j = int(np.argmax(short)) if np.max(short) > 0 else int(np.argmin(np.abs(schedule.profile.time_s - f.t_cycle[k])))
    t0 = float(schedule.profile.time_s[0])
    return (ScheduleBound(name, float(schedule.profile.time_s[j] - t0), float(schedule.needed_N[j]), float(margin[j]),
                          float(reach), "reach" if np.max(short) > 0 else "passes"),)


def _pass_record(k: int, schedule: PreloadSchedule, ev: Evaluation) -> MarginPass:
    n = ev.numbers
    return MarginPass(k, float(np.max(schedule.margin_N)), n.tracking_rms_N, n.tracking_rms_pct_of_range,
                      n.rigidity_ratio_min, n.lift_off_ratio_min, ev.met, n.preload_shortfall_max_N,
                      n.friction_energy_per_cycle)


def _check(cycles: int, passes: int, margin_factor: float) -> None:
    if not (isinstance(cycles, int) and cycles >= 1):
        raise InputError(f"cycles: must be an integer >= 1, got {cycles!r}")
    if not (isinstance(passes, int) and passes >= 1):
        raise InputError(f"passes: must be an integer >= 1, got {passes!r}")
    if not margin_factor >= 1.0:
        raise InputError(f"margin_factor: must be >= 1, got {margin_factor!r}")


def track_schedule(plant: DesignedPlant, controller: Controller, schedule: PreloadSchedule, *, cycles: int = 2,
                   seed: int = 0, passes: int = 3, margin_factor: float = 1.25, contact_N: float = 0.0,
                   settle_s: float = 0.5, ff_extra_V: Any = None, design: DesignSpec | None = None,
                   scatter: Plant | None = None, progress: ProgressLike | None = None) -> SystemRun:
    """Run the loop over the schedule on the designed plant after its pre-cycle; plan again with local margins while
    a requirement is missed (module docstring).

    ``contact_N``: the least force the stacks keep (:func:`schedule_reference`). ``settle_s``: the
    pre-cycle's hold at the first level (:func:`pre_cycle_for`). ``ff_extra_V``: a correction added
    to the feedforward, one value per sample of the run (a learned one, say); a callable
    ``f(reference) -> array`` makes it for each pass's reference. ``design``: the design's specification (the
    axis, the design variables' ranges): the run then says what its margins rest on (:func:`margin_basis`), the
    physical lift-off judged on the nominal plant and on ``scatter`` (a batch of the rig's parameters, the Monte
    Carlo plants: the last pass's reference and feedforward run on each). Returns the last pass's
    :class:`SystemRun`; its ``passes`` hold every pass's numbers.
    """
    _check(cycles, passes, margin_factor)
    if scatter is not None and design is None:
        raise InputError("scatter: the Monte Carlo plants judge the physical lift-off, which needs the design (its "
                         "axis and ranges): give design, or no scatter")
    say = say_of(progress) or (lambda _m: None)
    rig, pre = Rig(plant.rig), pre_cycle_for(plant, schedule, contact_N, settle_s)
    say(f"pre-cycle: the stacks from rest to {pre.level_N:.0f} N at {pre.slew_N_per_s:,.0f} N/s in "
        f"{1e3 * pre.ramp_s:.1f} ms, held {pre.settle_s:.3f} s: the first cut {pre.duration_s:.3f} s after the start")
    record: list[MarginPass] = []
    dt = float(plant.rig.sample_period_s)
    current, lag, hold = schedule, int(round(_LAG_MAX_S / dt)), int(round(_HOLD_S / dt))
    stretches = binding_stretches(schedule)  # the design's: where its requirements bind, whatever the margins
    before = added = response = None
    for k in range(1, passes + 1):
        pre = pre_cycle_for(plant, current, contact_N, settle_s)  # the first level may carry a margin
        reference = schedule_reference(plant, current, cycles, contact_N, pre)
        extra = ff_extra_V(reference) if callable(ff_extra_V) else ff_extra_V
        run = simulate(rig, controller, reference, seed=seed, ff_extra_V=extra)
        ev = evaluate_tracking(plant, current, run, cycles, pre_cycle_s=pre.duration_s,
                               constant_energy=schedule.constant_friction_energy_J, own=schedule.binding)
        record.append(_pass_record(k, current, ev))
        n = ev.numbers
        say(f"pass {k}: local margins up to {record[-1].preload_margin_N:.1f} N, tracking RMS {n.tracking_rms_N:.2f} N "
            f"({n.tracking_rms_pct_of_range:.2f} % of the range), least rigidity / requirement "
            f"{n.rigidity_ratio_min:.3f}, least preload / lift-off bound {n.lift_off_ratio_min:.3f}")
        folded = held_over_stretches(
            folded_shortfall(current, ev.frame, ev.shortfall, _lag_samples(run, ev.frame.cycle, lag), hold), stretches)
        if before is not None and added is not None:  # set together, from the second pass on
            response = _response(before, folded, added)
        wanted = local_margins(current, folded, margin_factor, response)
        if ev.met or k == passes:
            break
        before, added = folded, wanted - (current.margin_N - current.spec.preload_margin_N)
        current = schedule_preload(plant.screw, current.profile, current.spec, local_margin_N=wanted)
    out = SystemRun(schedule=current, design_schedule=schedule, plant=plant, cycles=cycles, run=run, pre_cycle=pre,
                    evaluation=ev, passes=tuple(record), bounds=_bounds(current, ev, wanted))
    if design is None:
        return out
    if scatter is not None:
        say(f"the physical lift-off on {scatter.batch_shape[0] + 1} Monte Carlo plants (the last pass's reference) ...")
    mc = None if scatter is None else simulate(Rig(scatter), controller, run.reference, seed=seed + 1,
                                               ff_extra_V=extra)
    ev = dc_replace(ev, requirements=_off_bounds(ev.requirements, ev.frame, current, plant.screw, design))
    basis, physical = margin_basis(dc_replace(out, evaluation=ev), design, mc)
    return dc_replace(out, evaluation=ev, basis=basis, physical_lift_off=physical)


# ---- what the margins rest on ---------------------------------------------------------------------------------------

def _at_bound(value: float, low: float, high: float) -> str | None:
    tol = 1e-6 * max(1.0, abs(high))
    return "low" if abs(value - low) <= tol else "high" if abs(value - high) <= tol else None


def off_bounds_screw(screw: BallScrew, design: DesignSpec) -> tuple[BallScrew, tuple[AtBound, ...]]:
    """The screw with its continuous design variables that sit at a bound of their range (the contact angle, the
    conformity) moved to the middle of that range, the balls (their diameter and number) and turns kept, and every
    design variable at a bound (those kept too, with ``instead`` their own value)."""
    at: list[AtBound] = []
    changes: dict[str, Any] = {}
    moved = {"contact_angle_deg": (screw.contact_angle_deg, design.contact_angle_deg),
             "conformity": (screw.conformity_screw, design.conformity)}
    for name, (value, (low, high)) in moved.items():
        side = _at_bound(float(value), float(low), float(high))
        if side is not None:
            mid = 0.5 * (float(low) + float(high))
            at.append(AtBound(f"ballscrew.{name}", float(value), side, mid))
            changes.update({"contact_angle_deg": mid} if name == "contact_angle_deg"
                           else {"conformity_screw": mid, "conformity_nut": mid})
    kept = {"ball_mm": (screw.ball_mm, design.ball_mm), "turns": (screw.turns, design.turns)}
    for name, (value, (low, high)) in kept.items():
        side = _at_bound(float(value), float(low), float(high))
        if side is not None:
            at.append(AtBound(f"ballscrew.{name}", float(value), side, float(value)))
    return dc_replace(screw, **changes), tuple(at)


def _off_bounds(requirements: tuple[Requirement, ...], frame: _Frame, schedule: PreloadSchedule, screw: BallScrew,
                design: DesignSpec) -> tuple[Requirement, ...]:
    """The rigidity and deflection verdicts with their record of the design variables at a bound: each judged again
    on the screw without them (:func:`off_bounds_screw`) at the same achieved preloads and loads."""
    other, at = off_bounds_screw(screw, design)
    if not any(a.instead != a.value for a in at):
        return requirements
    c, factor = frame.cutting, schedule.spec.rigidity_factor
    loads = other.nut_loads(np.maximum(frame.achieved[c], 1e-3), frame.load[c])
    k = factor * np.asarray(loads.rigidity_N_per_um, float)
    deflection = np.asarray(loads.deflection_um, float) / factor
    out = []
    for r in requirements:
        if r.key == RIGIDITY_KEY:
            i = int(np.argmin(k / frame.required[c]))
            value, limit = float(k[i]), float(frame.required[c][i])
        elif r.key == "schedule.deflection_max_um":
            value, limit = float(np.max(np.abs(deflection))), r.limit
        else:
            out.append(r)
            continue
        judged = _verdict(r.name, value, limit, r.unit, r.sense, r.source, r.key)
        out.append(dc_replace(r, off_bounds=OffBounds(at, judged.value, judged.margin_pct, judged.met)))
    return tuple(out)


def _lift_off_ratios(frame: _Frame, screw: BallScrew, achieved: Array) -> Array:
    """The nut law's lift-off load over the cutting load at each cutting sample (``achieved``: the preload, the
    samples last; any leading axes are plants)."""
    c = frame.cutting & (np.abs(frame.load) > 0)
    fp = np.maximum(achieved[..., c], 1e-3)
    return np.asarray(screw.lift_off_load_N(fp), float) / np.abs(frame.load[c])


def margin_basis(run: SystemRun, design: DesignSpec,
                 scatter: ClosedLoopRun | None = None) -> tuple[MarginBasis, Requirement]:
    """What the run's margins rest on (:class:`~piezopreload.artifacts.system.MarginBasis`) and the physical lift-off
    requirement: the nut law's lift-off load at the achieved preload against the cutting load, with no safety factor,
    the worst of the nominal run and ``scatter`` (the same reference and feedforward on the Monte Carlo plants; None:
    the nominal plant alone)."""
    f, screw, factor = run.evaluation.frame, run.plant.screw, run.schedule.spec.rigidity_factor
    n, c = run.numbers, f.cutting
    # the axis at the table: the nut in the machine at the verdict's sample, the screw and bearings over the travel
    travel = np.linspace(*design.feed_drive.travel_mm, 41)
    k_side = np.asarray(design.feed_drive.screw_side_stiffness_N_per_um(screw.root_diameter_mm, travel), float)
    k_axis = 1.0 / (1.0 / n.rigidity_at_worst_ratio_N_per_um + 1.0 / k_side)
    weakest = float(design.feed_drive.screw_side_stiffness_N_per_um(screw.root_diameter_mm,
                                                                   design.feed_drive.weakest_position_mm()))
    axis_deflection = np.abs(f.load[c]) * (1.0 / f.rigidity[c] + 1.0 / weakest)
    # the physical lift-off: the nominal run, then the Monte Carlo plants
    nominal = _lift_off_ratios(f, screw, f.achieved)
    ratios = nominal[None, :]
    if scatter is not None:
        achieved = run.plant.preload_N(np.asarray(scatter.force_N, float).reshape(-1, f.achieved.size))
        ratios = np.vstack([nominal, _lift_off_ratios(f, screw, achieved)])
    p, j = np.unravel_index(int(np.argmin(ratios)), ratios.shape)
    cut = c & (np.abs(f.load) > 0)
    preload = float(f.achieved[cut][j]) if p == 0 else float(achieved[p - 1][cut][j])
    load = float(abs(f.load[cut][j]))
    lift = float(screw.lift_off_load_N(preload))
    basis = MarginBasis(
        rigidity_in_machine_factor=factor, rigidity_in_machine_N_per_um=n.rigidity_at_worst_ratio_N_per_um,
        rigidity_table_N_per_um=n.rigidity_at_worst_ratio_N_per_um / factor,
        rigidity_required_N_per_um=n.rigidity_required_at_worst_ratio_N_per_um,
        axis_stiffness_min_N_per_um=float(np.min(k_axis)), axis_stiffness_max_N_per_um=float(np.max(k_axis)),
        nut_axial_deflection_max_um=n.deflection_max_um, axis_deflection_max_um=float(np.max(axis_deflection)),
        lift_off_law=LIFT_OFF_LAW, lift_off_ratio=lift / preload, lift_off_plants=int(ratios.shape[0]),
        lift_off_worst_plant=int(p), lift_off_preload_N=preload,
        lift_off_axial_load_N=load, lift_off_load_N=lift,
        lift_off_margin_physical_pct=100.0 * (float(ratios[p, j]) - 1.0),
        lift_off_margin_physical_nominal_pct=100.0 * (float(np.min(nominal)) - 1.0),
        lift_off_margin_catalogue_pct=100.0 * (LIFT_OFF_RATIO * preload / load - 1.0))
    over = "on the nominal plant" if scatter is None else f"the worst of {ratios.shape[0]} Monte Carlo plants"
    requirement = dc_replace(
        _verdict(f"lift-off load by the nut law against the cutting load, {over}", lift, load, "N", Sense.AT_LEAST,
                 f"physics: {LIFT_OFF_LAW}; no safety factor", "schedule.lift_off_physical"), basis="physics")
    return basis, requirement
