"""Every reader, given random and mutated input, reads it or refuses it with a PiezopreloadError that says why.

Never a traceback of another kind, and nothing written by a refused run. The mutations start
from a valid document (a gain set, a hysteresis model, a reference, a study file, a CSV record,
a reference CSV, a load profile, a learned signal, a hysteresis-model file, a run log) and delete a field, replace one
with any JSON value, or cut, duplicate or overwrite a stretch of the text.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rigkit import write_gain_set

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.hysteresis import DataSource, FitError, IdentifiedModel, SolverReport, Units
from piezopreload.artifacts.learned import KIND as LEARNED
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.artifacts.registry import write_artifact
from piezopreload.artifacts.responses import CreepRow, ReproductionRow, ResponseRun, ResponsesRecord
from piezopreload.cli import main
from piezopreload.core.errors import ArtifactError, PiezopreloadError
from piezopreload.core.tables import read_record
from piezopreload.data import __file__ as data_init
from piezopreload.design.study import read_profile
from piezopreload.models.closedloop import Reference
from piezopreload.models.hysteresis import model_from_dict
from piezopreload.rig.runlog import read_run_log
from piezopreload.rig.session import reference_for
from piezopreload.study import default_study, load_study

FAST = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
SLOW = settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**12, 10**12) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8)


def _paths(doc, prefix=()):
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:6]):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw, doc):
    """``doc`` (a JSON tree) with one field deleted or replaced by any JSON value."""
    doc = json.loads(json.dumps(doc))
    paths = _paths(doc)
    path = draw(st.sampled_from(paths))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if draw(st.booleans()) and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = draw(json_values)
    return doc


@st.composite
def mutated_text(draw, text):
    """``text`` with a stretch cut, duplicated or overwritten by random characters."""
    n = len(text)
    i = draw(st.integers(0, n))
    j = draw(st.integers(i, min(n, i + 40)))
    how = draw(st.sampled_from(["cut", "dup", "overwrite", "number"]))
    if how == "cut":
        return text[:i] + text[j:]
    if how == "dup":
        return text[:j] + text[i:j] + text[j:]
    if how == "number":
        return text[:i] + draw(st.sampled_from(["1e309", "-0", "nan", "inf", "1e9", "-1e9", "", ",", "\n"])) + text[j:]
    return text[:i] + draw(st.text(max_size=20)) + text[j:]


def _refused_cleanly(fn, *args):
    """``fn(*args)`` reads or raises a PiezopreloadError with a message; anything else fails the test."""
    try:
        fn(*args)
    except PiezopreloadError as exc:
        assert str(exc).strip(), f"{type(exc).__name__} without a message"


@pytest.fixture(scope="module")
def gain_doc(tmp_path_factory, study, feedforward):
    path = write_gain_set(tmp_path_factory.mktemp("g") / "g.json", study, feedforward)
    return path, json.loads(path.read_text())


@FAST
@given(data=st.data())
def test_gain_set_reader(gain_doc, data):
    path, doc = gain_doc
    bad = data.draw(mutated(doc))
    _refused_cleanly(GainSet.from_dict, bad)
    _refused_cleanly(GainSet.parse, json.dumps(bad))
    _refused_cleanly(GainSet.parse, data.draw(mutated_text(path.read_text())))
    _refused_cleanly(GainSet.parse, data.draw(st.text(max_size=60)))


@FAST
@given(data=st.data())
def test_hysteresis_model_reader(feedforward, data):
    _refused_cleanly(model_from_dict, data.draw(mutated(feedforward.to_dict())))
    _refused_cleanly(model_from_dict, data.draw(json_values))


@FAST
@given(data=st.data())
def test_reference_reader(study, data):
    _refused_cleanly(Reference.from_dict, data.draw(mutated(study.references["trajectory"].to_dict())))
    _refused_cleanly(Reference.from_dict, data.draw(json_values))


@SLOW
@given(data=st.data())
def test_study_file_reader(tmp_path_factory, data):
    text = Path(default_study()).read_text()
    path = tmp_path_factory.mktemp("s") / "study.toml"
    path.write_text(data.draw(mutated_text(text)))
    _refused_cleanly(load_study, path)


_RECORD = "".join(Path(data_init).with_name("hysteresis_v_150_1hz.csv").read_text().splitlines(True)[:120])


@FAST
@given(data=st.data())
def test_csv_record_reader(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("r") / "record.csv"
    path.write_text(data.draw(mutated_text(_RECORD)))
    _refused_cleanly(read_record, path)


_REF = "time_s,force_N\n0,25\n0.5,60\n1.0,40\n1.5,60\n"
_PROFILE = "time_s,axial_load_N,speed_rpm\n0,1000,100\n1,2500,300\n2,-800,50\n3,0,0\n"


@FAST
@given(data=st.data())
def test_reference_csv_and_load_profile_readers(tmp_path_factory, gain_doc, data):
    gain_set = GainSet.load(gain_doc[0])
    folder = tmp_path_factory.mktemp("c")
    ref, profile = folder / "ref.csv", folder / "profile.csv"
    ref.write_text(data.draw(mutated_text(_REF)))
    profile.write_text(data.draw(mutated_text(_PROFILE)))
    _refused_cleanly(reference_for, str(ref), gain_set)
    _refused_cleanly(read_profile, profile)


@SLOW
@given(data=st.data())
def test_rig_run_with_a_mutated_reference_exits_0_2_or_3_and_a_refusal_writes_nothing(tmp_path_factory, gain_doc,
                                                                                      data, capsys):
    folder = tmp_path_factory.mktemp("run")
    ref = folder / "ref.csv"
    ref.write_text(data.draw(mutated_text(_REF)))
    logs = folder / "runs"
    code = main(["rig", "run", str(gain_doc[0]), "--fast", "--reference", str(ref), "--log-dir", str(logs)])
    err = capsys.readouterr().err
    assert code in (0, 2, 3), err
    assert "Traceback" not in err and "internal failure" not in err, err
    if code == 2:
        assert err.startswith("error: ") and not (logs.exists() and any(logs.iterdir())), "a refused run wrote a log"


@pytest.fixture(scope="module")
def learned_doc(tmp_path_factory, gain_doc):
    """A learned signal for the gain set on a short step of its own (200 samples), as 'learn --out' writes one."""
    ref = Reference.step(25.0, 40.0, 0.05, 0.2)
    n = int(round(ref.duration_s / 1e-3)) + 1
    k = np.arange(n)
    path = tmp_path_factory.mktemp("l") / "learned.json"
    LearnedSignal(np.sin(k / 20.0), ref.at(k * 1e-3), 1e-3, ref, GainSet.load(gain_doc[0]).content_sha256,
                  iteration=1).save(path)
    return path, LearnedSignal.load(path).to_dict()


def _rehashed(path, body):
    """``body`` in a valid artifact envelope (its hash right), so the reader's field checks are what it meets."""
    try:
        write_artifact(path, LEARNED, body)
    except (ValueError, TypeError):  # the writer refuses it (a required field gone, a value JSON cannot hold)
        path.write_text(json.dumps(body, default=str))


@FAST
@given(data=st.data())
def test_learned_signal_reader(tmp_path_factory, learned_doc, data):
    path, doc = learned_doc
    folder = tmp_path_factory.mktemp("m")
    _refused_cleanly(LearnedSignal.from_dict, data.draw(mutated(doc)))
    _refused_cleanly(LearnedSignal.from_dict, data.draw(json_values))
    (folder / "cut.json").write_text(data.draw(mutated_text(path.read_text())))
    _refused_cleanly(LearnedSignal.load, folder / "cut.json")
    _rehashed(folder / "body.json", data.draw(mutated(doc)))
    _refused_cleanly(LearnedSignal.load, folder / "body.json")


@SLOW
@given(data=st.data())
def test_rig_run_with_a_mutated_learned_signal_exits_0_2_or_3_and_a_refusal_writes_nothing(tmp_path_factory, gain_doc,
                                                                                          learned_doc, data, capsys):
    folder = tmp_path_factory.mktemp("runl")
    bad = folder / "learned.json"
    if data.draw(st.booleans()):
        _rehashed(bad, data.draw(mutated(learned_doc[1])))
    else:
        bad.write_text(data.draw(mutated_text(learned_doc[0].read_text())))
    logs = folder / "runs"
    code = main(["rig", "run", str(gain_doc[0]), "--fast", "--learned", str(bad), "--log-dir", str(logs)])
    err = capsys.readouterr().err
    assert code in (0, 2, 3), err
    assert "Traceback" not in err and "internal failure" not in err, err
    if code == 2:
        assert err.startswith("error: ") and not (logs.exists() and any(logs.iterdir())), "a refused run wrote a log"


@pytest.mark.parametrize("key, value", [("iteration", math.inf), ("iteration", -3), ("sample_period_s", 1e-300),
                                        ("preview_s", math.nan), ("method", None), ("ff_extra_V", "abc"),
                                        ("inputs", 5), ("gain_set_sha256", 5)])
def test_the_learned_signal_reader_names_the_field(learned_doc, key, value):
    """Mutations hypothesis reaches only now and then, each refused by an ArtifactError naming its field."""
    doc = {**learned_doc[1], key: value}
    with pytest.raises(ArtifactError, match=key):
        LearnedSignal.from_dict(doc, "learned.json")


def test_a_learned_setpoint_beyond_the_safe_range_is_refused_before_arming(tmp_path, gain_doc, learned_doc, capsys):
    """The learned plan is what the loop runs: a level of 1e9 N in it is refused as a reference's would be."""
    body = json.loads(json.dumps(learned_doc[1]))
    body["setpoint_N"][100] = 1e9
    _rehashed(tmp_path / "learned.json", body)
    logs = tmp_path / "runs"
    assert main(["rig", "run", str(gain_doc[0]), "--fast", "--learned", str(tmp_path / "learned.json"),
                 "--log-dir", str(logs)]) == 2
    err = capsys.readouterr().err
    assert "setpoint_N" in err and "level 101" in err and "refused before arming" in err, err
    assert not logs.exists() or not any(logs.iterdir()), "a refused run wrote a log"


@FAST
@given(data=st.data())
def test_hysteresis_model_file_reader(tmp_path_factory, feedforward, data):
    folder = tmp_path_factory.mktemp("h")
    path = folder / "model.json"
    body = IdentifiedModel(feedforward, DataSource("simulated", "0" * 64, excitation={"v_max_V": 100.0}), Units(),
                           100.0, (0.0, 100.0), FitError(0.5, 1.5, (0.0, 6.0), 6001),
                           SolverReport("optimal", True, 9, 0.01, 0.2)).to_dict()
    write_artifact(path, "hysteresis-model", body)
    IdentifiedModel.load(path)  # the unmutated document reads
    (folder / "cut.json").write_text(data.draw(mutated_text(path.read_text())))
    _refused_cleanly(IdentifiedModel.load, folder / "cut.json")
    try:
        write_artifact(folder / "body.json", "hysteresis-model", data.draw(mutated(body)))
    except (ValueError, TypeError):  # the writer refuses it: nothing to read
        return
    _refused_cleanly(IdentifiedModel.load, folder / "body.json")


@pytest.fixture(scope="module")
def run_log_text(tmp_path_factory, gain_doc):
    """A short run's log as 'rig run' writes it (its first 60 lines), the input of 'learn --from-run'."""
    folder = tmp_path_factory.mktemp("log")
    assert main(["rig", "run", str(gain_doc[0]), "--fast", "--log-dir", str(folder)]) == 0
    return "".join(next(folder.glob("*.csv")).read_text().splitlines(True)[:60])


@FAST
@given(data=st.data())
def test_run_log_reader(tmp_path_factory, run_log_text, data):
    path = tmp_path_factory.mktemp("rl") / "run.csv"
    path.write_text(data.draw(mutated_text(run_log_text)))
    _refused_cleanly(read_run_log, path)


def test_the_mutations_reach_the_readers_checks(study):
    """Not every mutation is refused by the first check: a reference with a NaN level is refused by its own words."""
    doc = study.references["trajectory"].to_dict()
    key = next(k for k, v in doc.items() if isinstance(v, list) and v and isinstance(v[0], float))
    doc[key][1] = math.nan
    with pytest.raises(PiezopreloadError, match=key):
        Reference.from_dict(doc)


def _responses_record():
    runs = tuple(ResponseRun(g, c, ref, f"responses/{g}_{c}_{ref}.csv", settling_s=None if g == "study" else 0.05,
                             overshoot_N=1.5, tracking_rms_N=2.0)
                 for g in ("study", "tuned") for c in ("pid", "ff+pid") for ref in ("step", "trajectory"))
    return ResponsesRecord(runs, 1.5, "measured_N", 7, (ReproductionRow("ff+pid", "settling_s", 0.06, None, 0.05),),
                           (CreepRow("tuned", True, "modified+creep", "step", 0.05, 1.5, 2.0, 1.0),), {"seed": 7})


def test_the_responses_record_round_trips_and_finds_its_runs(tmp_path):
    record = _responses_record()
    back = ResponsesRecord.load(record.save(tmp_path / "responses.json"))
    assert back == record
    assert (back.run("tuned", "ff+pid", "step").settling_s == 0.05
            and back.run("study", "pid", "step").settling_s is None)
    with pytest.raises(ArtifactError, match="no run of tuned pid on the ramp"):
        back.run("tuned", "pid", "ramp")
    doc = record.to_dict()
    for key, value in (("inputs", [1]), ("band_N", 0), ("runs", {}), ("seed", 1.5)):
        with pytest.raises(ArtifactError, match=f"'{key}'"):
            ResponsesRecord.from_dict({**doc, key: value})


@FAST
@given(data=st.data())
def test_responses_record_reader(data):
    _refused_cleanly(ResponsesRecord.from_dict, data.draw(mutated(_responses_record().to_dict())))
    _refused_cleanly(ResponsesRecord.from_dict, data.draw(st.dictionaries(st.text(max_size=6), json_values)))
