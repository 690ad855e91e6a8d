"""A reader's check of a figure, on its pixels: no legend lies over the data or over a tick label.

Independent of how the report places its legends (reports/figures.py's ``legends``, on the artists' geometry): the
figure is drawn with its legends hidden, and the pixels each legend would cover are read. A data line, a marker, a
bar, a limit line or a tick label leaves ink there; the grid (light grey) and white do not.
"""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from piezopreload.reports.figures import STYLE

#: a pixel darker than this in any channel is ink (the grid, drawn at alpha 0.3 over white, is about 0.9)
INK = 0.8


def legends_over_ink(fig: Figure) -> list[str]:
    """Each legend of ``fig`` that covers ink (data, limits, tick labels) when drawn, as ``"axes title: N pixels"``."""
    import matplotlib as mpl

    with mpl.rc_context(STYLE):
        canvas = FigureCanvasAgg(fig)
        placed = [(ax, ax.get_legend()) for ax in fig.axes if ax.get_legend() is not None]
        canvas.draw()
        boxes = [(ax, legend.get_window_extent(canvas.get_renderer())) for ax, legend in placed]
        engine = fig.get_layout_engine()
        fig.set_layout_engine("none")  # the layout as drawn: a hidden legend must not move the axes
        for _, legend in placed:
            legend.set_visible(False)
        canvas.draw()
        image = np.asarray(canvas.buffer_rgba(), float)[..., :3] / 255.0
        for _, legend in placed:
            legend.set_visible(True)
        fig.set_layout_engine(engine)
    height = image.shape[0]
    found = []
    for ax, box in boxes:
        x0, x1 = int(np.floor(box.x0)), int(np.ceil(box.x1))
        y0, y1 = height - int(np.ceil(box.y1)), height - int(np.floor(box.y0))  # the image's rows run downwards
        patch = image[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)]
        ink = int(np.sum(np.min(patch, axis=-1) < INK)) if patch.size else 0
        if ink:
            found.append(f"{ax.get_title() or ax.get_ylabel()!r}: {ink} pixels of ink under its legend")
    return found


def report_figures(out) -> list[tuple[str, Figure]]:
    """The figures the report of the study run in ``out`` draws, built from its artifacts as the report stage does."""
    import datetime as dt

    from piezopreload.artifacts.manifest import StudyRunManifest
    from piezopreload.reports.inputs import Artifacts, ReportStudy
    from piezopreload.reports.study_report import build_report

    manifest = StudyRunManifest.load(out)
    ref = manifest.study
    study = ReportStudy(ref.name, "", ref.path, ref.sha256, ref.path)
    _, figures = build_report(study, Artifacts(out, manifest), dt.datetime.now(dt.UTC))
    return [(name, fig) for name, fig, _ in figures]
