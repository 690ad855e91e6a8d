"""The one-command study (piezopreload run) and its PDF report, end to end on a small study.

One session fixture runs ``tests/data/small_study.toml`` (the paper's rig and gains, short
references, 8 Monte Carlo plants, 5-point fronts: about a minute, most of it the PID tuning);
the other tests copy its output folder and change one thing each.
"""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.manifest import StudyRunManifest
from piezopreload.artifacts.registry import read_artifact
from piezopreload.artifacts.responses import ResponsesRecord
from piezopreload.artifacts.summaries import ValidateSummary
from piezopreload.cli import main
from piezopreload.core.errors import InputError
from piezopreload.pipeline import STAGES, run_study
from piezopreload.progress import Progress
from piezopreload.study import load_study

pypdf = pytest.importorskip("pypdf", reason="pypdf (the test extra) reads the report back")

pytestmark = pytest.mark.slow  # the small study runs end to end (tens of seconds), each test on a copy of its folder

SMALL = Path(__file__).parent / "data" / "small_study.toml"
TEMPLATE = Path(__file__).parents[1] / "reports" / "report.typ"


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("study") / "out"
    log = io.StringIO()
    result = run_study(SMALL, out, progress=Progress(stream=log))
    return out, result, log.getvalue()


def _copy(small_run, tmp_path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(small_run[0], out)
    (out / ".lock").unlink(missing_ok=True)
    return out


def _pdf_text(path: Path) -> tuple[list[str], str]:
    reader = pypdf.PdfReader(path)
    pages = [p.extract_text() or "" for p in reader.pages]
    return pages, " ".join(" ".join(pages).split())


def test_the_small_study_runs_every_stage_and_leaves_its_artifacts(small_run):
    out, result, log = small_run
    study = load_study(SMALL)
    applicable = [s.name for s in STAGES if s.applies(study) is None]
    assert list(result.ran) == applicable and not {"plant", "learn", "system"} & set(applicable)
    for i, stage in enumerate(STAGES, start=1):
        assert f"[{i}/{len(STAGES)}] {stage.name}:" in log
    assert f"the study's outputs are in {out.resolve()}/" in log
    manifest = StudyRunManifest.load(out)
    assert {name: r.status for name, r in manifest.stages.items()} == {
        s.name: "done" if s.name in applicable else "not applicable" for s in STAGES}
    gains = read_artifact(out / "gains.json", "gain-set")
    assert gains["status"] == "validated" and result.gain_set_sha256 == gains["content_sha256"]
    for name in ("gains.si.json", "gains.labview.txt", "pp_gains.h"):
        assert gains["content_sha256"] in (out / "exports" / name).read_text()
    run_log = result.rig_log
    assert run_log.parent == (out / "runs") and run_log.stat().st_size > 0
    sidecar = read_artifact(run_log.with_suffix(".json"), "rig-run")
    assert sidecar["status"] == "completed" and sidecar["gain_set_sha256"] == gains["content_sha256"]
    assert (out / "report.pdf").read_bytes().startswith(b"%PDF")


def test_the_compare_stage_reproduces_what_reproduce_prints(small_run):
    """The paper's gains in the report's table == ``piezopreload reproduce`` (its own feedforward identification)."""
    out = small_run[0]
    rows = ResponsesRecord.load(out / "responses" / "responses.json").reproduction
    ref = {(r.controller, r.metric): r.simulated for r in load_study(SMALL).reproduce().rows}
    assert len(rows) == len(ref) == 6
    for r in rows:
        assert r.study == pytest.approx(ref[(r.controller, r.metric)], abs=1e-12)


def test_the_pdf_holds_its_pages_tables_and_figures(small_run):
    out = small_run[0]
    pdf = out / "report.pdf"
    pages, text = _pdf_text(pdf)
    n = len(pages)
    assert 5 <= n <= 10
    for i, page in enumerate(pages, start=1):  # every page carries "i / n"
        assert f"{i} / {n}" in page
    squeezed = text.replace(" ", "")

    # the tables' numbers, formatted here from the artifacts (3 significant digits, 4 for gains)
    for r in ResponsesRecord.load(out / "responses" / "responses.json").reproduction:
        for col in (r.published, r.study, r.tuned):
            assert f"{col:.3g}" in text, (r, col)
    gains = read_artifact(out / "gains.json", "gain-set")
    g = gains["gains"]
    for value in (g["Kc_V_per_N"], g["Ti_s"], g["Td_s"], g["labview"]["Ti_min"], g["labview"]["Td_min"]):
        assert f"{value:.4g}" in text
    assert gains["content_sha256"] in squeezed
    validation = read_artifact(out / "validation.json", "validation")
    assert f"{validation['summary']['settling_s']['worst']:.3g}" in text
    optimum = read_artifact(out / "design" / "design.json", "design")["optimum"]["point"]
    assert f"{optimum['ball_mm']:.4g}" in text and f"{optimum['contact_angle_deg']:.3g}" in text
    study = load_study(SMALL)
    assert study.sha256 in squeezed and study.title.split(":")[0] in text

    # every figure the report names is in the PDF: its file, its caption, and its own text
    report = read_artifact(out / "report" / "report.json", "report")
    names = list(report["figures"])
    assert set(names) == {"step", "tracking", "hysteresis", "inverse", "monte-carlo", "rig-run", "stiffness", "pareto",
                          "schedule", "natural-frequency"}, \
        "the paper's rig has no whole-system, learning or gain-schedule figure; every other one"
    forms = 0
    for page in pypdf.PdfReader(pdf).pages:
        xobjects = page.get("/Resources", {}).get("/XObject", {})
        forms += sum(1 for x in xobjects.values() if x.get_object().get("/Subtype") == "/Form")
    assert forms == len(names)
    for name in names:
        figure = out / "report" / report["figures"][name]["file"]
        caption = " ".join(report["figures"][name]["caption"].split())
        assert caption[:60].replace(" ", "") in squeezed, name
        own = [line.strip() for line in (pypdf.PdfReader(figure).pages[0].extract_text() or "").splitlines()]
        label = max((s for s in own if not re.fullmatch(r"[-−\d.,e+ ]*", s)), key=len)
        assert label.replace(" ", "") in squeezed, (name, label)


@pytest.mark.skipif(shutil.which("pdftoppm") is None, reason="pdftoppm (poppler-utils) is not installed")
def test_the_first_page_renders_to_an_image(small_run, tmp_path):
    import matplotlib.image as mpimg

    subprocess.run(["pdftoppm", "-png", "-r", "40", "-f", "1", "-l", "1", str(small_run[0] / "report.pdf"),
                    str(tmp_path / "page")], check=True, timeout=60)
    png = next(tmp_path.glob("page*.png"))
    img = mpimg.imread(png)
    h, w = img.shape[:2]
    assert h / w == pytest.approx(297 / 210, rel=0.02)  # A4
    ink = img[..., :3].mean(axis=2) < 0.5
    assert 0.005 < ink.mean() < 0.5  # text on a white page, not blank, not black


def test_a_second_run_reruns_nothing_and_says_so(small_run, tmp_path, capsys):
    out = _copy(small_run, tmp_path)
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.rglob("*") if p.is_file() and p.name != ".lock"}
    code = main(["run", str(SMALL), "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0
    result = json.loads(captured.out)
    assert result["ran"] == [] and all(s["status"] in ("up to date", "not applicable") for s in result["stages"])
    assert "nothing to run: every stage is up to date" in captured.err
    after = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.rglob("*") if p.is_file() and p.name != ".lock"}
    assert after == before


def test_study_run_takes_a_function_for_its_progress_as_every_step_does(small_run, tmp_path):
    """``study.run(progress=print)`` gives each line to the function (it took only a Progress object before)."""
    out = _copy(small_run, tmp_path)
    lines: list[str] = []
    result = load_study(SMALL).run(out, progress=lines.append)
    assert result.ran == ()
    assert lines[0].startswith("[1/") and "up to date, not run again" in lines[0]
    assert any(line.startswith("nothing to run: every stage is up to date") for line in lines)
    assert not any("\n" in line for line in lines)


def test_a_changed_table_reruns_only_the_stages_that_read_it(small_run, tmp_path):
    out = _copy(small_run, tmp_path)
    study = tmp_path / "study.toml"
    study.write_text(SMALL.read_text().replace("pareto_points = 5", "pareto_points = 4"))
    result = run_study(study, out, progress=Progress(quiet=True))
    assert list(result.ran) == ["design", "report"]
    fronts = read_artifact(out / "design" / "design.json", "design")["fronts"]
    assert {len(f["points"]) for f in fronts} <= {4}
    # a changed or missing output is made again, and only what depends on it follows
    (out / "exports" / "gains.labview.txt").write_text("edited by hand\n")
    assert run_study(study, out, progress=Progress(quiet=True)).ran == ("export",)


def test_a_missed_validation_is_a_verdict_the_study_reports_and_exits_4(small_run, tmp_path, capsys):
    out = _copy(small_run, tmp_path)
    before = StudyRunManifest.load(out).stages
    study = tmp_path / "study.toml"
    study.write_text(SMALL.read_text().replace("plants = 8", "plants = 8\nsettling_max_s = 0.02"))
    code = main(["run", str(study), "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 4, "a study that ran but missed a requirement exits 4"
    assert "missed: worst settling time over 8 Monte Carlo plants:" in text and "against at most 0.02 s" in text
    manifest = StudyRunManifest.load(out)
    after = manifest.stages
    for name in ("identify", "design", "tune"):
        assert after[name] == before[name]
    validate = manifest.summary(ValidateSummary)
    assert validate is not None and validate.status == "candidate" and not validate.validated
    for name in ("export", "rig"):  # a candidate is never exported nor run, and the record says why
        assert after[name].status == "not applicable" and "settling" in (after[name].reason or "")
    assert after["report"].done and (out / "report.pdf").is_file()
    assert read_artifact(out / "gains.json", "gain-set")["status"] == "candidate"
    assert main(["export", str(out / "gains.json"), "--format", "labview"]) == 2
    capsys.readouterr()
    assert main(["run", str(study), "--out", str(out), "--json"]) == 4
    summary = json.loads(capsys.readouterr().out)["summary"]
    assert summary["requirements_met"] is False
    assert [r["name"] for r in summary["requirements_missed"]] == ["worst settling time over 8 Monte Carlo plants"]
    assert summary["requirements_missed"][0]["margin"] < 0


def test_an_internal_failure_names_its_stage_and_exits_1(small_run, tmp_path, capsys, monkeypatch):
    import piezopreload.tuning.compare as compare

    out = _copy(small_run, tmp_path)
    (out / "responses" / "responses.json").unlink()  # the compare stage runs again ...

    def broken(*args, **kwargs):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(compare, "simulate", broken)  # ... and meets a bug
    code = main(["run", str(SMALL), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "stage 'compare' failed: ZeroDivisionError: simulated bug" in err
    assert StudyRunManifest.load(out).status("compare") == "failed"


def test_report_renders_again_from_the_artifacts_alone(small_run, tmp_path, capsys, monkeypatch):
    import piezopreload.steps as steps
    import piezopreload.tuning.compare as compare
    import piezopreload.tuning.feedforward as feedforward

    out = _copy(small_run, tmp_path)
    before = StudyRunManifest.load(out).stages
    (out / "report.pdf").unlink()
    for module, name in ((compare, "simulate"), (steps, "simulate_loop"), (steps, "identify_feedforward"),
                         (steps, "optimise"), (feedforward, "identify_feedforward"),
                         (feedforward, "identify"), (feedforward, "simulate_open_loop")):
        monkeypatch.setattr(module, name, lambda *a, **k: pytest.fail("report recomputed a stage"))
    assert main(["report", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ran"] == ["report"] and Path(result["report"]).is_file()
    after = StudyRunManifest.load(out).stages
    assert {k: v for k, v in after.items() if k != "report"} == {k: v for k, v in before.items() if k != "report"}
    assert main(["report", str(tmp_path)]) == 2
    assert "not a study's output folder" in capsys.readouterr().err


@pytest.mark.parametrize("edit, expected", [
    (("[rig_run]", "[rig_run]\nspeed = 3"), r"small_study.toml:\d+: 'rig_run.speed' is an unknown key"),
    (("plants = 8", 'plants = "8"'), r":\d+: 'validation.plants' must be an integer >= 1 and <= 100000, got '8'"),
    (("plants = 8", "plants = 0"), r":\d+: 'validation.plants' must be an integer >= 1 and <= 100000, got 0"),
    (('formats = ["json", "labview", "c-header"]', 'formats = ["pdf"]'),
     r":\d+: 'export.formats' must be a list of strings from json"),
    (('reference = "step"', 'reference = "ramp"'), r":\d+: 'rig_run.reference' must be step, trajectory, schedule or"),
    (("[rig_run]", "[tuning]\nms_max = 0.9\n\n[rig_run]"), r":\d+: 'tuning.ms_max' must be a number > 1, got 0.9"),
    (("n_operators = 20", 'n_operators = 20\ndata = "nowhere.csv"'),
     r":\d+: 'feedforward.data' names .*nowhere.csv, which is not a file"),
])
def test_a_bad_study_is_refused_on_load_with_its_key_and_line(tmp_path, capsys, edit, expected):
    study = tmp_path / "small_study.toml"
    text = SMALL.read_text()
    assert edit[0] in text
    study.write_text(text.replace(edit[0], edit[1], 1))
    code = main(["run", str(study), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1
    assert re.search(expected, err), err
    assert not (tmp_path / "out" / "pipeline.json").exists()
    line = int(re.search(r"small_study.toml:(\d+):", err).group(1))
    key = re.search(r"'([a-z_]+)\.([a-z_]+)'", err).group(2)
    assert key in study.read_text().splitlines()[line - 1]


def test_one_run_at_a_time_per_folder(tmp_path, capsys):
    fcntl = pytest.importorskip("fcntl", reason="the lock is POSIX flock")
    out = tmp_path / "out"
    out.mkdir()
    with open(out / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(["run", str(SMALL), "--out", str(out)]) == 2
    assert "another 'piezopreload run' or 'report' is writing this folder" in capsys.readouterr().err


def test_a_folder_holding_another_study_is_refused_by_name_or_cleared_with_overwrite(small_run, tmp_path, capsys):
    """One folder, one study: the machine axis into the small study's folder is refused before anything is written
    (exit 2, one line naming the folder, the study it holds and the two fixes); with --overwrite the small study's
    files go (what its manifest records, the rig's logs, the folders left empty) and a file of the user's stays."""
    from piezopreload.pipeline import _one_study_per_folder

    out = _copy(small_run, tmp_path)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main(["run", "machine_axis", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {out}: holds the outputs of the study 'small'"), err
    assert "not of 'machine_axis'" in err and "--out" in err and "--overwrite" in err, err
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"}  # the folder's lock
    assert after == before, "a refused run wrote into the folder"
    with pytest.raises(InputError, match="holds the outputs of the study 'small'"):
        load_study("machine_axis").run(out)
    (out / "notes.txt").write_text("the user's own")
    _one_study_per_folder(out, load_study("machine_axis"), True, Progress(stream=io.StringIO()))
    left = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.name != ".lock")
    assert left == ["notes.txt"], left
    # the same study, changed or not, runs into its own folder as ever
    _one_study_per_folder(_copy(small_run, tmp_path / "again"), load_study(SMALL), False, Progress())


def test_measured_feedforward_data_is_identified_and_hashed(small_run, tmp_path):
    """``[feedforward] data``: the identify stage reads a measured V -> N loop (here the small run's own)."""
    loop = tmp_path / "loop.csv"
    cols = np.loadtxt(small_run[0] / "feedforward" / "loop.csv", delimiter=",", skiprows=2)
    np.savetxt(loop, cols[:, :3], delimiter=",", header="time_s,voltage_V,force_N", comments="", fmt="%.9g")
    study = tmp_path / "study.toml"
    study.write_text(SMALL.read_text().replace("n_operators = 20", 'n_operators = 20\ndata = "loop.csv"'))
    out = _copy(small_run, tmp_path)
    outputs = load_study(study).identify_feedforward().save(out / "feedforward")
    doc = read_artifact(outputs["model"], "hysteresis-model")
    assert doc["inputs"]["data"]["kind"] == "measured"
    assert doc["inputs"]["data"]["sha256"] == __import__("hashlib").sha256(loop.read_bytes()).hexdigest()
    simulated = read_artifact(small_run[0] / "feedforward" / "model.json", "hysteresis-model")
    # the same loop gives the same QP and so the same weights
    assert np.allclose(doc["model"]["weights"], simulated["model"]["weights"], atol=1e-6)


def test_report_typesets_an_edited_template_and_names_a_broken_one(small_run, tmp_path, capsys):
    out = _copy(small_run, tmp_path)
    edited = tmp_path / "mine.typ"
    edited.write_text((out / "report" / "report.typ").read_text().replace("= Summary", "= Summary for the shop floor"))
    assert main(["report", str(out), "--template", str(edited), "--quiet"]) == 0
    assert "Summary for the shop floor" in _pdf_text(out / "report.pdf")[1]
    before = (out / "report.pdf").read_bytes()
    edited.write_text("#let d = json(\"report.json\")\n#d.no_such_field\n")
    assert main(["report", str(out), "--template", str(edited), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "error: stage 'report' failed:" in err and "Typst could not compile" in err and "no_such_field" in err
    assert (out / "report.pdf").read_bytes() == before  # the last good report stays


@pytest.fixture(scope="module")
def creep_run(tmp_path_factory):
    """The small study with ``[feedforward] kind = "modified"`` and ``creep = true``, run through every stage."""
    folder = tmp_path_factory.mktemp("creep")
    study = folder / "study.toml"
    study.write_text(SMALL.read_text().replace("n_operators = 20", 'n_operators = 20\nkind = "modified"\ncreep = true'))
    out = folder / "out"
    run_study(study, out, progress=Progress(stream=io.StringIO()))
    return study, out


def test_a_study_asking_for_creep_compensates_it_and_reports_what_it_buys(creep_run):
    study, out = creep_run
    model_doc = read_artifact(out / "feedforward" / "model.json", "hysteresis-model")
    assert model_doc["model"]["kind"] == "modified+creep"
    plain = model_doc["identification"]["without_creep"]
    assert (plain["model"]["kind"] == "modified"
            and plain["fit"]["rms_pct"] > model_doc["identification"]["fit"]["rms_pct"])
    gains = GainSet.load(out / "gains.json")
    assert gains.feedforward is not None and gains.feedforward.kind == "modified+creep"
    assert "PP_CREEP_TIME_CONSTANTS_S" in (out / "exports" / "pp_gains.h").read_text()
    responses = ResponsesRecord.load(out / "responses" / "responses.json")
    rows = {(r.gains, r.creep, r.reference): r for r in responses.creep_effect}
    assert (set(rows)
            == {(g, c, ref) for g in ("study", "tuned") for c in (False, True) for ref in ("step", "trajectory")})
    runs = {(r.gains, r.reference): r for r in responses.runs if r.controller == "ff+pid"}
    for (g, ref), r in runs.items():  # with creep, the comparison is the compare stage's own FF + PID run
        for key in ("settling_s", "overshoot_N", "tracking_rms_N"):
            assert getattr(rows[(g, True, ref)], key) == pytest.approx(getattr(r, key), abs=1e-12), (g, ref, key)
    # the rig's truth creeps: compensating it settles the paper's FF + PID step sooner
    assert rows[("study", True, "step")].settling_s < rows[("study", False, "step")].settling_s
    _, text = _pdf_text(out / "report.pdf")
    assert "modified+creep" in text and "refitted without creep" in text
    for g in ("study", "tuned"):
        assert f"{rows[(g, False, 'step')].settling_s:.3g}" in text, g


def test_the_feedforward_kind_and_creep_keys_are_checked(tmp_path, capsys):
    study = tmp_path / "study.toml"
    study.write_text(SMALL.read_text().replace("n_operators = 20", 'n_operators = 20\nkind = "bouc-wen"'))
    with pytest.raises(InputError, match=r"'feedforward.kind' must be one of classical, paper-asymmetric, modified"):
        load_study(study)
    study.write_text(SMALL.read_text().replace("n_operators = 20", 'n_operators = 20\ncreep = "yes"'))
    with pytest.raises(InputError, match=r"study.toml:\d+: 'feedforward.creep'"):
        load_study(study)


def test_no_figure_of_the_paper_rig_report_has_a_legend_over_its_data(small_run):
    from figkit import legends_over_ink, report_figures

    covered = {name: found for name, fig in report_figures(small_run[0]) if (found := legends_over_ink(fig))}
    assert not covered, covered


def test_run_prints_the_gain_set_s_content_hash_as_that(small_run, capsys):
    """'gain set: ... (content hash 1234...)': the hash of the gain set's fields, which every artifact that uses it
    names; not the file's SHA-256 (sha256sum gives another), so it is not called that."""
    import hashlib

    from piezopreload.cli.study import _print_run

    out, result, _ = small_run
    _print_run(result)
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("gain set: ")][0]
    content = GainSet.load(out / "gains.json").content_sha256
    assert f"(content hash {content[:12]}..." in line and "sha256 " not in line, line
    assert hashlib.sha256((out / "gains.json").read_bytes()).hexdigest()[:12] not in line


def test_the_first_page_leads_with_the_designed_screw(small_run):
    """Page 1 of the run's own report names the screw's size and lead, the nuts and the contact angle, from the
    design stage's record, before the headline figures; the verdicts carry no config-key text."""
    out = small_run[0]
    pages, _ = _pdf_text(out / "report.pdf")
    first = " ".join(pages[0].split())
    study = load_study(SMALL)
    point = read_artifact(out / "design" / "design.json", "design")["optimum"]["point"]
    spec = study.design_spec
    screw = f"{spec.nominal_diameter_mm:g} x {spec.lead_mm:g} mm"
    assert f"{screw} screw" in first, first[:500]
    assert f"contact angle {point['contact_angle_deg']:.3g}°" in first
    assert f"{point['turns']:.0f} loaded turns x {point['balls_per_turn']:.0f} balls" in first
    report = read_artifact(out / "report" / "report.json", "report")
    assert report["lead"] and not any("[validation]" in v for v in report["verdicts"])
    assert first.index(screw) < first.index(" settle in ")  # the design before the step's headline
