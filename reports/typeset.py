"""Typesetting the report with Typst (the ``typst`` package from PyPI: the compiler and its fonts).

:data:`TEMPLATE` is the shipped template, ``report.typ``; it reads ``report.json`` and the
figures from its own folder (a sweep's report has its own, ``sweep.typ``). :func:`compile_pdf`
compiles a template in a folder with only the fonts Typst ships (Libertinus Serif, New Computer Modern, DejaVu Sans
Mono), so the PDF is the same on every machine.
"""

from __future__ import annotations

import datetime as _dt
from importlib import resources
from pathlib import Path

from piezopreload.core.errors import PiezopreloadError

__all__ = ["TEMPLATE", "ReportError", "template_text", "compile_pdf"]

TEMPLATE = "report.typ"


class ReportError(PiezopreloadError, RuntimeError):
    """Typst could not compile the report; the message carries its diagnostics."""


def template_text(name: str = TEMPLATE) -> str:
    """A shipped template's text: the study report's (``report.typ``), or another by its file name (``sweep.typ``)."""
    return (resources.files("piezopreload.reports") / name).read_text(encoding="utf-8")


def compile_pdf(main: str | Path, *, date: _dt.datetime | None = None) -> bytes:
    """Compile the Typst file ``main`` (its folder is the root files may be read from) to PDF bytes."""
    import typst

    main = Path(main)
    try:
        return typst.compile(str(main), root=str(main.parent), ignore_system_fonts=True, format="pdf",
                             timestamp=None if date is None else int(date.timestamp()))
    except typst.TypstError as exc:
        raise ReportError(f"{main}: Typst could not compile the report: {exc}") from None
