"""The run's manifest (``pipeline.json``): one type, one reader, the keys users parse kept.

``tests/data/small_axis.pipeline.json`` is the manifest ``piezopreload run tests/data/small_axis.toml`` wrote before the
stages returned typed summaries (every stage done, the system's thermal figures and the learning among them): the
typed manifest reads it and writes it back key for key, value for value, so a script that parses ``pipeline.json``
sees what it always saw.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from piezopreload.artifacts.manifest import StageRecord, StudyRunManifest
from piezopreload.artifacts.summaries import (
    SUMMARIES,
    DesignSummary,
    LearnSummary,
    RigSummary,
    SystemSummary,
    TuneSummary,
    ValidateSummary,
)
from piezopreload.core.errors import ArtifactError
from piezopreload.outcome import Headline

WRITTEN = Path(__file__).parent / "data" / "small_axis.pipeline.json"
ENVELOPE = ("schema", "package_version", "created_utc")


def _body() -> dict:
    doc = json.loads(WRITTEN.read_text())
    return {k: v for k, v in doc.items() if k not in ENVELOPE}


def test_a_written_manifest_reads_into_its_types_and_writes_back_the_same_document():
    body = _body()
    manifest = StudyRunManifest.from_dict(body, str(WRITTEN))
    assert set(manifest.stages) == set(SUMMARIES), "a stage of the run has no summary type"
    for name, record in manifest.stages.items():
        assert isinstance(record.summary, SUMMARIES[name]), name
    back = manifest.to_dict()
    assert json.dumps(back, sort_keys=True) == json.dumps(body, sort_keys=True)
    for name in body["stages"]:  # the keys a script reads, in the order they were written
        assert list(back["stages"][name]["summary"]) == list(body["stages"][name]["summary"]), name


def test_the_typed_summaries_hold_the_numbers_the_json_holds():
    body = _body()
    manifest = StudyRunManifest.from_dict(body)
    stages = body["stages"]
    tune = manifest.summary(TuneSummary)
    assert tune is not None and (tune.Kc_V_per_N, tune.gain_schedule) == (stages["tune"]["summary"]["Kc_V_per_N"],
                                                                          stages["tune"]["summary"]["gain_schedule"])
    validate = manifest.summary(ValidateSummary)
    assert validate is not None and validate.validated == (stages["validate"]["summary"]["status"] == "validated")
    system = manifest.summary(SystemSummary)
    assert system is not None and system.before is not None
    assert system.numbers.tracking_rms_N == stages["system"]["summary"]["tracking_rms_N"]
    written = stages["system"]["summary"]["thermal"]  # a summary written before the words and four figures
    assert system.thermal is not None and system.thermal.to_dict() == written
    assert system.thermal.figure("growth_max_um", "constant") == written["growth_max_um"]["constant"]
    assert system.thermal.drift.passive_left_N is None and system.thermal.ends == {}
    learn = manifest.summary(LearnSummary)
    assert learn is not None and list(learn.trials_per_pass) == stages["learn"]["summary"]["trials_per_pass"]
    rig = manifest.summary(RigSummary)
    assert rig is not None and rig.trip is None and rig.status == stages["rig"]["summary"]["status"]
    # every requirement the stages checked, in stage order: the validation's, then the system's
    expected = [r["name"] for name in ("validate", "system") for r in stages[name]["summary"]["requirements"]]
    assert [r.name for r in manifest.requirements] == expected
    headline = Headline.from_manifest(manifest)
    assert headline.nut_axial_deflection_max_um == stages["system"]["summary"]["deflection_max_um"]
    assert headline.learning_trials == stages["system"]["summary"]["learning_trials"]
    assert headline.rig_tracking_rms_N == stages["rig"]["summary"]["tracking_rms_N"]
    assert headline.gain_set_status == stages["validate"]["summary"]["status"]


def test_a_stage_that_did_not_run_has_no_summary_and_says_why():
    body = _body()
    body["stages"]["learn"] = {"status": "not applicable", "reason": "the study has no [learning] table", "key": "k",
                               "outputs": {}}
    manifest = StudyRunManifest.from_dict(body)
    assert manifest.summary(LearnSummary) is None and manifest.output("learn", "learning") is None
    assert manifest.record("learn").why_not == "the study has no [learning] table"
    assert manifest.summary(DesignSummary) is not None


@pytest.mark.parametrize("edit, named", [
    (lambda d: d["stages"]["tune"]["summary"].pop("Kc_V_per_N"), "stages.tune.summary.Kc_V_per_N' is missing"),
    (lambda d: d["stages"]["validate"]["summary"].update(plants="eight"), "stages.validate.summary.plants"),
    (lambda d: d["stages"]["design"].update(status="finished"), "stages.design.status' must be one of"),
    (lambda d: d["stages"]["rig"]["outputs"]["log_csv"].pop("sha256"), "stages.rig.outputs.log_csv.sha256"),
    (lambda d: d["stages"]["system"]["summary"].update(requirements_met=True), "requirements_met"),
    (lambda d: d["stages"].update(polish={"status": "done", "key": "k", "outputs": {}, "summary": {}}),
     "no stage 'polish'"),
])
def test_a_bad_field_is_refused_by_name(edit, named):
    body = copy.deepcopy(_body())
    edit(body)
    if named == "requirements_met":  # a verdict that contradicts its requirements
        body["stages"]["system"]["summary"]["requirements"][0]["value"] = -1e9
    with pytest.raises(ArtifactError) as exc:
        StudyRunManifest.from_dict(body, "out/pipeline.json")
    assert "out/pipeline.json" in str(exc.value) and named in str(exc.value), str(exc.value)


def test_the_record_the_stage_runner_keeps_reads_as_a_stage_record():
    """What :func:`piezopreload.core.stages.run_stages` keeps for a failed stage reads back with its message."""
    record = StageRecord.read("compare", {"status": "failed", "key": "k", "message": "stage 'compare' failed: x",
                                               "seconds": 0.5, "finished_utc": "2026-01-01T00:00:00Z",
                                               "outputs": {}})
    assert not record.done and record.why_not == "stage 'compare' failed: x" and record.summary is None
