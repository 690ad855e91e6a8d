"""What the report reads: the study's facts and its stages' artifacts, each read once.

:class:`ReportStudy` is what the report needs of the study itself (its names, its plant, the
published numbers it declares); :class:`Artifacts` reads the artifacts the stages wrote, each through its
type's one reader, named by the stage records of the run's manifest
(:class:`~piezopreload.artifacts.manifest.StudyRunManifest`): a stage that did not run has none, and the
report leaves its sections out with the stage's reason.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.hysteresis import IdentifiedModel
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.manifest import StageRecord, StudyRunManifest
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.responses import ResponsesRecord
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.system import SystemRecord
from piezopreload.artifacts.tuning import TuningResult
from piezopreload.artifacts.validation import ValidationResult
from piezopreload.core.errors import InputError

__all__ = ["ReportStudy", "Published", "Artifacts", "read_csv_columns"]


@dataclass(frozen=True)
class Published:
    """Published step numbers a study compares itself with (its ``[published]`` table).

    ``step`` maps a controller (``pid``, ``ff+pid``) to its rise, peak and settling times in s;
    ``gains_label`` names the study's starting gains in the report ("the paper's gains").
    """

    source: str
    gains_label: str
    step: dict[str, dict[str, float]]


@dataclass(frozen=True)
class ReportStudy:
    """What the report prints of the study itself (the rest comes from the artifacts)."""

    name: str
    title: str
    path: str
    sha256: str
    source: str  # the study file as the user named it
    description: str = ""
    screw_mm: tuple[float, float] | None = None  # the design's nominal diameter and lead
    stacks: tuple[int, str] | None = None  # the plant's stacks: how many, and their type
    frequency_min_Hz: float | None = None  # the design's limit on the first axial mode
    published: Published | None = None
    gains_label: str = "the study's gains"  # its [controller] gains, as the report names them

    def label(self, gains: str) -> str:
        """A gain set's name in a sentence: ``study`` (the ``[controller]`` gains) or ``tuned``."""
        return {"study": self.gains_label, "tuned": "the tuned gains", "simc": "SIMC's gains"}.get(gains, gains)


def read_csv_columns(path: str | Path) -> dict[str, np.ndarray]:
    """A CSV written by the pipeline (``#`` comments, one header line) as named columns."""
    with open(path, encoding="utf-8") as fh:
        lines = [line for line in fh if line.strip() and not line.startswith("#")]
    if not lines:
        raise InputError(f"{path}: no header line")
    names = lines[0].strip().split(",")
    data = np.loadtxt(lines[1:], delimiter=",", ndmin=2) if len(lines) > 1 else np.empty((0, len(names)))
    if data.shape[1] != len(names):
        raise InputError(f"{path}: {data.shape[1]} columns but the header names {len(names)}")
    return {name: data[:, j] for j, name in enumerate(names)}


@dataclass
class Artifacts:
    """The artifacts of a study's output folder, read on first use; ``has(stage)`` says whether a stage ran."""

    out: Path
    manifest: StudyRunManifest

    def has(self, stage: str) -> bool:
        return self.manifest.done(stage)

    def record(self, stage: str) -> StageRecord | None:
        """The stage's record (None: the run never reached it)."""
        return self.manifest.record(stage)

    def not_applicable(self, stage: str) -> bool:
        """Whether the stage did not apply to the study."""
        return self.manifest.status(stage) == "not applicable"

    def reason(self, stage: str) -> str:
        """Why a stage has no artifacts: its recorded reason, its failure, or its status."""
        record = self.manifest.record(stage)
        return "it did not run" if record is None else record.why_not

    def path(self, stage: str, label: str) -> Path:
        output = self.manifest.output(stage, label)
        if output is None:
            raise InputError(f"{self.out}: the stage '{stage}' has no output '{label}'; run the study again")
        return self.out / output.path

    # ---- the artifacts -----------------------------------------------------------------------------
    @functools.cached_property
    def gain_set(self) -> GainSet:
        return GainSet.load(self.path("validate", "gains"))

    @functools.cached_property
    def validation(self) -> ValidationResult:
        return ValidationResult.load(self.path("validate", "validation"))

    @functools.cached_property
    def responses(self) -> ResponsesRecord:
        return ResponsesRecord.load(self.path("compare", "responses"))

    @functools.cached_property
    def feedforward(self) -> IdentifiedModel:
        """The feedforward's identified model (``feedforward/model.json``)."""
        return IdentifiedModel.load(self.path("identify", "model"))

    @functools.cached_property
    def tuning(self) -> TuningResult:
        return TuningResult.load(self.path("tune", "tuning"))

    @functools.cached_property
    def design(self) -> DesignRecord | None:
        return DesignRecord.load(self.path("design", "design")) if self.has("design") else None

    @functools.cached_property
    def plant(self) -> DesignedPlant | None:
        return DesignedPlant.load(self.path("plant", "plant")) if self.has("plant") else None

    @functools.cached_property
    def system(self) -> SystemRecord | None:
        return SystemRecord.load(self.path("system", "system")) if self.has("system") else None

    @functools.cached_property
    def learning(self) -> LearningRecord | None:
        return LearningRecord.load(self.path("learn", "learning")) if self.has("learn") else None

    @functools.cached_property
    def rig_run(self) -> RigRunRecord | None:
        return RigRunRecord.load(self.path("rig", "log_json")) if self.has("rig") else None

    def csv(self, stage: str, label: str) -> dict[str, np.ndarray]:
        return read_csv_columns(self.path(stage, label))

    def response_runs(self) -> dict[str, dict[str, dict[str, np.ndarray]]]:
        """Each reference's closed-loop runs, by ``"<gains> <controller>"`` (``study pid``, ``tuned ff+pid``)."""
        runs: dict[str, dict[str, dict[str, np.ndarray]]] = {}
        for run in self.responses.runs:
            runs.setdefault(run.reference, {})[f"{run.gains} {run.controller}"] = read_csv_columns(self.out / run.csv)
        return runs

    def requirements(self) -> tuple[Requirement, ...]:
        """Every requirement the stages checked, in stage order (what ``run`` judges its exit code by)."""
        return self.manifest.requirements
