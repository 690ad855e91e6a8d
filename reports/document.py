"""The report as data: a summary, sections of paragraphs, tables and figures, and what was left out and why.

The builders of :mod:`piezopreload.reports.sections` make these from the study's artifacts;
:meth:`Report.to_dict` is ``report.json``, which the Typst template lays out without a word of
its own, so every sentence, caption and label comes from the study that ran. A number is
formatted by :func:`fmt`, which refuses a missing value: a figure that does not apply is left
out with its reason (:class:`Section.omitted`), never printed as a dash.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from piezopreload.core.quantities import number, quantity

__all__ = ["fmt", "q", "ratio", "pct", "ReportTable", "Section", "Report"]


def fmt(x: float, digits: int = 3, unit: str = "") -> str:
    """A number as the report prints it: the one rule of :func:`piezopreload.core.quantities.number` (``digits``
    significant digits, never finer than ``unit``'s resolution, whole numbers kept whole with thousands separated:
    13,236 and 1,697 rather than 1.32e+04 and 1697.3), which the console and the messages use too."""
    if x is None:  # a report never shows a dash for a missing number: the caller leaves it out with a reason
        raise ValueError("fmt: a missing number cannot be printed; leave the figure out and say why")
    return number(x, unit, digits)


def q(x: float, unit: str, digits: int = 3) -> str:
    """A quantity with its unit, by the same rule (``0.4 N``, ``1,126 N/um``, ``0.322 s``)."""
    return quantity(x, unit, digits)


def ratio(x: float) -> str:
    """A ratio against a requirement: three significant digits, or three decimals near 1 so that a ratio just
    over it does not print as 1.

    >>> ratio(1.0036), ratio(1.408), ratio(0.97)
    ('1.004', '1.41', '0.970')
    """
    return f"{float(x):.3f}" if abs(float(x) - 1.0) < 0.1 else fmt(x)


def pct(fraction: float, digits: int = 2) -> str:
    """A fraction as a percentage (0.724 -> ``72 %``, 0.0115 -> ``1.2 %``)."""
    return f"{fmt(100.0 * fraction, digits, '%')} %"


@dataclass(frozen=True)
class ReportTable:
    """A table: a header of strings, rows of strings, a caption and the columns' alignment (``l``, ``r``, ``c``)."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str
    align: str = ""
    small: bool = False

    def __post_init__(self) -> None:
        bad = [i for i, r in enumerate(self.rows) if len(r) != len(self.header)]
        if bad:
            raise ValueError(f"Table '{self.caption[:40]}': row {bad[0]} has {len(self.rows[bad[0]])} cells, "
                             f"the header {len(self.header)}")

    def to_dict(self) -> dict[str, Any]:
        align = self.align or "l" + "r" * (len(self.header) - 1)
        return {"header": list(self.header), "rows": [list(r) for r in self.rows], "caption": self.caption,
                "align": list(align), "small": self.small}


@dataclass(frozen=True)
class Section:
    """One section: its title, paragraphs, tables and figures (by name), subsections, and what it leaves out and why."""

    title: str
    paragraphs: tuple[str, ...] = ()
    tables: tuple[ReportTable, ...] = ()
    figures: tuple[str, ...] = ()
    omitted: tuple[str, ...] = ()
    subsections: tuple[Section, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"title": self.title, "paragraphs": list(self.paragraphs), "tables": [t.to_dict() for t in self.tables],
                "figures": list(self.figures), "omitted": list(self.omitted),
                "subsections": [s.to_dict() for s in self.subsections]}


@dataclass(frozen=True)
class Report:
    """The whole report: title, the study's line, the verdicts, the summary, the sections, the appendix; ``lead``,
    the design and what limits it, opens the first page where the study designs its screw."""

    title: str
    subtitle: str
    verdicts: tuple[str, ...]
    summary: tuple[str, ...]
    sections: tuple[Section, ...]
    appendix: tuple[Section, ...]
    figures: dict[str, dict[str, str]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    lead: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"title": self.title, "subtitle": self.subtitle, "lead": list(self.lead),
                "verdicts": list(self.verdicts),
                "summary": list(self.summary), "sections": [s.to_dict() for s in self.sections],
                "appendix": [s.to_dict() for s in self.appendix], "figures": self.figures, **self.meta}
