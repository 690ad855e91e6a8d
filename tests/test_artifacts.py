"""The artifact records: each reads through its one declared reader, in one message format, and the kinds'
required fields are the declarations' own.

The documents in ``tests/data/artifacts/`` were written by the package before its records declared their
fields (``piezopreload run`` on ``tests/data/small_study.toml`` and ``small_axis.toml``, ``piezopreload
sweep``; see the folder's README): they must still read, and write back as they were.
"""

import gzip
import json
import re
from dataclasses import replace
from pathlib import Path

import pytest

import piezopreload.artifacts  # noqa: F401 (every record's module, for _records())
from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.hysteresis import IdentifiedModel
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.registry import KINDS, read_artifact
from piezopreload.artifacts.responses import ResponsesRecord
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.sweep import PointFigures, SweepRecord
from piezopreload.artifacts.tuning import TuningResult
from piezopreload.artifacts.validation import ValidationResult
from piezopreload.core.artifacts import HASH_FIELD, content_hash
from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Artifact, Record, entry, record
from piezopreload.core.stagecache import CacheEntry

DATA = Path(__file__).parent / "data" / "artifacts"
FILES = {"gains.json": GainSet, "model.json": IdentifiedModel, "tuning.json": TuningResult,
         "validation.json": ValidationResult, "responses.json": ResponsesRecord, "run.json": RigRunRecord,
         "plant.json": DesignedPlant, "learning.json": LearningRecord, "sweep.json": SweepRecord,
         "cache-entry.json": CacheEntry, "design.json.gz": DesignRecord}
ENVELOPE = {"schema", "package_version", "created_utc", HASH_FIELD}
#: the documents no record declares yet (the run's manifest, the two reports): their fields are listed by hand
UNDECLARED = {"study-run", "report", "sweep-report"}


def _records(cls=Artifact):
    """The package's artifact records (not a record a test makes for itself)."""
    for sub in cls.__subclasses__():
        if sub.__module__.startswith("piezopreload."):
            yield sub
        yield from _records(sub)


def _doc(name):
    raw = (DATA / name).read_bytes()
    return json.loads(gzip.decompress(raw) if name.endswith(".gz") else raw)


def _write(path, doc, cls):
    """``doc`` written as it is, its hash made again for a hashed kind (so the reader reaches its fields)."""
    doc = dict(doc)
    if cls.HASHED:
        doc.pop(HASH_FIELD, None)
        doc[HASH_FIELD] = content_hash(doc)
    path.write_text(json.dumps(doc))
    return path


def _one_format(message, path, field, cls):
    """The one format: ``FILE: field 'PATH' (is missing; expected|must be ..., got|is not valid:) ...; AGAIN``."""
    head = re.escape(f"{path}: field '{field}") + r"(?:[.\[][^']*)?'"
    body = r" (is missing; expected .+|must be .+, got .+|is not valid: .+)"
    return re.fullmatch(head + body + re.escape(f"; {cls.AGAIN}") if cls.AGAIN else head + body, message)


def test_every_kind_is_declared_by_one_record_and_KINDS_is_its_required_fields():
    declared = {cls.KIND: cls for cls in _records() if cls.KIND}
    assert set(KINDS) == set(declared) | UNDECLARED, "a kind without a record, or a record not registered"
    for kind, cls in declared.items():
        assert KINDS[kind] == cls.required(), f"KINDS['{kind}'] is not {cls.__name__}'s declaration"
    assert {cls.KIND for cls in FILES.values()} | {"learned-signal", "system"} == set(declared), \
        "a kind with no document written before the declarations in tests/data/artifacts (or its own test)"


def _renamed(doc):
    """``doc`` with the sweep's thermal columns under the names they have had since they were unified with the
    thermal budget's (:attr:`PointFigures.RENAMED`, the one renaming a document written before allows)."""
    names = PointFigures.RENAMED
    if isinstance(doc, dict):
        return {names.get(k, k): _renamed(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [names.get(v, v) if isinstance(v, str) else _renamed(v) for v in doc]
    return doc


@pytest.mark.parametrize("name", FILES)
def test_a_document_written_before_the_declarations_reads_and_writes_back_unchanged(tmp_path, name):
    cls, doc = FILES[name], _doc(name)
    path = _write(tmp_path / name.removesuffix(".gz"), doc, cls) if name.endswith(".gz") else DATA / name
    loaded = cls.load(path)
    doc = _renamed(doc)
    body = loaded.to_dict()
    assert set(doc) - set(body) <= ENVELOPE, f"the record lost {sorted(set(doc) - set(body) - ENVELOPE)}"
    assert {k: doc[k] for k in body} == body, "to_dict() is not the document the record was read from"
    again = cls.from_dict(json.loads(json.dumps(body)), "again")
    assert again.to_dict() == body, "from_dict(to_dict()) is not the record"
    saved = tmp_path / "saved.json"
    loaded.save(saved)
    assert cls.load(saved).to_dict() == body, "save then load is not the record"


@pytest.mark.parametrize("name", FILES)
def test_the_required_fields_are_the_ones_the_reader_refuses_to_miss(tmp_path, name):
    """Leaving out a field KINDS lists is refused in the one format naming file and field; leaving out any other
    field of the document's top level is read (its default): so KINDS is exactly what the reader requires."""
    cls, doc = FILES[name], _doc(name)
    path = tmp_path / "doc.json"
    for key in doc:
        if key in ENVELOPE:
            continue
        _write(path, {k: v for k, v in doc.items() if k != key}, cls)
        if key in KINDS[cls.KIND]:
            with pytest.raises(ArtifactError) as err:
                cls.load(path)
            message = str(err.value)
            assert message.startswith(f"{path}: field '{key}' is missing; expected "), message
            assert _one_format(message, path, key, cls), message
            with pytest.raises(ArtifactError, match=re.escape(f"{path}: field '{key}' is missing; a {cls.KIND} "
                                                              "artifact holds")):
                read_artifact(path, cls.KIND)
        else:
            cls.load(path)  # a field with a default may be left out


def _wrong(value):
    """A JSON value of another type than ``value``."""
    if isinstance(value, bool):
        return "yes"
    if isinstance(value, int | float):
        return "fast"
    if isinstance(value, str):
        return [1.0]
    if isinstance(value, list):
        return {"list": True}
    if isinstance(value, dict):
        return [{"object": 1}]
    return 3.0


@pytest.mark.parametrize("name", FILES)
def test_a_mistyped_field_is_named_in_the_one_format(tmp_path, name):
    """Each top-level field and each field of the objects it holds, given a value of another JSON type, is refused
    with an ArtifactError naming the file and the field's path (never another exception, never read as it was)."""
    cls, doc = FILES[name], _doc(name)
    path = tmp_path / "doc.json"
    tried = 0
    for key, value in doc.items():
        if key in ENVELOPE or value is None:
            continue
        places = [((key,), value)] + ([((key, k), v) for k, v in value.items() if v is not None]
                                      if isinstance(value, dict) else [])
        for where, old in places:
            bad = json.loads(json.dumps(doc))
            holder = bad
            for part in where[:-1]:
                holder = holder[part]
            holder[where[-1]] = _wrong(old)
            _write(path, bad, cls)
            try:
                cls.load(path)
            except ArtifactError as exc:
                message = str(exc)
                assert _one_format(message, path, where[0], cls), message
                tried += 1
            # a value the record does not type (an object kept as it is, the inputs' hashes) may read
    assert tried >= 3, f"only {tried} fields of {name} were refused"


def test_one_message_for_a_mistyped_gain(tmp_path):
    doc = _doc("gains.json")
    doc["gains"]["Ti_s"] = "slow"
    path = _write(tmp_path / "g.json", doc, GainSet)
    with pytest.raises(ArtifactError) as err:
        GainSet.load(path)
    assert str(err.value) == (f"{path}: field 'gains.Ti_s' must be a finite number, got 'slow'; write the gain set "
                              "again with 'piezopreload tune'")


def test_a_gain_set_changed_after_it_was_written_is_refused(tmp_path):
    doc = _doc("gains.json")
    assert GainSet.load(DATA / "gains.json").content_sha256 == doc[HASH_FIELD]
    doc["gains"]["Kc_V_per_N"] *= 2
    path = tmp_path / "g.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match=re.escape(f"{path}: field '{HASH_FIELD}' does not match the content: the "
                                                      "file was changed after it was written")):
        GainSet.load(path)


@record
class _Window(Record):
    """A window of a record."""

    start_s: float = entry("Its start.", unit="s", ge=0)
    samples: tuple[int, ...] = entry("Its sample indices.", size=(1, 3), increasing=True)


@record
class _Fit(Record):
    """A fit."""

    NOUN = "the fit"
    AGAIN = "fit again"
    rms_pct: float = entry("The RMS error.", unit="%", ge=0)
    kind: str = entry("Its kind.", choices=("pi", "mpi"))
    window: _Window | None = entry("Its window.", default=None, omit=True)
    windows: tuple[_Window, ...] = entry("More windows.", default=(), omit=True)
    notes: dict[str, float] = entry("Numbers about it.", default={}, at="about")


@pytest.mark.parametrize("doc, message", [
    ({"kind": "pi"}, "f.json: field 'rms_pct' is missing; expected a finite number >= 0; fit again"),
    ({"rms_pct": -1, "kind": "pi"}, "f.json: field 'rms_pct' must be a finite number >= 0, got -1; fit again"),
    ({"rms_pct": True, "kind": "pi"}, "f.json: field 'rms_pct' must be a finite number >= 0, got true; fit again"),
    ({"rms_pct": 1, "kind": "x"}, "f.json: field 'kind' must be one of pi, mpi, got 'x'; fit again"),
    ({"rms_pct": 1, "kind": "pi", "window": {"start_s": 0}},
     "f.json: field 'window.samples' is missing; expected a list of 1 to 3 whole numbers, strictly increasing; fit "
     "again"),
    ({"rms_pct": 1, "kind": "pi", "windows": [{"start_s": 0, "samples": [1]}, {"start_s": 0, "samples": [2, 1]}]},
     "f.json: field 'windows[1].samples' must be a list of 1 to 3 whole numbers, strictly increasing, got [2, 1]; fit "
     "again"),
    ({"rms_pct": 1, "kind": "pi", "about": {"notes": {"a": "b"}}},
     "f.json: field 'about.notes.a' must be a finite number, got 'b'; fit again"),
    ({"rms_pct": 1, "kind": "pi", "about": 3}, "f.json: field 'about' must be an object, got 3; fit again"),
])
def test_the_one_format_names_the_path_what_was_expected_and_what_came(doc, message):
    with pytest.raises(ArtifactError) as err:
        _Fit.from_dict(doc, "f.json")
    assert str(err.value) == message


def test_a_declared_record_round_trips_and_documents_its_fields():
    fit = _Fit(0.5, "mpi", _Window(1.0, (0, 2)), (_Window(0.0, (1,)),), {"a": 2.0})
    doc = fit.to_dict()
    assert doc == {"rms_pct": 0.5, "kind": "mpi", "window": {"start_s": 1.0, "samples": [0, 2]},
                   "windows": [{"start_s": 0.0, "samples": [1]}], "about": {"notes": {"a": 2.0}}}
    assert _Fit.from_dict(json.loads(json.dumps(doc))) == fit
    assert _Fit.required() == ("rms_pct", "kind")
    assert "Parameters\n    ----------\n    rms_pct : float\n        The RMS error. Unit: %." in _Fit.__doc__
    assert "kind : {'pi', 'mpi'}" in _Fit.__doc__


def test_a_reader_of_two_kinds_names_both_in_the_one_format():
    from piezopreload.artifacts.tuning import warm_start_gains

    assert warm_start_gains(DATA / "tuning.json") == TuningResult.load(DATA / "tuning.json").gains
    assert warm_start_gains(DATA / "gains.json") == GainSet.load(DATA / "gains.json").gains
    with pytest.raises(ArtifactError) as err:
        warm_start_gains(DATA / "model.json")
    assert str(err.value) == (f"{DATA / 'model.json'}: field 'schema' must be the tuning record "
                              "(piezopreload/tuning/1) or the gain set (piezopreload/gain-set/1), got "
                              "'piezopreload/hysteresis-model/1' (a hysteresis-model artifact)")


def test_a_gain_set_written_before_the_filter_order_reads_as_first_order(tmp_path):
    """The stored gain set holds no ``filter_order``: it reads as the first-order filter on the derivative, the
    controller it describes runs that step, and it writes back without the field (as it was). A second-order set
    writes ``filter_order: 2`` and reads back as it; any other order is refused by name."""
    old = GainSet.load(DATA / "gains.json")
    assert "filter_order" not in _doc("gains.json")["gains"]
    assert old.gains.filter_order == 1 and old.controller().model.filter_order == 1
    assert "filter_order" not in old.to_dict()["gains"]
    second = GainSet(gains=replace(old.gains, filter_order=2), status=old.status, plant=old.plant,
                     inputs=old.inputs).save(tmp_path / "g2.json")
    doc = json.loads((tmp_path / "g2.json").read_text())
    assert doc["gains"]["filter_order"] == 2 and "second-order filter" in doc["gains"]["form"]
    again = GainSet.load(tmp_path / "g2.json")
    assert again.gains == second.gains and again.controller().model.filter_order == 2
    doc["gains"]["filter_order"] = 3
    path = _write(tmp_path / "g3.json", doc, GainSet)
    with pytest.raises(ArtifactError, match=re.escape("field 'gains.filter_order'")):
        GainSet.load(path)
