"""The learning of a schedule's passes: what the learn stage writes (``learn/learning.json``, kind ``learning``).

A schedule is planned again with a margin while its rigidity falls short (the system's passes);
the loop learns on each pass's repeated reference. :class:`LearningRecord` holds, per pass
(:class:`PassRecord`), the learned signal's file (``learned-pass<k>.json``, a
:class:`~piezopreload.artifacts.learned.LearnedSignal`), its reference's hash, the error per trial
(:class:`TrialRecord`; trial 0 is the tuned loop with its feedforward and the preview, no learned
correction), the trials the pass ran and the first that came within 1.1 times its best error, and,
at its top level, the last pass's figures (what the system stage plays last) and the trials over
all passes. :meth:`LearningRecord.load` is the one reader, :meth:`LearningRecord.save` the one writer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from piezopreload.artifacts._fields import count, flag, mapping, number, optional_number, text
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["KIND", "TrialRecord", "PassRecord", "LearningRecord"]

KIND = "learning"

_REQUIRED = object()


def _numbers(x: Any) -> float | list[float]:
    """One number, or one per plant."""
    if isinstance(x, list):
        if not x:
            raise ValueError("expected at least one number")
        return [number(v) for v in x]
    return number(x)


def _counts(x: Any) -> list[int]:
    if not isinstance(x, list) or not x:
        raise ValueError(f"expected a list of whole numbers, got {x!r}")
    return [count(v) for v in x]


def _worst(x: float | list[float]) -> float:
    return max(x) if isinstance(x, list) else x


class _Fields:
    """Reads the fields of one JSON object, naming a missing or invalid one (and where it sits)."""

    def __init__(self, doc: Any, where: str) -> None:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected a JSON object, got {type(doc).__name__}")
        self.doc, self.where = doc, where

    def __call__(self, name: str, convert: Callable[[Any], Any], default: Any = _REQUIRED) -> Any:
        if name not in self.doc:
            if default is _REQUIRED:
                raise ArtifactError(f"{self.where}: field '{name}' is missing; run the learn stage again")
            return default
        try:
            return convert(self.doc[name])
        except (TypeError, ValueError) as exc:
            raise ArtifactError(f"{self.where}: field '{name}' is invalid ({exc}); run the learn stage again") from exc


@dataclass(frozen=True)
class TrialRecord:
    """One trial: the RMS error of the true force (whole trajectory, and outside the transport after each
    change) against the reference, and of the measured force against the plan (what the law sees).
    One number, or one per plant."""

    iteration: int
    tracking_rms_N: float | list[float]
    tracking_rms_after_change_N: float | list[float]
    measured_rms_N: float | list[float]

    @property
    def worst_tracking_rms_N(self) -> float:
        return _worst(self.tracking_rms_N)

    def to_dict(self) -> dict[str, Any]:
        return {"iteration": self.iteration, "tracking_rms_N": self.tracking_rms_N,
                "tracking_rms_after_change_N": self.tracking_rms_after_change_N, "measured_rms_N": self.measured_rms_N}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "trial") -> TrialRecord:
        f = _Fields(doc, where)
        return cls(f("iteration", count), f("tracking_rms_N", _numbers), f("tracking_rms_after_change_N", _numbers),
                   f("measured_rms_N", _numbers))


def _trials(x: Any, where: str) -> list[TrialRecord]:
    if not isinstance(x, list) or not x:
        raise ValueError("expected a list of trials (at least trial 0)")
    return [TrialRecord.from_dict(h, f"{where}, trial {k}") for k, h in enumerate(x)]


@dataclass(frozen=True)
class PassRecord:
    """The learning on one pass's reference.

    ``trials`` learning trials ran after trial 0 (each one run of the pass's repeated reference);
    ``trials_to_within_1p1`` is the first trial whose error came within 1.1 times the pass's best;
    ``stop_reason`` why the pass stopped learning. ``warm_start`` says whether its trial 0 carried the
    correction learned on the pass before; ``tracking_rms_N`` is scored from the reference's first change
    (as the floors), ``tracking_rms_from_start_N`` from t = 0; ``before_learning_rms_N`` is the loop's error without any
    learned correction (trial 0, or for a warm start a run without it). ``noise_floor_N`` is the RMS
    difference of the true force between two runs of the same signal under other sensor noise.
    ``learning`` is the law's settings.
    """

    pass_number: int
    signal: str
    reference_sha256: str
    before_learning_rms_N: float
    before_learning_pct_of_range: float
    tracking_rms_N: float
    tracking_rms_pct_of_range: float
    trials: int
    trials_to_within_1p1: int
    stop_reason: str
    converged: bool
    best_iteration: list[int]
    causal_floor_N: float
    preview_floor_N: float
    noise_floor_N: float | None
    preview_s: float
    method: str
    warm_start: bool
    learning: dict[str, Any]
    history: list[TrialRecord]
    tracking_rms_from_start_N: float | None = None

    def __post_init__(self) -> None:
        if len(self.history) != self.trials + 1:
            raise ArtifactError(f"pass {self.pass_number}: {len(self.history)} trials recorded for {self.trials} "
                                "learning trials after trial 0")

    @property
    def iterations(self) -> int:
        """The learning updates (one per trial after trial 0): :attr:`trials`."""
        return self.trials

    @property
    def span_N(self) -> float:
        """The pass's reference's range (N), from its RMS in N and in % of the range."""
        pct = self.tracking_rms_pct_of_range
        return 100.0 * self.tracking_rms_N / pct if pct else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {"pass": self.pass_number, "signal": self.signal, "reference_sha256": self.reference_sha256,
                "before_learning_rms_N": self.before_learning_rms_N,
                "before_learning_pct_of_range": self.before_learning_pct_of_range,
                "tracking_rms_N": self.tracking_rms_N, "tracking_rms_pct_of_range": self.tracking_rms_pct_of_range,
                "iterations": self.trials, "trials": self.trials, "trials_to_within_1p1": self.trials_to_within_1p1,
                "stop_reason": self.stop_reason, "converged": self.converged, "best_iteration": self.best_iteration,
                "causal_floor_N": self.causal_floor_N, "preview_floor_N": self.preview_floor_N,
                "noise_floor_N": self.noise_floor_N, "preview_s": self.preview_s, "method": self.method,
                "warm_start": self.warm_start, "learning": self.learning,
                "history": [h.to_dict() for h in self.history],
                "tracking_rms_from_start_N": self.tracking_rms_from_start_N}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "pass") -> PassRecord:
        f = _Fields(doc, where)
        k = f("pass", count)
        where = f"{where} {k}"
        f = _Fields(doc, where)
        return cls(k, f("signal", text), f("reference_sha256", text), f("before_learning_rms_N", number),
                   f("before_learning_pct_of_range", number), f("tracking_rms_N", number),
                   f("tracking_rms_pct_of_range", number), f("trials", count), f("trials_to_within_1p1", count),
                   f("stop_reason", text), f("converged", flag), f("best_iteration", _counts),
                   f("causal_floor_N", number), f("preview_floor_N", number),
                   f("noise_floor_N", optional_number, None), f("preview_s", number), f("method", text),
                   f("warm_start", flag, False), f("learning", mapping), f("history", lambda x: _trials(x, where)),
                   f("tracking_rms_from_start_N", optional_number, None))


@dataclass(frozen=True)
class LearningRecord:
    """The learning of every pass of a schedule (module docstring); ``learned`` names the last pass's signal file,
    what the rig plays. The top-level figures are the last pass's."""

    passes: list[PassRecord]
    learned: str
    inputs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.passes:
            raise ArtifactError("a learning record needs at least one pass")

    @property
    def last(self) -> PassRecord:
        return self.passes[-1]

    @property
    def trials(self) -> int:
        """Learning trials over all passes (each one run of a pass's repeated reference after its trial 0)."""
        return sum(p.trials for p in self.passes)

    @property
    def trials_per_pass(self) -> list[int]:
        return [p.trials for p in self.passes]

    def signal_paths(self, folder: str | Path) -> list[Path]:
        """The passes' learned-signal files, in ``folder`` (where the record sits)."""
        return [Path(folder) / p.signal for p in self.passes]

    def to_dict(self) -> dict[str, Any]:
        last = self.last
        return {"pass_records": [p.to_dict() for p in self.passes], "passes": len(self.passes),
                "tracking_rms_N": last.tracking_rms_N, "tracking_rms_pct_of_range": last.tracking_rms_pct_of_range,
                "before_learning_rms_N": last.before_learning_rms_N,
                "before_learning_pct_of_range": last.before_learning_pct_of_range, "iterations": last.trials,
                "trials": self.trials, "trials_per_pass": self.trials_per_pass,
                "trials_to_within_1p1_per_pass": [p.trials_to_within_1p1 for p in self.passes],
                "converged": last.converged, "causal_floor_N": last.causal_floor_N,
                "preview_floor_N": last.preview_floor_N, "preview_s": last.preview_s, "method": last.method,
                "history": [h.to_dict() for h in last.history],
                "contraction_over_range": last.learning.get("contraction_over_range"), "learned": self.learned,
                "inputs": dict(self.inputs)}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "the learning record") -> LearningRecord:
        f = _Fields(doc, where)
        records = f("pass_records", lambda x: x if isinstance(x, list) and x else _raise("expected a list of passes"))
        passes = [PassRecord.from_dict(p, f"{where}, pass record {k + 1}") for k, p in enumerate(records)]
        if f("passes", count) != len(passes):
            raise ArtifactError(f"{where}: field 'passes' does not match its {len(passes)} pass records")
        record = cls(passes, f("learned", text), f("inputs", mapping, {}))
        if passes[-1].signal != record.learned:
            raise ArtifactError(f"{where}: field 'learned' ({record.learned}) is not the last pass's signal "
                                f"({passes[-1].signal})")
        return record

    def save(self, path: str | Path) -> Path:
        """Write atomically (the one writer)."""
        write_artifact(path, KIND, self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> LearningRecord:
        """The one reader: schema, kind and every field checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))


def _raise(message: str) -> Any:
    raise ValueError(message)
