"""The whole-system study end to end (a small copy of studies/machine_axis.toml): the plant from the design, the
schedule tracked, the summary of ``run --json``, and a changed design rebuilding the plant and all after it."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from piezopreload.cli import main
from piezopreload.core.artifacts import read_artifact
from piezopreload.pipeline import STAGES, read_manifest, run_study
from piezopreload.progress import Progress
from piezopreload.study import load_study

SMALL_AXIS = Path(__file__).parent / "data" / "small_axis.toml"


@pytest.fixture(scope="module")
def axis_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("axis") / "out"
    code = main(["run", str(SMALL_AXIS), "--out", str(out), "--json", "--quiet"])
    assert code == 0, "the small whole-system study failed"
    return out


def test_every_stage_runs_and_the_plant_is_the_designs(axis_run, capsys):
    out = axis_run
    manifest = read_manifest(out)
    assert {n: r["status"] for n, r in manifest["stages"].items()} == {s.name: "done" for s in STAGES}
    plant = read_artifact(out / "plant.json", "plant")
    assert plant["design_sha256"] == manifest["stages"]["design"]["outputs"]["design"]["sha256"]
    assert plant["rig"]["hertz_um_per_N23"] > 0 and plant["rig"]["bolt_preload_N"] == 0.0
    gains = read_artifact(out / "gains.json", "gain-set")
    assert gains["plant"]["rig"]["hertz_um_per_N23"] == plant["rig"]["hertz_um_per_N23"], \
        "the gain set was not tuned and validated on the designed plant"
    system = read_artifact(out / "system" / "system.json", "system")
    assert system["inputs"]["gain_set_sha256"] == gains["content_sha256"]
    assert 0 < system["tracking_rms_pct_of_range"] < 100 and system["rigidity_required_N_per_um"] > 0


def test_run_json_summary_names_the_whole_systems_numbers(axis_run, capsys):
    code = main(["run", str(SMALL_AXIS), "--out", str(axis_run), "--json", "--quiet"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ran"] == [], "an unchanged study ran a stage again"
    assert [s["stage"] for s in result["stages"]] == [s.name for s in STAGES]
    summary = result["summary"]
    system = read_artifact(axis_run / "system" / "system.json", "system")
    for key in ("tracking_rms_pct_of_range", "rigidity_min_cutting_N_per_um", "rigidity_required_N_per_um"):
        assert summary[key] == system[key], f"summary.{key} is not the system stage's"


def test_the_learn_stage_learns_on_each_pass_and_the_system_and_the_rig_play_it(axis_run):
    from piezopreload.artifacts.learned import LearnedSignal

    out = axis_run
    learning = read_artifact(out / "learn" / "learning.json", "learning")
    gains = read_artifact(out / "gains.json", "gain-set")
    system = read_artifact(out / "system" / "system.json", "system")
    assert learning["passes"] == len(system["passes"]), "a margin pass of the schedule was not learned"
    for record in learning["pass_records"]:
        signal = LearnedSignal.load(out / "learn" / record["signal"])
        assert signal.gain_set_sha256 == gains["content_sha256"], "a learned signal is not tied to the exported gain set"
        history = [h["tracking_rms_N"] for h in record["history"]]
        # at most [learning] iterations = 3 trials after trial 0, fewer where more no longer paid
        assert len(history) == record["trials"] + 1 <= 4, f"pass {record['pass']}: {record['trials']} trials, {history}"
        assert record["tracking_rms_N"] < 0.5 * record["before_learning_rms_N"], f"pass {record['pass']}: {history}"
    learn = read_manifest(out)["stages"]["learn"]["summary"]
    assert learn["trials"] == sum(learn["trials_per_pass"]) == learning["trials"], "the learn stage does not count trials"
    # the system stage's last pass plays the last pass's signal on its reference: the learning's best iterate, scored
    # as the system scores it (from t = 0: the start, 0 N against the stacks' contact force, counts), but with the
    # run's own noise draw (the trials draw seed + k)
    summary = read_manifest(out)["stages"]["system"]["summary"]
    assert system["tracking_rms_N"] < 0.5 * summary["tracking_rms_N_before_learning"]
    assert summary["tracking_rms_N_before_learning"] == pytest.approx(learning["before_learning_rms_N"])
    last = learning["pass_records"][-1]
    assert system["tracking_rms_N"] == pytest.approx(last["tracking_rms_from_start_N"], rel=0.15), \
        "the system stage's learned run is not the learning's best iterate"
    rig = read_manifest(out)["stages"]["rig"]
    assert rig["summary"]["learned_tracking_rms_measured_N"] is not None, "the rig stage did not play the learned signal back"


def test_a_changed_design_rebuilds_the_plant_and_everything_after_it(axis_run, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(axis_run, out)
    (out / ".lock").unlink(missing_ok=True)
    before = read_manifest(out)["stages"]
    study = load_study(SMALL_AXIS).replace(design={"amp_current_limit_A": 0.08})
    result = run_study(study, out, progress=Progress(stream=io.StringIO()))
    assert set(result["ran"]) >= {"design", "plant", "identify", "tune", "validate", "compare", "learn", "system",
                                  "rig", "report"}, f"a stage after the changed design was not run again: {result['ran']}"
    after = read_manifest(out)["stages"]
    assert after["plant"]["outputs"]["plant"]["sha256"] != before["plant"]["outputs"]["plant"]["sha256"]
    plant = read_artifact(out / "plant.json", "plant")
    assert plant["design_sha256"] == after["design"]["outputs"]["design"]["sha256"]
    assert plant["rig"]["amp_current_limit_A"] == pytest.approx(0.08), "the plant does not carry the new amplifier"


def test_the_tune_stage_chooses_between_the_schedule_and_the_robust_set_and_the_report_shows_it(axis_run):
    """[tuning] schedule_levels: the tuning records both sets' worst cases per level, the gain set is the chosen
    one (a schedule's table in its gains and exports), and the report carries the gain schedule's table and figure."""
    from piezopreload.tuning.schedule import choose

    tuning = read_artifact(axis_run / "tuning.json", "tuning")
    sched = tuning["tuning"]["schedule"]
    refs = load_study(SMALL_AXIS).references
    span = [min(float(refs[k].levels_N.min()) for k in ("step", "trajectory")),
            max(float(refs[k].levels_N.max()) for k in ("step", "trajectory"))]
    assert sched["levels_N"] == span, "the schedule's entries do not span the study's references"
    assert (sched["choice"], sched["reason"]) == choose(sched["levels"], sched["whole_range"])
    for r in sched["levels"]:
        for which in ("robust", "scheduled"):
            assert set(r[which]) >= {"settling_s", "overshoot_N", "tracking_rms_N", "passed"}, r
    gains = read_artifact(axis_run / "gains.json", "gain-set")["gains"]
    assert ("schedule" in gains) == (sched["choice"] == "schedule"), "the gain set is not the chosen set"
    if sched["choice"] == "schedule":
        assert gains["schedule"]["levels_N"] == sched["levels_N"]
        assert "PP_SCHEDULE_LEVELS_N" in (axis_run / "exports" / "pp_gains.h").read_text()
    else:
        assert gains["Kc_V_per_N"] == sched["robust"]["Kc_V_per_N"]
    report = read_artifact(axis_run / "report" / "report.json", "report")
    assert report["schedule"]["choice"] == sched["choice"] and len(report["schedule"]["rows"]) == 3
    assert (axis_run / "report" / "figures" / "gain-schedule.pdf").stat().st_size > 1000


def test_the_tune_stage_s_key_covers_the_validation_limits_only_where_it_chooses_by_them():
    """With a gain schedule the tune stage judges by the [validation] limits, so they are in its key; without, a
    changed limit reruns validate alone, as it always did."""
    from piezopreload.pipeline import _stage_key

    tune = next(s for s in STAGES if s.name == "tune")
    small = Path(__file__).parent / "data" / "small_study.toml"
    for path, scheduled in ((SMALL_AXIS, True), (small, False)):
        study = load_study(path)
        stricter = study.replace(validation={"overshoot_max_N": 1.0})
        changed = _stage_key(tune, study, {}) != _stage_key(tune, stricter, {})
        assert changed == scheduled, f"{path.name}: the tune stage's key {'ignores' if scheduled else 'follows'} " \
                                     "the validation limits"
