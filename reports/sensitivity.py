"""The report's account of the verdicts under the modelling assumptions: the section and its tornado figure.

From the system artifact's sensitivity study (:class:`~piezopreload.artifacts.sensitivity.SensitivityRecord`):
which verdicts hold over every assumption's range, which assumption flips which verdict and where, the ranges
and their sources, and per requirement the margin at each assumption's low and high end around the margin at the
study's values (a tornado, the assumption that swings the margin most on top, the zero line where a verdict
flips).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from piezopreload.artifacts.sensitivity import SensitivityRecord, SensitivityRow
from piezopreload.reports.document import ReportTable, Section, fmt
from piezopreload.reports.figures import COLOURS, legends, page_figure, styled
from piezopreload.reports.sections import Part

__all__ = ["sensitivity_section", "tornado", "range_text"]

_LOW, _HIGH = "#4575b4", "#fc8d59"


def range_text(r: SensitivityRow) -> str:
    """The row's range in words: ``2-5 K``, or a two-valued assumption's two names."""
    if r.labels:
        return f"{r.labels[0]} or {r.labels[1]}"
    return f"{fmt(r.low)}-{fmt(r.high)} {r.unit}".rstrip()


def _by_requirement(s: SensitivityRecord) -> dict[str, list[SensitivityRow]]:
    out: dict[str, list[SensitivityRow]] = {}
    for r in s.rows:
        out.setdefault(r.requirement, []).append(r)
    return out


@styled
def tornado(s: SensitivityRecord) -> Figure:
    """Per requirement, the margin (% of its limit) at each assumption's low and high end, drawn from the margin at
    the study's values; the assumptions sorted by the swing, the largest on top; the zero line, where the verdict
    flips."""
    groups = _by_requirement(s)
    heights = [len(rows) for rows in groups.values()]
    fig, ax = page_figure(0.7 + 0.28 * sum(heights) + 0.35 * len(groups), nrows=len(groups),
                      gridspec_kw={"height_ratios": [h + 1.2 for h in heights]})
    for j, (a, rows) in enumerate(zip(ax[:, 0], groups.values())):
        rows = sorted(rows, key=lambda r: r.swing_pct)
        y = np.arange(len(rows))
        nominal = rows[0].margin_pct_nominal
        for k, r in enumerate(rows):
            a.barh(k, r.margin_pct_low - nominal, left=nominal, height=0.6, color=_LOW,
                   label="at the low end" if k == 0 and j == 0 else None)
            a.barh(k, r.margin_pct_high - nominal, left=nominal, height=0.6, color=_HIGH,
                   label="at the high end" if k == 0 and j == 0 else None)
        a.axvline(0.0, color=COLOURS["limit"], lw=1.0, label="0: the verdict flips" if j == 0 else None)
        a.axvline(nominal, color="0.3", ls=":", lw=0.9, label="at the study's values" if j == 0 else None)
        a.set_yticks(y, [f"{r.assumption} ({range_text(r)})" for r in rows])
        a.set_title(rows[0].requirement_name)
        a.set_xlabel("margin (% of the limit)")
        a.set_ylim(-0.7, len(rows) - 0.3 + (0.9 if j == 0 else 0.0))
    legends(ax[0, 0])
    return fig


def _flip_words(rows: list[SensitivityRow]) -> str:
    return "; ".join(r.flip_sentence() for r in rows)


def sensitivity_section(s: SensitivityRecord) -> Part:
    """The section: how the assumptions were varied, which verdicts hold, which assumption flips which, the ranges
    and their sources, and the tornado."""
    groups = _by_requirement(s)
    n = len(s.assumptions)
    paragraphs = [
        f"Each requirement's verdict rests on modelling assumptions. The designed system as built (the design's "
        f"double nut, the last pass's schedule and the preload the force loop achieved along it) is judged again "
        f"with each of {n} assumptions at the low and at the high end of its stated range, one at a time, every "
        "other at the study's value; where a verdict differs between the ends, or beyond an end within the "
        "assumption's admissible domain, bisection finds the value at which it flips. A verdict is robust only "
        "where it is the same at both ends of every range.",
    ]
    def verdict(rows: list[SensitivityRow]) -> str:
        return "met" if rows[0].margin_pct_nominal >= 0 else "missed"

    robust = [rows for rows in groups.values() if all(r.holds for r in rows)]
    if robust:
        paragraphs.append("Robust over every range: " + "; ".join(
            f"{rows[0].requirement_name} ({verdict(rows)})" for rows in robust) + ".")
    for rows in groups.values():
        flips = [r for r in rows if not r.holds]
        if flips:
            paragraphs.append(f"Not robust: {rows[0].requirement_name} ({verdict(rows)} at the study's values, margin "
                              f"{rows[0].margin_pct_nominal:+.1f} %) flips with {_flip_words(flips)}.")
    if s.unmoved:
        enters = "its value or its limit" if len(s.unmoved) == 1 else "their values or their limits"
        paragraphs.append(f"No assumption of the study moves: {'; '.join(s.unmoved)} (none of these assumptions "
                          f"enters {enters}).")
    if s.not_judged:
        paragraphs.append("Not judged again under the assumptions: " + "; ".join(s.not_judged) + " (their verdicts "
                          "come from the Monte Carlo plants, which the study does not run again).")
    seen: dict[str, SensitivityRow] = {}
    for r in s.rows:
        seen.setdefault(r.key, r)
    table = ReportTable(("assumption", "study's value", "range", "why this range"),
                  tuple((r.assumption, r.value_text(r.nominal) if not r.labels else r.labels[int(r.nominal)],
                         range_text(r), r.source) for r in seen.values()),
                  "The assumptions the verdicts were judged under: the study's value, the range and its source.",
                  "llll")
    figures = (("sensitivity-tornado", tornado(s),
                "Each requirement's margin at each assumption's low (blue) and high (orange) end, from the margin at "
                "the study's values (dotted); the largest swing on top; red, zero: where the verdict flips."),)
    title = "The verdicts under the assumptions: " + ("robust" if s.verdict_robust else "not robust")
    return Part(Section(title, tuple(paragraphs), (table,), tuple(n for n, _, _ in figures)), figures)
