"""The tuning record: what the tune stage writes (``tuning.json``, kind ``tuning``) and the
report and validate stage read.

One frozen dataclass per part, each with ``to_dict``/``from_dict``:

* :class:`TuningRecord`: the tuned gains, the SIMC baseline, what the NLP did
  (:class:`TuningSolve`), the comparison table (:class:`ComparisonRow`, one per gain set with and
  without the feedforward), the gains on the ends of their search range (:class:`ActiveBound`),
  the minimum-time bound (:class:`MinimumTimeBound`) and the tracking floor
  (:class:`TrackingFloor`), the criteria the table was scored with and the inputs' hashes;
* :meth:`TuningRecord.save` writes it through :func:`piezopreload.core.artifacts.write_artifact`,
  :meth:`TuningRecord.load` reads it through :func:`~piezopreload.core.artifacts.read_artifact`
  (schema, kind and content hash checked); a missing or non-finite field is named.

The JSON layout is the one the tune stage wrote before the record was typed, with
``active_bounds`` added and the minimum-time bound's ``samples``, ``hold_s`` and ``seconds``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from piezopreload.artifacts._fields import (
    count,
    flag,
    mapping,
    number,
    optional_count,
    optional_number,
    optional_text,
    text,
)
from piezopreload.artifacts.gainset import GainSet, gains_from_dict, gains_to_dict
from piezopreload.core.artifacts import artifact_kind, read_artifact, schema_name, write_artifact
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.controller import PIDGains

__all__ = ["KIND", "ActiveBound", "ComparisonRow", "MinimumTimeBound", "TrackingFloor", "TuningSolve", "TuningRecord",
           "SIDES", "warm_start_gains"]

KIND = "tuning"
SIDES = ("lower", "upper")
_REQUIRED = object()
_AGAIN = "run the tune stage again"


def _optional_mapping(x: Any) -> dict[str, Any] | None:
    return None if x is None else mapping(x)


def _texts(x: Any) -> tuple[str, ...]:
    if not isinstance(x, list):
        raise ValueError(f"expected a list, got {type(x).__name__}")
    return tuple(text(v) for v in x)


def _ratios(x: Any) -> dict[str, float | None]:
    return {str(k): optional_number(v) for k, v in mapping(x).items()}


def _numbers(x: Any) -> dict[str, float]:
    return {str(k): number(v) for k, v in mapping(x).items()}


def _field(doc: Any, name: str, convert: Callable[[Any], Any], where: str, default: Any = _REQUIRED) -> Any:
    """``convert(doc[name])``; an :class:`ArtifactError` names ``where.name`` when it is missing or invalid."""
    if not isinstance(doc, dict):
        raise ArtifactError(f"field '{where}' must be an object, got {type(doc).__name__}; {_AGAIN}")
    if name not in doc:
        if default is _REQUIRED:
            raise ArtifactError(f"field '{where}.{name}' is missing; {_AGAIN}")
        return default
    try:
        return convert(doc[name])
    except (TypeError, ValueError, InputError) as exc:
        raise ArtifactError(f"field '{where}.{name}' is invalid: {exc}; {_AGAIN}") from None


def _check_finite(obj: Any, names: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    for name in names + optional:
        value = getattr(obj, name)
        if value is None and name in optional:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be a finite number, got {value!r}")


@dataclass(frozen=True)
class ActiveBound:
    """A tuned gain on an end of its search range, and what that means for the controller.

    Parameters
    ----------
    gain : str
        The gain's field in :class:`~piezopreload.models.controller.PIDGains` (``Kc``, ``Ti_s``, ``Td_s``, ``Tf_s``).
    side : {"lower", "upper"}
        Which end of the range.
    bound : float
        The end of the range, in the gain's unit.
    note : str
        What it means ("the controller is a PI (Td = 0, no derivative filter)").
    """

    gain: str
    side: str
    bound: float
    note: str

    def __post_init__(self) -> None:
        if self.side not in SIDES:
            raise ValueError(f"ActiveBound.side must be one of {', '.join(SIDES)}, got {self.side!r}")
        _check_finite(self, ("bound",))

    def sentence(self) -> str:
        """The bound in words: ``the derivative time Td at its lower bound (1e-05 s): ...``."""
        words, unit = _GAIN_WORDS.get(self.gain, (self.gain, ""))
        return f"{words} at its {self.side} bound ({self.bound:.4g}{unit}): {self.note}"

    def to_dict(self) -> dict[str, Any]:
        return {"gain": self.gain, "side": self.side, "bound": self.bound, "note": self.note}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "active_bounds[]") -> ActiveBound:
        return _construct(cls, where, gain=_field(doc, "gain", text, where), side=_field(doc, "side", text, where),
                          bound=_field(doc, "bound", number, where), note=_field(doc, "note", text, where))


#: each gain's words and unit, as a sentence names it
_GAIN_WORDS = {"Kc": ("the gain Kc", " V/N"), "Ti_s": ("the integral time Ti", " s"),
               "Td_s": ("the derivative time Td", " s"), "Tf_s": ("the derivative filter's time Tf", " s"),
               "b": ("the setpoint weight b", "")}


def _construct(cls: Any, where: str, **kwargs: Any) -> Any:
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ArtifactError(f"field '{where}' is invalid: {exc}; {_AGAIN}") from None


@dataclass(frozen=True)
class ComparisonRow:
    """One gain set without or with the feedforward on the nominal rig, scored as the validation scores a plant.

    ``row["settling_s"]`` reads a field by name, as the table's JSON names it.
    """

    gains: str
    feedforward: bool
    rise_s: float | None
    settling_s: float | None
    settling_measured_s: float | None
    overshoot_N: float
    tracking_rms_N: float
    tracking_rms_after_change_N: float
    peak_command_V: float

    def __post_init__(self) -> None:
        _check_finite(self, ("overshoot_N", "tracking_rms_N", "tracking_rms_after_change_N", "peak_command_V"),
                      ("rise_s", "settling_s", "settling_measured_s"))

    def __getitem__(self, key: str) -> Any:
        if key not in _ROW_FIELDS:
            raise KeyError(key)
        return getattr(self, key)

    def to_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in _ROW_FIELDS}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "table[]") -> ComparisonRow:
        values = {name: _field(doc, name, optional_number, where)
                  for name in ("rise_s", "settling_s", "settling_measured_s")}
        values |= {name: _field(doc, name, number, where)
                   for name in ("overshoot_N", "tracking_rms_N", "tracking_rms_after_change_N", "peak_command_V")}
        return _construct(cls, where, gains=_field(doc, "gains", text, where),
                          feedforward=_field(doc, "feedforward", flag, where), **values)


_ROW_FIELDS = tuple(f.name for f in fields(ComparisonRow))


@dataclass(frozen=True)
class MinimumTimeBound:
    """The least settling time any command reaches on the tuning model, beside the tuned loop's.

    ``settling_s`` None: no bound (``reason`` says why); ``samples`` the bound in samples, ``hold_s``
    how long the force stays in the band, ``seconds`` what computing it took;
    ``tuned_over_bound_ratio`` the tuned settling over the bound (None where either is missing).
    """

    settling_s: float | None
    tuned_over_bound_ratio: float | None
    samples: int | None = None
    hold_s: float | None = None
    seconds: float | None = None
    reason: str | None = None

    def __post_init__(self) -> None:
        _check_finite(self, (), ("settling_s", "tuned_over_bound_ratio", "hold_s", "seconds"))
        if self.settling_s is None and not self.reason:
            raise ValueError("MinimumTimeBound without settling_s needs the reason")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"settling_s": self.settling_s, "tuned_over_bound_ratio": self.tuned_over_bound_ratio}
        out |= {k: getattr(self, k) for k in ("samples", "hold_s", "seconds", "reason") if getattr(self, k) is not None}
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "minimum_time") -> MinimumTimeBound:
        return _construct(cls, where, settling_s=_field(doc, "settling_s", optional_number, where),
                          tuned_over_bound_ratio=_field(doc, "tuned_over_bound_ratio", optional_number, where),
                          samples=_field(doc, "samples", optional_count, where, None),
                          hold_s=_field(doc, "hold_s", optional_number, where, None),
                          seconds=_field(doc, "seconds", optional_number, where, None),
                          reason=_field(doc, "reason", optional_text, where, None))


@dataclass(frozen=True)
class TrackingFloor:
    """The least RMS tracking error of any causal controller without preview, and the tuned loop's over it."""

    rms_N: float
    rate_N_per_s: float
    tuned_over_floor_ratio: float | None

    def __post_init__(self) -> None:
        _check_finite(self, ("rms_N", "rate_N_per_s"), ("tuned_over_floor_ratio",))

    def to_dict(self) -> dict[str, Any]:
        return {"rms_N": self.rms_N, "rate_N_per_s": self.rate_N_per_s,
                "tuned_over_floor_ratio": self.tuned_over_floor_ratio}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "tracking_floor") -> TrackingFloor:
        return _construct(cls, where, rms_N=_field(doc, "rms_N", number, where),
                          rate_N_per_s=_field(doc, "rate_N_per_s", number, where),
                          tuned_over_floor_ratio=_field(doc, "tuned_over_floor_ratio", optional_number, where))


@dataclass(frozen=True)
class TuningSolve:
    """What the tuning NLP did: IPOPT's status, iterations and time, the engine, the objective, the Ms reached,
    the binding constraints and every constraint's margin (``g <= 0`` met), the FOPDT fit the start came from,
    the controller's form (``PI`` or ``PID``), the specification, how the search ended (``search``: its runs, those
    stopped on the iteration limit, where the result came from) and, if one was tuned, the gain schedule's record."""

    status: str
    iterations: int
    seconds: float
    engine: str
    compile_s: float
    objective: float
    ms: float
    binding: tuple[str, ...]
    constraint_margins: dict[str, float]
    fopdt: dict[str, float]
    form: str = "PID"
    spec: dict[str, Any] = field(default_factory=dict)
    schedule: dict[str, Any] | None = None
    search: str = ""

    def __post_init__(self) -> None:
        _check_finite(self, ("iterations", "seconds", "compile_s", "objective", "ms"))
        if self.form not in ("PI", "PID"):
            raise ValueError(f"TuningSolve.form must be 'PI' or 'PID', got {self.form!r}")

    def to_dict(self) -> dict[str, Any]:
        out = {"status": self.status, "iterations": self.iterations, "seconds": self.seconds, "engine": self.engine,
               "compile_s": self.compile_s, "objective": self.objective, "ms": self.ms, "binding": list(self.binding),
               "constraint_margins": dict(self.constraint_margins), "fopdt": dict(self.fopdt), "form": self.form,
               "spec": dict(self.spec), "search": self.search}
        if self.schedule is not None:
            out["schedule"] = self.schedule
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "tuning") -> TuningSolve:
        f = {name: _field(doc, name, convert, where) for name, convert in (
            ("status", text), ("iterations", count), ("seconds", number), ("engine", text), ("compile_s", number),
            ("objective", number), ("ms", number), ("binding", _texts), ("constraint_margins", _numbers),
            ("fopdt", _numbers))}
        return _construct(cls, where, **f, form=_field(doc, "form", text, where, "PID"),
                          spec=_field(doc, "spec", mapping, where, {}),
                          schedule=_field(doc, "schedule", _optional_mapping, where, None),
                          search=_field(doc, "search", text, where, ""))


@dataclass(frozen=True)
class TuningRecord:
    """The tune stage's artifact (see the module docstring).

    Parameters
    ----------
    gains, simc_baseline : PIDGains
        The tuned gains (the gain schedule's when one was chosen) and SIMC's on the FOPDT fit.
    solve : TuningSolve
        What the NLP did (the JSON's ``tuning``).
    table : tuple of ComparisonRow
        Each gain set without and with the feedforward on the nominal rig.
    minimum_time, tracking_floor : MinimumTimeBound, TrackingFloor
        The lower bounds the tuned loop is read against.
    active_bounds : tuple of ActiveBound
        The tuned gains on an end of their search range.
    criteria, tracking_improvement, inputs : dict
        How the table was scored, the study's starting gains' tracking RMS over the tuned one, the inputs' hashes.
    published : dict or None
        The published figures the table is read beside, where the study declares them (``[published]``).
    """

    gains: PIDGains
    simc_baseline: PIDGains
    solve: TuningSolve
    table: tuple[ComparisonRow, ...]
    minimum_time: MinimumTimeBound
    tracking_floor: TrackingFloor
    active_bounds: tuple[ActiveBound, ...] = ()
    criteria: dict[str, Any] = field(default_factory=dict)
    tracking_improvement: dict[str, float | None] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    published: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        for name in ("gains", "simc_baseline"):
            if not isinstance(getattr(self, name), PIDGains):
                raise ValueError(f"TuningRecord.{name} must be PIDGains, got {type(getattr(self, name)).__name__}")
        object.__setattr__(self, "table", tuple(self.table))
        object.__setattr__(self, "active_bounds", tuple(self.active_bounds))

    def row(self, gains: str = "tuned", feedforward: bool = True) -> ComparisonRow:
        """One row of the comparison table; a ``KeyError`` names what the table holds."""
        for r in self.table:
            if r.gains == gains and r.feedforward == feedforward:
                return r
        raise KeyError(f"no row ({gains!r}, feedforward={feedforward}) in the table; it holds "
                       + ", ".join(f"({r.gains!r}, {r.feedforward})" for r in self.table))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "gains": gains_to_dict(self.gains), "simc_baseline": gains_to_dict(self.simc_baseline),
            "tuning": self.solve.to_dict(), "criteria": dict(self.criteria), "table": [r.to_dict() for r in self.table],
            "minimum_time": self.minimum_time.to_dict(), "tracking_floor": self.tracking_floor.to_dict(),
            "tracking_improvement": dict(self.tracking_improvement),
            "active_bounds": [b.to_dict() for b in self.active_bounds], "inputs": dict(self.inputs)}
        if self.published is not None:
            out["published"] = self.published
        return out

    @classmethod
    def from_dict(cls, doc: Any, shown: str = "the tuning record") -> TuningRecord:
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names ``shown`` and the field."""
        try:
            return cls._from_dict(doc)
        except ArtifactError as exc:
            raise ArtifactError(f"{shown}: {exc}") from None

    @classmethod
    def _from_dict(cls, doc: Any) -> TuningRecord:
        def gains(name: str) -> PIDGains:
            return _field(doc, name, lambda g: gains_from_dict(g, name), "tuning record")

        table = _field(doc, "table", _list, "tuning record")
        bounds = _field(doc, "active_bounds", _list, "tuning record", [])
        return cls(
            gains=gains("gains"), simc_baseline=gains("simc_baseline"),
            solve=TuningSolve.from_dict(_field(doc, "tuning", mapping, "tuning record")),
            table=tuple(ComparisonRow.from_dict(r, f"table[{i}]") for i, r in enumerate(table)),
            minimum_time=MinimumTimeBound.from_dict(_field(doc, "minimum_time", mapping, "tuning record")),
            tracking_floor=TrackingFloor.from_dict(_field(doc, "tracking_floor", mapping, "tuning record")),
            active_bounds=tuple(ActiveBound.from_dict(b, f"active_bounds[{i}]") for i, b in enumerate(bounds)),
            criteria=_field(doc, "criteria", mapping, "tuning record", {}),
            tracking_improvement=_field(doc, "tracking_improvement", _ratios, "tuning record", {}),
            inputs=_field(doc, "inputs", mapping, "tuning record", {}),
            published=_field(doc, "published", _optional_mapping, "tuning record", None))

    @classmethod
    def load(cls, path: str | Path) -> TuningRecord:
        """The one reader: schema, kind, fields and content hash checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))

    def save(self, path: str | Path) -> Path:
        """Write atomically (:func:`~piezopreload.core.artifacts.write_artifact`); returns the path."""
        write_artifact(path, KIND, self.to_dict())
        return Path(path)


def warm_start_gains(path: str | Path) -> PIDGains:
    """The gains of a tuning record (``tuning.json``) or of a gain set (``gains.json``), each through its one reader
    (schema, fields and content hash checked): what ``[tuning] warm_start`` names. An :class:`ArtifactError` names
    the file where it is neither."""
    kind = artifact_kind(path)
    if kind == KIND:
        return TuningRecord.load(path).gains
    if kind == "gain-set":
        return GainSet.load(path).gains
    raise ArtifactError(f"{path}: is a {kind} artifact; expected a tuning record ({schema_name(KIND)}) or a gain set "
                        f"({schema_name('gain-set')})")


def _list(x: Any) -> list[Any]:
    if not isinstance(x, list):
        raise ValueError(f"expected a list, got {type(x).__name__}")
    return x
