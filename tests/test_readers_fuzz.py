"""Every reader, given random and mutated input, reads it or refuses it with a PiezopreloadError that says why.

Never a traceback of another kind, and nothing written by a refused run. The mutations start
from a valid document (a gain set, a hysteresis model, a reference, a study file, a CSV record,
a reference CSV, a load profile) and delete a field, replace one with any JSON value, or cut,
duplicate or overwrite a stretch of the text.
"""

import json
import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rigkit import write_gain_set

from piezopreload.cli import main
from piezopreload.core.errors import PiezopreloadError
from piezopreload.core.tables import read_record
from piezopreload.data import __file__ as data_init
from piezopreload.design.study import read_profile
from piezopreload.models.closedloop import Reference
from piezopreload.models.gainset import GainSet
from piezopreload.models.hysteresis import model_from_dict
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


def test_the_mutations_reach_the_readers_checks(study):
    """Not every mutation is refused by the first check: a reference with a NaN level is refused by its own words."""
    doc = study.references["trajectory"].to_dict()
    key = next(k for k, v in doc.items() if isinstance(v, list) and v and isinstance(v[0], float))
    doc[key][1] = math.nan
    with pytest.raises(PiezopreloadError, match=key):
        Reference.from_dict(doc)
