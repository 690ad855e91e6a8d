"""The artifact kinds are one explicit list (``artifacts.registry.KINDS``): nothing is registered as a module is
imported, a record reads and writes by its own declaration, and a kind named twice is refused where the list is
made."""

import subprocess
import sys

import pytest

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.registry import ARTIFACTS, KINDS, read_artifact
from piezopreload.core import artifacts as envelope
from piezopreload.core.artifacts import ArtifactError, ArtifactKind, Kinds
from piezopreload.core.records import Artifact, entry, kind_of, record


def test_a_record_made_after_the_list_is_not_added_to_it_and_still_reads_itself(tmp_path):
    before = dict(KINDS)

    @record
    class Note(Artifact):
        """A test's own artifact."""

        KIND = "test-note"
        text: str = entry("Its text.")

    assert dict(KINDS) == before and "test-note" not in KINDS, "defining a record changed the list of kinds"
    path = tmp_path / "note.json"
    Note("hello")._write(path)  # a record's save() is its own; the write under it takes its kind
    assert Note.load(path).text == "hello"
    with pytest.raises(ValueError, match="unknown artifact kind 'test-note'; the kinds known are"):
        read_artifact(path, "test-note")
    assert envelope.read_artifact(path, kind_of(Note))["text"] == "hello"


def test_the_list_is_the_records_and_the_documents_and_a_kind_named_twice_is_refused():
    assert set(KINDS) == {cls.KIND for cls in ARTIFACTS} | {k.name for k in envelope.DOCUMENTS}
    assert len(KINDS) == len(ARTIFACTS) + len(envelope.DOCUMENTS), "a kind named twice"
    assert KINDS.kind("gain-set") == kind_of(GainSet) and KINDS.kind("gain-set").hashed
    twice = ArtifactKind("gain-set", tuple, owner="another record")
    with pytest.raises(ValueError, match="artifact kind 'gain-set' is declared twice: by "
                                         "piezopreload.artifacts.gainset.GainSet and by another record"):
        Kinds([kind_of(GainSet), twice])


def test_the_kinds_a_program_knows_do_not_depend_on_what_it_imported_first():
    """One record's module imported alone reads and writes its kind; the core keeps no table of kinds to fill."""
    code = ("import piezopreload.core.artifacts as a, piezopreload.core.records as r, "
            "piezopreload.artifacts.learned as m, sys; "
            "print(sorted(n for n in vars(a) if n.isupper() and isinstance(getattr(a, n), dict)), "
            "r.kind_of(m.LearnedSignal).name, 'piezopreload.artifacts.registry' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["[]", "learned-signal", "False"], out


def test_a_wrong_kind_is_named_by_the_reader(tmp_path):
    path = tmp_path / "doc.json"
    envelope.write_artifact(path, envelope.STUDY_RUN, {"study": {}, "stages": {}})
    with pytest.raises(ArtifactError, match="must be 'piezopreload/report/1', got 'piezopreload/study-run/1'"):
        envelope.read_artifact(path, envelope.REPORT)
