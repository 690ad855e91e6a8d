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

from dataclasses import fields
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.records import Raw, Record, as_members, entry, record
from piezopreload.models.thermal import Feedback, HeatModel, ThermalMounting

__all__ = ["ThermalCase", "PreloadDrift", "ThermalRecord", "ThermalSummary", "PreloadCase", "CASES", "FIGURES",
           "FigurePair"]

Array = NDArray[np.float64]


class PreloadCase(StrEnum):
    """The two preloads a budget compares, by their names in the record's JSON: the schedule as the force loop
    achieved it, and the design's best constant preload."""

    SCHEDULE = "schedule"
    CONSTANT = "constant"


#: the two preloads a budget compares, in the order the report shows them
CASES = tuple(PreloadCase)
@record(eq=False)
class ThermalCase(Record):
    """One preload over the shift: the schedule's as the loop achieved it, or the best constant.

    Scalars: the nut's friction heat (cycle mean, the study's heat model and the other one; both include the
    seals'), the seals' part of it, the support bearings' (both ends, all of it), the mean preload, the screw's
    largest rise over the shift and where along the screw it sits (both heat models), the nut's, the nut's rise
    over the screw's under it at the shift's end (< 0: the nut colder), the largest force the held ends take up
    from the growth (compressive, or the pretension's loss; 0 fixed-free) and the largest force on each end's
    bearing pair (the pretension included), the largest growth at the table's positions (both models), the largest
    positioning error (the budget's total) and the tracking error's share of the deflection. At each of ``times_h`` (the
    warm-up's first minutes, then the end of each hour of the shift): the rise along the screw (``rise_along_K``,
    one row per time, one column per volume), the nut's rise and the nut's over the screw's under it, the growth
    at the table's positions (signed, um), and the budget there (um); ``elastic_um`` the deflection under the
    worst cut at each position.
    """

    heat_mean_W: float = entry("The nut's friction heat, cycle mean, under the study's heat model.", unit="W")
    heat_mean_other_W: float = entry("The same under the other heat model.", unit="W")
    seal_heat_mean_W: float = entry("The nut's seals' part of it (their torque times the speed; either model).",
                                    unit="W")
    bearing_heat_mean_W: float = entry("The support bearings' heat (both ends).", unit="W")
    preload_mean_N: float = entry("The mean preload.", unit="N")
    temperature_rise_max_K: float = entry("The screw's largest rise over the shift.", unit="K")
    rise_max_at_mm: float = entry("Where along the screw it sits, from bearing A.", unit="mm")
    temperature_rise_max_other_K: float = entry("The same under the other heat model.", unit="K")
    nut_rise_max_K: float = entry("The nut's largest rise.", unit="K")
    nut_over_screw_end_K: float = entry("The nut's rise over the screw's under it at the shift's end (< 0: the nut "
                                        "runs colder than the screw).", unit="K")
    end_force_max_N: float = entry("The largest force the held ends take up from the growth (0 fixed-free).",
                                   unit="N")
    bearing_force_max_N: float = entry("The largest force on each end's bearing pair over the shift, the "
                                       "pretension included (0 fixed-free).", unit="N")
    growth_max_um: float = entry("The largest growth at the table's positions.", unit="um")
    growth_max_other_um: float = entry("The same under the other heat model.", unit="um")
    positioning_error_max_um: float = entry("The largest positioning error (the budget's total).", unit="um")
    tracking_um: float = entry("The force loop's tracking error's share of the deflection.", unit="um")
    times_h: Array = entry("The times of the rows: the warm-up's first minutes, then the end of each hour.",
                           unit="h")
    rise_along_K: Array = entry("The rise along the screw: one row per time, one column per volume.", unit="K",
                                rows=True, size="times_h")
    nut_rise_K: Array = entry("The nut's rise at each time.", unit="K", size="times_h")
    nut_over_screw_K: Array = entry("The nut's rise over the screw's under it.", unit="K", size="times_h")
    growth_um: Array = entry("The growth at the table's positions (signed): one row per time, one column per "
                             "position.", unit="um", rows=True, size="times_h")
    elastic_um: Array = entry("The deflection under the worst cut at each position.", unit="um")
    budget_um: Array = entry("The error budget: one row per time, one column per position.", unit="um", rows=True,
                             size="times_h")

    def summary(self) -> dict[str, float]:
        """Its scalar figures by name (:data:`FIGURES`).

        Returns
        -------
        dict of str to float
            Each figure under its field's name.
        """
        return {name: float(getattr(self, name)) for name in FIGURES}

    @property
    def hourly(self) -> NDArray[np.bool_]:
        """Which of ``times_h`` end an hour of the shift (or the shift)."""
        return self.times_h >= 1.0 - 1e-9

    def worst(self) -> tuple[int, int]:
        """(time index, position index) of the largest budget."""
        h, p = np.unravel_index(int(np.argmax(self.budget_um)), self.budget_um.shape)
        return int(h), int(p)

    def to_dict(self) -> dict[str, Any]:
        """The case's figures and its rows.

        Returns
        -------
        dict
            Its object.
        """
        return {**self.summary(), **super().to_dict()}

    def shape_problem(self, volumes: int, positions: int) -> tuple[str, str] | None:
        """The first of its rows whose columns are not one per screw volume or table position: (field, what it
        must be); None where every one fits.

        Parameters
        ----------
        volumes, positions : int
            The screw's volumes and the table's positions.

        Returns
        -------
        tuple of (str, str) or None
            The field and what it must hold.
        """
        for name, width, per in (("rise_along_K", volumes, "screw volume"), ("growth_um", positions, "position"),
                                 ("budget_um", positions, "position")):
            if getattr(self, name).shape[1:] != (width,) and getattr(self, name).size:
                return name, f"must have {width} columns (one per {per}), got {getattr(self, name).shape[1]}"
        if self.elastic_um.shape != (positions,):
            return "elastic_um", f"must have {positions} entries (one per position), got {self.elastic_um.size}"
        return None


#: the scalar figures of a case (its fields that are one number), in their order: the one name each has from the
#: model to the sweep's column
FIGURES = tuple(f.name for f in fields(ThermalCase) if f.type in (float, "float"))


@record
class FigurePair(Record):
    """One scalar figure of a shift (a :data:`FIGURES` name of :class:`ThermalCase`) for both preloads."""

    schedule: float = entry("The schedule's preload as the force loop achieved it.")
    constant: float = entry("The design's best constant preload.")

    def of(self, case: PreloadCase | str) -> float:
        """The figure of one preload.

        Parameters
        ----------
        case : PreloadCase or str
            ``schedule`` or ``constant``.

        Returns
        -------
        float
            Its value.
        """
        return self.schedule if PreloadCase(case) is PreloadCase.SCHEDULE else self.constant


@record
class PreloadDrift(Record):
    """The passive nut's drift and the force loop's room to hold it.

    A spacer-preloaded double nut of the same design at the best constant preload, its nuts' loaded turns
    ``span_mm`` apart (middle to middle), changes its preload by ``passive_N_per_K`` per kelvin of nut over
    screw at first (the tangent); ``passive_max_N`` is its largest change over the shift by the nuts' own law,
    signed (< 0: the screw warmer than the nut, the preload falls), ``passive_left_N`` the preload then left and
    ``passive_linear_N`` what the tangent extrapolated would say (the law softens as the preload falls). With the
    stacks in the loop the preload holds; their stroke takes up the spacer's mismatch, ``stroke_max_um`` at most
    over the schedule's shift, ``voltage_needed_V`` of command (signed: + more voltage, the screw warmer than the
    nut), against ``headroom_V`` the run left on that side of the command's range.
    """

    span_mm: float = entry("The nuts' loaded turns apart, middle to middle.", unit="mm")
    passive_N_per_K: float = entry("The passive nut's preload change per kelvin of nut over screw.", unit="N/K")
    passive_max_N: float = entry("Its largest change over the shift by the nut law, signed (< 0: the preload "
                                 "falls).", unit="N")
    passive_left_N: float | None = entry("The preload left then (0: the nuts part); None in a summary written "
                                         "before it was recorded.", unit="N", absent=None, omit=True)
    passive_linear_N: float | None = entry("The tangent's linear extrapolation of that change, for comparison; None "
                                           "in a summary written before it was recorded.", unit="N", absent=None,
                                           omit=True)
    passive_preload_N: float = entry("The best constant preload it holds.", unit="N")
    stroke_max_um: float = entry("The stacks' largest stroke taking up the spacer's mismatch.", unit="um")
    voltage_needed_V: float = entry("The command that needs (signed: + more voltage).", unit="V")
    headroom_V: float = entry("The command's range the run left on that side.", unit="V")

    @property
    def held(self) -> bool:
        """Whether the command's range left by the run takes up the drift."""
        return abs(self.voltage_needed_V) <= self.headroom_V

    def to_dict(self) -> dict[str, Any]:
        """Its fields and whether the run's command range holds the drift.

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "held": self.held}


@record
class ThermalSummary(Record):
    """A shift's thermal budget without its series (:meth:`ThermalRecord.summary`): each scalar figure of the two
    cases (``schedule``, ``constant``) under its :class:`ThermalCase` name, the settings, the drift, and in words per
    case where the largest rise sits, the nut against the screw and the ends' force. Its document (``system.json``'s
    summary and ``run --json``'s ``thermal``) holds each figure as ``{"schedule": ..., "constant": ...}`` beside the
    settings; a summary written before a figure, a setting or the words were recorded lacks them, and is read and
    written back so."""

    figures: dict[str, FigurePair] = entry("Each scalar figure for both preloads, by its name (:data:`FIGURES`), at "
                                           "the top of the document's object.", spread=FIGURES)
    heat_model: HeatModel = entry("The study's heat model of the nut's friction.")
    other_model: HeatModel = entry("The other heat model, reported beside it.")
    lubricant_vg: int = entry("The lubricant's viscosity grade (ISO VG).", ge=0)
    sealed: bool = entry("Whether the nut is sealed.")
    seal_torque_Nm: float | None = entry("The seals' torque (0: an open nut).", unit="N m", absent=None, omit=True)
    nut_heat_share: float | None = entry("The share of the nut's heat entering the screw.", absent=None, omit=True)
    convection_factor: float | None = entry("The factor on the air's film coefficients.", absent=None, omit=True)
    mounting: ThermalMounting = entry("How the screw's ends are held.")
    pretension_K: float = entry("The screw's pretension, as a temperature rise it takes up.", unit="K")
    bearing_lift_off_N: float | None = entry("Each end's bearing pair's lift-off force.", unit="N", absent=None,
                                             omit=True)
    feedback: Feedback = entry("Where the position loop measures.")
    shift_h: float = entry("The shift's length.", unit="h")
    stroke_mm: tuple[float, float] = entry("The table's stroke (from, to), from bearing A.", unit="mm")
    film_mean_W_per_m2K: float = entry("The cycle's mean film coefficient on the screw.", unit="W/(m^2 K)")
    screw_time_constant_s: float = entry("The screw's lumped time constant under it.", unit="s")
    drift: PreloadDrift = entry("The passive nut's drift and the force loop's room to hold it.")
    rise_max_place: dict[str, str] = entry("Per case, where the largest rise sits, in words.", absent={}, omit=True)
    nut_against_screw: dict[str, str] = entry("Per case, the nut against the screw, in words.", absent={},
                                              omit=True)
    ends: dict[str, str] = entry("Per case, the ends' bearing pairs' force against their lift-off, in words.",
                                 absent={}, omit=True)

    def __post_init__(self) -> None:
        as_members(self)
        unknown = [name for name in self.figures if name not in FIGURES]
        if unknown:
            raise ValueError(f"{', '.join(unknown)} is no figure of a thermal case; they are {', '.join(FIGURES)}")

    def figure(self, name: str, case: PreloadCase | str) -> float:
        """One figure of one preload.

        Parameters
        ----------
        name : str
            The figure's name (:data:`FIGURES`).
        case : PreloadCase or str
            ``schedule`` or ``constant``.

        Returns
        -------
        float
            Its value.

        Raises
        ------
        KeyError
            Where the summary does not hold that figure (written before it was recorded, or no figure of that name).
        """
        if name not in self.figures:
            raise KeyError(f"{name!r}: the summary holds {', '.join(self.figures)}")
        return self.figures[name].of(case)


@record(eq=False)
class ThermalRecord(Record):
    """A shift's thermal budget: its settings, the screw's volumes and the table's positions (mm from bearing A),
    the cycle's mean film coefficient on the screw and the screw's lumped time constant under it, the two cases
    and the drift."""

    heat_model: HeatModel = entry("The study's heat model of the nut's friction.")
    other_model: HeatModel = entry("The other heat model, reported beside it.")
    lubricant_vg: int = entry("The lubricant's viscosity grade (ISO VG).", ge=0)
    sealed: bool = entry("Whether the nut is sealed.")
    seal_torque_Nm: float = entry("The seals' torque (0: an open nut).", unit="N m")
    nut_heat_share: float = entry("The share of the nut's heat entering the screw (the rest heats the nut).")
    convection_factor: float = entry("The factor on the air's film coefficients.")
    mounting: ThermalMounting = entry("How the screw's ends are held.")
    pretension_K: float = entry("The screw's pretension, as a temperature rise it takes up.", unit="K")
    bearing_lift_off_N: float = entry("Each end's bearing pair's lift-off force, 2^(3/2) its preload (0: ends not "
                                      "held, or no pair preload stated).", unit="N")
    feedback: Feedback = entry("Where the position loop measures (what growth it sees).")
    shift_h: float = entry("The shift's length.", unit="h")
    stroke_mm: tuple[float, float] = entry("The table's stroke (from, to), from bearing A.", unit="mm")
    screw_x_mm: Array = entry("The screw's volumes' positions, from bearing A.", unit="mm")
    positions_mm: Array = entry("The table's positions, from bearing A.", unit="mm")
    film_mean_W_per_m2K: float = entry("The cycle's mean film coefficient on the screw.", unit="W/(m^2 K)")
    screw_time_constant_s: float = entry("The screw's lumped time constant under it.", unit="s")
    schedule: ThermalCase = entry("The schedule's preload as the loop achieved it.", at="cases")
    constant: ThermalCase = entry("The best constant preload.", at="cases")
    drift: PreloadDrift = entry("The passive nut's drift and the force loop's room to hold it.")

    def __post_init__(self) -> None:
        as_members(self)

    def place(self, x_mm: float) -> str:
        """Where ``x_mm`` (from bearing A) lies on the screw, in words: at an end's bearing (its first or last 5 %),
        under the nut's stroke, or between."""
        dx = float(self.screw_x_mm[1] - self.screw_x_mm[0]) if self.screw_x_mm.size > 1 else 0.0
        length = float(self.screw_x_mm[-1]) + 0.5 * dx
        end = max(0.05 * length, dx)
        if x_mm <= end:
            return "at bearing A's end"
        if x_mm >= length - end:
            return "at bearing B's end"
        if self.stroke_mm[0] <= x_mm <= self.stroke_mm[1]:
            return "under the nut's stroke"
        return f"between the nut's stroke and bearing {'A' if x_mm < self.stroke_mm[0] else 'B'}"

    def nut_against_screw(self, case: ThermalCase) -> str:
        """Whether the nut runs warmer or colder than the screw under it at the shift's end, and, where colder (what
        measured axes do not show: their nut zone runs hottest), why the model has it so."""
        d = case.nut_over_screw_end_K
        if d >= 0:
            return f"the nut runs {d:.1f} K warmer than the screw under it"
        return (f"the nut runs {-d:.1f} K colder than the screw under it, against measured axes (their nut zone runs "
                f"hottest): the nut keeps {100.0 * (1.0 - self.nut_heat_share):.0f} % of its heat (nut_heat_share = "
                f"{self.nut_heat_share:g}, an assumption: no share is published) and loses it through its flange into "
                "the table faster than the screw loses its share, and the bearings heat the screw too")

    def heat_words(self, case: ThermalCase) -> str:
        """The case's heat by source: the bearings, the seals, the preload's drag (or rolling contacts)."""
        return (f"{case.bearing_heat_mean_W:.0f} W at the support bearings, {case.seal_heat_mean_W:.0f} W at the "
                f"nut's seals, {case.heat_mean_W - case.seal_heat_mean_W:.0f} W of the preload's friction at a mean "
                f"{case.preload_mean_N:,.0f} N")

    def ends_words(self, case: ThermalCase) -> str:
        """The force on the ends' bearing pairs against their lift-off ('' for a free end)."""
        if self.mounting is ThermalMounting.FIXED_FREE:
            return ""
        if self.bearing_lift_off_N <= 0:
            return f"the ends' bearings carry up to {case.bearing_force_max_N:,.0f} N"
        ratio = case.bearing_force_max_N / self.bearing_lift_off_N
        state = ("beyond it: one row of each pair runs unloaded, the other alone holds the screw" if ratio > 1
                 else "within it")
        return (f"the ends' bearing pairs carry up to {case.bearing_force_max_N:,.0f} N against their lift-off of "
                f"{self.bearing_lift_off_N:,.0f} N ({state})")

    def sentence(self) -> str:
        """The shift in one sentence: each preload's heat by source, the largest rise and where it sits, the nut
        against the screw, the growth and the ends' force."""
        s, c = self.schedule, self.constant
        ends = self.ends_words(s)
        return (f"over the {self.shift_h:g} h shift the schedule makes {self.heat_words(s)} ({self.heat_model} model; "
                f"best constant preload: {c.heat_mean_W - c.seal_heat_mean_W:.0f} W of preload friction); the screw "
                f"warms by up to {s.temperature_rise_max_K:.1f} K {self.place(s.rise_max_at_mm)} (constant: "
                f"{c.temperature_rise_max_K:.1f} K {self.place(c.rise_max_at_mm)}), {self.nut_against_screw(s)}; it "
                f"grows up to {s.growth_max_um:.1f} um at the table (constant: {c.growth_max_um:.1f} um)"
                + (f"; {ends}" if ends else ""))

    def case(self, name: str) -> ThermalCase:
        """The figures of the preload ``name`` (a :class:`PreloadCase` or its name)."""
        return self.schedule if PreloadCase(name) is PreloadCase.SCHEDULE else self.constant

    def summary(self) -> ThermalSummary:
        """Each figure for the schedule and the constant preload, the settings and the drift (no series)."""
        figures = {name: FigurePair(getattr(self.schedule, name), getattr(self.constant, name)) for name in FIGURES}
        return ThermalSummary(
            figures=figures, heat_model=self.heat_model,
            other_model=self.other_model, lubricant_vg=self.lubricant_vg,
            sealed=self.sealed, seal_torque_Nm=self.seal_torque_Nm, nut_heat_share=self.nut_heat_share,
            convection_factor=self.convection_factor, mounting=self.mounting, pretension_K=self.pretension_K,
            bearing_lift_off_N=self.bearing_lift_off_N, feedback=self.feedback,
            shift_h=self.shift_h, stroke_mm=self.stroke_mm, film_mean_W_per_m2K=self.film_mean_W_per_m2K,
            screw_time_constant_s=self.screw_time_constant_s, drift=self.drift,
            rise_max_place={c: self.place(self.case(c).rise_max_at_mm) for c in CASES},
            nut_against_screw={c: self.nut_against_screw(self.case(c)) for c in CASES},
            ends={c: self.ends_words(self.case(c)) for c in CASES})

    def to_dict(self) -> dict[str, Any]:
        """:meth:`summary`'s, the screw's volumes, the table's positions and both cases whole.

        Returns
        -------
        dict
            Its object.
        """
        return {**self.summary().to_dict(), **super().to_dict()}

    def _check_document(self, raw: Raw) -> None:
        for name in CASES:
            problem = self.case(name).shape_problem(self.screw_x_mm.size, self.positions_mm.size)
            if problem is not None:
                raise raw.fail(f"cases.{name}.{problem[0]}", problem[1])
