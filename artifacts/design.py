"""The design artifact (kind ``design``): the preload design's optimum, its Pareto fronts, the preload schedule and
the curves a designer reads, as one typed record.

:mod:`piezopreload.design.study` computes a design study and writes it as a :class:`DesignRecord`
(:meth:`DesignRecord.save`); the pipeline, the system stage and the report read it with
:meth:`DesignRecord.load` and its attributes. The preload schedule it holds
(:class:`~piezopreload.artifacts.schedule.PreloadSchedule`) is the one source of the best constant
preload, its friction energy and the plan's saving.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts._fields import Fields
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.core._typing import Array
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import InputError

__all__ = ["CONSTRAINT_WORDS", "VARIABLE_WORDS", "binding_words", "case_words", "DesignPoint", "Optimum", "Front",
           "PreloadCurve", "DutyCasePoint", "FrequencyCurve", "DesignRecord", "KIND"]

KIND = "design"


@dataclass(frozen=True)
class DesignPoint:
    """A design and everything it achieves."""

    contact_angle_deg: float
    ball_mm: float
    conformity: float
    turns: float
    balls_per_turn: float
    bolt_preload_N: float
    max_preload_N: float
    case_preload_N: tuple[float, ...]
    stiffness_N_per_um: float  # least rigidity over the duty cases
    rigidity_at_max_preload_N_per_um: float
    mean_drag_torque_Nm: float
    drag_torque_at_max_preload_Nm: float
    life_h: float
    c_dyn_N: float
    c0_N: float
    frequency_min_Hz: float
    peak_pressure_MPa: float
    stack_stroke_used_um: float
    objective: str
    integer: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DesignPoint:
        """The inverse of :meth:`to_dict` (a design artifact's ``optimum.point``)."""
        try:
            return cls(**{**data, "case_preload_N": tuple(float(x) for x in data["case_preload_N"])})
        except (KeyError, TypeError) as exc:
            raise InputError(f"a design point needs the fields of DesignPoint: {exc}") from exc

    @classmethod
    def from_fields(cls, f: Fields) -> DesignPoint:
        """A design point from an artifact's object, each field checked (its errors name the field)."""
        values: dict[str, Any] = {}
        for fd in fields(cls):
            if fd.name == "case_preload_N":
                values[fd.name] = tuple(float(x) for x in f.array(fd.name))
            elif fd.name == "objective":
                values[fd.name] = f.text(fd.name)
            elif fd.name == "integer":
                values[fd.name] = f.flag(fd.name)
            else:
                values[fd.name] = f.number(fd.name)
        return cls(**values)


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
            per_case.setdefault(base, []).append(int(rest.rstrip("]")))
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


@dataclass(frozen=True)
class Optimum:
    """The design optimum: its objective, its point, the constraints that bind, how it was solved
    (``integer_candidates``: each integer neighbour of the relaxation tried, as the solver recorded it)."""

    objective: str
    point: DesignPoint
    binding: tuple[str, ...]
    integer_candidates: tuple[dict[str, Any], ...]
    solve_s: float
    nlp_solves: int

    def to_dict(self) -> dict[str, Any]:
        return {"objective": self.objective, "point": self.point.to_dict(), "binding": list(self.binding),
                "integer_candidates": [dict(c) for c in self.integer_candidates], "solve_s": self.solve_s,
                "nlp_solves": self.nlp_solves}

    @classmethod
    def from_fields(cls, f: Fields) -> Optimum:
        candidates = f.raw("integer_candidates", [])
        if not isinstance(candidates, list) or not all(isinstance(c, dict) for c in candidates):
            raise f.fail("integer_candidates", "must be a list of objects")
        return cls(f.text("objective"), DesignPoint.from_fields(f.sub("point")), f.texts("binding", []),
                   tuple(dict(c) for c in candidates), f.number("solve_s", 0.0), f.integer("nlp_solves", 0))


@dataclass(frozen=True, eq=False)
class Front:
    """An epsilon-constraint Pareto front: ``x_name`` swept, ``y_name`` optimised, each point's design."""

    pair: str
    x_name: str
    y_name: str
    x: Array
    y: Array
    points: tuple[DesignPoint, ...]
    solve_s: float
    nlp_solves: int

    def to_dict(self) -> dict[str, Any]:
        return {"pair": self.pair, "x_name": self.x_name, "y_name": self.y_name, "x": np.asarray(self.x).tolist(),
                "y": np.asarray(self.y).tolist(), "points": [p.to_dict() for p in self.points],
                "solve_s": self.solve_s, "nlp_solves": self.nlp_solves}

    @classmethod
    def from_fields(cls, f: Fields) -> Front:
        x = f.array("x")
        return cls(f.text("pair"), f.text("x_name"), f.text("y_name"), x, f.array("y", x.size),
                   f.items("points", DesignPoint.from_fields), f.number("solve_s", 0.0), f.integer("nlp_solves", 0))


@dataclass(frozen=True)
class DutyCasePoint:
    """A duty case at its designed preload: the load, the preload and the rigidity there."""

    axial_load_N: float
    preload_N: float
    rigidity_N_per_um: float

    @classmethod
    def from_fields(cls, f: Fields) -> DutyCasePoint:
        return cls(f.number("axial_load_N"), f.number("preload_N"), f.number("rigidity_N_per_um"))


@dataclass(frozen=True, eq=False)
class PreloadCurve:
    """Rigidity and drag torque of the optimum's double nut against the preload, the duty cases marked."""

    preload_N: Array
    rigidity_N_per_um: Array
    drag_torque_Nm: Array
    cases: tuple[DutyCasePoint, ...]
    bolt_preload_N: float
    max_preload_N: float

    def to_dict(self) -> dict[str, Any]:
        return {"preload_N": self.preload_N.tolist(), "rigidity_N_per_um": self.rigidity_N_per_um.tolist(),
                "drag_torque_Nm": self.drag_torque_Nm.tolist(), "cases": [asdict(c) for c in self.cases],
                "bolt_preload_N": self.bolt_preload_N, "max_preload_N": self.max_preload_N}

    @classmethod
    def from_fields(cls, f: Fields) -> PreloadCurve:
        p = f.array("preload_N")
        return cls(p, f.array("rigidity_N_per_um", p.size), f.array("drag_torque_Nm", p.size),
                   f.items("cases", DutyCasePoint.from_fields), f.number("bolt_preload_N"), f.number("max_preload_N"))


@dataclass(frozen=True, eq=False)
class FrequencyCurve:
    """The first axial natural frequency along the travel, at the bolts' preload and at full stack drive."""

    position_mm: Array
    bolt_preload_Hz: Array
    max_preload_Hz: Array

    def to_dict(self) -> dict[str, Any]:
        return {"position_mm": self.position_mm.tolist(), "bolt_preload_Hz": self.bolt_preload_Hz.tolist(),
                "max_preload_Hz": self.max_preload_Hz.tolist()}

    @classmethod
    def from_fields(cls, f: Fields) -> FrequencyCurve:
        x = f.array("position_mm")
        return cls(x, f.array("bolt_preload_Hz", x.size), f.array("max_preload_Hz", x.size))


@dataclass(frozen=True, eq=False)
class DesignRecord:
    """The design artifact: the optimum, the fronts, the preload schedule on the optimum's screw (planned for the
    load profile ``profile``, a file or ``example``), the curves, the units and the inputs.

    The schedule's spec holds the stacks' reach (``schedule.spec.max_preload_N``) and the
    preload slew it was planned for; its ``constant_preload_N`` and ``constant_friction_energy_J``
    are the best constant preload's, recorded here only.
    """

    optimum: Optimum
    fronts: tuple[Front, ...]
    schedule: PreloadSchedule
    preload_curve: PreloadCurve
    natural_frequency: FrequencyCurve
    profile: str = "example"
    units: dict[str, str] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)

    @property
    def point(self) -> DesignPoint:
        return self.optimum.point

    def to_dict(self) -> dict[str, Any]:
        """The artifact's body (the layout the design artifact has always had, the schedule's series added)."""
        return {"preload_curve": self.preload_curve.to_dict(), "units": dict(self.units),
                "optimum": self.optimum.to_dict(), "fronts": [f.to_dict() for f in self.fronts],
                "schedule": self.schedule.to_dict(), "natural_frequency": self.natural_frequency.to_dict(),
                "inputs": {**self.inputs, "profile": self.profile}}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the design") -> DesignRecord:
        """The inverse of :meth:`to_dict`; an :class:`~piezopreload.core.errors.ArtifactError` names the field."""
        f = Fields(doc, shown)
        inputs = f.mapping("inputs", {})
        units = f.mapping("units", {})
        return cls(optimum=Optimum.from_fields(f.sub("optimum")), fronts=f.items("fronts", Front.from_fields),
                   schedule=PreloadSchedule.from_fields(f.sub("schedule")),
                   preload_curve=PreloadCurve.from_fields(f.sub("preload_curve")),
                   natural_frequency=FrequencyCurve.from_fields(f.sub("natural_frequency")),
                   profile=str(inputs.pop("profile", "example")), units={k: str(v) for k, v in units.items()},
                   inputs=inputs)

    def save(self, path: str | Path) -> Path:
        """Write the artifact atomically (kind ``design``)."""
        write_artifact(path, KIND, self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> DesignRecord:
        """Read a design artifact: its schema and every field checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))
