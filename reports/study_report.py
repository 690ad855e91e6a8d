"""A study's report: figures and the PDF from its artifacts, nothing recomputed.

:func:`render_report` reads what a study's stages wrote (named by the stage records of its
``pipeline.json``, through :class:`~piezopreload.reports.inputs.Artifacts`), builds the report for
that study (:mod:`piezopreload.reports.summary`, :mod:`piezopreload.reports.sections`), draws the
figures, writes ``report/report.json`` (every word and number the report shows) and
``report/report.typ`` (the shipped template, or an edited one), and typesets ``report.pdf`` with
Typst. What it needs of the study itself is :class:`~piezopreload.reports.inputs.ReportStudy`.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezopreload.artifacts.manifest import StudyRunManifest
from piezopreload.artifacts.summaries import ReportSummary
from piezopreload.core.artifacts import REPORT, atomic_write_bytes, atomic_write_text, package_version, write_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.parallel import Pool
from piezopreload.core.progress import Bar
from piezopreload.reports.document import Report
from piezopreload.reports.inputs import Artifacts, Published, ReportStudy
from piezopreload.reports.typeset import ReportError, compile_pdf, template_text

if TYPE_CHECKING:  # the figures and their sections load matplotlib: when a report is built, not on import
    from piezopreload.reports import sections as S

__all__ = ["ReportStudy", "Published", "render_report", "STAGES_READ"]

#: the stages whose artifacts the report reads, in the order the study runs them
STAGES_READ = ("design", "plant", "identify", "tune", "validate", "compare", "learn", "system", "export", "rig")


def _parts(study: ReportStudy, a: Artifacts) -> list[S.Part]:
    """The sections that apply to the study, in the order its reader asks for them."""
    from piezopreload.reports import sections as S
    from piezopreload.reports.sensitivity import sensitivity_section
    from piezopreload.reports.thermal import thermal_section

    parts = [S.study_section(study, a, STAGES_READ)]
    requirements = S.requirements_section(a)
    if requirements is not None:
        parts.append(requirements)
    if a.system is not None and a.design is not None:
        parts.append(S.system_section(a.system, a.design, a.learning))
        if a.system.thermal is not None:
            parts.append(thermal_section(a.system.thermal, [r for r in a.system.requirements if r.source.startswith(
                "[thermal]")]))
        if a.system.sensitivity is not None and a.system.sensitivity.rows:
            parts.append(sensitivity_section(a.system.sensitivity))
    if a.learning is not None:
        parts.append(S.learning_section(a.learning))
    parts += [S.controller_section(study, a), S.responses_section(study, a), S.feedforward_section(study, a)]
    if a.design is not None:
        parts.append(S.design_section(study, a.design, a.system is not None))
    parts.append(S.rig_section(study, a))
    return parts


def build_report(study: ReportStudy, a: Artifacts, now: _dt.datetime) -> tuple[Report, list[tuple[str, Any, str]]]:
    """The report for ``study`` from its artifacts, and the figures it names ``(name, figure, caption)``."""
    from piezopreload.reports import sections as S
    from piezopreload.reports.summary import design_lead, summary, verdicts

    version, date = package_version(), now.strftime("%Y-%m-%d %H:%M:%S")
    parts = _parts(study, a)
    appendix = S.provenance_section(study, a, STAGES_READ, version, date)
    figures = [f for p in parts for f in p.figures]
    report = Report(
        title=study.title or f"Study {study.name}",
        subtitle=f"Study {study.name} · {now.strftime('%Y-%m-%d')} · piezopreload {version}",
        lead=design_lead(study, a), verdicts=verdicts(a), summary=summary(study, a),
        sections=tuple(p.section for p in parts),
        appendix=(appendix.section,),
        figures={name: {"file": f"figures/{name}.pdf", "caption": caption} for name, _, caption in figures},
        meta={"study_name": study.name, "package_version": version,
              "inputs": {"gain_set_sha256": a.gain_set.content_sha256, "study_sha256": study.sha256}})
    return report, figures


def render_report(out: Path, manifest: StudyRunManifest, study: ReportStudy, *,
                  say: Callable[[str], None], bar: Bar,
                  template: str | None = None, pool: Pool | None = None) -> tuple[dict[str, Path], ReportSummary]:
    """Figures, ``report/report.json``, ``report/report.typ`` and ``report.pdf`` in ``out``.

    Parameters
    ----------
    out : Path
        The study's output folder.
    manifest : StudyRunManifest
        The stages' records (what they wrote, or why they did not run).
    study : ReportStudy
        What the report prints of the study itself.
    say : callable
        Given each message.
    bar : callable
        Given ``(done, total)`` as the figures are drawn.
    template : str, optional
        A Typst template's text (default: the shipped one).
    pool : Pool, optional
        The run's worker processes, which draw the figures (default: drawn here, one after another).

    Returns
    -------
    (dict of str to Path, ReportSummary)
        The files written, by label, and what the report stage records: the figures, the PDF's size, the sections.
    """
    from piezopreload.reports import figures as F

    folder = out / "report"
    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    report, figures = build_report(study, Artifacts(out, manifest), now)
    written: dict[str, Path] = {f"figure-{name}": folder / "figures" / f"{name}.pdf" for name, _, _ in figures}
    F.save_all([(fig, written[f"figure-{name}"]) for name, fig, _ in figures], pool=pool, bar=bar)
    write_artifact(folder / "report.json", REPORT, report.to_dict())
    atomic_write_text(folder / "report.typ", template if template is not None else template_text())
    try:
        pdf = compile_pdf(folder / "report.typ", date=now)
    except ReportError as exc:
        raise InputError(str(exc)) from None
    atomic_write_bytes(out / "report.pdf", pdf)
    written.update({"report": out / "report.pdf", "report_json": folder / "report.json",
                    "template": folder / "report.typ"})
    say(f"wrote {out / 'report.pdf'} ({len(pdf) / 1024:.0f} kB, {len(figures)} figures)")
    return written, ReportSummary(tuple(name for name, _, _ in figures), len(pdf),
                                  tuple(s.title for s in report.sections))


