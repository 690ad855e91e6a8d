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

from piezopreload.reports.figures import COLOURS, STYLE, legends

__all__ = ["sweep_plot", "numeric", "LABELS", "label", "MIN_SPAN"]

_WIDTH = 6.3  # inches: the study report's text width
#: the sweep's columns as a reader names them, with their units (the table's headers and the figures' axes)
LABELS = {
    "design_stiffness_N_per_um": "design's least rigidity (N/um)", "Kc_V_per_N": "Kc (V/N)", "Ti_s": "Ti (s)",
    "Td_s": "Td (s)", "Tf_s": "Tf (s)", "b": "setpoint weight b", "ms": "max. sensitivity Ms",
    "gain_set_status": "gain set", "validation_plants": "Monte Carlo plants", "validation_failures": "plants failed",
    "worst_settling_s": "worst settling (s)", "worst_overshoot_N": "worst overshoot (N)",
    "worst_tracking_rms_N": "worst tracking RMS (N)", "worst_peak_voltage_V": "worst peak command (V)",
    "tuned_settling_s": "nominal settling (s)", "tracking_rms_N": "tracking RMS (N)",
    "tracking_rms_pct_of_range": "tracking (% of range)",
    "tracking_rms_pct_of_range_before_learning": "tracking before learning (% of range)",
    "tracking_max_N": "largest tracking error (N)", "rigidity_min_cutting_N_per_um": "least rigidity (N/um)",
    "rigidity_required_at_min_N_per_um": "required there (N/um)",
    "rigidity_ratio_min": "least rigidity / requirement", "deflection_max_um": "largest deflection (um)",
    "friction_energy_per_cycle": "friction energy per cycle", "friction_saving_pct": "friction saved (%)",
    "constant_friction_energy_per_cycle": "best constant preload's friction energy", "rig_status": "rig run",
    "rig_tracking_rms_N": "rig tracking RMS (N)", "requirements_met": "requirements met",
}
#: a panel's axis spans at least this fraction of its values' size: a variation below it (below the 3 significant
#: digits the table prints) is drawn flat, not stretched over the whole axis
MIN_SPAN = 0.02


def label(column: str, rows: Sequence[dict[str, Any]] = ()) -> str:
    """A column's name as a reader reads it, with its unit (the friction energy's from the rows, J or N m s)."""
    name = LABELS.get(column, column)
    if column.endswith("friction_energy_per_cycle"):
        units = {r.get("energy_units") for r in rows if r.get("energy_units")}
        name += f" ({units.pop()})" if len(units) == 1 else ""
    return name


def _span(ax: Any, values: Sequence[float]) -> None:
    """At least :data:`MIN_SPAN` of the values' size on the axis, about their middle."""
    lo, hi = min(values), max(values)
    need = MIN_SPAN * max(abs(lo), abs(hi))
    if need > 0 and hi - lo < need:
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - need, mid + need)


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
        marked = []
        for ax, y in zip(axes, ys):
            for name, members in groups.items():
                pts = sorted((where[r[x]], float(r[y])) for r in members if numeric(r.get(y)))
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3.5, label=name or None)
            failed = [(where[r[x]], float(r[y])) for r in rows if r.get("status") == "failed" and numeric(r.get(y))]
            if failed:
                ax.plot([p[0] for p in failed], [p[1] for p in failed], "x", color=COLOURS["limit"], ms=7, mew=1.5,
                        label="failed point")
            ax.set_ylabel(label(y, rows))
            ax.yaxis.get_major_formatter().set_useOffset(False)  # the values themselves, not an offset from them
            _span(ax, [float(r[y]) for r in rows if numeric(r.get(y))])
            if ax.get_legend_handles_labels()[0] and (len(groups) > 1 or failed):
                marked.append(ax)
        axes[-1].set_xlabel(x)
        if labels is not None:
            axes[-1].set_xticks(range(len(labels)), [str(v) for v in labels])
        if title:
            axes[0].set_title(title)
        legends(*marked)
    return fig
