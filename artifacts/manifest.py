"""A study's run as its output folder records it: ``pipeline.json`` (kind ``study-run``), one type and one reader.

:class:`StudyRunManifest` holds the study the folder is for (:class:`StudyRef`), when the run started and one
:class:`StageRecord` per stage: its status (``done``, ``failed``, ``not applicable``), its key, its time, what it
wrote (:class:`OutputRecord`: a path relative to the folder and its SHA-256) and, for a done stage (or a rig run an
interlock stopped), its typed summary (:mod:`piezopreload.artifacts.summaries`). :meth:`StudyRunManifest.load` is
the one reader (the run, the report, the sweep and ``report DIR`` read the folder through it) and
:meth:`StudyRunManifest.save` the one writer. The keying and running of stages that fills it is
:mod:`piezopreload.core.stages`, which keeps each stage's record as the JSON this type reads.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Self, TypeVar

from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.summaries import StageSummary, read_summary
from piezopreload.core.artifacts import STUDY_RUN, read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Record, entry, record

__all__ = ["StudyRef", "OutputRecord", "StageRecord", "StudyRunManifest", "MANIFEST", "STUDY_COPY", "KIND",
           "STATUSES"]

KIND = STUDY_RUN.name
#: the manifest's file in an output folder, and the study's copy beside it
MANIFEST, STUDY_COPY = "pipeline.json", "study.toml"
STATUSES = ("done", "failed", "not applicable")
_AGAIN = "run the study again with --force"
S = TypeVar("S", bound=StageSummary)


@record
class StudyRef(Record):
    """Which study: its file as named, its SHA-256 and its name (``[study] name``)."""

    AGAIN: ClassVar[str] = _AGAIN
    path: str = entry("The study's file, as named.")
    sha256: str = entry("The file's SHA-256.")
    name: str = entry("The study's name.")


@record
class OutputRecord(Record):
    """A file a stage wrote: its path relative to the output folder and its SHA-256."""

    AGAIN: ClassVar[str] = _AGAIN
    path: str = entry("The file, relative to the output folder.")
    sha256: str = entry("Its SHA-256.")


@record
class StageRecord(Record):
    """One stage of a run as the manifest records it.

    ``reason`` says why a stage did not apply, ``message`` why it failed; ``summary`` is a done stage's (and a
    failed one's where it left one: a tripped rig run's trip), read by the stage's own record
    (:mod:`piezopreload.artifacts.summaries`).
    """

    AGAIN: ClassVar[str] = _AGAIN
    status: str = entry("Whether the stage ran.", choices=STATUSES)
    reason: str | None = entry("Why the stage did not apply.", default=None, omit=True)
    key: str = entry("The stage's content key.", default="", required=True)
    message: str | None = entry("Why the stage failed.", default=None, omit=True)
    seconds: float | None = entry("The stage's time.", unit="s", default=None, omit=True)
    finished_utc: str | None = entry("When it finished (UTC).", default=None, omit=True)
    summary: StageSummary | None = entry("The stage's summary (its record).", default=None, stored=False)
    outputs: dict[str, OutputRecord] = entry("What it wrote, by label.", default_factory=dict, required=True)

    @property
    def done(self) -> bool:
        return self.status == "done"

    @property
    def why_not(self) -> str:
        """Why the stage has no outputs to read: its reason, its failure, or its status."""
        return self.reason or self.message or self.status

    def to_dict(self) -> dict[str, Any]:
        """The record as ``pipeline.json`` holds it (the layout :mod:`piezopreload.core.stages` writes)."""
        out = super().to_dict()
        outputs = out.pop("outputs")
        if self.summary is not None:
            out["summary"] = self.summary.to_dict()
        return {**out, "outputs": outputs}

    @classmethod
    def read(cls, stage: str, doc: Any, shown: str = "stage record", path: str = "") -> Self:
        """A stage's record as :func:`piezopreload.core.stages.run_stages` keeps it, its summary read by the
        stage's record.

        Parameters
        ----------
        stage : str
            The stage's name.
        doc : dict
            The record's object.
        shown : str
            What the messages call the document.
        path : str
            Where the record sits in the document (default ``stages.STAGE``).

        Returns
        -------
        StageRecord
            The record.
        """
        path = path or f"stages.{stage}"
        made = cls.from_dict(doc, shown, path=path)
        if isinstance(doc, dict) and doc.get("summary") is not None:
            made = replace(made, summary=read_summary(stage, doc["summary"], shown, f"{path}.summary"))
        return made


@record
class _Document(Record):
    """The manifest's own fields (each stage's record is read by :meth:`StageRecord.read`, by its stage)."""

    AGAIN: ClassVar[str] = _AGAIN
    study: StudyRef = entry("Which study.")
    started_utc: str = entry("When the run started (UTC).")
    stages: dict[str, dict[str, Any]] = entry("Each stage's record, by the stage's name.")
    copy: str = entry("The study's copy in the folder.", at="study", default=STUDY_COPY)


@dataclass(frozen=True)
class StudyRunManifest:
    """An output folder's ``pipeline.json``: the study, when the run started, each stage's record in stage order."""

    study: StudyRef
    started_utc: str
    stages: dict[str, StageRecord]
    copy: str = STUDY_COPY

    # ---- reading the stages --------------------------------------------------------------------------------------
    def record(self, stage: str) -> StageRecord | None:
        """The record of ``stage`` (None: the run never reached it)."""
        return self.stages.get(stage)

    def done(self, stage: str) -> bool:
        """Whether ``stage`` ran (or is up to date) and left its outputs."""
        record = self.stages.get(stage)
        return record is not None and record.done

    def status(self, stage: str) -> str | None:
        record = self.stages.get(stage)
        return None if record is None else record.status

    def summary(self, kind: type[S]) -> S | None:
        """The summary of the stage ``kind`` is the record of (``manifest.summary(TuneSummary)``), where that stage is
        done; else None."""
        record = self.stages.get(kind.STAGE)
        if record is None or not record.done or record.summary is None:
            return None
        if not isinstance(record.summary, kind):  # pragma: no cover - the reader gives each stage its own
            raise ArtifactError(f"{MANIFEST}: the stage '{kind.STAGE}' holds a {type(record.summary).__name__}")
        return record.summary

    def output(self, stage: str, label: str) -> OutputRecord | None:
        """What a done stage wrote under ``label`` (None where it did not run or wrote none)."""
        record = self.stages.get(stage)
        return None if record is None or not record.done else record.outputs.get(label)

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        """Every requirement the stages that ran checked, in stage order (what ``run`` judges its exit code by)."""
        return tuple(r for rec in self.stages.values() if rec.done and rec.summary is not None
                     for r in rec.summary.requirements)

    def files(self) -> list[str]:
        """Every file the stages recorded, relative to the folder (a stage that failed: what it wrote)."""
        return [o.path for rec in self.stages.values() for o in rec.outputs.values()]

    # ---- the document --------------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"study": {**self.study.to_dict(), "copy": self.copy}, "started_utc": self.started_utc,
                "stages": {name: record.to_dict() for name, record in self.stages.items()}}

    @classmethod
    def from_dict(cls, doc: Any, shown: str = MANIFEST) -> StudyRunManifest:
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names the field."""
        head = _Document.from_dict(doc, shown)
        return cls(head.study, head.started_utc,
                   {name: StageRecord.read(name, record, shown) for name, record in head.stages.items()}, head.copy)

    @classmethod
    def from_records(cls, study: StudyRef, started_utc: str, records: dict[str, dict[str, Any]],
                     order: tuple[str, ...], shown: str = MANIFEST) -> StudyRunManifest:
        """The manifest of the stages' records as :func:`piezopreload.core.stages.run_stages` keeps them, in
        ``order`` (each stage's summary read by its type, so a stage's summary that does not read back is an error
        where it is written)."""
        return cls(study, started_utc, {name: StageRecord.read(name, records[name], shown)
                                        for name in order if name in records})

    def save(self, out: str | Path) -> Path:
        """Write ``out/pipeline.json`` atomically."""
        path = Path(out) / MANIFEST
        write_artifact(path, STUDY_RUN, self.to_dict())
        return path

    @classmethod
    def load(cls, out: str | Path) -> StudyRunManifest:
        """Read the output folder ``out``'s ``pipeline.json``: its schema and every field checked."""
        path = Path(out) / MANIFEST
        return cls.from_dict(read_artifact(path, STUDY_RUN), str(path))
