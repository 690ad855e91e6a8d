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
from dataclasses import replace
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.errors import InputError
from piezopreload.core.records import Artifact, Raw, entry, hold_members, record
from piezopreload.models.closedloop import Reference

__all__ = ["LearnedSignal", "LearningMethod", "reference_sha256", "KIND"]

class LearningMethod(StrEnum):
    """The learning law: the norm-optimal law (the default; the Riccati form, a sparse QP where the limits bind) or
    the P-type law (Q-filtered, with lead: the model-free option). Its value is what a study's ``[learning] method``
    and the learning's artifacts write."""

    NORM_OPTIMAL = "norm-optimal"
    P_TYPE = "p-type"


KIND = "learned-signal"


def reference_sha256(reference: Reference) -> str:
    """SHA-256 of a reference's document (canonical JSON): the identity a learned signal is tied to."""
    text = json.dumps(reference.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


@record(eq=False)
class LearnedSignal(Artifact):
    """A learned feedforward correction for one gain set and one reference."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the learned signal"
    AGAIN: ClassVar[str] = "learn the signal again ('piezopreload learn')"
    HASHED: ClassVar[bool] = True

    ff_extra_V: NDArray[np.float64] = entry("Voltage added to the feedforward at each sample (before the clamp).",
                                            unit="V")
    setpoint_N: NDArray[np.float64] = entry("The controller's setpoint at each sample (the preview plan; the "
                                            "reference itself without preview).", unit="N", size="ff_extra_V")
    sample_period_s: float = entry("The loop's sample period; the signals have one value per sample of the "
                                   "reference.", unit="s", gt=0)
    reference: Reference = entry("The reference it was learned on (what the tracking error is scored against).",
                                 read=Reference.from_dict, write=Reference.to_dict, takes="a reference")
    gain_set_sha256: str | None = entry("The gain set's content hash (None: learned on gains not saved as a gain "
                                        "set).")
    iteration: int = entry("Learning updates behind this signal (0: the preview alone).", ge=0, default=0)
    preview_s: float = entry("The preview horizon.", unit="s", ge=0, default=0.0)
    method: LearningMethod = entry("The learning law.", default=LearningMethod.P_TYPE)
    history: list[dict[str, Any]] = entry("The error per iteration as it was learned.", default=[])
    inputs: dict[str, Any] = entry("Where it came from (study, seed, run logs).", default={}, required=True)
    content_sha256: str | None = entry("Set by :meth:`load` and :meth:`save`.", default=None)

    def __post_init__(self) -> None:
        hold_members(self, InputError)
        self._check_fields()
        n = self._samples()
        for name in ("ff_extra_V", "setpoint_N"):
            x = np.asarray(getattr(self, name), float)
            if x.shape != (n,):
                raise InputError(f"LearnedSignal.{name} needs one value per sample of the reference ({n}), got shape "
                                 f"{x.shape}.")
            if not np.all(np.isfinite(x)):
                raise InputError(f"LearnedSignal.{name} must be finite.")
            object.__setattr__(self, name, x)

    def _check_fields(self) -> None:
        """Every field but the two signals: its type and range."""
        if not (np.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise InputError(f"LearnedSignal.sample_period_s must be > 0, got {self.sample_period_s!r}.")
        if not isinstance(self.reference, Reference):
            raise InputError(f"LearnedSignal.reference must be a Reference, got {type(self.reference).__name__}.")
        for name in ("gain_set_sha256", "content_sha256"):
            if not (getattr(self, name) is None or isinstance(getattr(self, name), str)):
                raise InputError(f"LearnedSignal.{name} must be a hash (text) or None, got {getattr(self, name)!r}.")
        if isinstance(self.iteration, bool) or not isinstance(self.iteration, int | np.integer) or self.iteration < 0:
            raise InputError(f"LearnedSignal.iteration must be a whole number >= 0, got {self.iteration!r}.")
        if not (np.isfinite(self.preview_s) and self.preview_s >= 0):
            raise InputError(f"LearnedSignal.preview_s must be finite and >= 0, got {self.preview_s!r}.")

    def _samples(self) -> int:
        """The reference's samples at the signal's period (refused beyond 1e8, before anything is sized by it)."""
        ratio = self.reference.duration_s / self.sample_period_s
        if not ratio < 1e8:
            raise InputError(f"LearnedSignal.sample_period_s {self.sample_period_s!r} gives {ratio:.3g} samples over "
                             f"the reference's {self.reference.duration_s} s; at most 1e8.")
        return int(round(self.reference.duration_s / self.sample_period_s)) + 1

    @property
    def reference_sha256(self) -> str:
        """The hash of the reference the signal was learned on (:func:`reference_sha256` of :attr:`reference`)."""
        return reference_sha256(self.reference)

    @property
    def setpoint(self) -> Reference:
        """The setpoint as a reference the loop can run (one level per sample)."""
        dt, s = self.sample_period_s, self.setpoint_N
        return Reference(np.arange(s.size - 1, dtype=np.float64) * dt, s[:-1], self.reference.duration_s)

    def check(self, gain_set_sha256: str | None, reference: Reference | None = None,
              shown: str = "the learned signal") -> None:
        """Refuse playing this signal with another gain set or on another reference (an :class:`InputError`).

        Parameters
        ----------
        gain_set_sha256 : str or None
            The hash of the gain set it is about to be played with (None: unsaved gains, which never match).
        reference : Reference or None
            The reference it is about to be played on; None leaves the reference unchecked.
        shown : str
            What the error message calls the signal (its file, or "the learned signal").

        Raises
        ------
        InputError
            Where the gain set or the reference is not the one the signal was learned with.
        """
        if self.gain_set_sha256 is None or gain_set_sha256 != self.gain_set_sha256:
            raise InputError(f"{shown} was learned with gain set {self.gain_set_sha256 or 'none (unsaved gains)'}, "
                             f"not with gain set {gain_set_sha256 or 'none'}: learn it again with that gain set "
                             "('piezopreload learn --gains FILE')")
        if reference is not None and reference_sha256(reference) != self.reference_sha256:
            raise InputError(f"{shown} was learned on reference {self.reference_sha256}, not on reference "
                             f"{reference_sha256(reference)}: run it with the reference it was learned on")

    def to_dict(self) -> dict[str, Any]:
        """The artifact's body: the fields and the reference's hash (its hash is the envelope's).

        Returns
        -------
        dict
            The document without its envelope.
        """
        out = super().to_dict()
        del out["content_sha256"]
        return {**out, "reference_sha256": self.reference_sha256}

    def _check_document(self, raw: Raw) -> None:
        stored = raw.get("reference_sha256")
        if stored is None:
            raise raw.fail("reference_sha256", "is missing; expected the SHA-256 of its reference")
        if stored != self.reference_sha256:
            raise raw.fail("reference_sha256", "does not match its reference")

    def save(self, path: str | Path) -> LearnedSignal:
        """Write atomically as a content-hashed artifact.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        LearnedSignal
            The signal with the hash it was written with.
        """
        doc = self._write(path)
        return replace(self, content_sha256=doc["content_sha256"])
