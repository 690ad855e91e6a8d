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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from piezopreload.artifacts._fields import Fields
from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.summaries import StageSummary, read_summary
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["StudyRef", "OutputRecord", "StageRecord", "StudyRunManifest", "MANIFEST", "STUDY_COPY", "KIND",
           "STATUSES"]

KIND = "study-run"
#: the manifest's file in an output folder, and the study's copy beside it
MANIFEST, STUDY_COPY = "pipeline.json", "study.toml"
STATUSES = ("done", "failed", "not applicable")
S = TypeVar("S", bound=StageSummary)


@dataclass(frozen=True)
class StudyRef:
    """Which study: its file as named, its SHA-256 and its name (``[study] name``)."""

    path: str
    sha256: str
    name: str

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "sha256": self.sha256, "name": self.name}

    @classmethod
    def from_fields(cls, f: Fields) -> StudyRef:
        return cls(f.text("path"), f.text("sha256"), f.text("name"))


@dataclass(frozen=True)
class OutputRecord:
    """A file a stage wrote: its path relative to the output folder and its SHA-256."""

    path: str
    sha256: str

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "sha256": self.sha256}

    @classmethod
    def from_fields(cls, f: Fields) -> OutputRecord:
        return cls(f.text("path"), f.text("sha256"))


@dataclass(frozen=True)
class StageRecord:
    """One stage of a run as the manifest records it.

    ``reason`` says why a stage did not apply, ``message`` why it failed; ``summary`` is a done stage's (and a
    failed one's where it left one: a tripped rig run's trip).
    """

    status: str
    key: str
    outputs: dict[str, OutputRecord] = field(default_factory=dict)
    seconds: float | None = None
    finished_utc: str | None = None
    summary: StageSummary | None = None
    reason: str | None = None
    message: str | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"StageRecord.status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    @property
    def done(self) -> bool:
        return self.status == "done"

    @property
    def why_not(self) -> str:
        """Why the stage has no outputs to read: its reason, its failure, or its status."""
        return self.reason or self.message or self.status

    def to_dict(self) -> dict[str, Any]:
        """The record as ``pipeline.json`` holds it (the layout :mod:`piezopreload.core.stages` writes)."""
        out: dict[str, Any] = {"status": self.status}
        if self.reason is not None:
            out["reason"] = self.reason
        out["key"] = self.key
        if self.message is not None:
            out["message"] = self.message
        if self.seconds is not None:
            out["seconds"] = self.seconds
        if self.finished_utc is not None:
            out["finished_utc"] = self.finished_utc
        if self.summary is not None:
            out["summary"] = self.summary.to_dict()
        out["outputs"] = {label: o.to_dict() for label, o in self.outputs.items()}
        return out

    @classmethod
    def from_fields(cls, stage: str, f: Fields) -> StageRecord:
        status, outputs = f.text("status"), f.sub("outputs")
        if status not in STATUSES:
            raise f.fail("status", f"must be one of {', '.join(STATUSES)}, got {status!r}")
        return cls(
            status=status, key=f.text("key"),
            outputs={label: OutputRecord.from_fields(outputs.sub(label)) for label in outputs.doc},
            seconds=f.optional_number("seconds"),
            finished_utc=f.text("finished_utc") if f.has("finished_utc") else None,
            summary=read_summary(stage, f.raw("summary"), f.shown, f.path("summary")) if f.has("summary") else None,
            reason=f.text("reason") if f.has("reason") else None,
            message=f.text("message") if f.has("message") else None)

    @classmethod
    def from_dict(cls, stage: str, doc: Any, shown: str = "stage record") -> StageRecord:
        """A stage's record as :func:`piezopreload.core.stages.run_stages` keeps it."""
        return cls.from_fields(stage, Fields(doc, shown, f"stages.{stage}"))


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
        f = Fields(doc, shown)
        study, stages = f.sub("study"), f.sub("stages")
        return cls(StudyRef.from_fields(study), f.text("started_utc"),
                   {name: StageRecord.from_fields(name, stages.sub(name)) for name in stages.doc},
                   study.text("copy", STUDY_COPY))

    @classmethod
    def from_records(cls, study: StudyRef, started_utc: str, records: dict[str, dict[str, Any]],
                     order: tuple[str, ...], shown: str = MANIFEST) -> StudyRunManifest:
        """The manifest of the stages' records as :func:`piezopreload.core.stages.run_stages` keeps them, in
        ``order`` (each stage's summary read by its type, so a stage's summary that does not read back is an error
        where it is written)."""
        return cls(study, started_utc, {name: StageRecord.from_dict(name, records[name], shown)
                                        for name in order if name in records})

    def save(self, out: str | Path) -> Path:
        """Write ``out/pipeline.json`` atomically."""
        path = Path(out) / MANIFEST
        write_artifact(path, KIND, self.to_dict())
        return path

    @classmethod
    def load(cls, out: str | Path) -> StudyRunManifest:
        """Read the output folder ``out``'s ``pipeline.json``: its schema and every field checked."""
        path = Path(out) / MANIFEST
        return cls.from_dict(read_artifact(path, KIND), str(path))
