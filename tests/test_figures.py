"""The report's figure writer: the same files drawn here or by worker processes, and written whole."""

import numpy as np
import pytest

from piezopreload.core.parallel import Pool
from piezopreload.reports import figures as F


def _figures(tmp_path, folder):
    t = np.linspace(0.0, 1.0, 200)
    return [(F.natural_frequency(t, 100 + t, 120 + t, 90.0), tmp_path / folder / f"f{i}.pdf") for i in range(3)]


def test_save_all_in_workers_writes_what_saving_here_writes(tmp_path):
    here = F.save_all(_figures(tmp_path, "here"), pool=Pool(1))
    seen = []
    with Pool(2) as pool:  # the run's processes draw them
        pooled = F.save_all(_figures(tmp_path, "pool"), pool=pool, bar=lambda i, n: seen.append((i, n)))
    assert [p.name for p in pooled] == [p.name for p in here]
    for a, b in zip(here, pooled, strict=True):
        assert a.read_bytes() == b.read_bytes(), f"{b} differs from {a}"
        assert a.read_bytes().startswith(b"%PDF")
    assert seen == [(1, 3), (2, 3), (3, 3)]


def test_a_failed_draw_leaves_no_partial_file(tmp_path, monkeypatch):
    fig, path = _figures(tmp_path, "x")[0]
    path.parent.mkdir(parents=True)
    path.write_bytes(b"the previous report's figure")

    def broken(*_a, **_k):
        raise RuntimeError("the disk is full")

    monkeypatch.setattr(fig, "savefig", broken)
    with pytest.raises(RuntimeError):
        F.save(fig, path)
    assert path.read_bytes() == b"the previous report's figure"
    assert [p.name for p in path.parent.iterdir()] == [path.name], "a temporary file was left behind"


# --------------------------------------------------------------------------------------
# legends off the data, integer counts: figures as the report draws them, checked on their pixels (tests/figkit.py)
# --------------------------------------------------------------------------------------
def _loops():
    """A hysteresis record as the paper's rig gives it: three loops of 0-100 V, 30-90 N, the model close to it."""
    t = np.linspace(0.0, 6.0, 3000)
    v = 50.0 - 50.0 * np.cos(2 * np.pi * t / 2.0)
    force = 30.0 + 0.6 * v + 4.0 * np.sin(2 * np.pi * t / 2.0)
    return t, v, force, force + 0.5 * np.sin(7 * t)


def _system(limit_um=5.0):
    t = np.linspace(0.0, 30.0, 3001)
    level = np.where((t % 15) < 2, 300.0, np.where((t % 15) < 7, 1700.0, np.where((t % 15) < 9, 300.0, 650.0)))
    cut = (t % 15) > 0.7
    rigidity = 700.0 + 0.25 * level
    required = np.where(level > 1000, 800.0, 300.0)
    deflection = np.where(cut, 3.15 * level / 1700.0, 0.0)
    return t, level, level + 0.3, rigidity, required, cut, deflection, limit_um


def _passes():
    """Two margin passes of a learning record (the stored one's, their numbers set here)."""
    from dataclasses import replace
    from pathlib import Path

    from piezopreload.artifacts.learning import LearningRecord, TrialRecord

    stored = LearningRecord.load(Path(__file__).parent / "data" / "artifacts" / "learning.json").passes[0]
    history = [TrialRecord(i, [20.0 / 8 ** i], [20.0 / 8 ** i], [20.0 / 8 ** i]) for i in range(3)]
    return [replace(stored, pass_number=1, tracking_rms_N=0.75, tracking_rms_pct_of_range=0.052, history=history,
                    trials=2, best_iteration=[2], causal_floor_N=0.68),
            replace(stored, pass_number=2, tracking_rms_N=0.43, tracking_rms_pct_of_range=0.0296,
                    history=history[:2], trials=1, best_iteration=[1], causal_floor_N=0.68)]


def _schedule():
    """A gain schedule's record of three entries (the machine axis's figures, rounded)."""
    from piezopreload.artifacts.tuning import GainScheduleRecord, ScheduleLevel, SetFigures, SetGains, WorstFigures
    from piezopreload.models.controller import GainSchedule

    def worst(tracking, overshoot):
        return WorstFigures(0.2, overshoot, tracking, None, True, ())

    table = GainSchedule((0.0, 2000.0, 4000.0), (0.01195, 0.01152, 0.01119), (0.0034, 0.0447, 0.0461),
                         (0.0, 0.0, 0.0))
    robust = SetGains(0.01077, 0.0486, 0.0, 0.0005, 0.5)
    levels = tuple(ScheduleLevel(lv, (lv - 1000.0, lv + 1000.0), SetGains(kc, ti, 0.0, 0.0005, 0.5), None, {},
                                 worst(tr, os_), worst(ts, oss))
                   for lv, kc, ti, tr, os_, ts, oss in zip(table.levels_N, table.Kc, table.Ti_s, (30.0, 23.7, 31.6),
                                                          (10.1, 28.9, 26.1), (15.9, 17.4, 34.2), (6.8, 19.3, 20.2)))
    return GainScheduleRecord("schedule", "the robust set misses a level", table.levels_N, table, 0.0005, 0.5, robust,
                              levels, SetFigures(worst(30.0, 20.0), worst(20.0, 15.0)), 50,
                              ("settling_s", "overshoot_N", "tracking_rms_N", "peak_voltage_V"),
                              {"tracking_rms_N": 40.0, "overshoot_N": 25.0}, 1.0)


def _drawn(name):
    if name == "hysteresis":
        return F.hysteresis_loops(*_loops())
    if name == "system":
        return F.system_tracking(*_system())
    if name == "learning":
        return F.learning_iterations(_passes())
    if name == "gain schedule":
        return F.gain_schedule(_schedule())
    t = np.linspace(0.0, 14.5, 1451)
    if name == "schedule":
        load = np.where(t < 1.5, 600.0, np.where(t < 6.5, 4000.0, np.where(t < 8, -600.0, -1500.0)))
        return F.preload_schedule(t, load, np.maximum(np.abs(load) / 2.83 * 1.2, 255.0), 1697.0, 1.2)
    t = np.linspace(0.0, 30.5, 3051)
    ref = np.where((t % 15) < 2, 50.0, np.where((t % 15) < 7, 1450.0, 380.0))
    return F.rig_run(t, ref, ref + 0.5, 0.02 * ref, (t > 29.9).astype(int))


@pytest.mark.parametrize("name", ["hysteresis", "system", "learning", "gain schedule", "schedule", "rig run"])
def test_no_legend_covers_the_data_or_a_tick_label(name):
    """Each figure's legends stand where no data, limit line or tick label is (the report's figure 7 had its legend
    over the loops and the y tick '0'; figure 1's over the deflection limit)."""
    from figkit import legends_over_ink

    assert legends_over_ink(_drawn(name)) == [], name


def test_counts_are_ticked_in_whole_numbers():
    """A learning trial and a number of plants are counts: no tick at 0.5 or 2.5."""
    learning = F.learning_iterations(_passes()).axes[0]
    validation = _validation()
    for hist in (F.monte_carlo(validation), validation.plot()):
        for ticks, what in ((learning.get_xticks(), "learning trials"),
                            *((a.get_yticks(), "plants") for a in hist.axes)):
            assert np.allclose(ticks, np.round(ticks)), f"{what}: ticks at {ticks}"


def _validation(n=200, never=3):
    """A validation over ``n`` plants of which ``never`` did not settle (NaN)."""
    from piezopreload.artifacts.validation import METRICS, Criteria, ValidationResult

    rng = np.random.default_rng(0)
    metrics = {k: rng.random(n) for k in METRICS}
    metrics["settling_s"] = 0.3 + 0.02 * rng.random(n)
    metrics["settling_s"][:never] = np.nan
    return ValidationResult(metrics, Criteria(), n, 0, {})


def test_the_monte_carlo_histogram_is_drawn_once_for_the_report_and_the_result():
    """The report's figure and ``ValidationResult.plot()`` are one drawing: the same panels, bars and titles, a
    plant that never settled counted in the title and left out of the bars (the report's copy looked for None,
    which the result never holds, so it counted a NaN as a plant and never said "never settled")."""
    validation = _validation()
    report, own = F.monte_carlo(validation), validation.plot()
    assert [a.get_title() for a in report.axes] == [a.get_title() for a in own.axes]
    assert report.axes[0].get_title() == "197 plants, 3 never settled"
    for a, b in zip(report.axes, own.axes):
        assert a.get_xlabel() == b.get_xlabel()
        assert [p.get_height() for p in a.patches] == [p.get_height() for p in b.patches]
    assert sum(p.get_height() for p in report.axes[0].patches) == 197
def test_every_plot_method_is_typed_to_return_a_figure_and_nothing_uses_pyplot():
    """Every result's ``plot()`` returns a matplotlib Figure made without pyplot (no global figure state): its
    annotation says so (a type checker then holds each body to it), and no module of the package imports pyplot."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    folders = ("core", "models", "artifacts", "design", "tuning", "rig", "reports", "piezopreload")
    plots, pyplot = [], []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef) and node.name == "plot":
                    plots.append((f"{path.relative_to(root)}:{node.lineno}", ast.unparse(node.returns)))
                if isinstance(node, ast.ImportFrom | ast.Import):
                    names = [getattr(node, "module", None) or ""] + [a.name for a in node.names]
                    if any(n == "matplotlib.pyplot" or n.endswith(".pyplot") or n == "pyplot" for n in names):
                        pyplot.append(f"{path.relative_to(root)}:{node.lineno}")
    assert len(plots) >= 19
    assert [p for p in plots if p[1] != "Figure"] == []
    assert pyplot == []


def test_the_schedule_figure_draws_the_lift_off_bound_its_table_states():
    """The design's table states the schedule's lift-off bound with its safety factor, lift_off_margin |F_a| / 2^1.5
    (1,697 N at the machining cycle's 4,000 N with the factor 1.2); the figure's dotted line is that bound, not the
    bare |F_a| / 2^1.5 (1,414 N)."""
    t = np.linspace(0.0, 14.5, 1451)
    load = np.where(t < 1.5, 600.0, np.where(t < 6.5, 4000.0, np.where(t < 8, -600.0, -1500.0)))
    fig = F.preload_schedule(t, load, np.maximum(np.abs(load) / 2.83 * 1.2, 255.0), 1706.0, 1.2)
    lines = [line for line in fig.axes[1].get_lines() if "lift-off" in str(line.get_label())]
    assert len(lines) == 1, [line.get_label() for line in fig.axes[1].get_lines()]
    drawn = np.asarray(lines[0].get_ydata(), float)
    np.testing.assert_allclose(drawn, 1.2 * np.abs(load) / 2.0 ** 1.5, rtol=1e-12)
    assert float(drawn.max()) == pytest.approx(1697.06, abs=0.01)


# --------------------------------------------------------------------------------------
# one layout, one draw: the layout the legends are placed in is the PDF's
# --------------------------------------------------------------------------------------
def _frames(fig):
    return np.array([ax.get_position().bounds for ax in fig.axes])


def test_the_legends_are_placed_in_the_layout_matplotlib_writes_the_pdf_in(tmp_path):
    """legends() lays a figure out as matplotlib's own PDF writer does (savefig lays a figure out again in the PDF's
    measure: points, text at its unhinted widths): the axes stand where savefig would put them, and save() crops
    the page as savefig's tight crop does. Placed in the screen's measure, they stood up to 2 pt away (11 pt on the
    sensitivity figure's long labels), so the PDF was laid out anew and its legends were checked in another layout
    than the one written."""
    import io

    import matplotlib as mpl
    import pypdf

    ours = F.hysteresis_loops(*_loops())
    frames = _frames(ours)
    reference = F.hysteresis_loops(*_loops())
    reference.set_layout_engine("constrained")  # matplotlib's writer: it lays the figure out in the PDF's measure
    written = io.BytesIO()
    with mpl.rc_context(F.STYLE):
        reference.savefig(written, format="pdf")
    np.testing.assert_allclose(frames, _frames(reference), rtol=0, atol=1e-9,
                               err_msg="the axes are not where matplotlib's PDF writer lays them out")
    box = [float(v) for v in pypdf.PdfReader(F.save(ours, tmp_path / "h.pdf")).pages[0].mediabox]
    expected = [float(v) for v in pypdf.PdfReader(written).pages[0].mediabox]
    np.testing.assert_allclose(box, expected, atol=1e-3, err_msg="the crop is not matplotlib's tight crop")


@pytest.mark.parametrize("rc", [{}, {"figure.constrained_layout.use": True}], ids=["default", "user-rc-constrained"])
def test_saving_a_figure_draws_it_once_and_does_not_lay_it_out_again(tmp_path, monkeypatch, rc):
    """Saving a report figure draws it once, in the layout its legends were placed in: no layout again, no draw to
    find the crop (savefig drew each figure twice and laid it out a third time, a fifth of the report's time); a
    user's matplotlibrc asking for a layout engine does not give the figure one back."""
    import matplotlib as mpl
    from matplotlib.figure import Figure
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    with mpl.rc_context(rc):
        fig = F.gain_schedule(_schedule())
    frames = _frames(fig)
    draws, layouts = [], []
    draw, execute = Figure.draw, ConstrainedLayoutEngine.execute
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: (draws.append(renderer), draw(self, renderer))[1])
    monkeypatch.setattr(ConstrainedLayoutEngine, "execute", lambda self, f: (layouts.append(f), execute(self, f))[1])
    with mpl.rc_context(rc):
        path = F.save(fig, tmp_path / "g.pdf")
    assert path.read_bytes().startswith(b"%PDF")
    assert (len(draws), len(layouts)) == (1, 0), f"saving drew it {len(draws)} times, laid it out {len(layouts)}"
    np.testing.assert_array_equal(_frames(fig), frames, err_msg="saving moved the axes the legends were placed in")


def test_a_figure_without_legends_is_laid_out_once_when_saved(tmp_path):
    """A figure whose legends() had nothing to place keeps its layout engine: save() lays it out, in the PDF's
    measure, and gives the engine back; the file crops what matplotlib's own tight crop does."""
    import io

    import matplotlib as mpl
    import pypdf

    def drawn():
        fig, ax = F.page_figure(2.0)
        ax[0][0].plot([0.0, 1.0], [0.0, 1.0e4])
        ax[0][0].set_ylabel("a long label of the force over the run (N)")
        F.legends()
        return fig

    ours, reference = drawn(), drawn()
    engine = ours.get_layout_engine()
    F.save(ours, tmp_path / "f.pdf")
    assert ours.get_layout_engine() is engine
    written = io.BytesIO()
    with mpl.rc_context(F.STYLE):
        reference.savefig(written, format="pdf")
    np.testing.assert_allclose(_frames(ours), _frames(reference), rtol=0, atol=1e-9)
    box = [float(v) for v in pypdf.PdfReader(tmp_path / "f.pdf").pages[0].mediabox]
    expected = [float(v) for v in pypdf.PdfReader(written).pages[0].mediabox]
    np.testing.assert_allclose(box, expected, atol=1e-3, err_msg="the crop is not matplotlib's tight crop")
