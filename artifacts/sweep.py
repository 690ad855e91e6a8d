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
from dataclasses import fields
from pathlib import Path
from typing import Any, ClassVar

from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Record, SavedArtifact, entry, record

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


def _point_values(x: Any) -> dict[str, Scalar]:
    if not isinstance(x, dict):
        raise ValueError(f"expected an object of the axes' keys and values, got {type(x).__name__}")
    return dict(x)


def _values(x: Any) -> tuple[Scalar, ...]:
    if not isinstance(x, list):
        raise ValueError(f"expected a list of finite numbers, strings or booleans, got {type(x).__name__}")
    return tuple(x)


@record
class SweepAxis(Record):
    """One swept key and its values, in order."""

    NOUN: ClassVar[str] = "the axis"

    key: str = entry("The key, ``TABLE.KEY`` (``reference.step.final_N``).")
    values: tuple[Scalar, ...] = entry("Its values: finite numbers, strings or booleans.", read=_values,
                                       write=list, takes="a list of finite numbers, strings or booleans")

    def __post_init__(self) -> None:
        if "." not in self.key or not all(self.key.split(".")):
            raise ValueError(f"SweepAxis.key must be TABLE.KEY, got {self.key!r}")
        if not self.values or not all(_is_scalar(v) for v in self.values):
            raise ValueError(f"SweepAxis '{self.key}': values must be a non-empty list of finite numbers, strings or "
                             f"booleans, got {self.values!r}")


def _figure(doc: str, unit: str = "") -> Any:
    return entry(doc, unit=unit, default=None, required=True)


@record
class PointFigures(Record):
    """A point's headline figures; None where the point's study has no such figure or its run stopped before it.

    Gains (the tune stage), the validation's verdict and worst cases over its Monte Carlo plants
    (the gain set), the tuned FF + PID step's settling on the nominal plant (compare), the whole
    system along its schedule (tracking, rigidity and deflection while cutting, friction energy: the
    system stage; where the study has a ``[thermal]`` table, the shift's nut heat, screw rise, growth and positioning
    error for the schedule and, ``constant_``, the best constant preload, each under its name in the thermal
    budget's :class:`~piezopreload.artifacts.thermal.ThermalCase`), the rig run and the requirements
    (``requirements_missed``: each missed one's ``Requirement.to_dict()``).
    """

    NOUN: ClassVar[str] = "the point's figures"
    #: the thermal columns as sweeps before the names were unified wrote them
    RENAMED: ClassVar[dict[str, str]] = {
        "heat_mean_constant_W": "constant_heat_mean_W",
        "temperature_rise_max_constant_K": "constant_temperature_rise_max_K",
        "thermal_growth_max_um": "growth_max_um", "thermal_growth_max_constant_um": "constant_growth_max_um",
        "positioning_error_max_constant_um": "constant_positioning_error_max_um"}

    design_stiffness_N_per_um: float | None = _figure("The design optimum's least rigidity.", "N/um")
    Kc_V_per_N: float | None = _figure("The tuned controller gain.", "V/N")
    Ti_s: float | None = _figure("The tuned integral time.", "s")
    Td_s: float | None = _figure("The tuned derivative time.", "s")
    Tf_s: float | None = _figure("The tuned derivative filter's time.", "s")
    b: float | None = _figure("The tuned setpoint weight.")
    ms: float | None = _figure("The sensitivity peak the tuning reached.")
    gain_schedule: str | None = _figure("The gain schedule in words, where one was tuned.")
    gain_set_status: str | None = _figure("The gain set's status.")
    validation_plants: int | None = _figure("The Monte Carlo plants.")
    validation_failures: int | None = _figure("The plants that missed a criterion.")
    worst_settling_s: float | None = _figure("The worst plant's settling time.", "s")
    worst_overshoot_N: float | None = _figure("The worst plant's overshoot.", "N")
    worst_tracking_rms_N: float | None = _figure("The worst plant's RMS tracking error.", "N")
    worst_peak_voltage_V: float | None = _figure("The worst plant's highest command.", "V")
    tuned_settling_s: float | None = _figure("The tuned FF + PID step's settling on the nominal plant.", "s")
    tracking_rms_N: float | None = _figure("The whole system's RMS tracking error along its schedule.", "N")
    tracking_rms_pct_of_range: float | None = _figure("The same, in % of the schedule's range.", "%")
    tracking_rms_pct_of_range_before_learning: float | None = _figure("The same before any learned correction.", "%")
    tracking_max_N: float | None = _figure("The largest tracking error.", "N")
    rigidity_min_cutting_N_per_um: float | None = _figure("The least rigidity while cutting.", "N/um")
    rigidity_required_at_min_N_per_um: float | None = _figure("The rigidity required at that moment.", "N/um")
    rigidity_ratio_min: float | None = _figure("The least ratio of the rigidity to its requirement.")
    deflection_max_um: float | None = _figure("The largest deflection while cutting.", "um")
    friction_energy_per_cycle: float | None = _figure("The friction energy per cycle, in ``energy_units``.")
    energy_units: str | None = _figure("The friction energy's unit.")
    constant_friction_energy_per_cycle: float | None = _figure("The best constant preload's friction energy per "
                                                               "cycle.")
    friction_saving_pct: float | None = _figure("The friction energy the schedule saves against it.", "%")
    heat_mean_W: float | None = _figure("The nut's mean friction heat along the schedule.", "W")
    constant_heat_mean_W: float | None = _figure("The same at the best constant preload.", "W")
    temperature_rise_max_K: float | None = _figure("The screw's largest rise over the shift.", "K")
    constant_temperature_rise_max_K: float | None = _figure("The same at the best constant preload.", "K")
    growth_max_um: float | None = _figure("The screw's largest growth at the table.", "um")
    constant_growth_max_um: float | None = _figure("The same at the best constant preload.", "um")
    positioning_error_max_um: float | None = _figure("The largest positioning error of the budget.", "um")
    constant_positioning_error_max_um: float | None = _figure("The same at the best constant preload.", "um")
    rig_status: str | None = _figure("How the rig run ended.")
    rig_tracking_rms_N: float | None = _figure("The rig run's RMS tracking error.", "N")
    requirements_met: bool | None = _figure("Whether every requirement held.")
    requirements_missed: tuple[dict[str, Any], ...] = entry("Each missed requirement's ``Requirement.to_dict()``.",
                                                            default=(), required=True)

    def __post_init__(self) -> None:
        for name, kind in _FIGURE_KINDS.items():
            object.__setattr__(self, name, _checked(getattr(self, name), kind, f"PointFigures.{name}"))
        missed = self.requirements_missed
        if not isinstance(missed, tuple | list) or not all(isinstance(r, dict) and "name" in r for r in missed):
            raise ArtifactError(f"PointFigures.requirements_missed: expected a list of requirements (objects with a "
                                f"'name'), got {missed!r}")
        object.__setattr__(self, "requirements_missed", tuple(dict(r) for r in missed))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))



#: each figure's kind (what ``_checked`` takes), from its annotation
_FIGURE_KINDS = {f.name: {"float | None": "number", "int | None": "int", "str | None": "str",
                          "bool | None": "bool"}[str(f.type)]
                 for f in fields(PointFigures) if f.name != "requirements_missed"}


@record
class SweepPoint(Record):
    """One point of a sweep: its values, its folder and its outcome."""

    NOUN: ClassVar[str] = "the point"

    index: int = entry("Its index in the sweep, from 0.", ge=0)
    values: dict[str, Scalar] = entry("Each axis' key and its value at the point.", read=_point_values,
                                      takes="an object of the axes' keys and values")
    folder: str = entry("Its folder, relative to the sweep's.")
    status: str = entry("``pending``, ``done`` or ``failed``.", choices=STATUSES, default="pending", required=True)
    error: str | None = entry("Why it failed.", default=None, required=True)
    failed_stage: str | None = entry("The stage that failed.", default=None, required=True)
    exit_code: int | None = entry("The exit code its run gave.", default=None, required=True)
    seconds: float | None = entry("How long it ran.", unit="s", default=None, required=True)
    ran: tuple[str, ...] = entry("The stages it ran.", default=(), required=True)
    reused: tuple[str, ...] = entry("The stages it reused.", default=(), required=True)
    figures: PointFigures = entry("Its headline figures.", default=PointFigures(), required=True)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"SweepPoint.status must be one of {', '.join(STATUSES)}, got {self.status!r}")
        if not all(_is_scalar(v) for v in self.values.values()):
            raise ValueError(f"SweepPoint.values must be finite numbers, strings or booleans, got {self.values!r}")
        if Path(self.folder).is_absolute() or not self.folder:
            raise ValueError(f"SweepPoint.folder must be relative to the sweep's folder, got {self.folder!r}")

    def row(self) -> dict[str, Any]:
        """The point as a row: index, folder, values, status, error and figures (nothing that varies between runs).

        Returns
        -------
        dict
            ``point`` (the index), ``folder``, each swept key's value, ``status``, ``error`` and each figure by name:
            one row of the sweep's table.
        """
        return {"point": self.index, "folder": self.folder, **self.values, "status": self.status, "error": self.error,
                **self.figures.to_dict()}



@record
class SweepRecord(SavedArtifact):
    """The sweep: the study it swept, how, its axes and its points."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the sweep"
    AGAIN: ClassVar[str] = "run the sweep again ('piezopreload sweep')"

    study_name: str = entry("The study's name.", at="study", name="name")
    study_path: str = entry("The study's file, as it was given.", at="study", name="path")
    study_sha256: str = entry("The study file's SHA-256.", at="study", name="sha256")
    mode: str = entry("How the axes combine: ``grid`` (every combination) or ``zip`` (their values side by side).",
                      choices=MODES)
    axes: tuple[SweepAxis, ...] = entry("The axes.")
    points: tuple[SweepPoint, ...] = entry("The points.")
    started_utc: str = entry("When the sweep started (UTC).", default="")

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
        """The record and its rows' columns.

        Returns
        -------
        dict
            The document's body.
        """
        return {**super().to_dict(), "columns": list(self.columns())}
