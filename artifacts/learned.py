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


_REQUIRED = object()


def _floats(x: Any) -> NDArray[np.float64]:
    if isinstance(x, str | dict):
        raise TypeError(f"expected a list of numbers, got {type(x).__name__}")
    return np.asarray(x, float)


def _number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise TypeError(f"expected a number, got {x!r}")
    return float(x)


def _count(x: Any) -> int:
    if isinstance(x, bool) or not isinstance(x, int | float) or not float(x).is_integer():
        raise ValueError(f"expected a whole number, got {x!r}")
    return int(x)


def _text(x: Any) -> str:
    if not isinstance(x, str):
        raise TypeError(f"expected text, got {x!r}")
    return x


def _optional_text(x: Any) -> str | None:
    return None if x is None else _text(x)


def _list(x: Any) -> list[Any]:
    if not isinstance(x, list):
        raise TypeError(f"expected a list, got {type(x).__name__}")
    return list(x)


def _mapping(x: Any) -> dict[str, Any]:
    if x is None:
        return {}
    if not isinstance(x, dict):
        raise TypeError(f"expected an object, got {type(x).__name__}")
    return dict(x)


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
        if not isinstance(self.method, str):
            raise InputError(f"LearnedSignal.method must be text, got {self.method!r}.")

    def _samples(self) -> int:
        """The reference's samples at the signal's period (refused beyond 1e8, before anything is sized by it)."""
        ratio = self.reference.duration_s / self.sample_period_s
        if not ratio < 1e8:
            raise InputError(f"LearnedSignal.sample_period_s {self.sample_period_s!r} gives {ratio:.3g} samples over "
                             f"the reference's {self.reference.duration_s} s; at most 1e8.")
        return int(round(self.reference.duration_s / self.sample_period_s)) + 1

    @property
    def reference_sha256(self) -> str:
        return reference_sha256(self.reference)

    @property
    def setpoint(self) -> Reference:
        """The setpoint as a reference the loop can run (one level per sample)."""
        dt, s = self.sample_period_s, self.setpoint_N
        return Reference(np.arange(s.size - 1, dtype=np.float64) * dt, s[:-1], self.reference.duration_s)

    def check(self, gain_set_sha256: str | None, reference: Reference | None = None,
              shown: str = "the learned signal") -> None:
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
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names the field that is missing or wrong."""
        if not isinstance(doc, dict):
            raise ArtifactError(f"{shown}: a learned signal is a JSON object, got {type(doc).__name__}")

        def field(name: str, convert: Any, default: Any = _REQUIRED) -> Any:
            if name not in doc:
                if default is _REQUIRED:
                    raise ArtifactError(f"{shown}: field '{name}' is missing; learn the signal again")
                return default
            try:
                return convert(doc[name])
            except (TypeError, ValueError, OverflowError) as exc:
                raise ArtifactError(f"{shown}: field '{name}' is invalid ({exc}); learn the signal again") from exc

        reference = field("reference", Reference.from_dict)
        if field("reference_sha256", str) != reference_sha256(reference):
            raise ArtifactError(f"{shown}: field 'reference_sha256' does not match its reference")
        try:
            return cls(field("ff_extra_V", _floats), field("setpoint_N", _floats), field("sample_period_s", _number),
                       reference, field("gain_set_sha256", _optional_text), field("iteration", _count, 0),
                       field("preview_s", _number, 0.0), field("method", _text, "p-type"),
                       field("history", _list, []), field("inputs", _mapping, {}),
                       field("content_sha256", _optional_text, None))
        except ArtifactError:
            raise
        except InputError as exc:  # the signal's own checks (sizes, ranges)
            raise ArtifactError(f"{shown}: {exc} Learn the signal again.") from exc

    @classmethod
    def load(cls, path: str | Path) -> LearnedSignal:
        """The one reader: schema, fields and content hash checked (a changed file is refused)."""
        return cls.from_dict(read_artifact(path, KIND), str(path))

    def save(self, path: str | Path) -> LearnedSignal:
        """Write atomically as a content-hashed artifact; returns the signal with its hash."""
        doc = write_artifact(path, KIND, self.to_dict())
        return replace(self, content_sha256=doc["content_sha256"])
