"""The learned signal: what iterative learning control hands to the loop, as one versioned artifact.

A learned signal is a per-sample setpoint (the planned force, :mod:`piezopreload.tuning.learning`)
and a per-sample voltage added to the controller's feedforward (``ff_extra_V`` of
:func:`~piezopreload.models.closedloop.simulate` and of the rig executor). It is only
meaningful for the controller it was learned with and the reference it was learned on, so the
document records both hashes: the gain set's ``content_sha256`` (or, learned on a study's gains
that were never saved as a gain set, ``None``) and :func:`reference_sha256` of the reference.
:meth:`LearnedSignal.load` is the one reader (schema, fields and content hash checked) and
:meth:`LearnedSignal.check` refuses a mismatched gain set or reference, naming both hashes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.closedloop import Reference

__all__ = ["LearnedSignal", "reference_sha256", "KIND"]

KIND = "learned-signal"


def reference_sha256(reference: Reference) -> str:
    """SHA-256 of a reference's document (canonical JSON): the identity a learned signal is tied to."""
    text = json.dumps(reference.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True, eq=False)
class LearnedSignal:
    """A learned feedforward correction for one gain set and one reference.

    Parameters
    ----------
    ff_extra_V : ndarray
        Voltage added to the feedforward at each sample (before the clamp).
    setpoint_N : ndarray
        The controller's setpoint at each sample (the preview plan; the reference itself without preview).
    sample_period_s : float
        The loop's sample period; the signals have one value per sample of the reference.
    reference : Reference
        The reference it was learned on (what the tracking error is scored against).
    gain_set_sha256 : str or None
        The gain set's content hash (None: learned on gains not saved as a gain set).
    iteration : int
        Learning updates behind this signal (0: the preview alone).
    preview_s, method : float, str
        The preview horizon and the learning law.
    history : list of dict
        The error per iteration as it was learned.
    inputs : dict
        Where it came from (study, seed, run logs).
    content_sha256 : str or None
        Set by :meth:`load` and :meth:`save`.
    """

    ff_extra_V: NDArray[np.float64]
    setpoint_N: NDArray[np.float64]
    sample_period_s: float
    reference: Reference
    gain_set_sha256: str | None
    iteration: int = 0
    preview_s: float = 0.0
    method: str = "p-type"
    history: list[dict[str, Any]] = field(default_factory=list)
    inputs: dict[str, Any] = field(default_factory=dict)
    content_sha256: str | None = None

    def __post_init__(self) -> None:
        u, s = np.asarray(self.ff_extra_V, float), np.asarray(self.setpoint_N, float)
        if not (np.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise InputError(f"LearnedSignal.sample_period_s must be > 0, got {self.sample_period_s!r}.")
        n = int(round(self.reference.duration_s / self.sample_period_s)) + 1
        for name, x in (("ff_extra_V", u), ("setpoint_N", s)):
            if x.shape != (n,):
                raise InputError(f"LearnedSignal.{name} needs one value per sample of the reference ({n}), got shape "
                                 f"{x.shape}.")
            if not np.all(np.isfinite(x)):
                raise InputError(f"LearnedSignal.{name} must be finite.")
        object.__setattr__(self, "ff_extra_V", u)
        object.__setattr__(self, "setpoint_N", s)

    @property
    def reference_sha256(self) -> str:
        return reference_sha256(self.reference)

    @property
    def setpoint(self) -> Reference:
        """The setpoint as a reference the loop can run (one level per sample)."""
        dt, s = self.sample_period_s, self.setpoint_N
        return Reference(np.arange(s.size - 1) * dt, s[:-1], self.reference.duration_s)

    def check(self, gain_set_sha256: str | None, reference: Reference | None = None, shown: str = "the learned signal") -> None:
        """Refuse playing this signal with another gain set or on another reference (an :class:`InputError`)."""
        if self.gain_set_sha256 is None or gain_set_sha256 != self.gain_set_sha256:
            raise InputError(f"{shown} was learned with gain set {self.gain_set_sha256 or 'none (unsaved gains)'}, "
                             f"not with gain set {gain_set_sha256 or 'none'}: learn it again with that gain set "
                             "('piezopreload learn --gains FILE')")
        if reference is not None and reference_sha256(reference) != self.reference_sha256:
            raise InputError(f"{shown} was learned on reference {self.reference_sha256}, not on reference "
                             f"{reference_sha256(reference)}: run it with the reference it was learned on")

    def to_dict(self) -> dict[str, Any]:
        return {"ff_extra_V": self.ff_extra_V.tolist(), "setpoint_N": self.setpoint_N.tolist(),
                "sample_period_s": self.sample_period_s, "reference": self.reference.to_dict(),
                "reference_sha256": self.reference_sha256, "gain_set_sha256": self.gain_set_sha256,
                "iteration": int(self.iteration), "preview_s": float(self.preview_s), "method": self.method,
                "history": self.history, "inputs": dict(self.inputs)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the learned signal") -> LearnedSignal:
        try:
            reference = Reference.from_dict(doc["reference"])
            if reference_sha256(reference) != doc["reference_sha256"]:
                raise ArtifactError(f"{shown}: field 'reference_sha256' does not match its reference")
            return cls(np.asarray(doc["ff_extra_V"], float), np.asarray(doc["setpoint_N"], float),
                       float(doc["sample_period_s"]), reference, doc["gain_set_sha256"], int(doc.get("iteration", 0)),
                       float(doc.get("preview_s", 0.0)), str(doc.get("method", "p-type")), list(doc.get("history", [])),
                       dict(doc.get("inputs") or {}), doc.get("content_sha256"))
        except ArtifactError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ArtifactError(f"{shown}: field {exc} is missing or invalid; learn the signal again") from exc

    @classmethod
    def load(cls, path: str | Path) -> LearnedSignal:
        """The one reader: schema, fields and content hash checked (a changed file is refused)."""
        return cls.from_dict(read_artifact(path, KIND), str(path))

    def save(self, path: str | Path) -> LearnedSignal:
        """Write atomically as a content-hashed artifact; returns the signal with its hash."""
        doc = write_artifact(path, KIND, self.to_dict())
        return replace(self, content_sha256=doc["content_sha256"])
