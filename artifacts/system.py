"""The system artifact (kind ``system``): the controlled preload along the design's schedule, as one typed record.

:func:`piezopreload.design.system.track_schedule` runs the force loop over the schedule and
makes a :class:`SystemRecord` of it (:meth:`SystemRun.record <piezopreload.design.system.SystemRun.record>`):
the pre-cycle that brings the stacks to the schedule's first level before the first cut, the
tracking, the requirements as verdicts (:class:`~piezopreload.artifacts.requirements.Requirement`,
``requirements`` beside ``requirements_met``), the bounds that stop a requirement where no schedule
within the stacks' force can meet it with the loop's error, the margin passes, the schedule the
last pass planned (its local margins), the time series and, where the study has a ``[thermal]`` table, the
shift's thermal budget (:class:`~piezopreload.artifacts.thermal.ThermalRecord`). The best constant preload is
not here: it is the design's (:class:`~piezopreload.artifacts.design.DesignRecord`'s schedule), and
``friction_saved_fraction`` is the achieved friction energy against it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts._fields import Fields
from piezopreload.artifacts.requirements import Requirement, requirements_from_dict
from piezopreload.artifacts.thermal import ThermalRecord
from piezopreload.core._typing import Array
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["TrackingNumbers", "PreCycle", "PassRecord", "ScheduleBound", "PlannedSchedule", "SystemSeries",
           "SystemRecord", "KIND"]

KIND = "system"


@dataclass(frozen=True)
class TrackingNumbers:
    """The numbers of one run over the schedule's cycles (the pre-cycle left out).

    Tracking of the stacks' share over the machining cycles (RMS, worst, in % of the
    schedule's range); the least rigidity while cutting (over the cutting samples) with the
    requirement at that moment and its time; apart from it, the least ratio of the rigidity to
    its requirement (the requirement follows the load) with the rigidity, the requirement and
    the time at that sample; the time below the requirement; the largest axial deflection
    while cutting and its limit (None: no limit); the least ratio of the achieved preload to
    the lift-off bound; the largest shortfall of the achieved preload below the least preload
    each sample's requirements need; the friction energy per cycle achieved and planned (the
    loop's reference: the last pass's schedule with its local margins and the stacks' least
    contact force, on the loop's samples), and the fraction the achieved one saves against
    the design's best constant preload; the peak voltage; the error when the first cut begins
    (after the pre-cycle).
    """

    tracking_rms_N: float
    tracking_max_N: float
    tracking_rms_pct_of_range: float
    schedule_range_N: float
    rigidity_min_cutting_N_per_um: float
    rigidity_required_at_min_N_per_um: float
    rigidity_min_t_s: float
    rigidity_ratio_min: float
    rigidity_at_worst_ratio_N_per_um: float
    rigidity_required_at_worst_ratio_N_per_um: float
    rigidity_worst_t_s: float
    rigidity_below_requirement_s: float
    deflection_max_um: float
    deflection_limit_um: float | None
    lift_off_ratio_min: float
    lift_off_margin: float
    preload_shortfall_max_N: float
    friction_energy_per_cycle: float
    planned_friction_energy_per_cycle: float
    friction_saved_fraction: float
    energy_units: str
    peak_voltage_V: float
    cycle_start_error_N: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_fields(cls, f: Fields) -> TrackingNumbers:
        values: dict[str, Any] = {}
        for fd in fields(cls):
            if fd.name == "energy_units":
                values[fd.name] = f.text(fd.name)
            elif fd.name == "deflection_limit_um":
                values[fd.name] = f.optional_number(fd.name)
            else:
                values[fd.name] = f.number(fd.name)
        return cls(**values)


@dataclass(frozen=True)
class PreCycle:
    """Before the first cut: the stacks at rest (0 N) for ``rest_s`` (room for a learned feedforward to lead the
    ramp), then to the schedule's first level ``level_N`` (their share) on a ramp at the slew limit
    ``slew_N_per_s`` (``ramp_s``), then held ``settle_s`` for the loop to settle."""

    level_N: float
    slew_N_per_s: float
    ramp_s: float
    settle_s: float
    rest_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.slew_N_per_s > 0 and min(self.ramp_s, self.settle_s, self.rest_s) >= 0
                and np.isfinite(self.level_N)):
            raise ValueError("PreCycle needs a finite level, slew > 0 and rest_s, ramp_s, "
                             f"settle_s >= 0, got {self!r}.")

    @property
    def duration_s(self) -> float:
        """The pre-cycle's time: from rest to the first cut."""
        return self.rest_s + self.ramp_s + self.settle_s

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "duration_s": self.duration_s}

    @classmethod
    def from_fields(cls, f: Fields) -> PreCycle:
        return f.build(lambda: cls(f.number("level_N"), f.number("slew_N_per_s"), f.number("ramp_s"),
                                   f.number("settle_s"), f.number("rest_s", 0.0)))


@dataclass(frozen=True)
class PassRecord:
    """One margin pass: the largest local margin it planned with and what the loop achieved on it."""

    number: int
    preload_margin_N: float
    tracking_rms_N: float
    tracking_rms_pct_of_range: float
    rigidity_ratio_min: float
    lift_off_ratio_min: float
    requirements_met: bool
    preload_shortfall_max_N: float
    friction_energy_per_cycle: float

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {"pass": d.pop("number"), **d}

    @classmethod
    def from_fields(cls, f: Fields) -> PassRecord:
        return cls(f.integer("pass"), f.number("preload_margin_N"), f.number("tracking_rms_N"),
                   f.number("tracking_rms_pct_of_range"), f.number("rigidity_ratio_min"),
                   f.number("lift_off_ratio_min"), f.flag("requirements_met"), f.number("preload_shortfall_max_N"),
                   f.number("friction_energy_per_cycle"))


@dataclass(frozen=True)
class ScheduleBound:
    """What stops a requirement: where the loop's error needs a margin above the requirement's least preload that the
    stacks' reach cannot give (``kind="reach"``), or where the margin passes ran out first (``kind="passes"``).

    At ``t_s`` (into the cycle) the requirement ``requirement`` needs ``needed_N`` of preload and the
    loop's error a margin of ``margin_N`` above it; the stacks reach ``reach_N``.
    """

    requirement: str
    t_s: float
    needed_N: float
    margin_N: float
    reach_N: float
    kind: str = "reach"

    @property
    def short_N(self) -> float:
        """How far the preload the loop needs lies beyond the stacks' reach (0 for ``kind="passes"``)."""
        return max(self.needed_N + self.margin_N - self.reach_N, 0.0)

    def sentence(self) -> str:
        if self.kind == "reach":
            return (f"{self.requirement} at t = {self.t_s:.3f} s into the cycle: the requirement needs "
                    f"{self.needed_N:,.0f} N of preload and the loop's error a margin of {self.margin_N:,.0f} N above "
                    f"it; the stacks reach {self.reach_N:,.0f} N, {self.short_N:,.0f} N short: no schedule within the "
                    "stacks' force meets it with this loop")
        return (f"{self.requirement} at t = {self.t_s:.3f} s into the cycle: the margin passes ended before the margin "
                f"met it; the next pass would plan {self.margin_N:,.0f} N above the {self.needed_N:,.0f} N it needs "
                f"(within the stacks' {self.reach_N:,.0f} N): raise [plant] passes")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "short_N": self.short_N, "sentence": self.sentence()}

    @classmethod
    def from_fields(cls, f: Fields) -> ScheduleBound:
        kind = f.text("kind", "reach")
        if kind not in ("reach", "passes"):
            raise f.fail("kind", f"must be 'reach' or 'passes', got {kind!r}")
        return cls(f.text("requirement"), f.number("t_s"), f.number("needed_N"), f.number("margin_N"),
                   f.number("reach_N"), kind)


@dataclass(frozen=True, eq=False)
class PlannedSchedule:
    """The schedule the last pass planned, on the load profile's samples: the preload, each sample's margin (the
    room left for the loop; local: only where its error needed it), the margin the stacks' reach could not give,
    and its friction energy per cycle."""

    time_s: Array
    preload_N: Array
    margin_N: Array
    margin_short_N: Array
    friction_energy: float
    energy_units: str
    status: str

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status, "friction_energy": self.friction_energy, "energy_units": self.energy_units,
                "preload_min_N": float(np.min(self.preload_N)), "preload_max_N": float(np.max(self.preload_N)),
                "preload_margin_N": float(np.max(self.margin_N)), "samples": int(self.time_s.size),
                "time_s": self.time_s.tolist(), "preload_N": self.preload_N.tolist(),
                "margin_N": self.margin_N.tolist(), "margin_short_N": self.margin_short_N.tolist()}

    @classmethod
    def from_fields(cls, f: Fields) -> PlannedSchedule:
        t = f.array("time_s")
        return cls(t, f.array("preload_N", t.size), f.array("margin_N", t.size), f.array("margin_short_N", t.size),
                   f.number("friction_energy"), f.text("energy_units"), f.text("status"))


#: the series of the run (every ``every``-th sample), their names in the artifact
SERIES = ("time_s", "planned_N", "achieved_N", "axial_load_N", "rigidity_N_per_um", "required_N_per_um",
          "planned_rigidity_N_per_um", "deflection_um", "voltage_V", "cutting")


@dataclass(frozen=True, eq=False)
class SystemSeries:
    """The run's time series (total preload planned and achieved, the load, the rigidity and its requirement, the
    deflection, the voltage, and whether the axis cuts); the pre-cycle is in them, not cutting."""

    time_s: Array
    planned_N: Array
    achieved_N: Array
    axial_load_N: Array
    rigidity_N_per_um: Array
    required_N_per_um: Array
    planned_rigidity_N_per_um: Array
    deflection_um: Array
    voltage_V: Array
    cutting: NDArray[np.bool_]

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {name: np.asarray(getattr(self, name), float).tolist() for name in SERIES[:-1]}
        out["cutting"] = np.asarray(self.cutting).astype(int).tolist()
        return out

    @classmethod
    def from_fields(cls, f: Fields) -> SystemSeries:
        t = f.array("time_s")
        values = {name: f.array(name, t.size) for name in SERIES[1:-1]}
        return cls(time_s=t, cutting=f.array("cutting", t.size) > 0.5, **values)


@dataclass(frozen=True, eq=False)
class SystemRecord:
    """The system artifact: the numbers, the requirements as verdicts, the bounds, the pre-cycle, the margin passes,
    the schedule the last pass planned, the series, the cycles run and the inputs' hashes."""

    numbers: TrackingNumbers
    requirements: tuple[Requirement, ...]
    bounds: tuple[ScheduleBound, ...]
    pre_cycle: PreCycle
    passes: tuple[PassRecord, ...]
    schedule: PlannedSchedule
    series: SystemSeries
    cycles: int
    inputs: dict[str, Any] = field(default_factory=dict)
    thermal: ThermalRecord | None = None  # the shift's thermal budget, where the study has a [thermal] table

    @property
    def requirements_met(self) -> bool:
        """Whether every requirement is met."""
        return all(r.met for r in self.requirements)

    @property
    def missed(self) -> tuple[Requirement, ...]:
        return tuple(r for r in self.requirements if not r.met)

    @property
    def preload_margin_N(self) -> float:
        """The largest margin the last pass's schedule left the loop (it is local: see ``schedule.margin_N``)."""
        return float(np.max(self.schedule.margin_N))

    def summary(self) -> dict[str, Any]:
        """The numbers, the verdicts and the passes (no series): what the system stage reports."""
        return {**self.numbers.to_dict(), "requirements_met": self.requirements_met,
                "requirements": [r.to_dict() for r in self.requirements], "bounds": [b.to_dict() for b in self.bounds],
                "pre_cycle": self.pre_cycle.to_dict(), "preload_margin_N": self.preload_margin_N, "cycles": self.cycles,
                "passes": [p.to_dict() for p in self.passes],
                **({} if self.thermal is None else {"thermal": self.thermal.summary()})}

    def to_dict(self) -> dict[str, Any]:
        return {**self.summary(), "schedule": self.schedule.to_dict(), "series": self.series.to_dict(),
                "inputs": dict(self.inputs), **({} if self.thermal is None else {"thermal": self.thermal.to_dict()})}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the system") -> SystemRecord:
        """The inverse of :meth:`to_dict`; an :class:`~piezopreload.core.errors.ArtifactError` names the field."""
        f = Fields(doc, shown)
        record = cls(numbers=TrackingNumbers.from_fields(f), requirements=requirements_from_dict(
                         f.raw("requirements"), f"{shown}: field 'requirements'"),
                     bounds=f.items("bounds", ScheduleBound.from_fields),
                     pre_cycle=PreCycle.from_fields(f.sub("pre_cycle")),
                     passes=f.items("passes", PassRecord.from_fields),
                     schedule=PlannedSchedule.from_fields(f.sub("schedule")),
                     series=SystemSeries.from_fields(f.sub("series")), cycles=f.integer("cycles"),
                     inputs=f.mapping("inputs", {}),
                     thermal=ThermalRecord.from_fields(f.sub("thermal")) if f.has("thermal") else None)
        if f.flag("requirements_met") != record.requirements_met:
            raise ArtifactError(f"{shown}: field 'requirements_met' does not agree with its 'requirements'")
        return record

    def save(self, path: str | Path) -> Path:
        """Write the artifact atomically (kind ``system``)."""
        write_artifact(path, KIND, self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> SystemRecord:
        """Read a system artifact: its schema and every field checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))
