"""Co-design of the preload system and its force controller, beside the sequential answer.

The study is sequential: the design NLP (:func:`~piezopreload.design.preload.optimise`) picks the screw for its
objective against rigidity, lift-off and life; the tuner (:func:`~piezopreload.tuning.pid.tune_pid`) then picks
the gains on the plant that design made; the schedule stage plans the least-friction preload schedule and the
system stage runs the loop along it, planning it again with local margins where the loop's lag left a requirement
short. :func:`codesign` chooses them together, **nested**: the design's continuous variables that shape the plant
outside (the least rigidity the design must keep, a floor that moves it along the design's least-heat front, and the
contact angle and the groove conformity), the design NLP, the tuning and the schedule's shape inside.

For each outer candidate ``(rigidity floor, contact angle, conformity)``:

1. the design NLP with the angle and conformity fixed chooses the rest (balls, turns, the bolts' preload and so the
   preload range) for the least nut heat whose least rigidity over the duty is at least the floor, under every
   design requirement (rigidity per duty case, lift-off with its safety factor, life, contact pressure, drag,
   frequency): a candidate no screw makes meet them is infeasible, not scored;
2. its plant is built as the plant stage builds it (``[plant]``'s sleeve, the study's ``[rig]`` hardware), the
   feedforward identified on it as the identify stage does;
3. the PID is tuned on it by the study's own tuning (Ms on every plant variant and force-per-volt slope over the
   whole stroke inside the NLP, the overshoot margin, the noise gain), started from the sequential gains, and where
   the study tunes a gain schedule (``[tuning] schedule_levels`` at least 2) each entry on its window at Ms over it:
   the controller compared is the study's own unless the robust set or the entries are asked for
   (:func:`follows_study`); the feedforward's preview lead along the schedule is chosen for that loop
   (:func:`choose_ff_lead`: a bounded scalar search of the lead with which the inverse P-I feedforward reads the
   schedule's reference ahead, for the least tracking RMS along it);
4. the whole-range tracking (the study's staircase) and the step are run on the nominal plant: the tracking RMS
   and the settling time are constraints of the co-design (the validation's limits), not checked after it;
5. the loop runs along the preload schedule (:func:`with_headroom`: the machining cycle's reference the rig follows,
   ``[plant] cycles`` of it after the pre-cycle, the system stage's own run): its tracking RMS there is the
   objective's tracking term, and the schedule's requirements on the achieved preload while cutting (the rigidity,
   the deflection, the lift-off bound) are constraints. The schedule is the inner problem's too
   (:func:`shape_schedule`): the one that meets them with the least objective, of the least-friction schedule with
   the system stage's margin passes (the sequential way) and, for each lead of :data:`LEADS_S` (every rise that much
   earlier), the least headroom (a factor on the levels the stacks drive) the loop meets them with
   (:func:`schedule_shapes`). The loop's lag
   sets what each needs, so the gains, the levels and their transitions trade;
6. the objective is the user's weighted sum of the screw's thermal growth over the shift (the design's duty-cycle
   estimate), the schedule's friction energy per cycle, the tracking RMS along the schedule and the peak command,
   each over its sequential value.

The outer search is a bounded compass (pattern) search on the three variables scaled to ``[0, 1]`` (the floor from
the least-heat design's rigidity to the sequential design's), started at the sequential design, whose schedule the
inner problem shapes first; a candidate replaces the incumbent only when it is feasible and lowers the objective, so
the answer is never worse than the sequential one (whose objective is 1 by the normalisation). A sequential answer
that misses the study (no gains the tuning finds meet the tracking or settling limit under the Ms limit, or the
schedule's requirements along the cycle) is replaced by the first candidate that meets it; where none does, the study
is refused naming the binding pair. The outer search is derivative-free, and why is :data:`STRATEGY_WHY` (the
literature problems of :mod:`piezopreload.design.codesign_problems` show the sensitivity-driven nested strategy where
the inner problem is one smooth parametric NLP). The gain schedule's levels are the study's, not decisions of the
outer loop; its entries' gains are the inner problem's where the study tunes a schedule (``codesign(schedule=None)``,
the default; ``schedule=False`` asks for the one robust set, ``True`` for the entries). The sequential answer runs
the study's controller without a feedforward lead, as the study's stages run it.

Both answers are then validated by the same Monte Carlo (:func:`~piezopreload.tuning.validate.validate`, the
study's ``[validation]`` plants, seed and limits).

:func:`codesign_fronts` sweeps both answers into fronts of thermal growth against tracking RMS at the study's Ms:
the design alone along its least-heat front, each point then tuned (sequential), and the co-design at several
weights of the growth against the tracking (co-designed); :func:`codesign_record` makes the artifact the report's
co-design section reads (:class:`~piezopreload.artifacts.codesign.CodesignRecord`, whose ``front_dominates`` judges
the fronts as computed).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from piezopreload.artifacts.codesign import FRONT_RTOL, CodesignRecord, FrontPoint, RequirementRow
from piezopreload.artifacts.design import DesignPoint
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.requirements import Requirement, Sense
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.artifacts.validation import Criteria, ValidationResult
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.design.preload import DesignInfeasible, DesignOptimum, DesignSpec, optimise, pareto_front
from piezopreload.design.schedule import headroom_schedule
from piezopreload.design.study import plan_schedule
from piezopreload.design.system import SystemRun
from piezopreload.design.tables import DesignTable, PlantTable, ScheduleTable
from piezopreload.design.thermal import duty_growth_um
from piezopreload.models.actuator import Plant
from piezopreload.models.ballscrew import lift_off_load_N
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.progress import ProgressLike, say_of
from piezopreload.spec import StudySpec
from piezopreload.steps import Solved, identify
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.pid import TuningInfeasible, TuningSpec, tune_pid
from piezopreload.tuning.preview import preview_feedforward
from piezopreload.tuning.schedule import schedule_levels, tune_entries
from piezopreload.tuning.validate import validate

__all__ = ["CodesignWeights", "Candidate", "CodesignResult", "codesign", "codesign_optimum", "codesign_design",
           "codesign_fronts", "codesign_record", "front_weights", "evaluate_design", "schedule_shapes",
           "shape_schedule", "follows_study", "choose_ff_lead", "TERMS",
           "STRATEGY_WHY"]

#: the objective's terms: (name, the candidate's attribute, unit)
TERMS = (("growth", "growth_um", "um over the shift"), ("friction", "friction_energy_J", "J per cycle"),
         ("tracking", "cycle_tracking_rms_N", "N along the schedule"), ("voltage", "peak_voltage_V", "V"))
#: the outer variables: (name, the design point's attribute its start is read from, unit); the rigidity floor
#: makes each candidate a point of the design's least-heat front (``stiffness:growth``): the least nut heat whose
#: least rigidity over the duty is at least the floor
VARIABLES = (("stiffness_floor_N_per_um", "stiffness_N_per_um", "N/um"),
             ("contact_angle_deg", "contact_angle_deg", "deg"), ("conformity", "conformity", ""))
#: the outer variables that shape the design (all of them: the schedule's shape is the inner problem's)
DESIGN_VARIABLES = 3
#: the inner problem's preload schedule shape: (name, unit); 1 and 0 are the least-friction schedule
SHAPE = (("schedule_headroom", ""), ("schedule_lead_s", "s"))
#: the headroom's range: from the least-friction levels (1, the sequential answer's) to half as much again; a
#: headroom whose raised levels pass the stacks' reach is not taken
HEADROOM_MAX = 1.5
#: the leads the inner problem tries (s): the transitions 25, 50 and 100 ms earlier, about one to several times the
#: tuned loops' lag behind a load step at the rig's 1 ms sample
LEADS_S = (0.025, 0.05, 0.1)
#: the regula falsi steps on the headroom for each lead (after its two ends)
SHAPE_STEPS = 3
#: the feedforward's preview lead's range (s): how far ahead of the reference the inverse P-I feedforward reads it,
#: from none (the study's controller as its stages run it) to 50 ms, several times the delay line's, the D/A's and
#: the amplifier's lag (:func:`~piezopreload.tuning.preview.feedforward_lead`: 3 ms on the default study) and about
#: the tuned loops' lag behind a load step
FF_LEAD_MAX_S = 0.05
#: the golden ratio's conjugate: the share of the bracket at which the lead's golden-section search probes
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
#: the design NLP's objective for a candidate: the least heat at the candidate's rigidity floor
CANDIDATE_OBJECTIVE = "heat"
STRATEGY = "nested"
#: why the study's co-design is nested (the result and the artifact say so)
STRATEGY_WHY = ("nested, not simultaneous, and derivative-free outside: the inner problem is no smooth function of the "
                "design variables, so no parametric sensitivity of its optimum (IPOPT's parameter multipliers or the "
                "implicit function theorem on its KKT system) can guide the outer search: the design NLP rounds the "
                "balls and turns to integers (along the rigidity floor the ball count jumps, 15 to 30 to 33 on the "
                "default study), the feedforward is identified by a QP on a simulated loop, the schedule's shape is a "
                "discrete choice with the system stage's margin passes, and in the tuning NLP (tuning/pid.py) only "
                "the Ms constraints' frequency-response data are parameters, its time-domain objective a callback "
                "over the compiled simulation whose plant enters as constants; the design outside is searched by a "
                "compass search, the design NLP, the tuning (the gain schedule's entries too where the study tunes "
                "them), the feedforward's preview lead (a bounded scalar search on the loop's run along the schedule) "
                "and the schedule's shape inside")


@dataclass(frozen=True)
class CodesignWeights:
    """The user's weights on the objective's terms (each term over its sequential value).

    Parameters
    ----------
    growth : float
        On the screw's largest thermal growth over the shift (the study's ``[thermal]``; the y of the design's
        ``stiffness:growth`` front).
    friction : float
        On the preload schedule's friction energy per machining cycle.
    tracking : float
        On the nominal plant's RMS tracking error along the preload schedule (the machining cycle's reference).
    voltage : float
        On the stacks' peak command over the step and the staircase.
    """

    growth: float = 0.0
    friction: float = 1.0
    tracking: float = 1.0
    voltage: float = 0.0

    def __post_init__(self) -> None:
        for name, _, _ in TERMS:
            w = getattr(self, name)
            if not (isinstance(w, int | float) and math.isfinite(w) and w >= 0):
                raise InputError(f"codesign weight '{name}': must be a finite number >= 0, got {w!r}")
        if self.growth + self.friction + self.tracking + self.voltage <= 0:
            raise InputError("codesign weights: at least one of growth, friction, tracking, voltage must be > 0")

    @classmethod
    def of_study(cls, study: StudySpec) -> CodesignWeights:
        """What the study states: the thermal growth and the tracking alike where it has a ``[thermal]`` table, else
        the schedule's friction energy and the tracking alike; the voltage not weighted.

        Parameters
        ----------
        study : StudySpec
            The parsed study; only whether it has a ``[thermal]`` table is read.

        Returns
        -------
        CodesignWeights
            growth 1 and friction 0 with a ``[thermal]`` table, growth 0 and friction 1 without; tracking 1 and voltage
            0 either way.
        """
        if study.thermal is not None:
            return cls(growth=1.0, friction=0.0, tracking=1.0, voltage=0.0)
        return cls(growth=0.0, friction=1.0, tracking=1.0, voltage=0.0)

    def to_dict(self) -> dict[str, float]:
        """The weights by term.

        Returns
        -------
        dict of str to float
            Each objective term's weight (``growth``, ``friction``, ``tracking``, ``voltage``).
        """
        return {name: float(getattr(self, name)) for name, _, _ in TERMS}


@dataclass(frozen=True)
class Candidate:
    """One design with its tuned controller: the design point, the gains and what they achieve on the nominal plant.

    Attributes
    ----------
    point : DesignPoint
        The design (its rigidity, life, preload range ...).
    gains : PIDGains
        The gains tuned on its plant.
    coupling_stiffness_N_per_um : float
        The nut's stiffness in series with the stacks that the plant sees.
    ms : float
        The tuned loop's largest sensitivity peak over the variants and slopes.
    friction_energy_J, tracking_rms_N, peak_voltage_V, settling_s : float
        The schedule's friction energy per cycle; the nominal tracking RMS over the staircase, the peak command and
        the step's settling time.
    feasible : bool
        Whether it meets the co-design's constraints (the tracking RMS and settling limits).
    why : str
        What it misses ("" where feasible).
    lift_off_N : float
        The lift-off load at the bolts' preload by the catalogue rule ``2^(3/2) F_p`` the design's constraint uses.
    growth_um : float
        The screw's largest thermal growth over the shift (NaN: the study has no ``[thermal]`` table).
    at : tuple of (str, float)
        The outer variables' values it was designed at (empty: the sequential design, read off its point).
    controller : str
        ``"robust"``: the one robust set; ``"schedule"``: the robust set with the gain schedule's entries, each tuned
        on its window (``ms`` is then the largest of ``entry_ms``, each entry's Ms over its window).
    entry_ms : tuple of float
        The schedule's entries' Ms, each over its window (empty: the robust set).
    schedule_headroom : float
        The preload schedule's headroom: its levels above the bolts' preload are this factor times the least-friction
        schedule's (1: the least-friction schedule itself; :func:`~piezopreload.design.schedule.headroom_schedule`).
    schedule_top_N : float
        The schedule's highest level over the machining cycle.
    schedule_stiffness_margin_N_per_um : float
        The schedule's least rigidity over its requirement along the cycle (what the headroom buys).
    schedule_lead_s : float
        The schedule's transitions advanced by this time (s; 0: the least-friction transitions).
    cycle_tracking_rms_N : float
        The tracking RMS along the preload schedule: the candidate's controller (its gains, the feedforward's
        inverse) following the schedule it runs (with its headroom, lead and the margin passes) on the designed
        plant for ``[plant] cycles`` machining cycles (NaN: not judged along the cycle).
    cycle_peak_voltage_V : float
        The stacks' peak command along the schedule.
    cycle_passes : int
        The schedule's margin passes the run took (1: the schedule met its requirements as planned).
    cycle_requirements : tuple of Requirement
        The schedule's requirements judged on the achieved preload while cutting
        (:func:`~piezopreload.design.system.requirements_of`).
    loop_feasible : bool or None
        Whether the controller meets the study's step and staircase limits (None: not judged along the cycle yet,
        ``feasible`` says it); ``feasible`` is this and the schedule's requirements met along the cycle.
    loop_why : str
        What the controller misses on the step and staircase ("" where it meets them).
    cycle_why : str
        What the achieved preload misses of the schedule's requirements along the cycle ("" where it meets them).
    ff_lead_s : float
        The feedforward's preview lead along the schedule (s; 0: none): the inverse P-I feedforward reads the
        schedule's reference this far ahead (:func:`~piezopreload.tuning.preview.preview_feedforward`, added to the
        controller's own feedforward as a per-sample correction, the channel the learned feedforward takes), chosen
        by the inner problem (:func:`choose_ff_lead`).
    ff_leads_tried : tuple of (float, float)
        The leads the inner problem's search tried, each ``(lead_s, tracking RMS along the least-friction schedule in
        one pass, N)``, the lead 0 first (empty: not searched).
    feedforward : IdentifiedFeedforward or None
        The feedforward identified on the candidate's plant (the cycle's run reuses it).
    least_plan : PreloadSchedule or None
        The least-friction schedule on its screw (each shape of the schedule starts from it).
    shapes : tuple of Candidate
        The schedules the inner problem chose this one from (:func:`schedule_shapes`; empty: not shaped).
    """

    point: DesignPoint = field(repr=False)
    gains: PIDGains
    coupling_stiffness_N_per_um: float
    ms: float
    friction_energy_J: float
    tracking_rms_N: float
    peak_voltage_V: float
    settling_s: float
    feasible: bool
    why: str = ""
    lift_off_N: float = math.nan
    growth_um: float = math.nan
    at: tuple[tuple[str, float], ...] = ()
    controller: str = "robust"
    entry_ms: tuple[float, ...] = ()
    schedule_headroom: float = 1.0
    schedule_top_N: float = math.nan
    schedule_stiffness_margin_N_per_um: float = math.nan
    schedule_lead_s: float = 0.0
    cycle_tracking_rms_N: float = math.nan
    cycle_peak_voltage_V: float = math.nan
    cycle_passes: int = 0
    cycle_requirements: tuple[Requirement, ...] = ()
    loop_feasible: bool | None = None
    loop_why: str = ""
    cycle_why: str = ""
    ff_lead_s: float = 0.0
    ff_leads_tried: tuple[tuple[float, float], ...] = ()
    feedforward: IdentifiedFeedforward | None = field(default=None, repr=False, compare=False)
    least_plan: PreloadSchedule | None = field(default=None, repr=False, compare=False)
    shapes: tuple[Candidate, ...] = field(default=(), repr=False, compare=False)

    def variables(self) -> dict[str, float]:
        """The outer variables' values (the design's read off its point where it was not designed at them) and the
        schedule's shape the inner problem chose."""
        out = dict(self.at) if self.at else {name: float(getattr(self.point, attr)) for name, attr, _ in VARIABLES}
        return {**out, "schedule_headroom": float(self.schedule_headroom),
                "schedule_lead_s": float(self.schedule_lead_s), "feedforward_lead_s": float(self.ff_lead_s)}

    def ff_lead_bought(self) -> tuple[float, float] | None:
        """The tracking RMS along the least-friction schedule (one pass) without the feedforward's lead and with the
        chosen one (N), as the inner problem's search measured them; None where it did not search."""
        tried = dict(self.ff_leads_tried)
        if 0.0 not in tried or self.ff_lead_s not in tried:
            return None
        return tried[0.0], tried[self.ff_lead_s]

    def objective(self, weights: CodesignWeights, reference: Candidate) -> float:
        """The weighted sum of the terms, each over ``reference``'s (the sequential answer's), over the weights' sum."""
        total = sum(getattr(weights, n) for n, _, _ in TERMS)
        return sum(getattr(weights, n) * getattr(self, a) / getattr(reference, a)
                   for n, a, _ in TERMS if getattr(weights, n) > 0) / total

    def to_dict(self) -> dict[str, Any]:
        p, bought = self.point, self.ff_lead_bought()
        return {"design": {"contact_angle_deg": p.contact_angle_deg, "conformity": p.conformity,
                           "ball_mm": p.ball_mm, "turns": p.turns, "balls_per_turn": p.balls_per_turn,
                           "bolt_preload_N": p.bolt_preload_N, "max_preload_N": p.max_preload_N,
                           "stiffness_N_per_um": p.stiffness_N_per_um, "life_h": p.life_h,
                           "mean_drag_torque_Nm": p.mean_drag_torque_Nm},
                "gains": {"Kc_V_per_N": self.gains.Kc, "Ti_s": self.gains.Ti_s, "Td_s": self.gains.Td_s,
                          "Tf_s": self.gains.Tf_s, "b": self.gains.b},
                "controller": self.controller, "entry_ms": list(self.entry_ms),
                "feedforward": {"lead_s": self.ff_lead_s, "lead_bounds_s": [0.0, FF_LEAD_MAX_S],
                                "tracking_rms_without_lead_N": None if bought is None else bought[0],
                                "tracking_rms_with_lead_N": None if bought is None else bought[1],
                                "leads_tried": [{"lead_s": lead, "tracking_rms_N": rms}
                                                for lead, rms in self.ff_leads_tried]},
                "preload_schedule": {"headroom": self.schedule_headroom, "lead_s": self.schedule_lead_s,
                                     "top_N": self.schedule_top_N,
                                     "stiffness_margin_min_N_per_um": self.schedule_stiffness_margin_N_per_um,
                                     "shapes_tried": [{"headroom": c.schedule_headroom, "lead_s": c.schedule_lead_s,
                                                       "margin_passes": c.cycle_passes,
                                                       "friction_energy_J": c.friction_energy_J,
                                                       "tracking_rms_N": _finite(c.cycle_tracking_rms_N),
                                                       "meets": c.feasible} for c in self.shapes]},
                "cycle": {"tracking_rms_N": _finite(self.cycle_tracking_rms_N),
                          "peak_voltage_V": _finite(self.cycle_peak_voltage_V), "margin_passes": self.cycle_passes,
                          "requirements": [{"requirement": r.name, "value": r.value, "limit": r.limit,
                                            "unit": r.unit, "sense": r.sense, "met": r.met}
                                           for r in self.cycle_requirements]},
                "schedule": None if self.gains.schedule is None else {
                    "levels_N": list(self.gains.schedule.levels_N), "Kc_V_per_N": list(self.gains.schedule.Kc),
                    "Ti_s": list(self.gains.schedule.Ti_s), "Td_s": list(self.gains.schedule.Td_s),
                    "b": None if self.gains.schedule.b is None else list(self.gains.schedule.b)},
                "coupling_stiffness_N_per_um": self.coupling_stiffness_N_per_um, "ms": self.ms,
                "friction_energy_J": self.friction_energy_J, "tracking_rms_N": self.tracking_rms_N,
                "peak_voltage_V": self.peak_voltage_V, "settling_s": self.settling_s, "lift_off_N": self.lift_off_N,
                "growth_um": None if math.isnan(self.growth_um) else self.growth_um,
                "feasible": self.feasible,
                "why": self.why}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class _Inner:
    """What the inner problems share: the study's pieces read once."""

    study: StudySpec
    spec: DesignSpec
    objective: str
    tuning: TuningSpec
    schedule_limits: dict[str, float]
    max_iterations: int
    say: Callable[[str], None]


def _designed(study: StudySpec, point: DesignPoint) -> DesignedPlant:
    table = study.plant_table or PlantTable()
    return table.plant(study.design_spec, point, study.rig)  # type: ignore[arg-type]


def _plant(study: StudySpec, point: DesignPoint) -> Plant:
    return _designed(study, point).rig


def _nominal(study: StudySpec, plant: Plant, gains: PIDGains, ff: IdentifiedFeedforward) -> dict[str, float]:
    """The gains on the nominal plant over the study's step and staircase (the validation's first plant)."""
    r = validate(gains, ff.model, plant, study.validation, n_plants=1, seed=study.seed,
                 step=study.references["step"], trajectory=study.references["trajectory"])
    return {k: float(r.metrics[k][0]) for k in ("tracking_rms_N", "peak_voltage_V", "settling_s", "overshoot_N")}


def _levels(study: StudySpec) -> np.ndarray | None:
    """The gain schedule's levels the study tunes (``[tuning] schedule_levels``; None: one robust set)."""
    n = study.tuning.schedule_levels
    if n < 2:
        return None
    span = np.concatenate([study.references[k].levels_N for k in ("step", "trajectory")])
    return schedule_levels(float(span.min()), float(span.max()), n)


def _misses(nominal: dict[str, float], c: Criteria) -> list[str]:
    out = []
    if nominal["tracking_rms_N"] > c.tracking_rms_max_N:
        out.append(f"tracking RMS {nominal['tracking_rms_N']:.1f} N > {c.tracking_rms_max_N:g} N "
                   "([validation] tracking_rms_max_N)")
    if not nominal["settling_s"] <= c.settling_max_s:  # NaN: never settled
        out.append(f"settling {nominal['settling_s']:.3f} s > {c.settling_max_s:g} s ([validation] settling_max_s)")
    return out


def evaluate_design(study: StudySpec, point: DesignPoint, *, start: PIDGains | None = None,
                    tuning: TuningSpec | None = None, max_iterations: int = 60,
                    feedforward: IdentifiedFeedforward | None = None, schedule: bool = False,
                    headroom: float = 1.0, lead_s: float = 0.0, cycle_binding: bool = True,
                    ff_lead: bool = True) -> Candidate:
    """The inner problem for one design: its plant, the feedforward identified on it, the PID tuned on it (Ms inside),
    the gain schedule's entries tuned on it (each at Ms over its own window) where the study tunes a schedule, and
    what the better controller achieves on the nominal plant (the whole-range tracking and the step, the schedule's
    friction).

    The controller is part of the inner problem's decisions: the robust set, or the robust set with the schedule's
    entries (Kc, Ti, Td and b each, tuned on its window by :func:`~piezopreload.tuning.schedule.tune_entries`),
    whichever meets the tracking and settling limits with the lower tracking RMS. ``schedule``: tune the entries
    (the study's ``[tuning] schedule_levels``, at least 2); False: the one robust set. ``headroom``, ``lead_s``: the
    preload schedule's factor on its least-friction levels and its transitions' lead (:func:`with_headroom`, which
    then runs the controller along that schedule; 1 and 0: the least-friction schedule); ``cycle_binding``: whether
    the schedule's requirements along the cycle are constraints (:func:`with_headroom`'s ``binding``); ``ff_lead``:
    choose the feedforward's preview lead along the schedule (:func:`choose_ff_lead`; False: none, 0 s).

    Raises :class:`~piezopreload.core.errors.InfeasibleError` naming the binding pair where no gains the tuning
    finds meet the study's Ms limit together with the tuning's other constraints.
    """
    spec = study.design_spec
    if spec is None:
        raise InputError(f"{study.path}: co-design needs the design's tables ([ballscrew], [design])")
    tuning = tuning or study.tuning
    plant = _plant(study, point)
    ff = feedforward or identify(study, Solved(study, point))
    known = None if start is None else {"the sequential gains": replace(start, schedule=None)}
    try:
        tuned = tune_pid(plant, ff.inverse(), tuning, starts=1, max_iterations=max_iterations, known=known)
    except TuningInfeasible as exc:
        raise InfeasibleError(f"{study.path}: the design (contact angle {point.contact_angle_deg:.2f} deg, conformity "
                              f"{point.conformity:.4f}, rigidity {point.stiffness_N_per_um:.0f} N/um) has no "
                              f"controller that meets Ms <= {tuning.ms_max:g} ([tuning] ms_max) with the tuning's "
                              f"other constraints: {exc}") from exc
    c = study.validation
    robust = tuned.found()
    gains, ms, controller = robust, float(tuned.ms), "robust"
    entry_ms: tuple[float, ...] = ()
    nominal = _nominal(study, plant, gains, ff)
    misses = _misses(nominal, c)
    levels = _levels(study) if schedule else None
    if schedule and levels is None:  # said before any tuning by codesign()
        raise InputError(f"{study.path}: a schedule's entries in the co-design need [tuning] schedule_levels >= 2")
    if levels is not None:
        entries, records = tune_entries(plant, ff.model, tuning, robust, levels_N=levels,
                                        step=study.references["step"], trajectory=study.references["trajectory"],
                                        starts=1, max_iterations=max_iterations)
        scheduled = replace(robust, schedule=entries)
        nominal_s = _nominal(study, plant, scheduled, ff)
        misses_s = _misses(nominal_s, c)
        # the schedule where it meets the limits the robust set misses, or meets them too and tracks better
        if not misses_s and (misses or nominal_s["tracking_rms_N"] < nominal["tracking_rms_N"]):
            gains, nominal, misses, controller = scheduled, nominal_s, misses_s, "schedule"
            entry_ms = tuple(float(r["ms"]) for r in records)
            ms = max(entry_ms)
    why = ""
    if misses:
        binding = ", ".join(tuned.binding) or "none"
        why = (f"with Ms <= {tuning.ms_max:g} ([tuning] ms_max; binding: {binding}) the best gains miss "
               + "; ".join(misses))
    cand = Candidate(point, gains, float(plant.coupling_stiffness_N_per_um), ms, math.nan,
                     nominal["tracking_rms_N"], nominal["peak_voltage_V"], nominal["settling_s"], not misses, why,
                     float(lift_off_load_N(point.bolt_preload_N)),
                     math.nan if study.thermal is None else float(duty_growth_um(spec, point, study.thermal)),
                     controller=controller, entry_ms=entry_ms, feedforward=ff)
    if ff_lead and not misses:  # the feedforward's lead for this loop (none mends a loop the step or staircase fail)
        cand = choose_ff_lead(study, cand)
    return with_headroom(study, cand, headroom, lead_s, binding=cycle_binding)


def planned_schedule(study: StudySpec, point: DesignPoint, headroom: float = 1.0, lead_s: float = 0.0,
                     least: PreloadSchedule | None = None) -> PreloadSchedule:
    """The preload schedule a candidate plans: the least-friction schedule on the screw of ``point`` (the study's
    ``[schedule]`` limits, the machining cycle), its levels above the bolts' preload raised by ``headroom`` and its
    transitions advanced by ``lead_s`` (:func:`~piezopreload.design.schedule.headroom_schedule`); ``least``: that
    least-friction schedule, planned already.

    Raises :class:`~piezopreload.core.errors.InfeasibleError` where the raised levels pass the stacks' reach.
    """
    spec = study.design_spec
    if spec is None:
        raise InputError(f"{study.path}: co-design needs the design's tables ([ballscrew], [design])")
    plan = least or plan_schedule(spec, point, None, **(study.schedule or ScheduleTable()).limits())[0]
    try:
        return headroom_schedule(spec.screw(point), plan, headroom, lead_s)
    except ValueError as exc:
        raise InfeasibleError(f"{study.path}: the design (rigidity {point.stiffness_N_per_um:.0f} N/um): {exc}") \
            from None


def along_schedule(study: StudySpec, cand: Candidate, plan: PreloadSchedule, passes: int | None = None,
                   lead_s: float | None = None) -> SystemRun:
    """``cand``'s controller (its gains with the inverse of the feedforward identified on its plant, read ahead by
    its feedforward's lead, ``cand.ff_lead_s``, or ``lead_s`` where given) following ``plan`` on the designed plant,
    as the study's system stage runs it: the pre-cycle held the settling limit, then ``[plant] cycles`` machining
    cycles, the schedule planned again with local margins while a requirement is missed (``passes`` at most; None:
    ``[plant] passes``; :func:`~piezopreload.design.system.track_schedule`), without the learned correction."""
    designed = _designed(study, cand.point)
    ff = cand.feedforward or identify(study, Solved(study, cand.point))
    dt = float(designed.rig.sample_period_s)
    controller = Controller(cand.gains, dt, ff.inverse())
    table = study.plant_table or PlantTable()
    if passes is not None:
        table = replace(table, passes=int(passes))
    lead = int(round(lead_s / dt)) if lead_s is not None else int(round(cand.ff_lead_s / dt))
    ahead = None if lead == 0 else lambda r: preview_feedforward(
        controller, r.at(np.arange(int(round(r.duration_s / dt)) + 1) * dt), lead)
    return table.track(designed, controller, plan, seed=study.seed, settle_s=study.validation.settling_max_s,
                       ff_extra_V=ahead)


def choose_ff_lead(study: StudySpec, cand: Candidate) -> Candidate:
    """The inner problem's feedforward lead for ``cand``'s design and controller: the preview lead in ``[0,``
    :data:`FF_LEAD_MAX_S` ``]`` (whole samples) with the least tracking RMS along the least-friction schedule, run
    once (no margin pass) as :func:`along_schedule` runs it.

    A bounded scalar search: golden sections of the bracket on whole samples until it spans at most 3, then every
    lead left in it (the least of a unimodal RMS exactly, either bound included, in about 10 runs for 50 samples);
    the lead 0 is tried first and kept unless a lead tracks better (of equal RMS, the shorter lead).

    Parameters
    ----------
    study : StudySpec
        The study.
    cand : Candidate
        The inner problem's candidate (its design and its controller).

    Returns
    -------
    Candidate
        ``cand`` with ``ff_lead_s`` chosen and ``ff_leads_tried`` (each lead tried with its tracking RMS, N).
    """
    plan = cand.least_plan if cand.least_plan is not None else planned_schedule(study, cand.point)
    if cand.feedforward is None:
        cand = replace(cand, feedforward=identify(study, Solved(study, cand.point)))
    cand = replace(cand, least_plan=plan)
    dt = float(_plant(study, cand.point).sample_period_s)
    top = int(math.floor(FF_LEAD_MAX_S / dt + 1e-9))
    tried: dict[int, float] = {}

    def rms(k: int) -> float:
        if k not in tried:
            run = along_schedule(study, cand, plan, 1, k * dt)
            tried[k] = float(run.evaluation.numbers.tracking_rms_N)
        return tried[k]

    rms(0)
    lo, hi = 0, top
    while hi - lo > 3:
        low = hi - round(_GOLDEN * (hi - lo))
        high = max(lo + round(_GOLDEN * (hi - lo)), low + 1)  # two probes, however the rounding falls
        if rms(low) <= rms(high):  # the least lies at or below the upper probe
            hi = high
        else:
            lo = low
    for k in range(lo, hi + 1):
        rms(k)
    best = min(tried, key=lambda k: (tried[k], k))  # the least RMS; of equals, the shorter lead
    return replace(cand, ff_lead_s=best * dt, ff_leads_tried=tuple((k * dt, tried[k]) for k in tried))


def with_headroom(study: StudySpec, cand: Candidate, headroom: float, lead_s: float = 0.0, *,
                  binding: bool = True) -> Candidate:
    """``cand`` running the schedule with ``headroom`` and ``lead_s`` (:func:`planned_schedule`), judged along it.

    The controller follows the schedule (:func:`along_schedule`). Two ways give the loop the room its lag needs: at
    headroom 1 and lead 0 (the least-friction schedule, as the study's schedule stage plans it) the system stage's
    margin passes (the plan again with local margins where the loop's achieved preload fell short, ``[plant]
    passes`` at most); with a headroom or a lead the shaped plan is the room, run in one pass (a margin pass plans
    the least-friction schedule again, which would undo the shape). The candidate's friction energy, top level and
    rigidity margin are those of the schedule the loop ends on, its tracking RMS along the cycle and the schedule's
    requirements on the achieved preload while cutting are its own. It is feasible where the controller meets the
    study's step and staircase limits and the achieved preload meets every requirement of the schedule (``binding``
    False: the controller's limits alone, the schedule's verdicts kept in ``cycle_why`` for the study's system stage
    to judge with its learned feedforward). The design and the controller are the same (their tuning is judged over
    the study's references; the schedule's shape is applied to its answer).
    """
    if cand.least_plan is None:  # planned once, kept for the candidate's other shapes
        cand = replace(cand, least_plan=planned_schedule(study, cand.point))
    plan = planned_schedule(study, cand.point, headroom, lead_s, cand.least_plan)
    if cand.feedforward is None:  # identified once, kept for the candidate's other schedules
        cand = replace(cand, feedforward=identify(study, Solved(study, cand.point)))
    loop_ok = cand.feasible if cand.loop_feasible is None else cand.loop_feasible
    loop_why = cand.why if cand.loop_feasible is None else cand.loop_why
    run = along_schedule(study, cand, plan, None if headroom == 1.0 and lead_s == 0.0 else 1)
    ev, final = run.evaluation, run.schedule
    missed = [f"{r.name} {r.value:.4g} {r.unit} against {r.sense.words} "
              f"{r.limit:.4g} {r.unit}" for r in ev.requirements if not r.met]
    cycle_why = (f"along the preload schedule (after {len(run.passes)} margin passes) the achieved preload misses "
                 + "; ".join(missed)) if missed else ""
    return replace(cand, friction_energy_J=float(final.friction_energy_J), schedule_headroom=float(headroom),
                   schedule_lead_s=float(lead_s), schedule_top_N=float(np.max(final.preload_N)),
                   schedule_stiffness_margin_N_per_um=float(np.min(final.rigidity_N_per_um - final.required_N_per_um)),
                   cycle_tracking_rms_N=float(ev.numbers.tracking_rms_N),
                   cycle_peak_voltage_V=float(ev.numbers.peak_voltage_V), cycle_passes=len(run.passes),
                   cycle_requirements=tuple(ev.requirements),
                   loop_feasible=bool(loop_ok), loop_why=loop_why, cycle_why=cycle_why,
                   feasible=bool(loop_ok) and not (missed and binding),
                   why="; ".join(w for w in (loop_why, cycle_why if binding else "") if w))


def _slack(cand: Candidate) -> float:
    """The least margin of the schedule's requirements along the cycle, each over its limit (>= 0: all met)."""
    return min(r.sense.margin(r.value, r.limit) / r.limit for r in cand.cycle_requirements if r.limit > 0)


def _least_headroom(study: StudySpec, cand: Candidate, lead_s: float) -> Candidate | None:
    """The least headroom (to the regula falsi's tolerance, feasible side) with which ``cand``'s loop meets the
    schedule's requirements along the cycle on the schedule led by ``lead_s``; None where even the most the stacks'
    reach and :data:`HEADROOM_MAX` allow does not."""
    def run(h: float) -> Candidate | None:
        try:
            return with_headroom(study, cand, h, lead_s)
        except InfeasibleError:  # past the stacks' reach
            return None

    low = run(1.0)
    if low is None or low.feasible:
        return low
    hi_h = HEADROOM_MAX
    high = run(hi_h)
    while high is None and hi_h > 1.01:  # the stacks' reach: less headroom
        hi_h = 1.0 + 0.5 * (hi_h - 1.0)
        high = run(hi_h)
    if high is None or not high.feasible:
        return None
    lo_h, g_lo, g_hi = 1.0, _slack(low), _slack(high)
    for _ in range(SHAPE_STEPS):
        span = hi_h - lo_h
        h = lo_h + span * min(0.9, max(0.1, -g_lo / (g_hi - g_lo)))  # kept inside the bracket
        c = run(h)
        if c is None:
            break
        if c.feasible:
            hi_h, high, g_hi = h, c, _slack(c)
        else:
            lo_h, g_lo = h, _slack(c)
    return high


def schedule_shapes(study: StudySpec, cand: Candidate) -> tuple[Candidate, ...]:
    """The preload schedules the inner problem chooses from for ``cand``'s design and controller, each judged along
    the cycle: the least-friction schedule with the system stage's margin passes (headroom 1, lead 0: the sequential
    answer's way) first, then for each lead of :data:`LEADS_S` the least headroom with which the loop meets the
    schedule's requirements in one pass (:func:`with_headroom`), where one does. Only the first where ``cand``'s
    controller misses the study's step or staircase limits (no schedule mends those).

    Parameters
    ----------
    study : StudySpec
        The study.
    cand : Candidate
        The inner problem's candidate (its design and its controller).

    Returns
    -------
    tuple of Candidate
        ``cand`` on each schedule; the least-friction one with the margin passes first.
    """
    loop_ok = cand.feasible if cand.loop_feasible is None else cand.loop_feasible
    base = cand if cand.loop_feasible is not None and cand.schedule_headroom == 1.0 and cand.schedule_lead_s == 0.0 \
        else with_headroom(study, cand, 1.0, 0.0)
    base = replace(base, shapes=())
    if not loop_ok:
        return (base,)
    found = [_least_headroom(study, base, lead) for lead in LEADS_S]
    return (base, *(c for c in found if c is not None))


def shape_schedule(study: StudySpec, cand: Candidate, weights: CodesignWeights | None = None,
                   reference: Candidate | None = None) -> Candidate:
    """The inner problem's preload schedule for ``cand``'s design and controller: of :func:`schedule_shapes` (kept on
    the answer, ``shapes``, and reused from ``cand`` where it has them), the one that meets the schedule's
    requirements along the cycle with the least objective.

    The loop's lag sets what each shape needs, so the gains and the schedule trade: a loop that lags less needs less
    headroom and lead, and so less friction, and follows the lower levels more closely.

    Parameters
    ----------
    study : StudySpec
        The study.
    cand : Candidate
        The inner problem's candidate (its design, its controller).
    weights : CodesignWeights, optional
        The objective's weights (None: the least friction per cycle alone, the schedule stage's own objective).
    reference : Candidate, optional
        The candidate the objective's terms are read over (the sequential answer; needed with ``weights``).

    Returns
    -------
    Candidate
        ``cand`` on the chosen schedule, judged along it (the least-friction schedule with the margin passes where
        no shape meets the requirements, or where it is as good).
    """
    shapes = cand.shapes or schedule_shapes(study, cand)
    if weights is not None and reference is None:
        raise InputError("shape_schedule: weights need the reference candidate their terms are read over")
    met = [c for c in shapes if c.feasible]
    if not met:
        return replace(shapes[0], shapes=shapes)

    def key(c: Candidate) -> float:
        return c.friction_energy_J if weights is None else c.objective(weights, reference)  # type: ignore[arg-type]

    return replace(min(met, key=key), shapes=shapes)  # the first of equals: the least-friction plan with its margins


@dataclass(frozen=True)
class CodesignResult:
    """The sequential answer and the co-designed one, each validated by the same Monte Carlo.

    Parameters
    ----------
    study : str
        The study's name.
    strategy : str
        How the co-design was solved (``"nested"``: the design outside, the tuning inside).
    weights : CodesignWeights
        The objective's weights.
    sequential : Candidate
        The sequential answer: the design NLP's optimum, then the tuning on its plant.
    codesigned : Candidate
        The co-designed answer (the sequential one where nothing beat it).
    objective_sequential : float
        The sequential answer's weighted objective (1 by the normalisation).
    objective_codesigned : float
        The co-designed answer's weighted objective.
    evaluations : int
        Inner problems solved (the sequential start included).
    infeasible : tuple of str
        The outer candidates refused and why.
    sequential_s : float
        Wall time of the sequential design plus tuning.
    codesign_s : float
        Wall time of the co-design's outer search after it.
    limits : dict
        The requirements' limits (the design's, the tuning's Ms, the validation's tracking RMS).
    candidates : tuple of Candidate
        Every feasible design-and-controller pair the search scored, the sequential start first (a co-designed
        front's points).
    validation_sequential : ValidationResult or None
        The sequential answer's Monte Carlo (None where not run).
    validation_codesigned : ValidationResult or None
        The co-designed answer's Monte Carlo, on the same plants' draw (None where not run).
    strategy_why : str
        Why that strategy, in words (:data:`STRATEGY_WHY`).
    evaluated : dict
        The inner problems solved, by the design variables' values (the headroom applied after them): the candidate
        at headroom 1 (None: refused) and why refused (a front's sweep starts from them).
    least_heat_N_per_um : float
        The least-heat design's least rigidity, the outer floor's low end (NaN: not computed).
    schedule : bool
        Whether the gain schedule's entries were decisions of the inner problem.
    shape : bool
        Whether the preload schedule's headroom and lead were outer variables (False: the least-friction schedule).
    study_levels : int
        The gain schedule's entries the study's own tune stage makes (``[tuning] schedule_levels``; below 2: one
        robust set), so that words on a co-design of the robust set alone say what the study runs instead.
    follows_study : bool
        Whether the controller compared was the study's own choice (``schedule=None``, the default) rather than asked
        for (``schedule`` True or False).
    ff_lead : bool
        Whether the feedforward's preview lead along the schedule was a decision of the inner problem.
    """

    study: str
    strategy: str
    weights: CodesignWeights
    sequential: Candidate
    codesigned: Candidate
    objective_sequential: float
    objective_codesigned: float
    evaluations: int
    infeasible: tuple[str, ...]
    sequential_s: float
    codesign_s: float
    limits: dict[str, float] = field(default_factory=dict, repr=False)
    candidates: tuple[Candidate, ...] = field(default=(), repr=False)
    validation_sequential: ValidationResult | None = field(default=None, repr=False)
    validation_codesigned: ValidationResult | None = field(default=None, repr=False)
    strategy_why: str = field(default=STRATEGY_WHY, repr=False)
    #: the inner problems solved, by the outer variables (a front's sweep starts from them)
    evaluated: dict[tuple[float, ...], tuple[Candidate | None, str]] = field(default_factory=dict, repr=False,
                                                                             compare=False)
    least_heat_N_per_um: float = field(default=math.nan, repr=False)
    #: whether the gain schedule's entries were decisions of the inner problem (``codesign(schedule=True)``)
    schedule: bool = field(default=False, repr=False)
    #: whether the preload schedule's headroom and lead were searched (``codesign(shape=True)``)
    shape: bool = field(default=True, repr=False)
    #: the gain schedule's entries the study's tune stage makes (``[tuning] schedule_levels``)
    study_levels: int = field(default=0, repr=False)
    #: whether the controller followed the study (``codesign(schedule=None)``) rather than being asked for
    follows_study: bool = field(default=True, repr=False)
    #: whether the feedforward's preview lead was the inner problem's (``codesign(ff_lead=True)``)
    ff_lead: bool = field(default=True, repr=False)

    @property
    def objective_ratio(self) -> float:
        """Co-designed over sequential objective (<= 1 by construction)."""
        return self.objective_codesigned / self.objective_sequential

    @property
    def time_ratio(self) -> float:
        """The whole co-design's time (the sequential start included) over the sequential design and tuning."""
        return (self.sequential_s + self.codesign_s) / self.sequential_s

    def controller_words(self) -> str:
        """What the co-design chose of the controller, in words: the robust set or the gain schedule, its gains and
        the Ms each was tuned under.

        Returns
        -------
        str
            ``one robust PID set ...`` with its gains, or ``the gain schedule ...`` with each entry's level, gains
            and Ms over its window.
        """
        c, ms_max = self.codesigned, self.limits.get("ms_max", math.nan)
        g = c.gains
        robust = f"Kc {g.Kc:.4g} V/N, Ti {g.Ti_s * 1e3:.3g} ms, Td {g.Td_s * 1e3:.3g} ms, b {g.b:.3g}"
        if c.controller == "schedule" and g.schedule is not None:
            s = g.schedule
            entries = "; ".join(f"{lv:,.0f} N: Kc {kc:.4g} V/N, Ti {ti * 1e3:.3g} ms, Ms {ms:.3f}"
                                for lv, kc, ti, ms in zip(s.levels_N, s.Kc, s.Ti_s, c.entry_ms))
            return (f"the gain schedule, each entry tuned on the candidate's plant at Ms <= {ms_max:g} over its "
                    f"window ({entries}), around the robust set ({robust})")
        why = " (the schedule's entries, tuned too, tracked no better)" if self.schedule else ""
        if not self.schedule and self.study_levels >= 2:  # what the study itself runs is not what was compared
            why = (f" (asked for: the study's tune stage makes a {self.study_levels}-entry gain schedule, not tuned "
                   "here: both answers are compared with one robust set; by default the co-design follows the "
                   "study and tunes the entries inside)")
        return f"one robust PID set tuned on the candidate's plant at Ms <= {ms_max:g} ({robust}){why}"

    def feedforward_words(self) -> str:
        """What the co-design chose of the feedforward's settings, and what it bought, in words.

        Returns
        -------
        str
            The preview lead chosen (the inverse P-I feedforward reading the schedule's reference that far ahead),
            its bounds, the tracking RMS along the least-friction schedule without and with it, and where the study's
            own stages and the Monte Carlo run without it; or why no lead was chosen.
        """
        c = self.codesigned
        if not self.ff_lead:
            return ("no feedforward lead: the inverse P-I feedforward reads the reference as it comes, as the study's "
                    "own stages run it (their feedforward along the schedule is the learned one, which carries no "
                    "lead; codesign without [design] method = \"codesign\" chooses one)")
        bought = c.ff_lead_bought()
        if bought is None:  # no search: the sequential answer kept as the study runs it
            return "no feedforward lead (the sequential answer kept: the study's controller, without one)"
        tried = len(c.ff_leads_tried)
        if c.ff_lead_s == 0.0:
            lead, rms = min(((lead, rms) for lead, rms in c.ff_leads_tried if lead > 0), key=lambda t: (t[1], t[0]),
                            default=(math.nan, math.nan))
            return (f"no feedforward lead: of the leads in [0, {1e3 * FF_LEAD_MAX_S:.3g}] ms the bounded scalar search "
                    f"tried ({tried}), none tracked the least-friction schedule (one pass) better than none "
                    f"({bought[0]:.2f} N; the best lead, {1e3 * lead:.3g} ms, {rms:.2f} N)")
        return (f"the inverse P-I feedforward reads the schedule's reference {1e3 * c.ff_lead_s:.3g} ms ahead, chosen "
                f"in [0, {1e3 * FF_LEAD_MAX_S:.3g}] ms by a bounded scalar search ({tried} leads tried): tracking RMS "
                f"along the least-friction schedule (one pass) {bought[0]:.2f} N without a lead, {bought[1]:.2f} N "
                "with it; the step, the staircase and the Monte Carlo run the feedforward without it, as the study's "
                "validate stage does, and the study's own stages cannot carry it (they run the learned feedforward "
                "along the schedule)")

    def changed(self) -> list[str]:
        """What the co-design changed in the design, in the design's units.

        Returns
        -------
        list of str
            One line per design variable that differs, ``NAME OLD -> NEW UNIT`` (the contact angle in deg, the ball in
            mm, the bolts' preload in N, the stiffness in N/um, the life in h), and the preload schedule's headroom
            where it differs (its top level in N and its least rigidity margin over the cycle's requirement in N/um,
            what the headroom bought); empty where the co-design kept the sequential design and schedule.
        """
        a, b = self.sequential.point, self.codesigned.point
        rows = []
        for name, unit in (("contact_angle_deg", "deg"), ("conformity", ""), ("ball_mm", "mm"), ("turns", ""),
                           ("balls_per_turn", ""), ("bolt_preload_N", "N"), ("stiffness_N_per_um", "N/um"),
                           ("life_h", "h")):
            x, y = float(getattr(a, name)), float(getattr(b, name))
            if not math.isclose(x, y, rel_tol=1e-6, abs_tol=1e-9):
                rows.append(f"{name} {x:.4g} -> {y:.4g}{' ' + unit if unit else ''}")
        s, c = self.sequential, self.codesigned
        if not math.isclose(s.schedule_headroom, c.schedule_headroom, rel_tol=1e-9):
            rows.append(f"schedule_headroom {s.schedule_headroom:.4g} -> {c.schedule_headroom:.4g} (the schedule's top "
                        f"level {s.schedule_top_N:,.0f} -> {c.schedule_top_N:,.0f} N; its least rigidity margin over "
                        f"the cycle's requirement {s.schedule_stiffness_margin_N_per_um:,.0f} -> "
                        f"{c.schedule_stiffness_margin_N_per_um:,.0f} N/um)")
        if not math.isclose(s.schedule_lead_s, c.schedule_lead_s, rel_tol=1e-9, abs_tol=1e-12):
            rows.append(f"schedule_lead_s {s.schedule_lead_s:.4g} -> {c.schedule_lead_s:.4g} s (the schedule's rises "
                        f"{1e3 * c.schedule_lead_s:.3g} ms before the loads that need them)")
        if not math.isclose(s.ff_lead_s, c.ff_lead_s, rel_tol=1e-9, abs_tol=1e-12):
            rows.append(f"feedforward_lead_s {s.ff_lead_s:.4g} -> {c.ff_lead_s:.4g} s ({self.feedforward_words()})")
        if s.cycle_passes != c.cycle_passes:
            rows.append(f"margin passes along the schedule {s.cycle_passes} -> {c.cycle_passes} (passes the loop's "
                        "shortfall asked the schedule to be planned again with local margins)")
        return rows

    def bought(self) -> list[dict[str, Any]]:
        """Each objective term: sequential, co-designed, the change, and its weighted share of the objective's
        change.

        Returns
        -------
        list of dict
            One row per objective term the study has (growth left out without ``[thermal]``): ``term``, ``unit``, the
            ``sequential`` and the ``codesigned`` value, their ``change``, the term's ``weight``, and
            ``objective_change``, the weighted relative change as a share of the weights' sum (negative: the term fell).
        """
        total = sum(getattr(self.weights, n) for n, _, _ in TERMS)
        rows = []
        for name, attr, unit in TERMS:
            s, c = getattr(self.sequential, attr), getattr(self.codesigned, attr)
            if math.isnan(s):  # growth without [thermal]
                continue
            w = getattr(self.weights, name)
            rows.append({"term": name, "unit": unit, "sequential": s, "codesigned": c, "change": c - s,
                         "weight": w, "objective_change": w * (c / s - 1.0) / total})
        return rows

    def coupling(self) -> str:
        """Which coupling bought the difference: the term whose weighted change is the largest fall.

        Returns
        -------
        str
            ``TERM: how the design reaches it`` for the term of :meth:`bought` with the largest weighted fall, or a
            sentence starting ``none:`` where no term fell.
        """
        rows = self.bought()
        best = min(rows, key=lambda r: r["objective_change"])
        if best["objective_change"] >= -1e-9:
            return ("none: no candidate the search tried beat the sequential design (every step away from it raised "
                    "the weighted objective or missed a requirement)")
        how = {"growth": "the nut's drag heat (the contact angle and conformity set the drag, the drag the growth)",
               "friction": "the schedule's friction (the screw's contact angle and conformity set its drag)",
               "tracking": "the loop along the schedule (the nut's stiffness against the stacks sets the force per "
                           "volt the loop's Ms limit allows; the schedule's levels and transitions what it follows)",
               "voltage": "the stacks' command (the force per volt sets the voltage a force needs)"}[best["term"]]
        return f"{best['term']}: {how}"

    def requirements(self) -> list[dict[str, Any]]:
        """Each requirement: its limit, the sequential's and the co-designed figure, in the requirement's units.

        Returns
        -------
        list of dict
            One row per requirement: ``requirement`` (in words), ``unit``, ``limit`` (None where the study sets none),
            ``kind`` (``min`` or ``max``), and the ``sequential`` and the ``codesigned`` design's figure; the Monte
            Carlo validation's rows where both designs were validated.
        """
        a, b = self.sequential, self.codesigned
        lim = self.limits
        rows: list[dict[str, Any]] = [
            # the design's own floor (0, the default, is none: the schedule's rigidity is judged along the cycle)
            {"requirement": "least rigidity over the duty", "unit": "N/um",
             "limit": lim.get("stiffness_min_N_per_um") or None,
             "kind": Sense.AT_LEAST, "sequential": a.point.stiffness_N_per_um,
             "codesigned": b.point.stiffness_N_per_um},
            {"requirement": "lift-off load at the bolts' preload", "unit": "N", "limit": lim.get("lift_off_min_N"),
             "kind": Sense.AT_LEAST, "sequential": a.lift_off_N, "codesigned": b.lift_off_N},
            {"requirement": "rating life", "unit": "h", "limit": lim.get("life_min_h"), "kind": Sense.AT_LEAST,
             "sequential": a.point.life_h, "codesigned": b.point.life_h},
            {"requirement": "Ms over the tuning's variants", "unit": "", "limit": lim.get("ms_max"),
             "kind": Sense.AT_MOST,
             "sequential": a.ms, "codesigned": b.ms},
            {"requirement": "nominal tracking RMS, whole range", "unit": "N", "limit": lim.get("tracking_rms_max_N"),
             "kind": Sense.AT_MOST, "sequential": a.tracking_rms_N, "codesigned": b.tracking_rms_N},
            {"requirement": "nominal tracking RMS along the preload schedule", "unit": "N", "limit": None,
             "kind": Sense.AT_MOST, "sequential": a.cycle_tracking_rms_N, "codesigned": b.cycle_tracking_rms_N},
            # what the schedule's headroom buys: rigidity above the cycle's requirement (the planned schedule's
            # least margin; 0 is the requirement met exactly)
            {"requirement": "preload schedule's least rigidity over the cycle's requirement", "unit": "N/um",
             "limit": 0.0, "kind": Sense.AT_LEAST, "sequential": a.schedule_stiffness_margin_N_per_um,
             "codesigned": b.schedule_stiffness_margin_N_per_um},
        ]
        # the schedule's requirements on the achieved preload while cutting, judged along the cycle: each as the
        # achieved over the required (the sample each is judged at, and so its limit, is each run's own)
        theirs = {r.name: r.value / r.limit for r in b.cycle_requirements if r.limit > 0}
        for r in a.cycle_requirements:
            if r.name in theirs and r.limit > 0:
                rows.append({"requirement": f"along the preload schedule: {r.name}, achieved over required",
                             "unit": "", "limit": 1.0, "kind": r.sense, "sequential": r.value / r.limit,
                             "codesigned": theirs[r.name]})
        if not math.isnan(a.growth_um):
            # the design's estimate over the duty cycle (the stiffness:growth front's y); the study's limit
            # (thermal_growth_max_um) is judged by the system stage along the controlled schedule, not here
            rows.append({"requirement": "thermal growth over the shift, duty-cycle estimate", "unit": "um",
                         "limit": None, "kind": Sense.AT_MOST, "sequential": a.growth_um, "codesigned": b.growth_um})
        vs, vc = self.validation_sequential, self.validation_codesigned
        if vs is not None and vc is not None:
            for metric, unit, limit in (("settling_s", "s", vs.criteria.settling_max_s),
                                        ("overshoot_N", "N", vs.criteria.overshoot_max_N),
                                        ("tracking_rms_N", "N", vs.criteria.tracking_rms_max_N),
                                        ("peak_voltage_V", "V", vs.criteria.peak_voltage_max_V)):
                rows.append({"requirement": f"Monte Carlo worst {metric}", "unit": unit, "limit": limit,
                             "kind": Sense.AT_MOST,
                             "sequential": float(getattr(vs.worst, metric)),
                             "codesigned": float(getattr(vc.worst, metric))})
            rows.append({"requirement": f"Monte Carlo ({vs.n_plants} plants) passed", "unit": "", "limit": None,
                         "kind": "verdict", "sequential": bool(vs.passed), "codesigned": bool(vc.passed)})
        for row in rows:
            if isinstance(row["kind"], Sense) and row["limit"] is not None:
                for which in ("sequential", "codesigned"):
                    row[f"{which}_met"] = row["kind"].meets(row[which], row["limit"])
        return rows

    def to_dict(self) -> dict[str, Any]:
        """The co-design's result as ``codesign --json`` prints it.

        Returns
        -------
        dict
            The study, the strategy and why, the weights, both objectives and their ratio, whether the schedule's
            entries were inner decisions, both designs, :meth:`changed`, :meth:`bought`, :meth:`coupling`,
            :meth:`controller_words`, :meth:`requirements`, the infeasible candidates, the times (s) and each design's
            Monte Carlo verdict (None where not validated).
        """
        return {"study": self.study, "strategy": self.strategy, "strategy_why": self.strategy_why,
                "weights": self.weights.to_dict(),
                "objective_sequential": self.objective_sequential, "objective_codesigned": self.objective_codesigned,
                "objective_ratio": self.objective_ratio, "evaluations": self.evaluations,
                "schedule_inside": self.schedule, "controller_follows_study": self.follows_study,
                "sequential_meets_the_study": self.sequential.feasible,
                "sequential": self.sequential.to_dict(), "codesigned": self.codesigned.to_dict(),
                "changed": self.changed(), "bought": self.bought(), "coupling": self.coupling(),
                "controller": self.controller_words(), "feedforward": self.feedforward_words(),
                "feedforward_lead_inside": self.ff_lead,
                "requirements": self.requirements(), "infeasible": list(self.infeasible),
                "sequential_s": self.sequential_s, "codesign_s": self.codesign_s, "time_ratio": self.time_ratio,
                "validated": {"sequential": None if self.validation_sequential is None
                              else bool(self.validation_sequential.passed),
                              "codesigned": None if self.validation_codesigned is None
                              else bool(self.validation_codesigned.passed)}}

    def __repr__(self) -> str:
        return (f"CodesignResult({self.study}, {self.strategy}: objective {self.objective_codesigned:.4f} against the "
                f"sequential {self.objective_sequential:.4f} (ratio {self.objective_ratio:.4f}), "
                f"{self.evaluations} inner solves, coupling {self.coupling().split(':')[0]})")


def _optimum_at(spec: DesignSpec, values: dict[str, float]) -> DesignOptimum:
    """The design NLP's least-heat optimum at the outer variables ``values``: the contact angle and conformity fixed,
    the least rigidity over the duty at least the floor, and every design requirement inside."""
    a, c = values["contact_angle_deg"], values["conformity"]
    floor = max(spec.stiffness_min_N_per_um, values["stiffness_floor_N_per_um"] * (1.0 - _FLOOR_TOL))
    fixed = replace(spec, contact_angle_deg=(a, a), conformity=(c, c), stiffness_min_N_per_um=floor)
    return optimise(fixed, CANDIDATE_OBJECTIVE)


_FLOOR_TOL = 1e-6  # the floor at the stiffness optimum's rigidity, less the solver's tolerance


def codesign_optimum(study: StudySpec, progress: ProgressLike | None = None) -> DesignOptimum:
    """The design optimum a study with ``[design] method = "codesign"`` takes: the co-design's design (its Monte
    Carlo left to the study's validate stage), as the design NLP's optimum at the co-designed rigidity floor, contact
    angle and conformity (the sequential optimum itself where the co-design kept it), its objective named
    ``"codesign"``."""
    budget = (study.design_table or DesignTable()).codesign_budget
    return _chosen(study, codesign(study, budget=budget, validate_plants=0, shape=False, ff_lead=False,
                                   progress=progress))


def _chosen(study: StudySpec, result: CodesignResult) -> DesignOptimum:
    spec = study.design_spec
    objective = (study.design_table or DesignTable()).objective
    if spec is None:  # codesign refused it already; for the type checker
        raise InputError(f"{study.path}: co-design needs the design's tables")
    c = result.codesigned
    if c.ff_lead_s != 0.0:  # the later stages run the learned feedforward: they carry no preview lead
        raise InfeasibleError(f"{study.path}: the co-design chose a feedforward lead of {c.ff_lead_s:g} s, which the "
                              "study's later stages do not run (their feedforward along the schedule is the learned "
                              "one); run `piezopreload codesign` instead")
    if c.schedule_headroom != 1.0 or c.schedule_lead_s != 0.0:  # the later stages plan the least-friction schedule
        raise InfeasibleError(f"{study.path}: the co-design chose a preload schedule headroom of "
                              f"{c.schedule_headroom:g} and lead of {c.schedule_lead_s:g} s, which the study's "
                              "schedule stage does not plan (it plans the least-friction schedule); run "
                              "`piezopreload codesign` instead")
    chosen = optimise(spec, objective) if result.codesigned is result.sequential else \
        _optimum_at(spec, result.codesigned.variables())
    return replace(chosen, objective="codesign")  # what chose it (the design artifact and the report say so)


def codesign_design(study: StudySpec, *, points: int = 3, progress: ProgressLike | None = None,
                    inputs: dict[str, Any] | None = None) -> tuple[DesignOptimum, CodesignRecord]:
    """The design stage of a study with ``[design] method = "codesign"``: the co-designed optimum
    (:func:`codesign_optimum`'s) and the co-design's artifact for the report: both answers validated by the same
    Monte Carlo (the study's ``[validation]`` plants) and, where the study has ``[thermal]``, the two fronts of
    ``points`` each (:func:`codesign_fronts`).

    Parameters
    ----------
    study : StudySpec
        The study.
    points : int
        Points of each front's sweep.
    progress : ProgressLike, optional
        Where the steps are said.
    inputs : dict, optional
        The hashes the artifact records.

    Returns
    -------
    (DesignOptimum, CodesignRecord)
        The design the study's later stages take, and the artifact.
    """
    budget = (study.design_table or DesignTable()).codesign_budget
    # the later stages plan the least-friction schedule and run the learned feedforward, which no lead can be given
    result = codesign(study, budget=budget, shape=False, ff_lead=False, progress=progress)
    fronts: tuple[tuple[FrontPoint, ...], tuple[FrontPoint, ...]] = ((), ())
    if study.thermal is not None:
        fronts = codesign_fronts(study, result, points=points, budget=budget, progress=progress)
    return _chosen(study, result), codesign_record(study, result, fronts, inputs)


def follows_study(study: StudySpec, schedule: bool | None = None) -> bool:
    """Whether the co-design's controller is the gain schedule's entries (True) or the one robust set (False).

    Parameters
    ----------
    study : StudySpec
        The study (its ``[tuning] schedule_levels``).
    schedule : bool, optional
        None: as the study's own tune stage makes it (the entries where it tunes at least 2, else the robust set);
        True or False: asked for.

    Returns
    -------
    bool
        Whether the entries are inner decisions.

    Raises
    ------
    InputError
        Where the entries are asked for but the study tunes fewer than 2.
    """
    levels = study.tuning.schedule_levels
    if schedule is None:
        return levels >= 2
    if schedule and levels < 2:
        raise InputError(f"{study.path}: the co-design's schedule entries need [tuning] schedule_levels >= 2, got "
                         f"{levels}; compare with the one robust set instead (codesign --robust-set, "
                         "schedule=False)")
    return bool(schedule)


def codesign(study: StudySpec, weights: CodesignWeights | None = None, *, budget: int = 9, step: float = 0.25,
             min_step: float = 0.0625, validate_plants: int | None = None, max_iterations: int = 60,
             time_factor: float | None = 10.0, schedule: bool | None = None, shape: bool = True,
             ff_lead: bool = True, progress: ProgressLike | None = None) -> CodesignResult:
    """The sequential design and tuning, then the nested co-design started from it; both validated alike.

    Parameters
    ----------
    study : StudySpec
        A study with the design's tables (``[ballscrew]``, ``[design]``).
    weights : CodesignWeights, optional
        The objective's weights (default: :meth:`CodesignWeights.of_study`, what the study states).
    budget : int
        The most inner problems the outer search solves after the sequential start.
    step, min_step : float
        The compass search's first and last step on the variables scaled to their ranges.
    validate_plants : int, optional
        Monte Carlo plants for each answer (default: the study's ``[validation] plants``; 0: none).
    max_iterations : int
        IPOPT's iteration limit of each inner tuning.
    time_factor : float, optional
        The co-design's time limit as a multiple of the sequential design and tuning: no inner problem is started
        that would end after it were it as slow as the slowest so far (None: the budget alone limits it).
    schedule : bool, optional
        The controller both answers are compared with. None (the default): as the study's own tune stage makes it
        (:func:`follows_study`): the gain schedule's entries (``[tuning] schedule_levels``) as decisions of the inner
        problem, each tuned at Ms over its window (:func:`evaluate_design`), where the study tunes a schedule (at
        least 2 entries), else the one robust set; True: the entries, asked for (the study must tune at least 2);
        False: the one robust set, asked for (one tuning per inner problem, where the point does not need the
        entries). Each entry costs every inner problem one more PID tuning.
    shape : bool
        The preload schedule's headroom and lead are the inner problem's (:func:`shape_schedule`) and the schedule's
        requirements along the cycle its constraints; False: every candidate runs the least-friction schedule (with
        the margin passes the loop asks for), as the study's schedule and system stages plan it, and the schedule's
        requirements along it are reported, not constraints (those stages judge them with the learned feedforward,
        which the co-design does not learn); the tracking RMS along it is the objective's term either way.
    ff_lead : bool
        The feedforward's preview lead along the schedule is the inner problem's (:func:`choose_ff_lead`) for every
        candidate but the sequential answer (whose controller is the study's, without a lead); False: no lead, as
        the study's own stages run the controller (they cannot carry one: their feedforward along the schedule is
        the learned one).
    progress : ProgressLike, optional
        Where the steps are said.

    Returns
    -------
    CodesignResult
        Both answers, their objective, what changed, what it bought, the Monte Carlo of each.
    """
    say = say_of(progress) or (lambda _m: None)
    weights = weights or CodesignWeights.of_study(study)
    if weights.growth > 0 and study.thermal is None:
        raise InputError(f"{study.path}: the co-design's growth weight needs a [thermal] table (the shift the growth "
                         "is read over); weight friction instead")
    if budget < 0:
        raise InputError(f"codesign budget: must be >= 0 inner solves, got {budget!r}")
    if time_factor is not None and not time_factor > 1:
        raise InputError(f"codesign time_factor: must be > 1 (a multiple of the sequential time), got {time_factor!r}")
    if not 0 < min_step <= step <= 1:
        raise InputError(f"codesign steps: need 0 < min_step <= step <= 1, got {min_step!r}, {step!r}")
    asked, schedule = schedule, follows_study(study, schedule)  # the controller compared: the study's unless asked
    spec = study.design_spec
    if spec is None:
        raise InputError(f"{study.path}: co-design needs the design's tables ([ballscrew], [design]); see "
                         "studies/machine_axis.toml")
    objective = (study.design_table or DesignTable()).objective

    # ---- the sequential answer: the design, then the tuning on its plant ----------------------------------
    t0 = time.perf_counter()
    try:
        seq_point = optimise(spec, objective).point
    except DesignInfeasible as exc:
        raise InfeasibleError(f"{study.path}: {exc}") from exc
    sequential = evaluate_design(study, seq_point, max_iterations=max_iterations, schedule=schedule,
                                 cycle_binding=shape, ff_lead=False)  # the study's controller: no feedforward lead
    sequential_s = time.perf_counter() - t0
    say(f"sequential: {objective} design, then the tuning ({sequential_s:.1f} s): tracking RMS "
        f"{sequential.tracking_rms_N:.2f} N (staircase), {sequential.cycle_tracking_rms_N:.2f} N along the schedule "
        f"({sequential.cycle_passes} margin passes), friction {sequential.friction_energy_J:.4g} J per cycle"
        + ("" if sequential.feasible else f"; it misses the study: {sequential.why}"))

    # ---- the nested co-design: a compass search over the plant-shaping variables --------------------------
    t1 = time.perf_counter()
    search = _Search(study, spec, objective, weights, sequential, sequential_s, max_iterations, time_factor, say,
                     schedule=schedule, shape=shape, ff_lead=ff_lead)
    best, best_f = search.run(budget, step, min_step)
    codesign_s = time.perf_counter() - t1
    if not best.feasible:  # the sequential design has no controller that meets the study, and no candidate had one
        raise InfeasibleError(f"{study.path}: the sequential design (contact angle {seq_point.contact_angle_deg:.2f} "
                              f"deg, conformity {seq_point.conformity:.4f}, rigidity "
                              f"{seq_point.stiffness_N_per_um:.0f} N/um) has no controller that meets the study: "
                              f"{sequential.why}; nor had any of the {search.evaluations} designs the co-design tried")
    say(f"co-design ({STRATEGY}, {search.evaluations} inner solves{search.stopped}, {codesign_s:.1f} s): objective "
        f"{best_f:.4f} against the sequential 1")

    # ---- the same Monte Carlo for both ---------------------------------------------------------------------
    plants = study.validation.plants if validate_plants is None else int(validate_plants)
    v_seq = v_co = None
    if plants > 0:
        v_seq = _monte_carlo(study, sequential, plants)
        v_co = v_seq if best is sequential else _monte_carlo(study, best, plants)
        say(f"Monte Carlo ({plants} plants): sequential {'passed' if v_seq.passed else 'failed'}, co-designed "
            f"{'passed' if v_co.passed else 'failed'}")
    limits = {"stiffness_min_N_per_um": spec.stiffness_min_N_per_um,
              "lift_off_min_N": spec.lift_off_margin * spec.failsafe_load_N, "life_min_h": spec.life_min_h,
              "ms_max": study.tuning.ms_max, "tracking_rms_max_N": study.validation.tracking_rms_max_N}
    return CodesignResult(study.name, STRATEGY, weights, sequential, best, 1.0, best_f, search.evaluations + 1,
                          tuple(search.refused), sequential_s, codesign_s, limits, tuple(search.scored), v_seq, v_co,
                          STRATEGY_WHY, search.cache, search.least_heat, schedule, shape,
                          study.tuning.schedule_levels, asked is None, ff_lead)


class _Search:
    """The outer compass search over :data:`VARIABLES` scaled to ``[0, 1]``, from the sequential design.

    A candidate replaces the incumbent only when it is feasible and lowers the objective, so the answer is never
    worse than the start; each inner tuning starts from the incumbent's gains.
    """

    def __init__(self, study: StudySpec, spec: DesignSpec, objective: str, weights: CodesignWeights,
                 sequential: Candidate, sequential_s: float, max_iterations: int, time_factor: float | None,
                 say: Callable[[str], None], cache: dict[tuple[float, ...], tuple[Candidate | None, str]] | None = None,
                 least_heat: float | None = None, schedule: bool = False, shape: bool = True,
                 ff_lead: bool = True) -> None:
        # the clock starts here, as the caller's co-design time does: the front's soft end solved below is spent
        # inside the time limit too
        self.t0 = time.perf_counter()
        self.study, self.spec, self.objective, self.weights = study, spec, objective, weights
        self.sequential, self.sequential_s = sequential, sequential_s
        self.max_iterations, self.time_factor, self.say = max_iterations, time_factor, say
        # the inner problems solved, by the outer variables (the weights do not enter them: a sweep shares them)
        self.cache = {} if cache is None else cache
        if least_heat is None:
            least_heat = optimise(spec, CANDIDATE_OBJECTIVE).point.stiffness_N_per_um  # the front's soft end
        self.least_heat, self.schedule = least_heat, schedule
        top = sequential.point.stiffness_N_per_um
        self.shape, self.ff_lead = shape, ff_lead
        self.ranges = [(min(least_heat, top), top), tuple(spec.contact_angle_deg), tuple(spec.conformity)]
        # the start's design is the sequential one (its schedule shaped by the inner problem in run())
        self.cache.setdefault(self.design_key(self.values(self.start())), (sequential, ""))
        self.evaluations, self.stopped, self.slowest = 0, "", 0.0
        self.refused: list[str] = []
        self.scored: list[Candidate] = [sequential]

    @staticmethod
    def design_key(values: dict[str, float]) -> tuple[float, ...]:
        """The inner problem's key: the design variables' values."""
        return tuple(round(v, 9) for v in list(values.values())[:DESIGN_VARIABLES])

    def values(self, z: np.ndarray) -> dict[str, float]:
        return {name: float(lo + zi * (hi - lo)) for (name, _, _), (lo, hi), zi in zip(VARIABLES, self.ranges, z)}

    def in_time(self) -> bool:
        """Whether one more inner solve, as slow as the slowest so far, ends inside the time limit."""
        if self.time_factor is None:
            return True
        spent = time.perf_counter() - self.t0
        return self.sequential_s + spent + max(self.slowest, 0.5 * self.sequential_s) <= \
            self.time_factor * self.sequential_s

    def score(self, z: np.ndarray, start: PIDGains) -> tuple[Candidate | None, float]:
        """One inner problem at ``z``: the candidate and its objective (inf: infeasible, and why is kept)."""
        values = self.values(z)
        key = self.design_key(values)
        if key in self.cache:  # solved already (another weight of a sweep: its schedule chosen for these weights)
            cand, refused = self.cache[key]
            if cand is not None and self.shape and cand.shapes:
                cand = shape_schedule(self.study, cand, self.weights, self.sequential)
        else:
            self.evaluations += 1
            t0 = time.perf_counter()
            try:
                cand = evaluate_design(self.study, _optimum_at(self.spec, values).point, start=start,
                                       max_iterations=self.max_iterations, schedule=self.schedule,
                                       cycle_binding=self.shape, ff_lead=self.ff_lead)
                if self.shape:  # the schedule's headroom and lead for this loop, by the objective
                    cand = shape_schedule(self.study, cand, self.weights, self.sequential)
                refused = ""
            except InfeasibleError as exc:  # no screw, or no controller, for these values
                cand, refused = None, str(exc)
            finally:
                self.slowest = max(self.slowest, time.perf_counter() - t0)
            self.cache[key] = (cand, refused)
        if cand is not None:
            cand = replace(cand, at=tuple(values.items()))
        if cand is None:
            self.refused.append(f"{values}: {refused}")
            return None, math.inf
        if not cand.feasible:
            self.refused.append(f"{values}: {cand.why}")
            return cand, math.inf
        f = cand.objective(self.weights, self.sequential)
        self.scored.append(cand)
        self.say(f"  candidate {', '.join(f'{k} {v:.4g}' for k, v in values.items())}: objective {f:.4f}")
        return cand, f

    def start(self) -> np.ndarray:
        """The sequential answer's design, scaled."""
        at = self.sequential.variables()
        return np.array([(at[name] - lo) / (hi - lo) if hi > lo else 0.0
                         for (name, _, _), (lo, hi) in zip(VARIABLES, self.ranges)])

    def shape_start(self, key: tuple[float, ...]) -> Candidate | None:
        """The sequential design and controller with the feedforward's lead chosen and the schedule shaped for its
        loop (the inner problem's decisions that keep the design and the gains), kept in the cache under ``key``;
        None where that is the sequential answer itself or misses the study."""
        start = self.cache[key][0]
        if not (self.shape or self.ff_lead) or start is None:
            return None
        t0 = time.perf_counter()
        shaped = start
        loop_ok = start.feasible if start.loop_feasible is None else start.loop_feasible
        if self.ff_lead and loop_ok and not start.ff_leads_tried:
            shaped = with_headroom(self.study, choose_ff_lead(self.study, start), 1.0, 0.0, binding=self.shape)
        if self.shape:
            shaped = shape_schedule(self.study, shaped, self.weights, self.sequential)
        self.slowest = max(self.slowest, time.perf_counter() - t0)
        self.cache[key] = (shaped, "")
        if (shaped.schedule_headroom, shaped.schedule_lead_s, shaped.ff_lead_s) == (1.0, 0.0, 0.0) \
                or not shaped.feasible:
            return None
        self.scored.append(shaped)
        self.say(f"  the sequential design, its feedforward led {1e3 * shaped.ff_lead_s:.3g} ms and its schedule "
                 f"shaped (headroom {shaped.schedule_headroom:.4g}, lead {1e3 * shaped.schedule_lead_s:.3g} ms): "
                 f"objective {shaped.objective(self.weights, self.sequential):.4f}")
        return shaped

    def run(self, budget: int, step: float, min_step: float) -> tuple[Candidate, float]:
        z = self.start()
        best = self.sequential  # a start that misses the study is replaced by the first candidate that meets it
        best_f = self.sequential.objective(self.weights, self.sequential) if self.sequential.feasible else math.inf
        seen = {tuple(np.round(z, 9))}
        shaped = self.shape_start(self.design_key(self.values(z)))
        if shaped is not None:
            f = shaped.objective(self.weights, self.sequential)
            if f < best_f - 1e-9:
                best, best_f = shaped, f
        h = step
        # opportunistic polling: the first direction that improves is taken, and tried first at the next poll
        directions = [(i, sign) for i in range(len(VARIABLES)) for sign in (-1.0, +1.0)]
        while h >= min_step and self.evaluations < budget and not self.stopped:
            improved = False
            for i, sign in list(directions):
                lo, hi = self.ranges[i]
                trial = z.copy()
                trial[i] = min(1.0, max(0.0, trial[i] + sign * h))
                key = tuple(np.round(trial, 9))
                if hi <= lo or key in seen or self.evaluations >= budget or self.stopped:
                    continue
                if not self.in_time():
                    self.stopped = f" (stopped at {self.time_factor:g} times the sequential time)"
                    continue
                seen.add(key)
                cand, f = self.score(trial, best.gains)
                if cand is not None and f < best_f - 1e-9:
                    best, best_f, z, improved = cand, f, trial, True
                    directions.remove((i, sign))
                    directions.insert(0, (i, sign))
                    break
            if not improved:
                h /= 2.0
        return best, best_f


def _monte_carlo(study: StudySpec, cand: Candidate, plants: int) -> ValidationResult:
    ff = identify(study, Solved(study, cand.point))
    return validate(cand.gains, ff.model, _plant(study, cand.point), study.validation, n_plants=plants,
                    seed=study.seed if study.validation.seed is None else study.validation.seed,
                    step=study.references["step"],
                    trajectory=study.references["trajectory"])


# ---- the two fronts: thermal growth against tracking RMS at the study's Ms ----------------------------------------
def _front_point(c: Candidate, label: str, swept: float) -> FrontPoint:
    return FrontPoint(label, float(swept), float(c.growth_um), float(c.cycle_tracking_rms_N), float(c.ms),
                      float(c.peak_voltage_V), float(c.point.stiffness_N_per_um), float(c.point.contact_angle_deg),
                      bool(c.feasible), None if not math.isfinite(c.settling_s) else float(c.settling_s), c.why)


def front_weights(points: int) -> list[float]:
    """The growth's weights of the co-designed front's sweep: ``points`` from 1 (the growth alone) to 0 (the tracking
    alone), the tracking's weight one less the growth's."""
    if not (isinstance(points, int) and points >= 2):
        raise InputError(f"codesign front points: must be a whole number >= 2, got {points!r}")
    return [float(w) for w in np.linspace(1.0, 0.0, points)]


def codesign_fronts(study: StudySpec, result: CodesignResult, *, points: int = 3, budget: int | None = None,
                    progress: ProgressLike | None = None) -> tuple[tuple[FrontPoint, ...], tuple[FrontPoint, ...]]:
    """The two fronts of thermal growth against the nominal tracking RMS, every pair tuned at the study's Ms.

    Parameters
    ----------
    study : StudySpec
        The study ``result`` co-designed (it needs ``[thermal]``: the growth).
    result : CodesignResult
        Its co-design (the sequential answer, its gains, the inner problems solved: the sweeps start from them).
    points : int
        Points of each sweep (at least 2).
    budget : int, optional
        The most inner problems each weight's search solves (default: the co-design's own budget, 9).
    progress : ProgressLike, optional
        Where the steps are said.

    Returns
    -------
    (tuple of FrontPoint, tuple of FrontPoint)
        The sequential front's sweep: the design NLP alone along its ``stiffness:growth`` front (the least heat at
        ``points`` least rigidities from the least-heat design's to the sequential optimum's), each design then
        tuned, the sequential answer last (unless the front's stiff end is it); the co-designed front's sweep: the
        co-design (the same nested search, from the same sequential answer) for each growth weight of
        :func:`front_weights`, the tracking weighted by the rest.
    """
    say = say_of(progress) or (lambda _m: None)
    spec, table = study.design_spec, study.thermal
    if spec is None or table is None:
        raise InputError(f"{study.path}: the fronts of thermal growth against tracking need the design's tables and "
                         "a [thermal] table (the shift the growth is read over)")
    weights = front_weights(points)
    budget = 9 if budget is None else budget
    seq = result.sequential
    front = pareto_front(spec, "stiffness:growth", points, growth=lambda p: duty_growth_um(spec, p, table))
    sequential = []
    for p in front.points:
        c = evaluate_design(study, p, start=seq.gains, schedule=result.schedule, cycle_binding=result.shape,
                            ff_lead=False)  # the sequential way: the study's controller, no feedforward lead
        sequential.append(_front_point(c, f"rigidity at least {p.stiffness_N_per_um:,.0f} N/um",
                                       p.stiffness_N_per_um))
        say(f"  sequential front: rigidity {p.stiffness_N_per_um:,.0f} N/um: growth {c.growth_um:.2f} um, tracking "
            f"RMS along the schedule {c.cycle_tracking_rms_N:.2f} N, Ms {c.ms:.3f}"
            f"{'' if c.feasible else ' (' + c.why + ')'}")
    if not any(math.isclose(p.stiffness_N_per_um, seq.point.stiffness_N_per_um, rel_tol=FRONT_RTOL)
               and math.isclose(p.growth_um, seq.growth_um, rel_tol=FRONT_RTOL) for p in sequential):
        sequential.append(_front_point(seq, "the sequential answer", seq.point.stiffness_N_per_um))
    codesigned = []
    objective = (study.design_table or DesignTable()).objective
    least_heat = result.least_heat_N_per_um if math.isfinite(result.least_heat_N_per_um) else None
    for w in weights:
        search = _Search(study, spec, objective, CodesignWeights(growth=w, friction=0.0, tracking=1.0 - w), seq,
                         result.sequential_s, 60, None, lambda _m: None, cache=result.evaluated,
                         least_heat=least_heat, schedule=result.schedule, shape=result.shape,
                         ff_lead=result.ff_lead)
        best, _ = search.run(budget, 0.25, 0.0625)
        least_heat = search.least_heat
        codesigned.append(_front_point(best, f"growth weight {w:.2g}, tracking {1 - w:.2g}", w))
        say(f"  co-designed front: growth weight {w:.2g}: growth {best.growth_um:.2f} um, tracking RMS "
            f"{best.cycle_tracking_rms_N:.2f} N along the schedule, Ms {best.ms:.3f} ({search.evaluations} new inner "
            "solves)")
    return tuple(sequential), tuple(codesigned)


def codesign_record(study: StudySpec, result: CodesignResult, fronts: tuple[tuple[FrontPoint, ...],
                    tuple[FrontPoint, ...]] = ((), ()), inputs: dict[str, Any] | None = None) -> CodesignRecord:
    """The co-design artifact of ``result``: both answers requirement by requirement and the two fronts.

    Parameters
    ----------
    study : StudySpec
        The study.
    result : CodesignResult
        Its co-design.
    fronts : (tuple of FrontPoint, tuple of FrontPoint)
        :func:`codesign_fronts`'s sweeps (empty: not computed).
    inputs : dict, optional
        The hashes it came from.

    Returns
    -------
    CodesignRecord
        The record.
    """
    rows = []
    for row in result.requirements():
        if not isinstance(row["kind"], Sense):  # the Monte Carlo's verdict row
            continue
        a, b = row["sequential"], row["codesigned"]
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        rows.append(RequirementRow(row["requirement"], row["unit"], row["kind"], float(a), float(b),
                                   None if row["limit"] is None else float(row["limit"])))
    vs, vc = result.validation_sequential, result.validation_codesigned
    return CodesignRecord(result.study, result.strategy, result.strategy_why, result.weights.to_dict(),
                          float(study.tuning.ms_max), float(result.objective_ratio), tuple(result.changed()),
                          result.coupling(), f"{result.controller_words()}; feedforward: {result.feedforward_words()}",
                          tuple(rows), 0 if vs is None else vs.n_plants,
                          fronts[0], fronts[1], None if vs is None else bool(vs.passed),
                          None if vc is None else bool(vc.passed), dict(inputs or {}))
