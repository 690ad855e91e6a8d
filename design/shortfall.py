"""Why no design meets a study's requirements: the requirement that binds, the value the best design reaches, and
by how much it falls short.

The design NLP's constraint rows (:data:`~piezopreload.design.preload.CONSTRAINTS`) are the study's
requirements in the solver's form. Each requirement a user sets is one group of rows
(:data:`REQUIREMENTS`: the per-case rows of a requirement together), and the least rigidity
``[design] stiffness_min_N_per_um``, a bound on the epigraph variable in the NLP, is a row here. The
rows that say what a design is (the epigraph ``t <= K_j``, the cases' preloads between the bolts'
and the highest, the balls fitting on the helix) are kept hard.

For each requirement in turn, :func:`binding` solves the NLP with that requirement's rows given
one slack and every other requirement kept, minimising the slack: a requirement that cannot be met
even when every other is kept is one that binds, and the point the NLP stops at is the best design
for it (the closest to it). Its shortfall and the value it reaches are read there, in the
requirement's units (hours for the life, not its logarithm), on the relaxation and then on the
integer turns and balls per turn around it (the best of them: a design that can be built). Where
no requirement binds alone but all together cannot be met, the least total violation of every
requirement (the elastic problem) names what the closest design misses.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from piezopreload.artifacts.design import CONSTRAINT_WORDS, case_words
from piezopreload.artifacts.requirements import Sense
from piezopreload.models.ballscrew import LIFT_OFF_RATIO

if TYPE_CHECKING:  # the NLP's type only: design/preload.py calls this module when it finds no design
    from piezopreload.design.preload import DesignNLP, DesignQuantities, DesignSpec

__all__ = ["REQUIREMENTS", "Shortfall", "binding", "shortfall_message"]

_TOL = 1e-6  # a slack (scaled, O(1) rows) below this meets the requirement

Reading = Callable[["DesignSpec", "DesignQuantities", int], tuple[float, float]]
def _case(spec: DesignSpec, j: int) -> str:
    return f"{case_words([j + 1])} (axial load {spec.duty[j].axial_load_N:,.0f} N)"


#: each requirement a study sets (its words and key: :data:`~piezopreload.artifacts.design.CONSTRAINT_WORDS`): its
#: unit; its sense (at least or at most the limit); its value and its limit at a design, from the design's
#: expressions and a case index
REQUIREMENTS: dict[str, tuple[str, Sense, Reading]] = {
    "stiffness_min": ("N/um", Sense.AT_LEAST, lambda s, e, j: (min(e.rigidity), s.stiffness_min_N_per_um)),
    "life": ("h", Sense.AT_LEAST, lambda s, e, j: (math.exp(e.log_L), s.life_min_h)),
    "preload_limit": ("N", Sense.AT_MOST, lambda s, e, j: (e.F_hi, s.preload_fraction_max * e.c_dyn)),
    # the largest load without lift-off at the highest preload, 2^1.5 F_hi / lift_off_margin
    "lift_off_max_load": ("N", Sense.AT_LEAST, lambda s, e, j: (LIFT_OFF_RATIO * e.F_hi / s.lift_off_margin,
                                                       s.axial_load_max_N)),
    # the load the bolts alone carry without lift-off, 2^1.5 F_i / lift_off_margin
    "lift_off_failsafe": ("N", Sense.AT_LEAST, lambda s, e, j: (LIFT_OFF_RATIO * e.F_i / s.lift_off_margin,
                                                       s.failsafe_load_N)),
    "contact_pressure_screw": ("MPa", Sense.AT_MOST, lambda s, e, j: (e.p_screw, s.contact_pressure_max_MPa)),
    "contact_pressure_nut": ("MPa", Sense.AT_MOST, lambda s, e, j: (e.p_nut, s.contact_pressure_max_MPa)),
    "drag_torque": ("N m", Sense.AT_MOST, lambda s, e, j: (e.drag_hi, s.drag_torque_max_Nm)),
    "stack_stroke": ("um", Sense.AT_MOST, lambda s, e, j: (e.stroke, s.actuator.stroke_um)),
    "stack_force": ("N", Sense.AT_MOST, lambda s, e, j: (e.F_hi - e.F_i, s.actuator.blocked_force_N)),
    "ball_lead": ("mm", Sense.AT_MOST, lambda s, e, j: (e.D_w, s.ball_lead_ratio_max * s.lead_mm)),
    "nut_length": ("mm", Sense.AT_MOST, lambda s, e, j: (e.turns * s.lead_mm, s.nut_length_max_mm)),
    "lift_off_case": ("N", Sense.AT_LEAST, lambda s, e, j: (LIFT_OFF_RATIO * e.F_case[j] / s.lift_off_margin,
                                                   abs(s.duty[j].axial_load_N))),
    "frequency_case": ("Hz", Sense.AT_LEAST, lambda s, e, j: (e.freq[j], s.frequency_min_Hz)),
}


#: what a requirement's value is, where "reaches" would not say it
_READINGS = {"lift_off_max_load": "carries without lift-off at most", "lift_off_failsafe": "carries on the bolts "
             "alone without lift-off at most", "lift_off_case": "carries without lift-off at most"}


def _group(row: str) -> str:
    return row.split("[")[0]


def _problem(nlp: DesignNLP) -> tuple[Any, list[str]]:
    """The requirement-by-requirement problem: variables (y, s), parameters the rows' mask; minimise s subject to
    g - mask * s <= 0 (the least rigidity a row here), s >= 0."""
    spec, y = nlp.spec, nlp.problem["x"]
    rows = list(nlp.row_names) + ["stiffness_min"]
    t = nlp.offset[7] + nlp.scale[7] * y[7]
    g = ca.vertcat(nlp.problem["g"], (spec.stiffness_min_N_per_um - t) / 100.0)
    s, mask = ca.SX.sym("s"), ca.SX.sym("mask", len(rows))
    solver = ca.nlpsol("design_binding", "ipopt", {"x": ca.vertcat(y, s), "f": s, "g": g - mask * s, "p": mask},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 500,
                        "show_eval_warnings": False})
    return solver, rows


def _least_slack(nlp: DesignNLP, solver: Any, rows: list[str], groups: set[str], y0: np.ndarray,
                 integers: tuple[int, int] | None) -> tuple[float, np.ndarray] | None:
    """The least slack the rows of ``groups`` need with every other requirement kept, and the point; None where the
    solver found no such point."""
    lbx, ubx = nlp.bounds(integers, stiffness_min=0.0)
    g0 = np.asarray(nlp.constraints(np.clip(y0, lbx, ubx))).ravel()
    start = max(float(np.max(g0, initial=0.0)), 0.0) + 1.0
    out = solver(x0=np.append(np.clip(y0, lbx, ubx), start), lbx=np.append(lbx, 0.0), ubx=np.append(ubx, np.inf),
                 lbg=-np.inf, ubg=0.0, p=np.array([float(_group(r) in groups) for r in rows]))
    if not solver.stats()["success"]:
        return None
    x = np.asarray(out["x"]).ravel()
    return float(x[-1]), x[:-1]


@dataclass(frozen=True)
class Shortfall:
    """A requirement no design meets, read at its closest design: the constraint's group, the requirement in words
    and the study key that sets it, how the reading is said, the value reached against the value required (``sense``
    ``min``: at least, ``max``: at most), the shortfall, in ``units``, and the closest design's turns and balls per
    turn (None: the relaxed design)."""

    constraint: str
    requirement: str
    key: str
    reading: str
    reached: float
    required: float
    sense: Sense
    short_by: float
    units: str
    turns: int | None
    balls_per_turn: int | None


def _reading(nlp: DesignNLP, group: str, y: np.ndarray, turns: tuple[int, int] | None) -> Shortfall:
    """What a binding requirement reads at the closest design ``y``: its worst row's value against its limit."""
    unit, sense, read = REQUIREMENTS[group]
    what, key = CONSTRAINT_WORDS[group]
    spec, e = nlp.spec, nlp.evaluate(y)
    cases = range(len(spec.duty)) if group.endswith("_case") else (0,)
    values = [(*read(spec, e, j), j) for j in cases]
    reached, required, j = min(values, key=lambda v: sense.margin(v[0], v[1]))
    x = nlp.to_physical(y)
    short = -sense.margin(reached, required)
    return Shortfall(constraint=group, requirement=what.format(cases=_case(spec, j)), key=key,
                     reading=_READINGS.get(group, "reaches"), reached=float(reached), required=float(required),
                     sense=sense, short_by=float(short), units=unit, turns=int(round(x[3])) if turns else None,
                     balls_per_turn=int(round(x[4])) if turns else None)


def _closest(nlp: DesignNLP, solver: Any, rows: list[str], groups: set[str], y0: np.ndarray,
             candidates: Callable[[np.ndarray], list[tuple[int, int]]]
             ) -> tuple[float, np.ndarray, tuple[int, int] | None] | None:
    """The least slack ``groups``' rows need with every other requirement kept: on the relaxation, then on the
    integer designs around it (the best of them; the relaxation's where none solves). None: the solver found none."""
    relaxed = _least_slack(nlp, solver, rows, groups, y0, None)
    if relaxed is None:  # from the infeasible solve's last point the solver may leave the model's domain
        relaxed = _least_slack(nlp, solver, rows, groups, nlp.initial_guess(), None)
    if relaxed is None:
        return None
    best: tuple[float, np.ndarray, tuple[int, int] | None] = (relaxed[0], relaxed[1], None)
    fixed_best = math.inf
    for ints in candidates(relaxed[1]):
        fixed = _least_slack(nlp, solver, rows, groups, relaxed[1], ints)
        if fixed is not None and fixed[0] < fixed_best:
            fixed_best, best = fixed[0], (fixed[0], fixed[1], ints)
    return best


def binding(nlp: DesignNLP, y0: np.ndarray, candidates: Callable[[np.ndarray], list[tuple[int, int]]]
            ) -> list[Shortfall]:
    """What no design meets (module docstring), each a :class:`Shortfall`: every requirement that cannot be met with
    every other kept, each at its closest design; where each can be met alone, every requirement the closest design to
    all of them at once misses. ``candidates(y)`` gives the integer turns and balls per turn around a relaxed point."""
    solver, rows = _problem(nlp)
    groups = [g for g in REQUIREMENTS if g != "stiffness_min" or nlp.spec.stiffness_min_N_per_um > 0]
    found = []
    for group in groups:
        closest = _closest(nlp, solver, rows, {group}, y0, candidates)
        if closest is not None and closest[0] > _TOL:
            found.append(_reading(nlp, group, closest[1], closest[2]))
    if found:
        return found
    closest = _closest(nlp, solver, rows, set(groups), y0, candidates)
    if closest is None:
        return []
    readings = [_reading(nlp, group, closest[1], closest[2]) for group in groups]
    return [r for r in readings if r.short_by > _TOL * max(1.0, abs(r.required))]


def _number(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def shortfall_message(misses: list[Shortfall]) -> str:
    """The error's words: each binding requirement, the value its closest design reaches and the shortfall."""
    parts = []
    for m in misses:
        design = "" if m.turns is None else f" ({m.turns} turns of {m.balls_per_turn} balls per turn)"
        parts.append(f"{m.requirement}, set by {m.key}: the closest design{design} {m.reading} "
                     f"{_number(m.reached)} {m.units} against {m.sense.words} "
                     f"{_number(m.required)} {m.units}, {_number(m.short_by)} {m.units} short")
    return "; ".join(parts)
