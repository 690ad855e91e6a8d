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

import math
from pathlib import Path
from typing import Any, ClassVar

from piezopreload.artifacts.learned import LearningMethod
from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Raw, Record, SavedArtifact, entry, hold_members, record

__all__ = ["KIND", "TrialRecord", "PassRecord", "LearningRecord"]

KIND = "learning"

def _numbers(x: Any) -> float | list[float]:
    """One number, or one per plant."""
    if isinstance(x, list):
        if not x:
            raise ValueError("expected at least one number")
        return [_number(v) for v in x]
    return _number(x)


def _number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ValueError(f"expected a finite number, got {x!r}")
    return float(x)


def _worst(x: float | list[float]) -> float:
    return max(x) if isinstance(x, list) else x


_PER_PLANT = "a finite number, or a list of them (one per plant)"


@record
class TrialRecord(Record):
    """One trial: the RMS error of the true force (whole trajectory, and outside the transport after each
    change) against the reference, and of the measured force against the plan (what the law sees).
    One number, or one per plant."""

    NOUN: ClassVar[str] = "the trial"

    iteration: int = entry("The trial's number (0: before any learned correction).", ge=0)
    tracking_rms_N: float | list[float] = entry("The true force's RMS error over the whole trajectory.", unit="N",
                                                read=_numbers, takes=_PER_PLANT)
    tracking_rms_after_change_N: float | list[float] = entry(
        "The true force's RMS error outside the transport after each change.", unit="N", read=_numbers,
        takes=_PER_PLANT)
    measured_rms_N: float | list[float] = entry("The measured force's RMS error against the plan.", unit="N",
                                                read=_numbers, takes=_PER_PLANT)

    @property
    def worst_tracking_rms_N(self) -> float:
        """The worst plant's :attr:`tracking_rms_N`."""
        return _worst(self.tracking_rms_N)


@record
class PassRecord(Record):
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

    NOUN: ClassVar[str] = "the pass record"

    pass_number: int = entry("The pass's number (from 1).", name="pass", ge=0)
    signal: str = entry("Its learned signal's file (beside the record).")
    reference_sha256: str = entry("Its reference's SHA-256.")
    before_learning_rms_N: float = entry("The loop's error without any learned correction.", unit="N")
    before_learning_pct_of_range: float = entry("The same, in % of the reference's range.", unit="%")
    tracking_rms_N: float = entry("The error with the learned correction, from the reference's first change.",
                                  unit="N")
    tracking_rms_pct_of_range: float = entry("The same, in % of the reference's range.", unit="%")
    trials: int = entry("The learning trials after trial 0.", ge=0)
    trials_to_within_1p1: int = entry("The first trial whose error came within 1.1 times the pass's best.", ge=0)
    stop_reason: str = entry("Why the pass stopped learning.")
    converged: bool = entry("Whether the learning converged.")
    best_iteration: list[int] = entry("The best trial (one per plant).", ge=0)
    causal_floor_N: float = entry("The least RMS error of any causal controller without preview.", unit="N")
    preview_floor_N: float = entry("The least RMS error with the preview.", unit="N")
    noise_floor_N: float | None = entry("The RMS difference of the true force between two runs of the same signal "
                                        "under other sensor noise.", unit="N", absent=None)
    preview_s: float = entry("The preview horizon.", unit="s")
    method: LearningMethod = entry("The learning law.")
    warm_start: bool = entry("Whether trial 0 carried the correction learned on the pass before.", absent=False)
    learning: dict[str, Any] = entry("The law's settings.")
    history: list[TrialRecord] = entry("The error per trial (trial 0 first).")
    tracking_rms_from_start_N: float | None = entry("The error with the learned correction, from t = 0.", unit="N",
                                                    default=None)

    def __post_init__(self) -> None:
        hold_members(self)
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
        """The pass's object (its trials also as ``iterations``, the name it had first).

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "iterations": self.trials}


@record
class LearningRecord(SavedArtifact):
    """The learning of every pass of a schedule (module docstring); the top-level figures are the last pass's."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the learning record"
    AGAIN: ClassVar[str] = "run the learn stage again"

    passes: list[PassRecord] = entry("One record per pass, in order.", name="pass_records")
    learned: str = entry("The last pass's signal file: what the rig plays.")
    inputs: dict[str, Any] = entry("Where it came from (the study, the gain set).", default={}, required=True)

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
        """The passes' records and, at the top, the last pass's figures and the trials over all passes.

        Returns
        -------
        dict
            The document's body.
        """
        last = self.last
        return {**super().to_dict(), "passes": len(self.passes),
                "tracking_rms_N": last.tracking_rms_N, "tracking_rms_pct_of_range": last.tracking_rms_pct_of_range,
                "before_learning_rms_N": last.before_learning_rms_N,
                "before_learning_pct_of_range": last.before_learning_pct_of_range, "iterations": last.trials,
                "trials": self.trials, "trials_per_pass": self.trials_per_pass,
                "trials_to_within_1p1_per_pass": [p.trials_to_within_1p1 for p in self.passes],
                "converged": last.converged, "causal_floor_N": last.causal_floor_N,
                "preview_floor_N": last.preview_floor_N, "preview_s": last.preview_s, "method": last.method,
                "history": [h.to_dict() for h in last.history],
                "contraction_over_range": last.learning.get("contraction_over_range")}

    def _check_document(self, raw: Raw) -> None:
        if raw.get("passes", len(self.passes)) != len(self.passes):  # a figure written beside them, checked if there
            raise raw.fail("passes", f"must be {len(self.passes)}, the number of its pass records, got "
                                     f"{raw.get('passes')!r}")
        if self.passes[-1].signal != self.learned:
            raise raw.fail("learned", f"must be the last pass's signal ({self.passes[-1].signal}), got "
                                      f"{self.learned!r}")
