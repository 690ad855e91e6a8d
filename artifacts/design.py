"""The design artifact (kind ``design``): the preload design's optimum, its Pareto fronts, the preload schedule and
the curves a designer reads, as one typed record.

:mod:`piezopreload.design.study` computes a design study and writes it as a :class:`DesignRecord`
(:meth:`DesignRecord.save`); the pipeline, the system stage and the report read it with
:meth:`DesignRecord.load` and its attributes. The preload schedule it holds
(:class:`~piezopreload.artifacts.schedule.PreloadSchedule`) is the one source of the best constant
preload, its friction energy and the plan's saving.
"""

from __future__ import annotations

from typing import Any, ClassVar

from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.core._typing import Array
from piezopreload.core.records import Record, SavedArtifact, entry, object_without, record

__all__ = ["CONSTRAINT_WORDS", "VARIABLE_WORDS", "binding_words", "case_words", "DesignPoint", "Optimum", "Front",
           "PreloadCurve", "DutyCasePoint", "FrequencyCurve", "DesignRecord", "KIND"]

KIND = "design"


@record
class DesignPoint(Record):
    """A design and everything it achieves."""

    NOUN: ClassVar[str] = "the design point"

    contact_angle_deg: float = entry("The contact angle.", unit="deg")
    ball_mm: float = entry("The ball diameter.", unit="mm")
    conformity: float = entry("The groove conformity.")
    turns: float = entry("The loaded turns per nut.")
    balls_per_turn: float = entry("The balls per turn.")
    bolt_preload_N: float = entry("The bolts' preload: the bottom of the preload range.", unit="N")
    max_preload_N: float = entry("The highest preload.", unit="N")
    case_preload_N: tuple[float, ...] = entry("The preload in each duty case.", unit="N")
    stiffness_N_per_um: float = entry("The least rigidity over the duty cases.", unit="N/um")
    rigidity_at_max_preload_N_per_um: float = entry("The rigidity at the highest preload.", unit="N/um")
    mean_drag_torque_Nm: float = entry("The drag torque over the duty cycle.", unit="N m")
    drag_torque_at_max_preload_Nm: float = entry("The drag torque at the highest preload.", unit="N m")
    life_h: float = entry("The rating life over the duty cycle.", unit="h")
    c_dyn_N: float = entry("The dynamic load rating.", unit="N")
    c0_N: float = entry("The static load rating.", unit="N")
    frequency_min_Hz: float = entry("The least first axial natural frequency.", unit="Hz")
    peak_pressure_MPa: float = entry("The peak contact pressure at the largest axial load.", unit="MPa")
    stack_stroke_used_um: float = entry("The stacks' stroke from the bolts' preload to the highest.", unit="um")
    objective: str = entry("The objective it optimises.")
    integer: bool = entry("Whether its balls per turn are a whole number (the integer neighbour of the relaxation).")


#: the design's requirements and constraint rows in words, with the study key that sets each limit ("" where none
#: does: the geometry, the design's own variables); a per-case row ``name[j]`` is ``name`` in duty case j (its
#: words' ``{cases}``). What the report and the infeasible design's message say instead of the solver's row names.
CONSTRAINT_WORDS: dict[str, tuple[str, str]] = {
    "stiffness_min": ("the least rigidity over the duty cases", "[design] stiffness_min_N_per_um"),
    "preload_limit": ("the highest preload at its share of the dynamic rating C_dyn", "[design] preload_fraction_max"),
    "lift_off_max_load": ("no lift-off at the largest axial load with the highest preload",
                          "[design] axial_load_max_N"),
    "lift_off_failsafe": ("no lift-off at the fail-safe load on the bolts alone", "[design] failsafe_load_N"),
    "contact_pressure_screw": ("the peak contact pressure at the largest axial load, screw side",
                               "[design] contact_pressure_max_MPa"),
    "contact_pressure_nut": ("the peak contact pressure at the largest axial load, nut side",
                             "[design] contact_pressure_max_MPa"),
    "life": ("the rating life over the duty cycle", "[design] life_min_h"),
    "drag_torque": ("the drag torque at the highest preload", "[design] drag_torque_max_Nm"),
    "stack_stroke": ("the stacks' stroke from the bolts' preload to the highest", "[design] stack_drive_V"),
    "stack_force": ("the stacks' blocked force against their share of the preload", "[design] stack_drive_V"),
    "ball_fit": ("the balls filling a turn of the helix", ""),
    "ball_lead": ("the ball diameter against the lead", "[design] ball_lead_ratio_max"),
    "nut_length": ("the nut's length, turns times lead", "[design] nut_length_max_mm"),
    "lift_off_case": ("no lift-off {cases} at its preload", "[design] lift_off_margin"),
    "stiffness_case": ("the rigidity {cases}, the least over the duty cases", ""),
    "frequency_case": ("the first axial natural frequency {cases}", "[design] frequency_min_Hz"),
    "stiffness_worst": ("the rigidity {cases} at the worst corner of the as-built tolerances", "[design] robust"),
    "frequency_worst": ("the first axial natural frequency {cases} at the worst corner of the as-built tolerances",
                        "[design] frequency_min_Hz, robust"),
    "preload_order_low": ("the preload {cases} down at the bolts' preload", ""),
    "preload_order_high": ("the preload {cases} up at the highest preload", ""),
}
#: the design variables a bound can hold, in words, with their unit
VARIABLE_WORDS: dict[str, tuple[str, str]] = {
    "contact_angle_deg": ("the contact angle", "°"), "ball_mm": ("the ball diameter", " mm"),
    "conformity": ("the groove conformity", ""), "turns": ("the loaded turns per nut", ""),
    "balls_per_turn": ("the balls per turn", ""), "bolt_preload_N": ("the bolts' preload", " N"),
    "max_preload_N": ("the highest preload", " N"), "stiffness_min_N_per_um": ("the least rigidity", " N/um"),
}


def case_words(numbers: list[int]) -> str:
    """``in duty case 1``, ``in duty cases 1, 2 and 3`` (the cases numbered from 1)."""
    if not numbers:
        return "in a duty case"
    words = [str(n) for n in sorted(numbers)]
    listed = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
    return f"in duty case{'s' if len(words) > 1 else ''} {listed}"


def binding_words(binding: tuple[str, ...] | list[str], point: DesignPoint) -> list[str]:
    """The constraints that bind at a design (its ``Optimum.binding``: row names, ``"<variable> at its upper
    bound"``) in words: each with the key that sets it, a per-case row once with its cases, a variable with its
    value and unit."""
    per_case: dict[str, list[int]] = {}
    out: list[tuple[str, str]] = []
    for name in binding:
        base, _, rest = name.partition("[")
        if rest:
            if base not in per_case:
                out.append((base, ""))
            case = int(rest.rstrip("]"))
            if case not in per_case.setdefault(base, []):  # a robust design's corners share their case's number
                per_case[base].append(case)
        elif " at its " in name:
            var, _, side = name.partition(" at its ")
            words, unit = VARIABLE_WORDS.get(var, (var, ""))
            value = getattr(point, var, None)
            out.append((f"{words} at its {side}" + ("" if value is None else f" ({value:.3g}{unit})"), "text"))
        else:
            out.append((name, ""))
    text = []
    for name, kind in out:
        if kind == "text":
            text.append(name)
            continue
        words, key = CONSTRAINT_WORDS.get(name, (name, ""))
        text.append(words.format(cases=case_words(per_case.get(name, []))) + (f" ({key})" if key else ""))
    return text


@record
class Optimum(Record):
    """The design optimum: its objective, its point, the constraints that bind, how it was solved."""

    objective: str = entry("The objective.")
    point: DesignPoint = entry("The optimum.")
    binding: tuple[str, ...] = entry("The constraints that bind (row names, ``\"<variable> at its upper bound\"``).",
                                     absent=())
    integer_candidates: tuple[dict[str, Any], ...] = entry("Each integer neighbour of the relaxation tried, as the "
                                                           "solver recorded it.", absent=())
    solve_s: float = entry("The solve's time.", unit="s", absent=0.0)
    nlp_solves: int = entry("The NLPs solved.", ge=0, absent=0)


@record(eq=False)
class Front(Record):
    """An epsilon-constraint Pareto front: ``x_name`` swept, ``y_name`` optimised, each point's design."""

    pair: str = entry('The pair of objectives ("stiffness-drag").')
    x_name: str = entry("The quantity swept.")
    y_name: str = entry("The quantity optimised.")
    x: Array = entry("The swept values.")
    y: Array = entry("The optimised values.", size="x")
    points: tuple[DesignPoint, ...] = entry("Each point's design.")
    solve_s: float = entry("The solves' time.", unit="s", absent=0.0)
    nlp_solves: int = entry("The NLPs solved.", ge=0, absent=0)


@record
class DutyCasePoint(Record):
    """A duty case at its designed preload: the load, the preload and the rigidity there."""

    axial_load_N: float = entry("The case's axial load.", unit="N")
    preload_N: float = entry("Its designed preload.", unit="N")
    rigidity_N_per_um: float = entry("The rigidity there.", unit="N/um")


@record(eq=False)
class PreloadCurve(Record):
    """Rigidity and drag torque of the optimum's double nut against the preload, the duty cases marked."""

    preload_N: Array = entry("The preloads.", unit="N")
    rigidity_N_per_um: Array = entry("The rigidity at each.", unit="N/um", size="preload_N")
    drag_torque_Nm: Array = entry("The drag torque at each.", unit="N m", size="preload_N")
    cases: tuple[DutyCasePoint, ...] = entry("The duty cases at their designed preloads.")
    bolt_preload_N: float = entry("The bolts' preload.", unit="N")
    max_preload_N: float = entry("The highest preload.", unit="N")


@record(eq=False)
class FrequencyCurve(Record):
    """The first axial natural frequency along the travel, at the bolts' preload and at full stack drive."""

    position_mm: Array = entry("The table's positions.", unit="mm")
    bolt_preload_Hz: Array = entry("The frequency at the bolts' preload.", unit="Hz", size="position_mm")
    max_preload_Hz: Array = entry("The frequency at the highest preload.", unit="Hz", size="position_mm")


@record(eq=False)
class DesignRecord(SavedArtifact):
    """The design artifact: the optimum, the fronts, the preload schedule on the optimum's screw, the curves, the
    units and the inputs.

    The schedule's spec holds the stacks' reach (``schedule.spec.max_preload_N``) and the
    preload slew it was planned for; its ``constant_preload_N`` and ``constant_friction_energy_J``
    are the best constant preload's, recorded here only.
    """

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the design"
    AGAIN: ClassVar[str] = "run the design again ('piezopreload design')"

    optimum: Optimum = entry("The design optimum.")
    fronts: tuple[Front, ...] = entry("The Pareto fronts.")
    schedule: PreloadSchedule = entry("The preload schedule on the optimum's screw.")
    preload_curve: PreloadCurve = entry("Rigidity and drag torque against the preload.")
    natural_frequency: FrequencyCurve = entry("The first axial natural frequency along the travel.")
    profile: str = entry("The load profile the schedule was planned for (a file, or ``example``).", at="inputs",
                         default="example")
    units: dict[str, str] = entry("The units of the figures.", default={}, required=True)
    inputs: dict[str, Any] = entry("The inputs' hashes.", read=object_without("profile"), default={}, required=True)

    @property
    def point(self) -> DesignPoint:
        """The optimum's design point (the optimum's :attr:`Optimum.point`)."""
        return self.optimum.point
