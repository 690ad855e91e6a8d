"""A design sweep's record: its axes, its points and each point's headline figures (``sweep.json``).

A sweep runs one study at every point of a grid (or a zip) of values of its keys, each point in
its own folder. :class:`SweepRecord` is the one type of what it writes: the study swept, the axes
(:class:`SweepAxis`), and per point (:class:`SweepPoint`) its values, its folder, its status
(``pending``, ``done`` or ``failed``, with the error and the stage that failed) and its headline
figures (:class:`PointFigures`, read from the point's artifacts: None where the study or the
failure left a figure out). :meth:`SweepRecord.rows` is the table a sweep shows: one row per
point, its values and figures, and nothing that differs between two runs of the same sweep
(times, hashes), so two runs of it give the same rows. It is written and read through the
artifact envelope (kind ``sweep``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["SweepAxis", "PointFigures", "SweepPoint", "SweepRecord", "STATUSES", "MODES", "KIND", "Scalar",
           "DEFAULT_SWEEP_OUT", "EXIT_POINT_FAILED"]

KIND = "sweep"
#: the folder a sweep writes into unless told
DEFAULT_SWEEP_OUT = "piezopreload-sweep"
#: the exit code of a sweep that ran but where a point failed (its row says why); 0 done, 1 internal, 2 bad input
EXIT_POINT_FAILED = 5
STATUSES = ("pending", "done", "failed")
MODES = ("grid", "zip")
Scalar = bool | int | float | str


def _is_scalar(value: Any) -> bool:
    return isinstance(value, bool | int | str) or (isinstance(value, float) and math.isfinite(value))


def _checked(value: Any, kind: str, where: str) -> Any:
    """``value`` as a field of ``kind`` (``number``, ``int``, ``str``, ``bool``; each may be None),
    or an error naming it."""
    if value is None:
        return None
    if kind == "number" and isinstance(value, int | float) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ArtifactError(f"{where}: must be a finite number or null, got {value!r}")
        return float(value)
    if kind == "int" and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind == "str" and isinstance(value, str):
        return value
    if kind == "bool" and isinstance(value, bool):
        return value
    raise ArtifactError(f"{where}: expected {'a ' + kind if kind != 'int' else 'an integer'} or null, got {value!r}")


@dataclass(frozen=True)
class SweepAxis:
    """One swept key (``TABLE.KEY``, ``reference.step.final_N``) and its values, in order."""

    key: str
    values: tuple[Scalar, ...]

    def __post_init__(self) -> None:
        if "." not in self.key or not all(self.key.split(".")):
            raise ValueError(f"SweepAxis.key must be TABLE.KEY, got {self.key!r}")
        if not self.values or not all(_is_scalar(v) for v in self.values):
            raise ValueError(f"SweepAxis '{self.key}': values must be a non-empty list of finite numbers, strings or "
                             f"booleans, got {self.values!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"key": self.key, "values": list(self.values)}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "axis") -> SweepAxis:
        if not isinstance(doc, dict) or not isinstance(doc.get("key"), str) or not isinstance(doc.get("values"), list):
            raise ArtifactError(f"{where}: expected an object with 'key' (a string) and 'values' (a list), got {doc!r}")
        try:
            return cls(doc["key"], tuple(doc["values"]))
        except ValueError as exc:
            raise ArtifactError(f"{where}: {exc}") from None


def _figure(kind: str) -> Any:
    return field(default=None, metadata={"kind": kind})


@dataclass(frozen=True)
class PointFigures:
    """A point's headline figures; None where the point's study has no such figure or its run stopped before it.

    Gains (the tune stage), the validation's verdict and worst cases over its Monte Carlo plants
    (the gain set), the tuned FF + PID step's settling on the nominal plant (compare), the whole
    system along its schedule (tracking, rigidity and deflection while cutting, friction energy: the
    system stage; where the study has a ``[thermal]`` table, the shift's nut heat, screw rise, growth and positioning
    error for the schedule and, ``_constant``, the best constant preload), the rig run and the requirements
    (``requirements_missed``: each missed one's ``Requirement.to_dict()``).
    """

    design_stiffness_N_per_um: float | None = _figure("number")
    Kc_V_per_N: float | None = _figure("number")
    Ti_s: float | None = _figure("number")
    Td_s: float | None = _figure("number")
    Tf_s: float | None = _figure("number")
    b: float | None = _figure("number")
    ms: float | None = _figure("number")
    gain_schedule: str | None = _figure("str")
    gain_set_status: str | None = _figure("str")
    validation_plants: int | None = _figure("int")
    validation_failures: int | None = _figure("int")
    worst_settling_s: float | None = _figure("number")
    worst_overshoot_N: float | None = _figure("number")
    worst_tracking_rms_N: float | None = _figure("number")
    worst_peak_voltage_V: float | None = _figure("number")
    tuned_settling_s: float | None = _figure("number")
    tracking_rms_N: float | None = _figure("number")
    tracking_rms_pct_of_range: float | None = _figure("number")
    tracking_rms_pct_of_range_before_learning: float | None = _figure("number")
    tracking_max_N: float | None = _figure("number")
    rigidity_min_cutting_N_per_um: float | None = _figure("number")
    rigidity_required_at_min_N_per_um: float | None = _figure("number")
    rigidity_ratio_min: float | None = _figure("number")
    deflection_max_um: float | None = _figure("number")
    friction_energy_per_cycle: float | None = _figure("number")
    energy_units: str | None = _figure("str")
    constant_friction_energy_per_cycle: float | None = _figure("number")
    friction_saving_pct: float | None = _figure("number")
    heat_mean_W: float | None = _figure("number")
    heat_mean_constant_W: float | None = _figure("number")
    temperature_rise_max_K: float | None = _figure("number")
    temperature_rise_max_constant_K: float | None = _figure("number")
    thermal_growth_max_um: float | None = _figure("number")
    thermal_growth_max_constant_um: float | None = _figure("number")
    positioning_error_max_um: float | None = _figure("number")
    positioning_error_max_constant_um: float | None = _figure("number")
    rig_status: str | None = _figure("str")
    rig_tracking_rms_N: float | None = _figure("number")
    requirements_met: bool | None = _figure("bool")
    requirements_missed: tuple[dict[str, Any], ...] = field(default=(), metadata={"kind": "list"})

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.metadata["kind"] != "list":
                object.__setattr__(self, f.name, _checked(getattr(self, f.name), f.metadata["kind"],
                                                          f"PointFigures.{f.name}"))
        missed = self.requirements_missed
        if not isinstance(missed, tuple | list) or not all(isinstance(r, dict) and "name" in r for r in missed):
            raise ArtifactError(f"PointFigures.requirements_missed: expected a list of requirements (objects with a "
                                f"'name'), got {missed!r}")
        object.__setattr__(self, "requirements_missed", tuple(dict(r) for r in missed))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["requirements_missed"] = [dict(r) for r in self.requirements_missed]
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "figures") -> PointFigures:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected an object, got {type(doc).__name__}")
        missing = [name for name in cls.names() if name not in doc]
        if missing:
            raise ArtifactError(f"{where}: field '{missing[0]}' is missing")
        try:
            return cls(**{name: doc[name] for name in cls.names()})
        except ArtifactError as exc:
            raise ArtifactError(f"{where}: {exc}") from None


@dataclass(frozen=True)
class SweepPoint:
    """One point: its index, its values (key -> value), its folder (relative to the sweep's), its outcome."""

    index: int
    values: dict[str, Scalar]
    folder: str
    status: str = "pending"
    error: str | None = None
    failed_stage: str | None = None
    exit_code: int | None = None
    seconds: float | None = None
    ran: tuple[str, ...] = ()
    reused: tuple[str, ...] = ()
    figures: PointFigures = PointFigures()

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"SweepPoint.status must be one of {', '.join(STATUSES)}, got {self.status!r}")
        if not all(_is_scalar(v) for v in self.values.values()):
            raise ValueError(f"SweepPoint.values must be finite numbers, strings or booleans, got {self.values!r}")
        if Path(self.folder).is_absolute() or not self.folder:
            raise ValueError(f"SweepPoint.folder must be relative to the sweep's folder, got {self.folder!r}")

    def row(self) -> dict[str, Any]:
        """The point as a row: index, folder, values, status, error and figures (nothing that varies between runs)."""
        return {"point": self.index, "folder": self.folder, **self.values, "status": self.status, "error": self.error,
                **self.figures.to_dict()}

    def to_dict(self) -> dict[str, Any]:
        return {"index": self.index, "values": dict(self.values), "folder": self.folder, "status": self.status,
                "error": self.error, "failed_stage": self.failed_stage, "exit_code": self.exit_code,
                "seconds": self.seconds, "ran": list(self.ran), "reused": list(self.reused),
                "figures": self.figures.to_dict()}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "point") -> SweepPoint:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected an object, got {type(doc).__name__}")
        for name, kind in (("index", "int"), ("folder", "str"), ("status", "str"), ("error", "str"),
                           ("failed_stage", "str"), ("exit_code", "int"), ("seconds", "number")):
            if name not in doc:
                raise ArtifactError(f"{where}: field '{name}' is missing")
            _checked(doc[name], kind, f"{where}.{name}")
        for name in ("values", "ran", "reused"):
            if not isinstance(doc.get(name), dict if name == "values" else list):
                raise ArtifactError(f"{where}: field '{name}' is missing or of the wrong type")
        figures = PointFigures.from_dict(doc.get("figures"), f"{where}.figures")
        try:
            return cls(doc["index"], dict(doc["values"]), doc["folder"], doc["status"], doc["error"],
                       doc["failed_stage"], doc["exit_code"], doc["seconds"], tuple(doc["ran"]),
                       tuple(doc["reused"]), figures)
        except (TypeError, ValueError) as exc:
            raise ArtifactError(f"{where}: {exc}") from None


@dataclass(frozen=True)
class SweepRecord:
    """The sweep: the study it swept (name, path as given, SHA-256), how (``grid`` or ``zip``), its axes and points."""

    study_name: str
    study_path: str
    study_sha256: str
    mode: str
    axes: tuple[SweepAxis, ...]
    points: tuple[SweepPoint, ...]
    started_utc: str = ""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"SweepRecord.mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        keys = [a.key for a in self.axes]
        if not keys or len(set(keys)) != len(keys):
            raise ValueError(f"SweepRecord.axes: one axis per key, at least one, got {keys}")
        bad = [p.index for p in self.points if set(p.values) != set(keys)]
        if bad:
            raise ValueError(f"SweepRecord: point {bad[0]} does not give a value to each axis ({', '.join(keys)})")

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(a.key for a in self.axes)

    def columns(self) -> tuple[str, ...]:
        """The rows' columns, in order."""
        return ("point", "folder", *self.keys, "status", "error", *PointFigures.names())

    def rows(self) -> list[dict[str, Any]]:
        """One row per point (:meth:`SweepPoint.row`), in the points' order."""
        return [p.row() for p in self.points]

    def with_point(self, point: SweepPoint) -> SweepRecord:
        """This record with ``point`` in place of the point of its index."""
        return SweepRecord(self.study_name, self.study_path, self.study_sha256, self.mode, self.axes,
                           tuple(point if p.index == point.index else p for p in self.points), self.started_utc)

    def to_dict(self) -> dict[str, Any]:
        return {"study": {"name": self.study_name, "path": self.study_path, "sha256": self.study_sha256},
                "mode": self.mode, "started_utc": self.started_utc, "axes": [a.to_dict() for a in self.axes],
                "points": [p.to_dict() for p in self.points], "columns": list(self.columns())}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "sweep") -> SweepRecord:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected an object, got {type(doc).__name__}")
        study = doc.get("study")
        if not isinstance(study, dict) or not all(isinstance(study.get(k), str) for k in ("name", "path", "sha256")):
            raise ArtifactError(f"{where}: field 'study' must hold 'name', 'path' and 'sha256' (strings)")
        for name in ("axes", "points"):
            if not isinstance(doc.get(name), list):
                raise ArtifactError(f"{where}: field '{name}' is missing or not a list")
        axes = tuple(SweepAxis.from_dict(a, f"{where}.axes[{i}]") for i, a in enumerate(doc["axes"]))
        points = tuple(SweepPoint.from_dict(p, f"{where}.points[{i}]") for i, p in enumerate(doc["points"]))
        try:
            return cls(study["name"], study["path"], study["sha256"], str(doc.get("mode")), axes, points,
                       str(doc.get("started_utc", "")))
        except ValueError as exc:
            raise ArtifactError(f"{where}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write the record atomically (kind ``sweep``)."""
        write_artifact(path, KIND, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> SweepRecord:
        """Read a sweep record: schema and fields checked, a missing or wrong one named."""
        return cls.from_dict(read_artifact(path, KIND), str(path))
