"""The study report's figures (matplotlib), from plain arrays.

Every function takes the numbers it plots (read from the study's artifacts by the caller) and
returns a :class:`matplotlib.figure.Figure` built without pyplot, so no global figure state is
touched and any backend works. One style (:data:`STYLE`) for all: vector output, units on
every axis, the same colour for the same controller in every figure.

A figure is laid out once, as its PDF is measured (points, text at its unhinted widths), when
:func:`legends` places its legends off the data; that layout is then its own, and :func:`save`
draws it once into the PDF, cropped on it.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import pickle
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import as_completed
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib as mpl
import numpy as np
from matplotlib.backend_bases import FigureCanvasBase
from matplotlib.backends.backend_pdf import PdfFile, RendererPdf
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from piezopreload.core.parallel import Pool
from piezopreload.core.progress import Bar
from piezopreload.core.quantities import quantity
from piezopreload.models.metrics import Signal

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

    from piezopreload.artifacts.design import DesignPoint, Front, PreloadCurve
    from piezopreload.artifacts.learning import PassRecord
    from piezopreload.artifacts.tuning import GainScheduleRecord
    from piezopreload.artifacts.validation import ValidationResult

__all__ = [
    "STYLE", "COLOURS", "legends", "page_figure", "styled", "save", "save_all", "hysteresis_loops", "inverse_model",
    "step_responses", "tracking",
    "stiffness_vs_preload", "pareto_fronts", "preload_schedule", "natural_frequency", "monte_carlo",
    "rig_run", "closed_loop",
]

STYLE: dict[RcKeyType, Any] = {
    "font.size": 8.5, "axes.titlesize": 9, "axes.labelsize": 8.5, "legend.fontsize": 7.5,
    "xtick.labelsize": 7.5, "ytick.labelsize": 7.5, "axes.grid": True, "grid.alpha": 0.3,
    "grid.linewidth": 0.5, "lines.linewidth": 1.1, "axes.spines.top": False, "axes.spines.right": False,
    "legend.frameon": False, "pdf.fonttype": 3, "savefig.bbox": "tight", "savefig.pad_inches": 0.03,
}
#: one colour per controller, the same in every figure
COLOURS = {"reference": "0.35", "study pid": "#d95f02", "study ff+pid": "#7570b3", "tuned pid": "#e7298a",
           "tuned ff+pid": "#1b9e77", "measured": "0.55", "model": "#1b9e77", "limit": "#b2182b"}
_WIDTH = 6.3  # inches: the text width of an A4 page with 2 cm margins


def page_figure(height: float, ncols: int = 1, nrows: int = 1, **kw: Any) -> tuple[Figure, Any]:
    """A page-wide figure and its axes, for a figure function under :func:`styled` (:data:`STYLE`).

    Parameters
    ----------
    height
        The figure's height (inches); its width is the page's.
    ncols, nrows
        The grid of axes.
    **kw
        Passed to :meth:`matplotlib.figure.Figure.subplots` (``sharex``, ``gridspec_kw``...).

    Returns
    -------
    tuple
        The figure and its axes, a 2-D array (``squeeze=False``).
    """
    fig = Figure(figsize=(_WIDTH, height), layout="constrained")
    return fig, fig.subplots(nrows, ncols, squeeze=False, **kw)


#: where a legend may sit inside its axes, in the order tried
_INSIDE = ("upper right", "upper left", "lower right", "lower left", "center right", "center left", "upper center",
           "lower center", "center")


#: the placement's margins, in points: how near a legend's box a line may pass and still be on it, and the pad of the
#: band raised above the data for a legend (2 and 12 pixels of the 100 dpi screen they were chosen on); the gap
#: between the axes' label and a legend below it (4 pt: a screen, which hints text at its pixels, draws the label a
#: pixel or two lower than the PDF's measure puts it)
_GRAZE_PT, _BAND_PAD_PT, _BELOW_PT = 1.44, 8.64, 4.0


def _display(ax: Any, points: float) -> float:
    """``points`` in the display units of the axes' figure (pixels at its dpi; points where it is measured as PDF)."""
    return points * ax.get_figure().dpi / 72.0


def _covers(box: Any, ax: Any) -> bool:
    """Whether the display box ``box`` covers any of the axes' data: a line's path or markers, a patch (bars,
    spans), a collection's points, a text drawn in the axes."""
    pad = _display(ax, _GRAZE_PT)  # a line grazing the box's edge is on it
    grown = box.expanded(1.0, 1.0).padded(pad)
    for line in ax.get_lines():
        if not line.get_visible():
            continue
        path = line.get_transform().transform_path(line.get_path()).cleaned(remove_nans=True)
        if line.get_linestyle() not in ("None", "", " ") and path.intersects_bbox(grown, filled=False):
            return True
        if line.get_marker() not in ("None", "", " ", None) and grown.count_contains(path.vertices) > 0:
            return True
    for patch in ax.patches:
        if patch.get_visible() and patch.get_transform().transform_path(patch.get_path()).intersects_bbox(grown):
            return True
    for coll in ax.collections:
        if coll.get_visible() and grown.count_contains(coll.get_offset_transform().transform(coll.get_offsets())):
            return True
    return any(text.get_visible() and text.get_text() and box.overlaps(text.get_window_extent()) for text in ax.texts)


def _clear_of_axes(box: Any, fig: Any, renderer: Any) -> bool:
    """Whether a legend outside its axes stays on the figure and off every axes, their tick labels, axis labels and
    titles (the data is inside the axes)."""
    if not fig.bbox.contains(box.x0, box.y0) or not fig.bbox.contains(box.x1, box.y1):
        return False
    return not any(box.overlaps(ax.get_tightbbox(renderer, bbox_extra_artists=[])) for ax in fig.axes)


def _fits(ax: Any, renderer: Any) -> bool:
    """Whether the axes' legend is off the data: inside the axes covering none of it, or outside every axes."""
    legend = ax.get_legend()
    if legend is None:
        return False
    frame, box = ax.get_window_extent(renderer), legend.get_window_extent(renderer)
    if frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1):
        return not _covers(box, ax)
    return not box.overlaps(frame) and _clear_of_axes(box, ax.get_figure(), renderer)


def _headroom(ax: Any, renderer: Any) -> tuple[float, float]:
    """Raise the axes' top so that a band above the data holds the legend (its height and a pad), in the axes'
    scale (linear or log); returns the limits before."""
    before = ax.get_ylim()
    box, frame = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    share = min((box.height + _display(ax, _BAND_PAD_PT)) / frame.height, 0.6)
    scale = ax.yaxis.get_transform()  # the data's scale: linear, or log
    lo, hi = np.ravel(scale.transform(np.array(before, float)))
    top = lo + (hi - lo) / (1.0 - share)
    ax.set_ylim(top=float(np.ravel(scale.inverted().transform(np.array([top])))[0]))
    return before


def _outside(ax: Any, renderer: Any, kw: dict[str, Any]) -> None:
    """At the axes' right, or below their axis label, whichever is clear of every axes (below where neither is)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kw)
    if _fits(ax, renderer):
        return
    frame, tight = ax.get_window_extent(renderer), ax.get_tightbbox(renderer, bbox_extra_artists=[])
    below = (frame.y0 - tight.y0 + _display(ax, _BELOW_PT)) / frame.height
    entries = len(ax.get_legend_handles_labels()[0])
    for ncols in (entries, 2, 1):  # one row where the figure is wide enough
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -below), borderaxespad=0.0, ncols=ncols, **kw)
        box = ax.get_legend().get_window_extent(renderer)
        if ax.get_figure().bbox.x0 <= box.x0 and box.x1 <= ax.get_figure().bbox.x1:
            return


def _place(ax: Any, renderer: Any, kw: dict[str, Any]) -> bool:
    """The axes' legend at the first free place; whether the figure's layout may have moved (the legend outside the
    axes, or their top raised: a tick label that changes width moves the axes). A legend inside its axes does not
    move them: the layout reads the axes' extent, which holds it."""
    legend = ax.legend(loc=_INSIDE[0], **kw)  # made once, then moved from place to place
    for loc in _INSIDE:
        legend.set_loc(loc)
        if _fits(ax, renderer):
            return False
    before = _headroom(ax, renderer)  # no free place: a band above the data, the legend in it
    for loc in ("upper right", "upper left", "upper center"):
        legend.set_loc(loc)
        if _fits(ax, renderer):
            return True
    ax.set_ylim(before)  # the band did not free a place (lines across the whole height): outside
    _outside(ax, renderer, kw)
    return True


class _PdfMeasure(FigureCanvasBase):
    """A canvas whose renderer measures as the PDF writer does: in points (72 to the inch), text at its unhinted
    widths. The screen's renderer hints text at its pixels and measures it a few % narrower, which moves a layout by
    up to 2 pt and lets a long tick label's end fall outside the crop."""

    def __init__(self, figure: Figure, image_dpi: float) -> None:
        super().__init__(figure)
        width, height = figure.get_size_inches()
        self.renderer = RendererPdf(PdfFile(io.BytesIO()), image_dpi, height, width)

    def get_renderer(self) -> RendererPdf:
        """The renderer the figure's layout and extents are measured with."""
        return self.renderer


@contextlib.contextmanager
def _as_pdf(fig: Figure) -> Iterator[RendererPdf]:
    """The figure measured as the PDF writer measures it (:class:`_PdfMeasure`, its dpi the PDF's 72), then given
    back its canvas and dpi."""
    canvas, dpi = fig.canvas, fig.dpi
    measure = _PdfMeasure(fig, dpi)
    fig.dpi = 72.0
    try:
        yield measure.get_renderer()
    finally:
        fig.dpi = dpi
        fig.set_canvas(canvas)


def _set_layout_engine(fig: Figure, engine: Any) -> None:
    """``fig``'s layout engine set to ``engine``; None is none (matplotlib reads None as the rc's
    ``figure.constrained_layout.use`` or ``figure.autolayout``, which a user's matplotlibrc may set)."""
    with mpl.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
        fig.set_layout_engine(engine)


def legends(*placed: Any, **kw: Any) -> None:
    """Legends off the data: each axes' legend at the first place of :data:`_INSIDE` where it stays inside the axes
    and covers none of their data (:func:`_covers`), or outside the axes at their right where there is none. Called
    once a figure's artists are all drawn; ``placed`` are axes, or ``(axes, legend keywords)`` pairs.

    The figure is laid out as its PDF is (:func:`save`), the legends placed, and laid out again only where a place
    moved the axes (a legend outside them, or their top raised), until every legend fits. That layout is then the
    figure's own (its layout engine removed): saving neither lays the figure out again nor moves the data under a
    legend.
    """
    pairs = [(p, dict(kw)) if not isinstance(p, tuple) else (p[0], {**kw, **p[1]}) for p in placed]
    if not pairs:
        return
    fig = pairs[0][0].get_figure()
    engine = fig.get_layout_engine()
    lay_out = engine.execute if engine is not None else (lambda _fig: None)
    with _as_pdf(fig) as renderer:
        for _ in range(3):
            lay_out(fig)
            unfit = [(ax, k) for ax, k in pairs if not _fits(ax, renderer)]
            if not unfit or not any([_place(ax, renderer, k) for ax, k in unfit]):
                break  # every legend fits the layout as it stands
        else:
            lay_out(fig)  # the last round's places, laid out
    _set_layout_engine(fig, None)


def save(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` as PDF (vector; the text stays text, in Type 3 fonts: matplotlib's default, written
    without the font subsetting TrueType embedding runs per file, which took half the report's time),
    cropped to what it draws and a pad of ``savefig.pad_inches`` (:data:`STYLE`).

    The figure is drawn once: it is laid out here only if :func:`legends` has not laid it out (it keeps its layout
    engine then), and the crop is measured on that layout, so the PDF writer neither lays it out again nor draws it
    a first time to find its extent. The file is written whole or not at all (a temporary file renamed over it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    engine = fig.get_layout_engine()
    try:
        with os.fdopen(fd, "wb") as fh, mpl.rc_context(STYLE):
            with _as_pdf(fig) as renderer:
                if engine is not None:
                    engine.execute(fig)
                crop = fig.get_tightbbox(renderer).padded(float(mpl.rcParams["savefig.pad_inches"]))
            _set_layout_engine(fig, None)
            fig.savefig(fh, format="pdf", bbox_inches=crop, metadata={"CreationDate": None, "ModDate": None})
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        _set_layout_engine(fig, engine)
    return path


def _save_pickled(blob: bytes, path: str) -> str:
    return str(save(pickle.loads(blob), path))


def save_all(figures: Sequence[tuple[Figure, str | Path]], *, pool: Pool | None = None,
             bar: Bar | None = None) -> list[Path]:
    """Write each ``(figure, path)`` as :func:`save` does, drawn by the run's worker processes at once.

    Drawing is most of a report's time and the figures are independent: each is drawn by a process of
    ``pool`` (the run's :class:`~piezopreload.core.parallel.Pool`); without one, or with one worker, they are
    drawn here, one after the other. ``bar(done, total)`` is called as each file is written.
    """
    total = len(figures)
    say = bar or (lambda _i, _n: None)
    if pool is None or not pool.parallel or total <= 1:
        written = []
        for i, (fig, path) in enumerate(figures, start=1):
            written.append(save(fig, path))
            say(i, total)
        return written
    futures = [pool.submit(_save_pickled, pickle.dumps(fig), str(path)) for fig, path in figures]
    for i, _ in enumerate(as_completed(futures), start=1):
        say(i, total)
    return [Path(f.result()) for f in futures]


def styled(fn: Any) -> Any:
    """A figure function that runs under :data:`STYLE` (artists take rcParams when created): the decorator of every
    figure of the report.

    Parameters
    ----------
    fn
        A function that returns a :class:`~matplotlib.figure.Figure`.

    Returns
    -------
    Callable
        ``fn`` run inside ``matplotlib.rc_context(STYLE)``.
    """
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Figure:
        with mpl.rc_context(STYLE):
            return fn(*args, **kwargs)
    return wrapper


@styled
def hysteresis_loops(time_s: np.ndarray, voltage_V: np.ndarray, measured_N: np.ndarray,
                     model_N: np.ndarray) -> Figure:
    """Measured and modelled voltage -> force loops, and the model's error over the record (where the measurement
    came from is the caption's)."""
    fig, ax = page_figure(2.6, ncols=2)
    a, b = ax[0]
    a.plot(voltage_V, measured_N, color=COLOURS["measured"], lw=0.8, label="measured")
    a.plot(voltage_V, model_N, color=COLOURS["model"], lw=1.0, ls="--", label="P-I model")
    a.set_xlabel("command voltage (V)")
    a.set_ylabel("force (N)")
    a.set_title("hysteresis loops")
    err = model_N - measured_N
    b.plot(time_s, err, color=COLOURS["model"], lw=0.6)
    b.set_xlabel("time (s)")
    b.set_ylabel("model - measured (N)")
    b.set_title(f"model error: RMS {quantity(float(np.sqrt(np.mean(err ** 2))), 'N')}, "
                f"largest {quantity(float(np.max(np.abs(err))), 'N')}")
    legends(a)
    return fig


@styled
def inverse_model(desired_N: np.ndarray, command_V: np.ndarray, force_N: np.ndarray, time_s: np.ndarray) -> Figure:
    """The inverse P-I model (desired force -> voltage) and the compensated rig in open loop."""
    fig, ax = page_figure(2.6, ncols=2)
    a, b = ax[0]
    a.plot(desired_N, command_V, color=COLOURS["model"])
    a.set_xlabel("desired force (N)")
    a.set_ylabel("inverse model's voltage (V)")
    a.set_title("inverse P-I model")
    settled = time_s >= 0.5 * time_s[-1]
    b.plot(desired_N[settled], force_N[settled], color=COLOURS["tuned ff+pid"], lw=0.9, label="rig through the inverse")
    lim = [float(np.min(desired_N)), float(np.max(desired_N))]
    b.plot(lim, lim, color=COLOURS["reference"], ls=":", lw=0.8, label="ideal")
    b.set_xlabel("desired force (N)")
    b.set_ylabel("rig's force (N)")
    b.set_title("compensated, open loop (second cycle)")
    legends(b)
    return fig


def _runs_axes(ax: Any, runs: Mapping[str, Mapping[str, np.ndarray]], keys: Sequence[str], signal: str,
               t_max: float | None) -> None:
    first = runs[keys[0]]
    ax.plot(first["time_s"], first["reference_N"], color=COLOURS["reference"], ls=":", lw=0.9, label="reference")
    for key in keys:
        r = runs[key]
        name = key.split(" ", 1)[1].replace("ff+pid", "FF + PID").replace("pid", "PID")
        ax.plot(r["time_s"], r[signal], color=COLOURS[key], lw=0.8, label=name)
    if t_max is not None:
        ax.set_xlim(0, t_max)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (N)")


@styled
def step_responses(runs: Mapping[str, Mapping[str, np.ndarray]], band_N: float, signal: str,
                   labels: Mapping[str, str], t_max_s: float | None = None) -> Figure:
    """The step with the study's gains (left) and the tuned gains (right), PID alone and with FF; ``labels`` names
    the two gain sets (``{"study": ..., "tuned": ...}``) as the study does."""
    fig, ax = page_figure(2.7, ncols=2, sharey=True)
    for a, who in zip(ax[0], ("study", "tuned")):
        keys = [f"{who} pid", f"{who} ff+pid"]
        _runs_axes(a, runs, keys, signal, t_max_s)
        final = float(runs[keys[0]]["reference_N"][-1])
        for s in (-1, 1):
            a.axhline(final + s * band_N, color=COLOURS["limit"], lw=0.5, ls="--")
        a.set_title(labels[who])
    ax[0][1].set_ylabel("")
    legends(*ax[0])
    return fig


@styled
def tracking(runs: Mapping[str, Mapping[str, np.ndarray]], signal: str, labels: Mapping[str, str]) -> Figure:
    """The trajectory: the four controllers, and the tracking error of each (its scale from the errors after the
    first moments of each change, so the transients do not hide them)."""
    fig, ax = page_figure(4.4, ncols=2, nrows=2, sharex=True)
    errors = np.concatenate([r["reference_N"] - r["force_N"] for r in runs.values()])
    scale = float(np.percentile(np.abs(errors), 98)) * 1.5 or 1.0
    for j, who in enumerate(("study", "tuned")):
        keys = [f"{who} pid", f"{who} ff+pid"]
        _runs_axes(ax[0][j], runs, keys, signal, None)
        ax[0][j].set_title(labels[who])
        ax[0][j].set_xlabel("")
        for key in keys:
            r = runs[key]
            ax[1][j].plot(r["time_s"], r["reference_N"] - r["force_N"], color=COLOURS[key], lw=0.6,
                          label=key.replace("ff+pid", "FF + PID").replace("pid", "PID"))
        ax[1][j].set_ylim(-scale, scale)
        ax[1][j].set_xlabel("time (s)")
        ax[1][j].set_ylabel("reference - force (N)")
    legends(*ax[0])
    return fig


@styled
def stiffness_vs_preload(curve: PreloadCurve, runs_N: tuple[float, float] | None = None) -> Figure:
    """Rigidity (and drag torque) of the optimum's screw against preload; the duty cases marked; shaded, the
    preloads the schedule runs (``runs_N``, its least and highest)."""
    fig, ax = page_figure(2.6, ncols=2)
    a, b = ax[0]
    fp = np.asarray(curve.preload_N)
    a.plot(fp, curve.rigidity_N_per_um, color=COLOURS["model"], label="no axial load")
    for j, case in enumerate(curve.cases):
        a.plot(case.preload_N, case.rigidity_N_per_um, "o", ms=4,
               label=f"case {j + 1}: {quantity(case.axial_load_N, 'N')}")
    for a_ in (a, b):
        if runs_N is not None:
            a_.axvspan(*runs_N, color="0.9", lw=0, zorder=0)
        a_.axvline(curve.bolt_preload_N, color="0.5", ls=":", lw=0.8)
        a_.axvline(curve.max_preload_N, color="0.3", ls="--", lw=0.8)
        a_.set_xlabel("preload (N)")
    a.set_ylabel("axial rigidity (N/um)")
    a.set_title("axial rigidity")
    b.plot(fp, curve.drag_torque_Nm, color=COLOURS["study pid"])
    b.set_ylabel("drag torque (N m)")
    b.set_title("preload drag torque")
    legends(a)
    return fig


_FRONT_LABELS = {"stiffness": "least rigidity (N/um)", "preload": "highest preload (N)",
                 "drag": "mean drag torque (N m)", "life": "rating life (h)", "growth": "growth over the shift (um)"}


@styled
def pareto_fronts(fronts: Sequence[Front], optimum: DesignPoint | None = None) -> Figure:
    """The epsilon-constraint Pareto fronts, one panel each, the design optimum marked."""
    n = max(len(fronts), 1)
    fig, ax = page_figure(2.4, ncols=n)
    keys = {"stiffness": "stiffness_N_per_um", "preload": "max_preload_N",
            "drag": "mean_drag_torque_Nm", "life": "life_h"}
    for a, f in zip(ax[0], fronts):
        a.plot(f.x, f.y, "o-", ms=2.5, color=COLOURS["model"], label="front")
        if optimum is not None and f.y_name in keys:  # a point's growth is not one of its fields
            a.plot(getattr(optimum, keys[f.x_name]), getattr(optimum, keys[f.y_name]), "*", ms=8,
                   color=COLOURS["limit"], label="the design optimum")
        a.set_xlabel(_FRONT_LABELS[f.x_name])
        a.set_ylabel(_FRONT_LABELS[f.y_name])
        if f.y_name == "life":
            a.set_yscale("log")
    legends(ax[0][0])
    return fig


@styled
def preload_schedule(time_s: np.ndarray, load_N: np.ndarray, preload_N: np.ndarray, constant_N: float,
                     lift_off_margin: float) -> Figure:
    """The load profile and the least-friction preload schedule against the best constant preload, with the
    schedule's lift-off bound ``lift_off_margin |F_a| / 2^(3/2)`` (the catalogues' rule, the safety factor
    included; the caption says whether the schedule sits on it)."""
    fig, ax = page_figure(3.6, nrows=2, sharex=True)
    a, b = ax[0][0], ax[1][0]
    a.plot(time_s, load_N, color=COLOURS["reference"], drawstyle="steps-post")
    a.set_ylabel("axial load (N)")
    a.set_title("load profile")
    b.plot(time_s, preload_N, color=COLOURS["model"], drawstyle="steps-post", label="schedule")
    b.axhline(constant_N, color=COLOURS["study pid"], ls="--", label="best constant preload")
    b.plot(time_s, lift_off_margin * np.abs(load_N) / 2.0 ** 1.5, color=COLOURS["limit"], lw=0.6, ls=":",
           label=f"lift-off bound {lift_off_margin:g} |F_a| / 2^1.5")
    b.set_xlabel("time (s)")
    b.set_ylabel("preload (N)")
    legends(b)
    return fig


@styled
def natural_frequency(position_mm: np.ndarray, low_Hz: np.ndarray, high_Hz: np.ndarray,
                      frequency_min_Hz: float | None) -> Figure:
    """The axial natural frequency against table position at the bolts' and the full preload."""
    fig, ax = page_figure(2.4)
    a = ax[0][0]
    a.plot(position_mm, low_Hz, color=COLOURS["study pid"], label="bolt preload (stacks off)")
    a.plot(position_mm, high_Hz, color=COLOURS["model"], label="maximum preload (stacks at full drive)")
    if frequency_min_Hz:
        a.axhline(frequency_min_Hz, color=COLOURS["limit"], ls="--", lw=0.8, label="required minimum")
    a.set_xlabel("nut position from bearing A (mm)")
    a.set_ylabel("axial natural frequency (Hz)")
    legends(a)
    return fig


@styled
def monte_carlo(validation: ValidationResult) -> Figure:
    """The validation's distributions over the Monte Carlo plants, limits marked (drawn by
    :meth:`~piezopreload.artifacts.validation.ValidationResult.draw_histograms`)."""
    fig, ax = page_figure(2.4, ncols=len(validation.histogram_metrics()))
    legends(*validation.draw_histograms(ax[0], colour=COLOURS["model"], limit_colour=COLOURS["limit"]))
    return fig


@styled
def gain_schedule(schedule: GainScheduleRecord) -> Figure:
    """The gain schedule against the preload (Kc and Ti, the entries marked, the robust set dashed) and each
    set's worst-case settling time and tracking RMS over the Monte Carlo plants at each level.

    Parameters
    ----------
    schedule : GainScheduleRecord
        The gain schedule's record (a tuning's ``solve.schedule``).

    Returns
    -------
    Figure
        Kc, Ti and the worst cases against the preload level, the choice in the title.
    """
    table, robust = schedule.table, schedule.robust
    lv = np.asarray(table.levels_N, float)
    x = np.linspace(lv[0], lv[-1], 200)
    fig, ax = page_figure(2.6, ncols=3)
    for a, column, at_robust, label in ((ax[0][0], table.Kc, robust.Kc_V_per_N, "Kc (mV/N)"),
                                        (ax[0][1], table.Ti_s, robust.Ti_s, "Ti (ms)")):
        a.plot(x, 1e3 * np.interp(x, lv, column), color=COLOURS["model"], label="schedule")
        a.plot(lv, 1e3 * np.asarray(column, float), "o", color=COLOURS["model"], ms=4)
        a.axhline(1e3 * at_robust, color=COLOURS["limit"], ls="--", lw=0.9, label="robust set")
        a.set_xlabel("preload setpoint (N)")
        a.set_ylabel(label)
    a = ax[0][2]
    at = np.array([r.level_N for r in schedule.levels])
    for which, marker, name in (("robust", "s", "robust set"), ("scheduled", "o", "schedule")):
        a.plot(at, [r.of(which).tracking_rms_N for r in schedule.levels], marker=marker, ls="-",
               label=f"{name}: tracking RMS")
        a.plot(at, [r.of(which).overshoot_N for r in schedule.levels], marker=marker, ls=":",
               label=f"{name}: overshoot")
    for key, ls in (("tracking_rms_N", "--"), ("overshoot_N", ":")):
        if key in schedule.limits:
            a.axhline(schedule.limits[key], color=COLOURS["limit"], ls=ls, lw=0.8)
    a.set_xlabel("preload level (N)")
    a.set_ylabel("worst case over the plants (N)")
    fig.suptitle(f"chosen: {schedule.choice.words}", fontsize=8)
    legends(ax[0][0], (a, {"fontsize": 6}))
    return fig


@styled
def rig_run(time_s: np.ndarray, reference_N: np.ndarray, force_N: np.ndarray, voltage_V: np.ndarray,
            mode: np.ndarray) -> Figure:
    """The rig executor's run from its log: force against the reference, and the stack voltage."""
    fig, ax = page_figure(3.4, nrows=2, sharex=True)
    a, b = ax[0][0], ax[1][0]
    control = mode == 0
    a.plot(time_s, reference_N, color=COLOURS["reference"], ls=":", label="reference")
    a.plot(time_s[control], force_N[control], color=COLOURS["tuned ff+pid"], lw=0.7, label="force read")
    a.set_ylabel("force (N)")
    b.plot(time_s, voltage_V, color=COLOURS["study ff+pid"], lw=0.7)
    if (~control).any():
        b.axvspan(float(time_s[~control][0]), float(time_s[-1]), color="0.9", label="ramp down, disarm")
    b.set_xlabel("time (s)")
    b.set_ylabel("stack voltage (V)")
    legends(a, *([b] if (~control).any() else []))
    return fig


@styled
def closed_loop(run: Mapping[str, np.ndarray], band_N: float | None, signal: Signal, title: str = "") -> Figure:
    """One closed-loop run: reference, true and measured force (top; the band about the last level dashed),
    the controller's command and the amplifier's voltage (bottom)."""
    fig, ax = page_figure(3.6, nrows=2, sharex=True)
    a, b = ax[0][0], ax[1][0]
    t = run["time_s"]
    a.plot(t, run["reference_N"], color=COLOURS["reference"], ls=":", lw=0.9, label="reference")
    if Signal(signal) is Signal.MEASURED:
        a.plot(t, run["measured_N"], color=COLOURS["measured"], lw=0.5, label="measured force")
    a.plot(t, run["force_N"], color=COLOURS["tuned ff+pid"], lw=0.9, label="true force")
    if band_N is not None:
        for s in (-1, 1):
            a.axhline(float(run["reference_N"][-1]) + s * band_N, color=COLOURS["limit"], lw=0.5, ls="--")
    a.set_ylabel("force (N)")
    a.set_title(title)
    b.plot(t, run["command_V"], color=COLOURS["study ff+pid"], lw=0.7, label="command")
    b.plot(t, run["voltage_V"], color=COLOURS["study pid"], lw=0.7, label="amplifier")
    b.set_xlabel("time (s)")
    b.set_ylabel("voltage (V)")
    legends(a, b)
    return fig


@styled
def system_tracking(time_s: np.ndarray, planned_N: np.ndarray, achieved_N: np.ndarray, rigidity_N_per_um: np.ndarray,
                    required_N_per_um: np.ndarray, cutting: np.ndarray, deflection_um: np.ndarray,
                    deflection_limit_um: float | None) -> Figure:
    """The whole system over the cycles: planned and achieved preload, rigidity against the requirement
    while cutting, and the axial deflection under the cutting load."""
    fig, ax = page_figure(6.0, nrows=3, sharex=True)
    a, b, c = ax[0][0], ax[1][0], ax[2][0]
    a.plot(time_s, planned_N, color=COLOURS["reference"], lw=0.9, label="planned (schedule)")
    a.plot(time_s, achieved_N, color=COLOURS["model"], lw=0.7, label="achieved (true force)")
    a.set_ylabel("preload (N)")
    cut = np.asarray(cutting, bool)
    b.plot(time_s, np.where(cut, rigidity_N_per_um, np.nan), color=COLOURS["model"], lw=0.8, label="achieved")
    b.plot(time_s, np.where(cut, required_N_per_um, np.nan), color=COLOURS["limit"], ls="--", lw=0.8,
           label="required")
    b.set_ylabel("rigidity under load (N/um)")
    c.plot(time_s, np.where(cut, np.abs(deflection_um), np.nan), color=COLOURS["model"], lw=0.8, label="|deflection|")
    if deflection_limit_um is not None and np.isfinite(deflection_limit_um):
        c.axhline(deflection_limit_um, color=COLOURS["limit"], ls="--", lw=0.8, label="limit")
    c.set_xlabel("time (s)")
    c.set_ylabel("axial deflection (um)")
    legends(a, b, c)
    return fig


@styled
def learning_iterations(passes: Sequence[PassRecord]) -> Figure:
    """The error per learning iteration on the repeated schedule, one line per margin pass (the whole trajectory's RMS
    of the true force in % of the schedule's range), the causal floor beside it."""
    fig, ax = page_figure(2.8)
    a = ax[0][0]
    for k, p in enumerate(passes):
        span = p.tracking_rms_N / p.tracking_rms_pct_of_range * 100.0 if p.tracking_rms_pct_of_range else 1.0
        it = [h.iteration for h in p.history]
        pct = [100.0 * h.worst_tracking_rms_N / span for h in p.history]
        a.semilogy(it, pct, "o-", ms=3, lw=0.9, color=f"C{k}",
                   label=f"pass {p.pass_number} (best: trial {int(np.max(p.best_iteration))})")
        a.axhline(100.0 * p.causal_floor_N / span, color=f"C{k}", ls=":", lw=0.7)
    a.set_xlabel("learning trial (0: before the pass learns)")
    a.set_ylabel("tracking RMS (% of the pass's range)")
    a.xaxis.set_major_locator(MaxNLocator(integer=True))  # trials are counted
    legends(a)
    return fig
