"""The report's account of the shift: the preload's heat, the screw's temperature and growth, the error budget.

From the system artifact's thermal budget (:class:`~piezopreload.artifacts.thermal.ThermalRecord`), for the
schedule as the force loop achieved it and for the design's best constant preload: the summary's lines, the
section (its paragraphs and table) and its three figures (the temperature along the screw at the end of each
hour, the growth against the table's position, the error budget's parts at the worst position of each hour).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.thermal import PreloadDrift, ThermalCase, ThermalRecord
from piezopreload.models.thermal import Feedback, ThermalMounting
from piezopreload.reports.document import ReportTable, Section, fmt, pct
from piezopreload.reports.figures import COLOURS, legends, page_figure, styled
from piezopreload.reports.sections import Part

__all__ = ["thermal_lines", "thermal_section", "temperature_along_screw", "growth_along_travel", "error_budget"]

_NAMES = {"schedule": "schedule (achieved)", "constant": "best constant preload"}
_MODELS = {"catalogue": "catalogue drag torque", "contact": "rolling-contact loss"}
_FEEDBACK = {"semi-closed": "a semi-closed loop (the motor's encoder): the growth is a positioning error",
             "linear-scale": "a linear scale on the table: the growth does not move the table, and the budget leaves "
                             "it out"}


def _saving(s: float, c: float) -> str:
    return pct(1.0 - s / c) if c > 0 else "nothing"


def thermal_lines(t: ThermalRecord) -> list[str]:
    """The summary's sentences: each preload's heat by source, rise (and where), growth and positioning error, the
    nut against the screw, and the saving's bounds."""
    s, c = t.schedule, t.constant
    ends = t.ends_words(s)
    return [
        f"Over the {fmt(t.shift_h)} h shift the schedule makes {t.heat_words(s)} ({_MODELS[t.heat_model]}): the "
        f"screw warms by at most {fmt(s.temperature_rise_max_K)} K {t.place(s.rise_max_at_mm)} and grows "
        f"{fmt(s.growth_max_um)} um at the table, for a positioning error of up to {fmt(s.positioning_error_max_um)} "
        f"um; the best constant preload's {fmt(c.heat_mean_W - c.seal_heat_mean_W)} W of preload friction: "
        f"{fmt(c.temperature_rise_max_K)} K {t.place(c.rise_max_at_mm)}, {fmt(c.growth_max_um)} um, "
        f"{fmt(c.positioning_error_max_um)} um.",
        f"With the schedule {t.nut_against_screw(s)}" + (f"; {ends}." if ends else "."),
        f"The schedule saves {_saving(s.heat_mean_W, c.heat_mean_W)} of the nut's heat (its seals' "
        f"{fmt(s.seal_heat_mean_W)} W included, which no preload saves) by the {_MODELS[t.heat_model]} and "
        f"{_saving(s.heat_mean_other_W, c.heat_mean_other_W)} by the {_MODELS[t.other_model]} (the bounds; growth "
        f"{fmt(s.growth_max_other_um)} against {fmt(c.growth_max_other_um)} um by the latter).",
    ]


def _rows(t: ThermalRecord) -> tuple[tuple[str, str, str], ...]:
    s, c = t.schedule, t.constant

    def row(label: str, a: float, b: float, digits: int = 3) -> tuple[str, str, str]:
        unit = label.rpartition("(")[2].rstrip(")")  # the unit the label names: one rule per quantity's kind
        return label, fmt(a, digits, unit), fmt(b, digits, unit)

    return (
        row("mean preload (N)", s.preload_mean_N, c.preload_mean_N, 4),
        row(f"nut friction heat, {_MODELS[t.heat_model]} (W)", s.heat_mean_W, c.heat_mean_W),
        row(f"nut friction heat, {_MODELS[t.other_model]} (W)", s.heat_mean_other_W, c.heat_mean_other_W),
        row("of which the seals' (W)", s.seal_heat_mean_W, c.seal_heat_mean_W),
        row("support bearings' heat, both ends (W)", s.bearing_heat_mean_W, c.bearing_heat_mean_W),
        row("largest rise of the screw (K)", s.temperature_rise_max_K, c.temperature_rise_max_K),
        ("where it sits", t.place(s.rise_max_at_mm), t.place(c.rise_max_at_mm)),
        row(f"largest rise of the screw, {_MODELS[t.other_model]} (K)", s.temperature_rise_max_other_K,
            c.temperature_rise_max_other_K),
        row("rise of the nut (K)", s.nut_rise_max_K, c.nut_rise_max_K),
        row("nut over the screw under it, shift's end (K)", s.nut_over_screw_end_K, c.nut_over_screw_end_K),
        row("force the held ends take up from the growth (N)", s.end_force_max_N, c.end_force_max_N, 4),
        row("largest force on each end's bearing pair (N)", s.bearing_force_max_N, c.bearing_force_max_N, 4),
        row("largest growth at the table (um)", s.growth_max_um, c.growth_max_um),
        row(f"largest growth at the table, {_MODELS[t.other_model]} (um)", s.growth_max_other_um,
            c.growth_max_other_um),
        row("largest positioning error, the budget (um)", s.positioning_error_max_um, c.positioning_error_max_um),
        row("the force loop's share of it (um)", s.tracking_um, c.tracking_um),
    )


def thermal_section(t: ThermalRecord, requirements: Sequence[Requirement] = ()) -> Part:
    """The section: what was modelled, the two preloads' shifts, the budget, the passive nut's drift."""
    s, c, d = t.schedule, t.constant, t.drift
    _, p = s.worst()
    pretensioned = t.mounting is ThermalMounting.PRETENSIONED
    mounting = t.mounting + (f" ({fmt(t.pretension_K)} K of pretension)" if pretensioned else "")
    paragraphs = [
        f"The preload's friction heat over a shift of {fmt(t.shift_h)} h of the machining cycle from a cold axis: the "
        f"nut's heat by the {_MODELS[t.heat_model]} (ISO VG{t.lubricant_vg}, "
        f"{'sealed' if t.sealed else 'open'} nut; the {_MODELS[t.other_model]} beside it as the other bound), its "
        f"share entering the screw under the nut as the nut runs out over its "
        f"{fmt(t.stroke_mm[0])}-{fmt(t.stroke_mm[1])} mm stroke and back once a cycle, and the support bearings' "
        f"heat at the screw's ends. Averaged over the cycle, the heat and the rotating screw's film coefficient "
        f"({fmt(t.film_mean_W_per_m2K)} W/m^2 K, a time constant of {fmt(t.screw_time_constant_s / 60.0)} min) drive "
        f"the screw's temperature along its length; the growth follows from its mounting, {mounting}, and the "
        f"position loop is {_FEEDBACK[t.feedback]}.",
        _assumptions(t),
        f"The schedule the force loop achieved makes {fmt(s.heat_mean_W)} W against the best constant preload's "
        f"{fmt(c.heat_mean_W)} W ({_saving(s.heat_mean_W, c.heat_mean_W)} less; "
        f"{_saving(s.heat_mean_other_W, c.heat_mean_other_W)} by the {_MODELS[t.other_model]}): the screw warms by "
        f"at most {fmt(s.temperature_rise_max_K)} against {fmt(c.temperature_rise_max_K)} K and grows at most "
        f"{fmt(s.growth_max_um)} against {fmt(c.growth_max_um)} um at the table. The error budget (the deflection "
        "under the cycle's worst cut, the growth and the force loop's share, added as magnitudes: a worst case) "
        f"reaches {fmt(s.positioning_error_max_um)} um at {fmt(t.positions_mm[p])} mm with the schedule "
        f"({_settled(s)}), {fmt(c.positioning_error_max_um)} um with the constant preload.",
        _drift_text(d),
        "Each of the schedule's requirements, the heat (either model) and the growth grow with the preload at every "
        "sample, so the least-friction schedule is also the least-heat and least-growth one: the plan does not "
        "change when its objective is the heat.",
    ]
    names = [r.name for r in requirements]
    if names:
        paragraphs.append("The study's limits on them are requirements (" + "; ".join(names) + "), judged on the "
                          "schedule: see the requirements' table.")
    table = ReportTable(("over the shift", _NAMES["schedule"], _NAMES["constant"]), _rows(t),
                  f"The shift's heat, temperature, growth and positioning error ({t.heat_model} model unless named).",
                  "lrr")
    limit = next((r.limit for r in requirements if "growth" in r.name), None)
    budget_limit = next((r.limit for r in requirements if "positioning" in r.name), None)
    figures = (
        ("thermal-temperature", temperature_along_screw(t), "The screw's temperature rise along its length "
         f"{_times_words(s.times_h)} into the shift (darker: later), the schedule as achieved and the best constant "
         f"preload; grey, the nut's stroke; {t.heat_model} model."),
        ("thermal-growth", growth_along_travel(t, limit), "The screw's growth at the table's positions "
         f"{_times_words(s.times_h)} into the shift (darker: later), for its {t.mounting} mounting"
         + ("" if limit is None else "; dashed, the study's limit") + "."),
        ("thermal-budget", error_budget(t, budget_limit), "The error budget at the worst table position of each hour: "
         "the deflection under the cycle's worst cut, the thermal growth and the force loop's share, schedule (left) "
         "and best constant preload (right)" + ("" if budget_limit is None else "; dashed, the study's limit") + "."),
    )
    return Part(Section("Heat, temperature and growth over a shift", tuple(paragraphs), (table,),
                        tuple(n for n, _, _ in figures)), figures)


def _assumptions(t: ThermalRecord) -> str:
    """What the figures rest on: the seals, the heat split, the convection, the ends."""
    seals = (f"the seals' torque {fmt(t.seal_torque_Nm)} N m, apart from the preload's" if t.sealed else
             "no seal torque (an open nut)")
    ends = ("" if t.mounting is ThermalMounting.FIXED_FREE else
            f" Each end is a preloaded bearing pair of the axis' bearing stiffness, lifting off at "
            f"{fmt(t.bearing_lift_off_N, 4)} N; the pretension, where set, is relieved as the screw warms." if
            t.bearing_lift_off_N > 0 else " Each end is a spring of the axis' bearing stiffness.")
    return (f"It rests on {seals}; {fmt(t.nut_heat_share)} of the nut's heat entering the screw (an assumption: no "
            f"share is published; measured axes run hottest at the nut); the air's film coefficients times "
            f"{fmt(t.convection_factor)}.{ends} With the schedule, {t.nut_against_screw(t.schedule)}.")


def _times_words(times_h: np.ndarray) -> str:
    """The times the curves are drawn at, in words: ``at 5 min, 10 min, 20 min, 30 min and 1 h to 8 h, hourly``."""
    times = [float(h) for h in times_h]
    whole = [h for h in times if h >= 1.0 and abs(h - round(h)) < 1e-9]
    hourly = len(whole) >= 3 and [round(h) for h in whole] == list(range(round(whole[0]), round(whole[-1]) + 1))
    early = [_when(h) for h in times if not (hourly and h in whole)]
    late = [f"{_when(whole[0])} to {_when(whole[-1])}, hourly"] if hourly else []
    words = early + late
    return "at " + (words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1])


def _when(hours: float) -> str:
    return f"{fmt(60.0 * hours)} min" if hours < 1.0 else f"{fmt(hours)} h"


def _settled(case: ThermalCase) -> str:
    """When the budget's largest value is first within 1 % of its largest over the shift."""
    k = int(np.argmax(np.max(case.budget_um, axis=1) >= 0.99 * case.positioning_error_max_um))
    return f"within 1 % of it from {_when(case.times_h[k])} into the shift on"


def _drift_text(d: PreloadDrift) -> str:
    change = "fall" if d.passive_max_N < 0 else "rise"
    lost = ("" if d.passive_left_N is None else " (it would lose it: the nuts part)" if d.passive_left_N <= 0 else
            f", leaving {fmt(d.passive_left_N, 3)} N")
    linear = ("" if d.passive_linear_N is None else
              f" (the first kelvin's rate extrapolated would say {fmt(abs(d.passive_linear_N), 3)} N)")
    held = (f"within the {fmt(d.headroom_V)} V the command's range leaves on that side." if d.held else
            f"beyond the {fmt(d.headroom_V)} V the command's range leaves on that side: the loop could not hold it.")
    return (f"A passive double nut of the same design, preloaded by a spacer at the best constant preload "
            f"({fmt(d.passive_preload_N, 4)} N; its nuts' loaded turns {fmt(d.span_mm)} mm apart), changes its "
            f"preload by {fmt(d.passive_N_per_K)} N per kelvin of nut over screw at first: over the shift, along the "
            f"nuts' own law, it would {change} by up to {fmt(abs(d.passive_max_N), 3)} N{lost}{linear}. The force "
            "loop holds the piezo "
            f"preload: the stacks take up the spacer's mismatch ({fmt(d.stroke_max_um)} um at most over the "
            f"schedule's shift), {fmt(abs(d.voltage_needed_V))} V of command "
            f"{'more' if d.voltage_needed_V > 0 else 'less'} than the run used, " + held)


def _hour_colours(n: int, name: str) -> list[tuple[float, ...]]:
    cmap = colormaps[name]
    return [cmap(0.35 + 0.6 * k / max(n - 1, 1)) for k in range(n)]


@styled
def temperature_along_screw(t: ThermalRecord) -> Figure:
    """The rise along the screw at the end of each hour, one panel per preload, the stroke shaded."""
    fig, ax = page_figure(2.7, ncols=2, sharey=True)
    for a, (name, cmap) in zip(ax[0], (("schedule", "Blues"), ("constant", "Oranges"))):
        case: ThermalCase = t.case(name)
        a.axvspan(*t.stroke_mm, color="0.92", lw=0)
        n = case.times_h.size
        for k, (when, rise) in enumerate(zip(case.times_h, case.rise_along_K)):
            a.plot(t.screw_x_mm, rise, color=_hour_colours(n, cmap)[k], lw=0.9,
                   label=_when(when) if k in (0, n - 1) else None)
        a.set_title(_NAMES[name])
        a.set_xlabel("position from bearing A (mm)")
    ax[0][0].set_ylabel("temperature rise (K)")
    legends(*ax[0])
    return fig


@styled
def growth_along_travel(t: ThermalRecord, limit_um: float | None = None) -> Figure:
    """The growth at the table's positions at the end of each hour, one panel per preload."""
    fig, ax = page_figure(2.7, ncols=2, sharey=True)
    for a, (name, cmap) in zip(ax[0], (("schedule", "Blues"), ("constant", "Oranges"))):
        case = t.case(name)
        n = case.times_h.size
        for k, (when, growth) in enumerate(zip(case.times_h, case.growth_um)):
            a.plot(t.positions_mm, growth, color=_hour_colours(n, cmap)[k], lw=0.9,
                   label=_when(when) if k in (0, n - 1) else None)
        if limit_um is not None:
            for sign in (1.0, -1.0):
                a.axhline(sign * limit_um, color=COLOURS["limit"], ls="--", lw=0.8)
        a.set_title(_NAMES[name])
        a.set_xlabel("table position from bearing A (mm)")
    ax[0][0].set_ylabel("thermal growth (um)")
    legends(*ax[0])
    return fig


@styled
def error_budget(t: ThermalRecord, limit_um: float | None = None) -> Figure:
    """Stacked bars per hour, schedule beside constant: elastic, thermal and the loop's share at the worst position."""
    fig, ax = page_figure(2.7)
    a = ax[0][0]
    width = 0.38
    semi = t.feedback is Feedback.SEMI_CLOSED
    for j, name in enumerate(("schedule", "constant")):
        case = t.case(name)
        budget, growth = case.budget_um[case.hourly], case.growth_um[case.hourly]
        worst = np.argmax(budget, axis=1)
        rows = np.arange(worst.size)
        elastic = case.elastic_um[worst]
        thermal = np.abs(growth[rows, worst]) if semi else np.zeros(rows.size)
        x = rows + (j - 0.5) * width
        alpha = 1.0 if name == "schedule" else 0.55
        a.bar(x, elastic, width, color="#1b9e77", alpha=alpha, label="deflection under the cut" if j == 0 else None)
        a.bar(x, thermal, width, bottom=elastic, color="#d95f02", alpha=alpha,
              label="thermal growth" if j == 0 else None)
        a.bar(x, np.full(rows.size, case.tracking_um), width, bottom=elastic + thermal, color="#7570b3", alpha=alpha,
              label="the force loop's share" if j == 0 else None)
        a.annotate(fmt(float(budget[-1, worst[-1]])), (x[-1], float(budget[-1, worst[-1]])), ha="center",
                   va="bottom", fontsize=7)
    if limit_um is not None:
        a.axhline(limit_um, color=COLOURS["limit"], ls="--", lw=0.8, label="limit")
    hours = t.schedule.times_h[t.schedule.hourly]
    a.set_xticks(np.arange(hours.size), [_when(h) for h in hours])
    a.set_ylabel("positioning error (um)")
    a.set_xlabel("end of hour (left bar: schedule, right: best constant preload)")
    legends(a)
    return fig
