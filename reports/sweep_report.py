"""A sweep's report: its table, its figures and the PDF from its record, nothing recomputed.

:func:`render_sweep_report` reads a sweep's record (:class:`~piezopreload.artifacts.sweep.SweepRecord`,
each point's headline figures), draws the figures against the first swept key
(:func:`~piezopreload.reports.sweep_figures.sweep_plot`; a figure no point has numbers for is left
out, with the reason), writes ``report/report.json`` (every number the report shows, formatted)
and ``report/report.typ`` (the shipped ``sweep.typ``, or an edited one) and typesets
``report.pdf`` with Typst, as the study report does.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypedDict

from piezopreload.artifacts.sweep import SweepPoint, SweepRecord
from piezopreload.core.artifacts import (
    SWEEP_REPORT,
    atomic_write_bytes,
    atomic_write_text,
    package_version,
    write_artifact,
)
from piezopreload.core.errors import InputError
from piezopreload.core.parallel import Pool
from piezopreload.reports import figures as F
from piezopreload.reports.document import fmt
from piezopreload.reports.sweep_figures import label, numeric, sweep_plot
from piezopreload.reports.typeset import ReportError, compile_pdf, template_text

__all__ = ["render_sweep_report", "SWEEP_TEMPLATE", "SWEEP_FIGURES", "TABLE_COLUMNS"]

SWEEP_TEMPLATE = "sweep.typ"
#: the figures, in the template's order: name, the columns drawn (one panel each), what they show,
#: the stage writing them
SWEEP_FIGURES: tuple[tuple[str, tuple[str, ...], str, str], ...] = (
    ("gains", ("Kc_V_per_N", "Ti_s", "Td_s"), "The tuned PID gains", "tune"),
    ("validation", ("worst_settling_s", "worst_overshoot_N", "worst_tracking_rms_N"),
     "The validation's worst cases over its Monte Carlo plants (settling time, overshoot, tracking RMS after the "
     "changes)", "validate"),
    ("system", ("tracking_rms_pct_of_range", "rigidity_min_cutting_N_per_um", "deflection_max_um"),
     "The designed system along its schedule: tracking RMS in % of the schedule's range, the least rigidity and the "
     "largest deflection while cutting", "system"),
    ("friction", ("friction_energy_per_cycle", "friction_saving_pct"),
     "Friction energy per machining cycle at the achieved preload, and the saving against the best constant preload",
     "system"),
)
#: the table's columns after the point, its values and its status: column and significant digits (the header is the
#: column's label, :data:`~piezopreload.reports.sweep_figures.LABELS`, as on the figures' axes)
TABLE_COLUMNS: tuple[tuple[str, int], ...] = (
    ("Kc_V_per_N", 4), ("Ti_s", 3), ("Td_s", 3), ("gain_set_status", 0), ("worst_settling_s", 3),
    ("worst_overshoot_N", 3), ("tuned_settling_s", 3), ("tracking_rms_pct_of_range", 3),
    ("rigidity_min_cutting_N_per_um", 3), ("deflection_max_um", 3), ("friction_saving_pct", 3),
    ("requirements_met", 0),
)
#: where a long name may break in a table's header: after each dot and underscore (a zero-width space: a swept key
#: such as schedule.stiffness_min_N_per_um is one word to the typesetter, wider than its column)
_BREAK = str.maketrans({".": ".\u200b", "_": "_\u200b"})
#: the figures the summary gives the range of: column, words, unit
_RANGES = (("worst_settling_s", "the worst settling time", "s"), ("worst_overshoot_N", "the worst overshoot", "N"),
           ("tracking_rms_pct_of_range", "the schedule's tracking RMS", "% of its range"),
           ("rigidity_min_cutting_N_per_um", "the least rigidity while cutting", "N/um"),
           ("friction_saving_pct", "the friction energy saved", "%"))


def _label(point: SweepPoint | dict[str, Any], keys: tuple[str, ...]) -> str:
    values = point.values if isinstance(point, SweepPoint) else {k: point[k] for k in keys}
    return ", ".join(f"{k} = {v}" for k, v in values.items())


def _cell(value: Any, digits: int) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    return fmt(float(value), digits) if numeric(value) else str(value)


def _summary(record: SweepRecord) -> list[str]:
    """The sweep in sentences: its points' outcome, the validation's verdicts, each headline
    figure's range, requirements."""
    rows, keys = record.rows(), record.keys
    failed = [p for p in record.points if p.status == "failed"]
    lines = [f"{len(rows)} points of the study {record.study_name} ({record.mode} over "
             + "; ".join(f"{a.key} = {', '.join(str(v) for v in a.values)}" for a in record.axes) + "): "
             + f"{len(rows) - len(failed)} ran to the end"
             + (f", {len(failed)} failed (listed below)." if failed else ".")]
    judged = [r for r in rows if r["gain_set_status"] is not None]
    if judged:
        passed = [r for r in judged if r["gain_set_status"] == "validated"]
        lines.append(f"The tuned gains passed the validation at {len(passed)} of {len(judged)} points that reached it"
                     + ("." if len(passed) == len(judged) else "; they failed it at "
                        + "; ".join(_label(r, keys) for r in judged if r["gain_set_status"] != "validated") + "."))
    for column, words, unit in _RANGES:
        have = [r for r in rows if numeric(r[column])]
        if len(have) >= 2:
            lo, hi = min(have, key=lambda r: r[column]), max(have, key=lambda r: r[column])
            if fmt(lo[column]) == fmt(hi[column]):  # one value to the digits shown: no range to speak of
                lines.append(f"At every point, {words} is {fmt(lo[column])} {unit}.")
                continue
            lines.append(f"Over the points, {words} runs from {fmt(lo[column])} {unit} ({_label(lo, keys)}) to "
                         f"{fmt(hi[column])} {unit} ({_label(hi, keys)}).")
    stated = [r for r in rows if r["requirements_met"] is not None]
    if stated:
        missed = [r for r in stated if not r["requirements_met"]]
        lines.append(f"The study's requirements are met at {len(stated) - len(missed)} of {len(stated)} points"
                     + ("." if not missed else "; missed at " + "; ".join(
                         _label(r, keys) + (" (" + ", ".join(m["name"] for m in r["requirements_missed"]) + ")"
                                            if r["requirements_missed"] else "") for r in missed) + "."))
    return lines


class SweepTable(TypedDict):
    """The report's table of the points, as its template reads it: the header's cells and each row's."""

    header: list[str]
    rows: list[list[str]]


def _table(record: SweepRecord) -> SweepTable:
    rows = record.rows()
    columns = [c for c in TABLE_COLUMNS if any(r[c[0]] is not None for r in rows)]
    header = ["point", *(k.translate(_BREAK) for k in record.keys), "status", *(label(c[0], rows) for c in columns)]
    body = [[f"p{r['point']:03d}", *(str(r[k]) for k in record.keys), r["status"],
             *(_cell(r[c[0]], c[1]) for c in columns)] for r in rows]
    return SweepTable(header=header, rows=body)


def _omitted_reason(record: SweepRecord, stage: str) -> str:
    done = sum(p.status == "done" for p in record.points)
    if done:
        return (f"no point has these figures: {done} of {len(record.points)} points ran to the end and none wrote them "
                f"(the {stage} stage does not apply to the study)")
    return f"no point has these figures: none reached the {stage} stage"


def _figures(record: SweepRecord, figdir: Path, bar: Callable[[int, int], None] | None, pool: Pool | None) -> tuple[
        dict[str, dict[str, str]], list[dict[str, str]], dict[str, Path]]:
    rows, keys = record.rows(), record.keys
    x, by = keys[0], (list(keys[1:]) if record.mode == "grid" else [])
    shown, omitted, written, pending = {}, [], {}, []
    for name, columns, what, stage in SWEEP_FIGURES:
        have = [c for c in columns if any(numeric(r[c]) for r in rows)]
        if not have:
            omitted.append({"figure": name, "what": what, "reason": _omitted_reason(record, stage)})
            continue
        path = written[f"figure-{name}"] = figdir / f"{name}.pdf"
        pending.append((sweep_plot(rows, x, have, by), path))
        lines = f", one line per {', '.join(by)}" if by else ""
        failed = any(r["status"] == "failed" and any(numeric(r[c]) for c in have) for r in rows)
        shown[name] = {"file": f"figures/{name}.pdf",
                       "caption": f"{what}, against {x}{lines}"
                       + ("; red crosses: points that failed" if failed else "")
                                  + "."}
    F.save_all(pending, pool=pool, bar=bar)
    return shown, omitted, written


def render_sweep_report(out: Path, record: SweepRecord, *, say: Callable[[str], None],
                        bar: Callable[[int, int], None] | None = None, template: str | None = None,
                        now: _dt.datetime | None = None, pool: Pool | None = None) -> dict[str, Path]:
    """The figures, ``report/report.json``, ``report/report.typ`` and ``report.pdf`` of the sweep in ``out``.

    ``template``: a Typst template's text (default: the shipped ``sweep.typ``); ``say`` gets messages; ``pool``:
    the worker processes that draw the figures (default: drawn here, one after another).
    Returns what it wrote: ``report``, ``report_json``, ``template`` and ``figure-NAME``.
    """
    out = Path(out)
    folder = out / "report"
    now = now or _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    shown, omitted, written = _figures(record, folder / "figures", bar, pool)
    version = package_version()
    data = {
        "title": f"Sweep of the study {record.study_name}",
        "study": {"name": record.study_name, "path": record.study_path, "sha256": record.study_sha256},
        "summary": _summary(record),
        "table": _table(record),
        "errors": [f"p{p.index:03d} ({_label(p, record.keys)}): {p.error}" for p in record.points if p.error],
        "figures": shown, "omitted": omitted,
        "provenance": {"package_version": version, "date": now.strftime("%Y-%m-%d"), "rows": [
            ["package", f"piezopreload {version}"], ["study file", record.study_path],
            ["study SHA-256", record.study_sha256], ["sweep started (UTC)", record.started_utc],
            ["report date (UTC)", now.strftime("%Y-%m-%d %H:%M:%S")],
            ["points' folders",
             f"{record.points[0].folder} to {record.points[-1].folder}" if record.points else "none"],
            ["rows", "sweep.csv, sweep.json"]]},
    }
    write_artifact(folder / "report.json", SWEEP_REPORT, data)
    atomic_write_text(folder / "report.typ", template if template is not None else template_text(SWEEP_TEMPLATE))
    try:
        pdf = compile_pdf(folder / "report.typ", date=now)
    except ReportError as exc:
        raise InputError(str(exc)) from None
    atomic_write_bytes(out / "report.pdf", pdf)
    say(f"wrote {out / 'report.pdf'} ({len(pdf) / 1024:.0f} kB, {len(shown)} figures)")
    return {**written, "report": out / "report.pdf", "report_json": folder / "report.json",
            "template": folder / "report.typ"}
