"""The Python API as a script uses it: the README's snippet, the study's typed tables and copies, the
gain set's one reader and its exports, [feedforward] data honoured by every step, and the examples.

The snippet and the examples run on the small study (tests/data/small_study.toml: short references,
few Monte Carlo plants, 5-point fronts); each tunes the PID once or twice, which is most of their time.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

import piezopreload as pp
from piezopreload.cli import main
from piezopreload.core.tables import write_csv

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "tests" / "data" / "small_study.toml"


def _readme_snippet() -> str:
    text = (ROOT / "README.md").read_text()
    match = re.search(r"## Python API.*?```python\n(.*?)```", text, re.S)
    assert match, "README has no python block in its 'Python API' section"
    return match.group(1)


def _small(snippet: str) -> str:
    """The snippet with small settings: the small study, 8 Monte Carlo plants. Nothing else changes."""
    assert 'pp.load_study("paper2021")' in snippet and "plants=200" in snippet
    return (snippet.replace('pp.load_study("paper2021")', f"pp.load_study({str(SMALL)!r})", 1)
            .replace("plants=200", "plants=8"))


@pytest.mark.slow  # it tunes, validates and runs every stage of the small study: half a minute
def test_the_readme_snippet_runs_end_to_end(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(_small(_readme_snippet()), "README.md (Python API)", "exec"), ns)
    study, tuned, gain_set, run, plc, result = (ns[k] for k in ("study", "tuned", "gain_set", "run", "plc", "result"))
    assert isinstance(gain_set, pp.GainSet) and gain_set.validated, gain_set.validation
    assert gain_set.validation.n_plants == 8
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == str(gain_set.validation.worst.settling_s), "the snippet prints the worst settling time"
    assert isinstance(run, pp.ClosedLoopRun)
    m = run.step_metrics()
    assert isinstance(m, pp.StepMetrics) and 0 < m.settling_s < study.references["step"].duration_s
    # the run is the tuned gains' with the gain set's feedforward: the comparison table's tuned row
    assert m.settling_s == pytest.approx(tuned.row("tuned")["settling_measured_s"], abs=study.plant.sample_period_s)
    assert "FUNCTION_BLOCK PP_CONTROLLER" in plc and plc == pp.export(gain_set, "plc")
    assert list(result.ran) == [s.name for s in __import__("piezopreload.pipeline").pipeline.STAGES
                                if s.applies(study) is None]
    shown = repr(result).splitlines()  # the verdict and each requirement with its margin, a line each
    assert printed[1:1 + len(shown)] == shown and len(shown) == 5 + len(result.requirements)
    assert result.requirements_met is True and result.exit_code == 0
    assert (tmp_path / "paper2021-out" / "report.pdf").read_bytes().startswith(b"%PDF"), "not where it says"
    assert not (tmp_path / "piezopreload-out").exists(), "the paper's study wrote into the main job's folder"
    for fig in (tuned.plot(), run.plot(), gain_set.plot()):
        assert isinstance(fig, Figure) and fig.axes, f"{fig!r} draws nothing"
    for r in (tuned, run, result):
        json.dumps(r.to_dict(), allow_nan=False)  # what --json prints: plain, finite JSON


# ---- the study ---------------------------------------------------------------------------------------
def test_the_study_docstring_examples_run():
    import doctest

    import piezopreload.spec
    import piezopreload.study

    failed, tried = doctest.testmod(piezopreload.study)
    assert tried >= 3 and failed == 0
    failed, tried = doctest.testmod(piezopreload.spec)
    assert tried >= 3 and failed == 0


def test_studies_by_default_name_and_path():
    assert {"paper2021", "machine_axis"} <= set(pp.shipped_studies())
    a, b, c = pp.load_study(), pp.load_study("machine_axis"), pp.load_study(ROOT / "studies" / "machine_axis.toml")
    assert a.sha256 == b.sha256 == c.sha256 and a.plant_from_design, "the default study is the machine axis"
    p, q = pp.load_study("paper2021"), pp.load_study(ROOT / "studies" / "paper2021.toml")
    assert p.sha256 == q.sha256 and not p.plant_from_design
    with pytest.raises(pp.InputError, match="no such study file"):
        pp.load_study("no-such-study")


def test_typed_tables_mirror_the_file_and_a_copy_is_checked_as_a_file_is():
    study = pp.load_study(SMALL)
    assert study.reference.step.duration_s == 3.0 and study.design_table.pareto_points == 5
    assert study.validation.plants == 8 and study.export.formats == ("json", "labview", "c-header")
    changed = study.replace(rig={"bolt_preload_N": 30.0}, reference={"step": {"final_N": 70.0}},
                            design={"pareto_points": 7})
    assert changed.rig.bolt_preload_N == 30.0 and changed.references["step"].levels_N.tolist() == [25.0, 70.0]
    assert changed.design_table.pareto_points == 7 and changed.sha256 != study.sha256
    assert study.rig.bolt_preload_N == 25.0 and changed.plant.bolt_preload_N == 30.0  # the original stays
    # what replace wrote is a study file that reads back to the same tables; None removes a key
    path = Path(__import__("tempfile").mkdtemp()) / "copy.toml"
    path.write_text(changed.to_toml())
    assert pp.load_study(path).tables() == changed.tables()
    assert changed.replace(rig={"bolt_preload_N": None}).rig.bolt_preload_N == pp.load_study(SMALL).replace(
        rig={"bolt_preload_N": None}).plant.bolt_preload_N == 25.0  # the model's default


# ---- the gain set --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gain_set(tmp_path_factory):
    """A validated gain set with the small study's own feedforward (the paper's gains: no tuning needed)."""
    study = pp.load_study(SMALL)
    ff = study.identify_feedforward()
    gs = pp.GainSet(gains=study.controller, status="validated", feedforward=ff.model, feedforward_info=ff.info(),
                    plant=study.plant, preset=study.name, references=dict(study.references),
                    criteria=study.validation, inputs={"study_sha256": study.sha256})
    return gs.save(tmp_path_factory.mktemp("gs") / "gains.json"), tmp_path_factory.getbasetemp()


def test_the_gain_set_round_trips_and_its_exports_are_the_cli_s(gain_set, tmp_path, capsys):
    gs, _ = gain_set
    path = tmp_path / "gains.json"
    again = gs.save(path)
    loaded = pp.GainSet.load(path)
    assert loaded.content_sha256 == again.content_sha256 and loaded.to_dict() == gs.to_dict()
    assert pp.GainSet.from_dict(json.loads(path.read_text())).to_dict() == gs.to_dict()
    for fmt in ("json", "labview", "plc", "c-header", "casadi-c"):
        out = tmp_path / f"export.{fmt}"
        assert main(["export", str(path), "--format", fmt, "--out", str(out)]) == 0
        capsys.readouterr()
        assert out.read_text() == pp.export(loaded, fmt), f"{fmt}: the API's text is not the CLI's"
    # the units each format states: LabVIEW's minutes, the PLC block's Kc, Ti_s and Td_s in SI, the C header in SI
    g = gs.gains
    lv = dict(line.split(" = ") for line in pp.export(loaded, "labview").splitlines()
              if " = " in line and not line.startswith(";"))
    assert ([float(lv[k]) for k in ("Kc", "Ti (min)", "Td (min)")]
            == pytest.approx([g.Kc, g.Ti_s / 60, g.Td_s / 60], rel=1e-11))
    plc = dict(re.findall(r"^    (\w+) : LREAL := ([^;]+);", pp.export(loaded, "plc"), re.MULTILINE))
    assert [float(plc[k]) for k in ("Kc", "Ti_s", "Td_s", "u_max_V")] == [g.Kc, g.Ti_s, g.Td_s, g.u_max_V]
    assert f"#define PP_TI_S {g.Ti_s!r}" in pp.export(loaded, "c-header")
    assert json.loads(pp.export(loaded, "json"))["gains"]["Ti_s"] == g.Ti_s
    doc = json.loads(path.read_text())
    doc["gains"]["Ti_s"] = 0.5
    path.write_text(json.dumps(doc))
    with pytest.raises(pp.ArtifactError, match="content_sha256"):
        pp.GainSet.load(path)


def test_gain_set_and_reference_documents_are_checked_naming_the_field():
    ref = pp.Reference.staircase(25.0, [60.0, 80.0], 0.5, t_start_s=0.1)
    back = pp.Reference.from_dict(json.loads(json.dumps(ref.to_dict())))
    np.testing.assert_array_equal(back.times_s, ref.times_s)
    np.testing.assert_array_equal(back.levels_N, ref.levels_N)
    assert back.duration_s == ref.duration_s
    with pytest.raises(pp.InputError, match="levels_N is missing"):
        pp.Reference.from_dict({"times_s": [0.0], "duration_s": 1.0})
    with pytest.raises(pp.InputError, match="times_s must start at 0"):
        pp.Reference.from_dict({"times_s": [0.5], "levels_N": [25.0], "duration_s": 1.0})
    doc = {"status": "candidate", "gains": {"Kc_V_per_N": 0.5, "Ti_s": 0.1, "Td_s": 0.0}, "inputs": {}}
    assert pp.GainSet.from_dict(doc).gains.Kc == 0.5
    for field, value, match in (("status", "approved",
                                 "field 'status' must be one of validated, candidate, got 'approved'"),
                                ("gains", {"Kc_V_per_N": 0.5}, r"field 'gains.Ti_s' is missing"),
                                ("references", {"step": {"times_s": [0.0]}},
                                 r"field 'references.step' is not valid"),
                                ("plant", {"rig": {"noise_N": -1.0}},
                                 r"field 'plant.rig.noise_N' must be a number >= 0, got -1.0")):
        with pytest.raises(pp.ArtifactError, match=match):
            pp.GainSet.from_dict({**doc, field: value}, "g.json")
    with pytest.raises(pp.InputError, match="GainSet.status"):
        pp.GainSet(gains=pp.PIDGains(Kc=0.5, Ti_s=0.1), status="ok")


# ---- [feedforward] data, honoured by every step ---------------------------------------------------------
@pytest.fixture(scope="module")
def measured_study(tmp_path_factory):
    """The small study with a 'measured' loop: the simulated one, its force scaled by 1.1 (another rig)."""
    folder = tmp_path_factory.mktemp("measured")
    loop = pp.load_study(SMALL).identify_feedforward().loop
    write_csv(folder / "loop.csv", {"time_s": loop.time_s, "voltage_V": loop.input, "force_N": 1.1 * loop.output},
              "a measured loop")
    path = folder / "study.toml"
    path.write_text(SMALL.read_text().replace("n_operators = 20", 'n_operators = 20\ndata = "loop.csv"'))
    return pp.load_study(path), folder / "loop.csv"


def test_feedforward_data_is_honoured_by_simulate_and_reproduce(measured_study):
    study, loop = measured_study
    ff = study.identify_feedforward()
    plain = pp.load_study(SMALL).identify_feedforward()
    assert ff.source.to_dict() == {"kind": "measured", "path": str(loop), "sha256": ff.source.sha256}
    assert not np.allclose(ff.model.weights, plain.model.weights, rtol=0.05)  # a different rig, a different model
    run = study.simulate(controller="ff+pid")
    assert f"the measured loop {loop}" in run.to_dict()["feedforward"]["source"]
    ref = study.simulate(controller="ff+pid", feedforward=ff)
    np.testing.assert_array_equal(run.command_V, ref.command_V)
    assert study.reproduce().feedforward_fit == ff.fit.to_dict()


def test_feedforward_data_is_honoured_by_tune(measured_study, monkeypatch, capsys):
    """``piezopreload tune`` hands the tuner the inverse of the model identified from the study's data."""
    import piezopreload.steps as steps

    study, _ = measured_study
    expected = study.identify_feedforward().model
    seen = {}

    class Stop(Exception):
        pass

    def tuner(params, feedforward, spec, **kwargs):
        seen["feedforward"] = feedforward
        raise Stop

    monkeypatch.setattr(steps, "tune_pid", tuner)
    assert main(["tune", "--study", study.path, "--plants", "2"]) == 1  # the stand-in stops it there
    assert "Stop" in capsys.readouterr().err
    np.testing.assert_allclose(seen["feedforward"].forward.weights, expected.weights, rtol=1e-12)


# ---- the examples ---------------------------------------------------------------------------------------
def _example(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # a tuning and a validation
def test_example_sweep_of_the_bolt_preload(tmp_path):
    """The example on a study whose plant is its ``[rig]`` (the small study), with the options a user gives: one
    preload, not the study's own, is enough to show ``[rig] bolt_preload_N`` set from ``--preloads`` and the figure
    written to ``--out``; a sweep over several preloads, each another plant, is the next test's (the machine axis's
    three). The preload is 28 N: at 22 N, which this test also ran, the PID tuning alone took half a minute (about a
    thousand IPOPT evaluations a start), a cost of the tuner at that plant and not of what is checked here."""
    rows = _example("sweep_bolt_preload").main(["--study", str(SMALL), "--preloads", "28", "--plants", "4",
                                                "--out", str(tmp_path)])
    assert [r["bolt_preload_N"] for r in rows] == [28.0]
    assert pp.load_study(SMALL).plant.bolt_preload_N != 28.0, "the preload asked for is the study's own"
    for r in rows:  # settled inside the 3 s step, on the nominal rig and on every Monte Carlo plant
        assert 0 < r["settling_s"] < 3.0 and 0 < r["worst_settling_s"] < 3.0, r
    assert (tmp_path / "settling_vs_bolt_preload.png").stat().st_size > 0


def _check_example_output(out, tmp_path, loop):
    """The example's held-out error as written, recomputed from the saved model and the record; its exports."""
    result = out["identification"]
    model = pp.IdentifiedModel.load(tmp_path / "model.json").model
    record = pp.read_record(loop)
    window = record.window(*result.record.test.window_s)
    err = model(record.input)[window] - record.output[window]
    assert (100 * np.sqrt(np.mean(err ** 2)) / np.ptp(record.output)
            == pytest.approx(result.record.test.rms_pct, rel=1e-9))
    assert result.record.test.rms_pct < result.record.line.test.rms_pct / 3  # the P-I model explains what a line cannot
    gs = out["gain_set"]
    assert pp.GainSet.load(tmp_path / "gains.json").content_sha256 == gs.content_sha256
    assert gs.feedforward_info["source"]["kind"] == "measured"
    assert "FUNCTION_BLOCK PP_FEEDFORWARD" in (tmp_path / "feedforward.plc.st").read_text()
    if gs.validated:
        assert (tmp_path / "gains.labview.txt").read_text() == pp.export(gs, "labview")
        assert "FUNCTION_BLOCK PP_CONTROLLER" in (tmp_path / "gains.plc.st").read_text()
        assert "[feedforward operators]" in (tmp_path / "gains.labview.txt").read_text()
    else:  # a candidate is never exported
        assert not (tmp_path / "gains.labview.txt").exists()
    return gs


@pytest.mark.slow
def test_example_sweep_of_the_bolt_preload_on_its_documented_default(tmp_path, monkeypatch):
    """``python examples/sweep_bolt_preload.py``: the machine axis, whose bolts' preload is its design's. Each row is
    another design (the failsafe requirement gives the bolts' preload asked for), so another plant: the nuts' Hertz
    contacts stiffen with the preload as their law says, and the tuned loop changes with them."""
    example = _example("sweep_bolt_preload")
    monkeypatch.chdir(tmp_path)
    rows = example.main([])
    axis = pp.load_study(progress=lambda _m: None)
    own = axis.designed_plant.bolt_preload_N
    assert [r["asked_N"] for r in rows] == [round(f * own, 1) for f in (0.5, 1.0, 2.0)]
    for r in rows:  # the failsafe requirement binds: the design gives the bolts' preload asked for
        assert r["bolt_preload_N"] == pytest.approx(r["asked_N"], rel=1e-6), r
        plant = example.with_bolt_preload(axis, r["asked_N"]).plant
        k = plant.effective_stiffness_N_per_um  # the Hertz law at the bolts' preload, dF/dx = 1/(1/k + 2c/(3 F0^1/3))
        hertz = 1.0 / (1.0 / k + 2.0 * plant.hertz_um_per_N23 / (3.0 * np.cbrt(r["bolt_preload_N"])))
        assert r["stiffness_at_bolts_N_per_um"] == pytest.approx(hertz, rel=1e-9)
        assert r["validated"] and 0 < r["settling_s"] <= r["worst_settling_s"] < 0.6, r
    stiffness = [r["stiffness_at_bolts_N_per_um"] for r in rows]
    assert np.all(np.diff(stiffness) > 0), f"the plant does not stiffen with the bolts' preload: {stiffness}"
    assert len({r["settling_s"] for r in rows}) == 3 and len({r["Kc_V_per_N"] for r in rows}) == 3, \
        f"the sweep sweeps nothing: {rows}"
    fig = example.plot(rows, axis.name)
    left, right = fig.axes
    assert left.lines[0].get_ydata().tolist() == stiffness
    assert right.lines[0].get_ydata().tolist() == [r["settling_s"] for r in rows]
    assert (tmp_path / "sweep-out" / "settling_vs_bolt_preload.png").stat().st_size > 0


def test_example_identify_from_a_csv_and_export(measured_study, tmp_path):
    _, loop = measured_study
    out = _example("identify_and_export").main([str(loop), "--study", str(SMALL), "--operators", "20",
                                                "--plants", "4", "--out", str(tmp_path)])
    assert out["study"] == "small"
    _check_example_output(out, tmp_path, loop)


@pytest.mark.slow
def test_example_identify_and_export_on_its_default_path(tmp_path, capsys):
    """As its docstring says: the paper's study, its loop simulated on the paper's rig, the study's Monte Carlo."""
    out = _example("identify_and_export").main(["--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert out["study"] == "paper2021" and "study paper2021" in printed and "25 to 100 N" in printed
    gs = _check_example_output(out, tmp_path, tmp_path / "loop.csv")
    assert gs.validated and gs.validation.n_plants == pp.load_study("paper2021").validation.plants
    assert gs.feedforward_info["source"]["path"] == str((tmp_path / "loop.csv").resolve())


def test_example_refuses_a_loop_that_does_not_cover_the_studys_references(measured_study, tmp_path, monkeypatch):
    """The paper rig's loop (25-110 N) for the machine axis (references 0-4,000 N): refused before the design and
    the tuning run, with both ranges in the message."""
    from piezopreload.steps import Solved

    monkeypatch.setattr(Solved, "designed", lambda *a, **k: pytest.fail("the design ran first"))
    _, loop = measured_study
    with pytest.raises(pp.InputError) as exc:
        _example("identify_and_export").main([str(loop), "--study", "machine_axis", "--operators", "20",
                                              "--out", str(tmp_path)])
    message = str(exc.value)
    assert re.search(r"identified over [\d.]+ to [\d.]+ N", message) and "span 0 to 4,000 N" in message, message
    assert not (tmp_path / "gains.json").exists()


def test_example_pareto_front_of_a_catalogue_screw_on_its_documented_default(tmp_path, monkeypatch):
    """``python examples/pareto_catalogue_screw.py``: the machine axis' design tables, 30 points."""
    monkeypatch.chdir(tmp_path)
    design = _example("pareto_catalogue_screw").main([])
    assert design.spec == pp.load_study().replace(ballscrew={"nominal_diameter_mm": 40.0, "lead_mm": 10.0,
                                                             "ball_mm": [6.35, 6.35], "turns": [4, 4]}).design_spec
    assert len(design.fronts[0].points) >= 25 and np.all(np.diff(design.fronts[0].y) >= -1e-9)
    assert (tmp_path / "pareto-out" / "pareto.png").stat().st_size > 0


def test_example_pareto_front_of_a_catalogue_screw(tmp_path):
    design = _example("pareto_catalogue_screw").main(["--study", str(SMALL), "--points", "5", "--out", str(tmp_path)])
    front, p = design.fronts[0], design.optimum.point
    assert front.pair == "stiffness:drag" and len(front.points) >= 4
    assert all(q.ball_mm == pytest.approx(6.35) and q.turns == 4 for q in front.points + [p])  # the catalogue's screw
    assert np.all(np.diff(front.y) >= -1e-9)  # more rigidity costs drag along the front
    assert p.stiffness_N_per_um == pytest.approx(front.x.max(), rel=1e-5)  # the stiffest design, the front's end
    assert (tmp_path / "pareto.png").stat().st_size > 0 and (tmp_path / "design.json").is_file()


def test_requirement_verdicts_and_their_doctest():
    import doctest

    import piezopreload.artifacts.requirements as module
    from piezopreload.artifacts.requirements import Requirement, missed

    assert doctest.testmod(module).failed == 0
    low = Requirement("deflection", 5.2, 5.0, "um", "max")
    ok = Requirement("rigidity", 1200.0, 800.0, "N/um", "min")
    assert (low.met, ok.met) == (False, True), "the sense of a limit decides the verdict"
    assert abs(low.margin + 0.2) < 1e-12 and ok.margin == 400.0
    assert missed([ok, low]) == (low,)
    assert Requirement.from_dict(low.to_dict()) == low


def test_results_show_themselves_in_a_terminal_and_a_notebook(gain_set):
    """repr fits a line and names what matters; _repr_html_ is a table; plot() is a Figure with something drawn."""
    from matplotlib.figure import Figure

    from piezopreload.artifacts.manifest import StudyRef
    from piezopreload.artifacts.requirements import Requirement
    from piezopreload.artifacts.validation import Criteria, ValidationResult
    from piezopreload.models.actuator import Rig
    from piezopreload.models.closedloop import simulate
    from piezopreload.models.controller import Controller
    from piezopreload.outcome import Headline, StageOutcome, StudyResult

    gs = gain_set[0]
    text = repr(gs)
    assert text.startswith("GainSet(validated: PID Kc") and gs.content_sha256[:12] in text and "\n" not in text
    assert "<table>" in gs._repr_html_() and gs.status in gs._repr_html_()
    study = pp.load_study(SMALL)
    run = simulate(Rig(study.plant), Controller(study.controller, study.plant.sample_period_s),
                   study.references["step"])
    assert repr(run).startswith("ClosedLoopRun(") and "25 -> 60 N" in repr(run) and "<table>" in run._repr_html_()
    metrics = {k: np.array([0.1, 0.2]) for k in ("rise_s", "settling_s", "settling_measured_s", "overshoot_N",
                                                 "tracking_rms_N", "saturated_fraction", "tracking_rms_all_N",
                                                 "tracking_max_N", "peak_voltage_V")}
    metrics["settling_s"] = np.array([0.1, np.nan])  # one plant never settled
    val = ValidationResult(metrics, Criteria(), 2, 0, {})
    assert not val.passed and val.worst.settling_s is None and "failed on 1 plants" in repr(val)
    assert isinstance(val.plot(), Figure) and "<b>missed</b>" in val._repr_html_()
    missed = Requirement("rigidity while cutting", 761.0, 1000.0, "N/um", "min", "[schedule] stiffness_min_N_per_um")
    result = StudyResult(Path("out"), StudyRef("axis.toml", "0" * 64, "axis"),
                         (StageOutcome("design", True, "done", 1.0),), 1.0, Headline(), (missed,))
    assert (result.exit_code == 4 and "1 of 1 requirement missed" in repr(result)
            and "-23.9 %  761 N/um >= 1,000 N/um" in repr(result)
            and "<b>missed</b>" in result._repr_html_())
    fig = result.plot()
    assert isinstance(fig, Figure) and fig.axes[0].patches, "the margin bars are drawn"
    assert result.to_dict()["summary"]["requirements_missed"][0]["margin"] == -239.0
