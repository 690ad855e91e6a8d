"""The thermal budget of a shift, as the system artifact records it (``system.json``'s ``thermal``).

:func:`piezopreload.design.thermal.thermal_budget` computes it (:mod:`piezopreload.models.thermal` is the
physics): for the preload the force loop achieved along the schedule and for the design's best constant
preload, the nut's friction heat under both heat models, the screw's temperature along its length at the end
of each hour of the shift, its growth at the table's positions, and the error budget per position and hour
(the elastic deflection under the cutting load, the thermal growth where the position loop does not see it,
and the force loop's tracking error's share); and what a passive spacer-preloaded nut of the same design would
drift, against the command range the force loop has left to hold it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts._fields import Fields

__all__ = ["ThermalCase", "PreloadDrift", "ThermalRecord", "CASES"]

Array = NDArray[np.float64]
#: the two preloads a budget compares, in the order the report shows them
CASES = ("schedule", "constant")
#: the scalar figures of a case, in its summary's order
_FIGURES = ("heat_mean_W", "heat_mean_other_W", "bearing_heat_mean_W", "preload_mean_N", "temperature_rise_max_K",
            "temperature_rise_max_other_K", "nut_rise_max_K", "end_force_max_N", "growth_max_um",
            "growth_max_other_um", "positioning_error_max_um", "tracking_um")


def _matrix(f: Fields, key: str, rows: int, cols: int) -> Array:
    """A list of ``rows`` lists of ``cols`` finite numbers."""
    x = f.raw(key)
    if not isinstance(x, list) or len(x) != rows:
        raise f.fail(key, f"must be a list of {rows} rows")
    sub = Fields({str(i): r for i, r in enumerate(x)}, f.shown, f.path(key))
    return np.array([sub.array(str(i), cols) for i in range(rows)]).reshape(rows, cols)


@dataclass(frozen=True, eq=False)
class ThermalCase:
    """One preload over the shift: the schedule's as the loop achieved it, or the best constant.

    Scalars: the nut's friction heat (cycle mean, the study's heat model and the other one), the support
    bearings' (both ends, all of it), the mean preload, the screw's largest rise over the shift (both heat
    models), the nut's, the largest force the held ends take up from the growth (compressive, or the pretension's
    loss; 0 fixed-free), the largest growth at the table's positions (both models), the largest positioning
    error (the budget's total) and the tracking error's share of the deflection. At each of ``times_h`` (the
    warm-up's first minutes, then the end of each hour of the shift): the rise along the screw (``rise_along_K``,
    one row per time, one column per volume), the nut's rise and the nut's over the screw's under it, the growth
    at the table's positions (signed, um), and the budget there (um); ``elastic_um`` the deflection under the
    worst cut at each position.
    """

    heat_mean_W: float
    heat_mean_other_W: float
    bearing_heat_mean_W: float
    preload_mean_N: float
    temperature_rise_max_K: float
    temperature_rise_max_other_K: float
    nut_rise_max_K: float
    end_force_max_N: float
    growth_max_um: float
    growth_max_other_um: float
    positioning_error_max_um: float
    tracking_um: float
    times_h: Array
    rise_along_K: Array
    nut_rise_K: Array
    nut_over_screw_K: Array
    growth_um: Array
    elastic_um: Array
    budget_um: Array

    def summary(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in _FIGURES}

    @property
    def hourly(self) -> NDArray[np.bool_]:
        """Which of ``times_h`` end an hour of the shift (or the shift)."""
        return self.times_h >= 1.0 - 1e-9

    def worst(self) -> tuple[int, int]:
        """(time index, position index) of the largest budget."""
        h, p = np.unravel_index(int(np.argmax(self.budget_um)), self.budget_um.shape)
        return int(h), int(p)

    def to_dict(self) -> dict[str, Any]:
        return {**self.summary(), "times_h": self.times_h.tolist(), "rise_along_K": self.rise_along_K.tolist(),
                "nut_rise_K": self.nut_rise_K.tolist(), "nut_over_screw_K": self.nut_over_screw_K.tolist(),
                "growth_um": self.growth_um.tolist(), "elastic_um": self.elastic_um.tolist(),
                "budget_um": self.budget_um.tolist()}

    @classmethod
    def from_fields(cls, f: Fields, volumes: int, positions: int) -> ThermalCase:
        times = f.array("times_h")
        n = times.size
        return cls(**{name: f.number(name) for name in _FIGURES}, times_h=times,
                   rise_along_K=_matrix(f, "rise_along_K", n, volumes), nut_rise_K=f.array("nut_rise_K", n),
                   nut_over_screw_K=f.array("nut_over_screw_K", n), growth_um=_matrix(f, "growth_um", n, positions),
                   elastic_um=f.array("elastic_um", positions), budget_um=_matrix(f, "budget_um", n, positions))


@dataclass(frozen=True)
class PreloadDrift:
    """The passive nut's drift and the force loop's room to hold it.

    A spacer-preloaded double nut of the same design at the best constant preload, its nuts' loaded turns
    ``span_mm`` apart (middle to middle), changes its preload by ``passive_N_per_K`` per kelvin of nut over
    screw; ``passive_max_N`` is its largest change over the shift, signed (< 0: the screw warmer than the nut,
    the preload falls). With the stacks in the loop the preload holds; their stroke takes up the spacer's
    mismatch, ``stroke_max_um`` at most over the schedule's shift, ``voltage_needed_V`` of command (signed: + more
    voltage, the screw warmer than the nut), against ``headroom_V`` the run left on that side of the command's
    range.
    """

    span_mm: float
    passive_N_per_K: float
    passive_max_N: float
    passive_preload_N: float
    stroke_max_um: float
    voltage_needed_V: float
    headroom_V: float

    @property
    def held(self) -> bool:
        """Whether the command's range left by the run takes up the drift."""
        return abs(self.voltage_needed_V) <= self.headroom_V

    def to_dict(self) -> dict[str, Any]:
        return {"span_mm": self.span_mm, "passive_N_per_K": self.passive_N_per_K,
                "passive_max_N": self.passive_max_N, "passive_preload_N": self.passive_preload_N,
                "stroke_max_um": self.stroke_max_um, "voltage_needed_V": self.voltage_needed_V,
                "headroom_V": self.headroom_V, "held": self.held}

    @classmethod
    def from_fields(cls, f: Fields) -> PreloadDrift:
        return cls(*(f.number(k) for k in ("span_mm", "passive_N_per_K", "passive_max_N",
                                           "passive_preload_N", "stroke_max_um", "voltage_needed_V", "headroom_V")))


@dataclass(frozen=True, eq=False)
class ThermalRecord:
    """A shift's thermal budget: its settings, the screw's volumes and the table's positions (mm from bearing A),
    the cycle's mean film coefficient on the screw and the screw's lumped time constant under it, the two cases
    and the drift."""

    heat_model: str
    other_model: str
    lubricant_vg: int
    sealed: bool
    mounting: str
    pretension_K: float
    feedback: str
    shift_h: float
    stroke_mm: tuple[float, float]
    screw_x_mm: Array
    positions_mm: Array
    film_mean_W_per_m2K: float
    screw_time_constant_s: float
    schedule: ThermalCase
    constant: ThermalCase
    drift: PreloadDrift

    def sentence(self) -> str:
        """The shift in one sentence: each preload's heat, rise and growth."""
        s, c = self.schedule, self.constant
        return (f"over the {self.shift_h:g} h shift the schedule's {s.heat_mean_W:.1f} W of nut friction warm the "
                f"screw by up to {s.temperature_rise_max_K:.1f} K and grow it up to {s.growth_max_um:.1f} um at the "
                f"table; the best constant preload's {c.heat_mean_W:.1f} W: {c.temperature_rise_max_K:.1f} K, "
                f"{c.growth_max_um:.1f} um ({self.heat_model} model)")

    def case(self, name: str) -> ThermalCase:
        return {"schedule": self.schedule, "constant": self.constant}[name]

    def summary(self) -> dict[str, Any]:
        """Each figure for the schedule and the constant preload (``heat_mean_W: {schedule, constant}``), the
        settings and the drift: what ``system.json``'s summary and ``run --json`` hold as ``thermal``."""
        figures = {name: {c: getattr(self, c).summary()[name] for c in CASES} for name in _FIGURES}
        return {**figures, "heat_model": self.heat_model, "other_model": self.other_model,
                "lubricant_vg": self.lubricant_vg, "sealed": self.sealed, "mounting": self.mounting,
                "pretension_K": self.pretension_K, "feedback": self.feedback, "shift_h": self.shift_h,
                "stroke_mm": list(self.stroke_mm), "film_mean_W_per_m2K": self.film_mean_W_per_m2K,
                "screw_time_constant_s": self.screw_time_constant_s, "drift": self.drift.to_dict()}

    def to_dict(self) -> dict[str, Any]:
        return {**self.summary(), "screw_x_mm": self.screw_x_mm.tolist(), "positions_mm": self.positions_mm.tolist(),
                "cases": {c: getattr(self, c).to_dict() for c in CASES}}

    @classmethod
    def from_fields(cls, f: Fields) -> ThermalRecord:
        x, positions = f.array("screw_x_mm"), f.array("positions_mm")
        stroke = f.array("stroke_mm", 2)
        cases = f.sub("cases")
        schedule, constant = (ThermalCase.from_fields(cases.sub(c), x.size, positions.size) for c in CASES)
        return cls(f.text("heat_model"), f.text("other_model"), f.integer("lubricant_vg"), f.flag("sealed"),
                   f.text("mounting"), f.number("pretension_K"), f.text("feedback"), f.number("shift_h"),
                   (float(stroke[0]), float(stroke[1])), x, positions, f.number("film_mean_W_per_m2K"),
                   f.number("screw_time_constant_s"), schedule, constant, PreloadDrift.from_fields(f.sub("drift")))
