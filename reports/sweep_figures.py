"""A sweep's figures: headline figures against a swept key, one line per value of the other keys.

:func:`sweep_plot` draws rows (one dict per point, as
:meth:`piezopreload.artifacts.sweep.SweepRecord.rows` gives them) without pyplot, in the study
report's style (:data:`piezopreload.reports.figures.STYLE`). A key whose values are not all
numbers is drawn on evenly spaced positions labelled with its values. A point with no value of a
column is left out of that panel; a failed point that has one is marked with a red cross.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import matplotlib as mpl
from matplotlib.figure import Figure

from piezopreload.reports.figures import COLOURS, STYLE

__all__ = ["sweep_plot", "numeric"]

_WIDTH = 6.3  # inches: the study report's text width


def numeric(value: Any) -> bool:
    """Whether a cell is a number to plot (booleans are not)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _positions(rows: Sequence[dict[str, Any]], x: str) -> tuple[dict[Any, float], list[Any] | None]:
    """Each x value's position, and the tick labels where the values are not all numbers (else None)."""
    values = list(dict.fromkeys(row[x] for row in rows))
    if all(numeric(v) for v in values):
        return {v: float(v) for v in values}, None
    return {v: float(i) for i, v in enumerate(values)}, values


def _groups(rows: Sequence[dict[str, Any]], by: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(", ".join(f"{k}={row[k]}" for k in by), []).append(row)
    return groups


def sweep_plot(rows: Sequence[dict[str, Any]], x: str, ys: Sequence[str], by: Sequence[str] = (), *,
               title: str | None = None) -> Figure:
    """One panel per column of ``ys`` against ``x``, one line per combination of ``by``'s values.

    Raises :class:`ValueError` naming a column of ``ys`` that has no number at any point.
    """
    empty = [y for y in ys if not any(numeric(row.get(y)) for row in rows)]
    if empty:
        raise ValueError(f"the column '{empty[0]}' has no number at any point of the sweep")
    where, labels = _positions(rows, x)
    groups = _groups(rows, by)
    with mpl.rc_context(STYLE):
        fig = Figure(figsize=(_WIDTH, 0.9 + 1.35 * len(ys)), layout="constrained")
        axes = fig.subplots(len(ys), 1, squeeze=False, sharex=True)[:, 0]
        for ax, y in zip(axes, ys):
            for name, members in groups.items():
                pts = sorted((where[r[x]], float(r[y])) for r in members if numeric(r.get(y)))
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3.5, label=name or None)
            failed = [(where[r[x]], float(r[y])) for r in rows if r.get("status") == "failed" and numeric(r.get(y))]
            if failed:
                ax.plot([p[0] for p in failed], [p[1] for p in failed], "x", color=COLOURS["limit"], ms=7, mew=1.5,
                        label="failed point")
            ax.set_ylabel(y)
            if ax.get_legend_handles_labels()[0] and (len(groups) > 1 or failed):
                ax.legend(loc="best")
        axes[-1].set_xlabel(x)
        if labels is not None:
            axes[-1].set_xticks(range(len(labels)), [str(v) for v in labels])
        if title:
            axes[0].set_title(title)
    return fig
