"""The preload schedule's types: the load profile, what the schedule must keep, and the planned schedule.

:func:`piezopreload.design.schedule.schedule_preload` computes a :class:`PreloadSchedule`; the design
artifact (:class:`~piezopreload.artifacts.design.DesignRecord`) records it, and every reader
(the system stage, the report) takes it from there: the best constant preload and its friction
energy are computed once, by the design, and read from this record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.artifacts._fields import Fields
from piezopreload.core._typing import Array

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LoadProfile", "ScheduleSpec", "PreloadSchedule"]


@dataclass(frozen=True)
class LoadProfile:
    """Axial load (N) and screw speed (rpm) against time (s), one row per sample."""

    time_s: Array
    axial_load_N: Array
    speed_rpm: Array | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s, float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"LoadProfile.time_s must be 1-D with at least 2 samples, got shape {t.shape}.")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("LoadProfile.time_s must be finite and strictly increasing.")
        for name in ("axial_load_N", "speed_rpm"):
            v = getattr(self, name)
            if v is None:
                continue
            v = np.asarray(v, float)
            if v.shape != t.shape or not np.all(np.isfinite(v)):
                raise ValueError(f"LoadProfile.{name} must be finite with the shape of time_s {t.shape}.")
        if self.speed_rpm is not None and np.any(np.asarray(self.speed_rpm) < 0):
            raise ValueError("LoadProfile.speed_rpm must be >= 0 (the load's sign carries the direction).")

    @property
    def dt_s(self) -> Array:
        """Each sample's share of time (half the gaps to its neighbours)."""
        t = np.asarray(self.time_s, float)
        gaps = np.diff(t)
        return 0.5 * (np.concatenate([[0.0], gaps]) + np.concatenate([gaps, [0.0]]))

    @property
    def cutting(self) -> NDArray[np.bool_]:
        """The samples under load (where the schedule's requirements are judged)."""
        return np.abs(np.asarray(self.axial_load_N, float)) > 0


@dataclass(frozen=True)
class ScheduleSpec:
    """The schedule's requirements and limits (``deflection_max_um`` inf: no limit)."""

    bolt_preload_N: float
    max_preload_N: float
    slew_N_per_s: float
    stiffness_min_N_per_um: float = 0.0
    deflection_max_um: float = math.inf
    lift_off_margin: float = 1.2
    preload_margin_N: float = 0.0  # the control's room everywhere: every requirement holds at the preload less this

    def __post_init__(self) -> None:
        if not 0 < self.bolt_preload_N < self.max_preload_N < math.inf:
            raise ValueError(f"ScheduleSpec needs 0 < bolt_preload_N < max_preload_N, got {self.bolt_preload_N!r} "
                             f"and {self.max_preload_N!r}.")
        if not (self.slew_N_per_s > 0 and math.isfinite(self.slew_N_per_s)):
            raise ValueError(f"ScheduleSpec.slew_N_per_s must be a finite number > 0, got {self.slew_N_per_s!r}.")
        if not (self.stiffness_min_N_per_um >= 0 and self.deflection_max_um > 0 and self.lift_off_margin >= 1):
            raise ValueError("ScheduleSpec needs stiffness_min_N_per_um >= 0, deflection_max_um > 0 and "
                             "lift_off_margin >= 1.")
        if not (math.isfinite(self.preload_margin_N) and self.preload_margin_N >= 0):
            raise ValueError(f"ScheduleSpec.preload_margin_N must be finite and >= 0, got {self.preload_margin_N!r}.")

    def required_stiffness(self, axial_load_N: ArrayLike) -> Array:
        return np.maximum(self.stiffness_min_N_per_um, np.abs(np.asarray(axial_load_N, float)) / self.deflection_max_um)

    def to_dict(self) -> dict[str, Any]:
        return {"bolt_preload_N": self.bolt_preload_N, "max_preload_N": self.max_preload_N,
                "slew_N_per_s": self.slew_N_per_s, "stiffness_min_N_per_um": self.stiffness_min_N_per_um,
                "deflection_max_um": None if math.isinf(self.deflection_max_um) else self.deflection_max_um,
                "lift_off_margin": self.lift_off_margin, "preload_margin_N": self.preload_margin_N}

    @classmethod
    def from_fields(cls, f: Fields) -> ScheduleSpec:
        deflection = f.optional_number("deflection_max_um")
        return f.build(lambda: cls(
            f.number("bolt_preload_N"), f.number("max_preload_N"), f.number("slew_N_per_s"),
            f.number("stiffness_min_N_per_um", 0.0), math.inf if deflection is None else deflection,
            f.number("lift_off_margin", 1.2), f.number("preload_margin_N", 0.0)))


#: the per-sample series a schedule records (beside the profile's time, load and speed)
_SERIES = ("preload_N", "needed_N", "margin_N", "margin_short_N", "rigidity_N_per_um", "required_N_per_um",
           "constant_rigidity_N_per_um")


@dataclass(frozen=True, eq=False)
class PreloadSchedule:
    """The planned schedule, the best constant preload, and what the schedule saves.

    ``needed_N`` is each sample's least preload meeting its requirements (no margin): the
    requirement's own bound, and its maximum is the best constant preload. ``margin_N`` is the
    room each sample leaves the force loop (every requirement holds at ``preload_N - margin_N``:
    the spec's uniform margin plus the local margins the whole system asked for), and
    ``margin_short_N`` the local margin the stacks' reach could not give (0 where it could).
    """

    profile: LoadProfile
    spec: ScheduleSpec
    preload_N: Array
    constant_preload_N: float
    rigidity_N_per_um: Array
    required_N_per_um: Array
    constant_rigidity_N_per_um: Array
    friction_energy_J: float
    constant_friction_energy_J: float
    energy_units: str
    status: str
    needed_N: Array
    margin_N: Array
    margin_short_N: Array

    def __post_init__(self) -> None:
        n = np.asarray(self.profile.time_s).size
        for name in _SERIES:
            value = np.asarray(getattr(self, name), float)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise ValueError(f"PreloadSchedule.{name} must hold one finite number per sample ({n}).")
            object.__setattr__(self, name, value)
        for name in ("constant_preload_N", "friction_energy_J", "constant_friction_energy_J"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"PreloadSchedule.{name} must be finite, got {getattr(self, name)!r}.")

    @property
    def saving_fraction(self) -> float:
        """The plan's friction energy against the best constant preload's: the fraction it saves."""
        return 1.0 - self.friction_energy_J / self.constant_friction_energy_J

    def summary(self) -> dict[str, Any]:
        """The schedule's numbers (no series): what ``design --json`` prints."""
        return {
            "status": self.status, "friction_energy": self.friction_energy_J,
            "constant_friction_energy": self.constant_friction_energy_J, "energy_units": self.energy_units,
            "saving_fraction": self.saving_fraction, "constant_preload_N": self.constant_preload_N,
            "preload_min_N": float(self.preload_N.min()), "preload_max_N": float(self.preload_N.max()),
            "stiffness_margin_min_N_per_um": float(np.min(self.rigidity_N_per_um - self.required_N_per_um)),
            "samples": int(self.preload_N.size), **self.spec.to_dict(),
            "local_margin_max_N": (0.0 if self.margin_N is None else
                                   float(np.max(self.margin_N - self.spec.preload_margin_N, initial=0.0))),
        }

    def to_dict(self) -> dict[str, Any]:
        """:meth:`summary`, the profile and every series: the design artifact's ``schedule``."""
        p = self.profile
        return {**self.summary(), "time_s": p.time_s.tolist(), "axial_load_N": p.axial_load_N.tolist(),
                "speed_rpm": None if p.speed_rpm is None else np.asarray(p.speed_rpm, float).tolist(),
                **{name: getattr(self, name).tolist() for name in _SERIES}}

    @classmethod
    def from_fields(cls, f: Fields) -> PreloadSchedule:
        """The inverse of :meth:`to_dict`, each field checked (its errors name the field)."""
        t = f.array("time_s")
        profile = f.build(lambda: LoadProfile(t, f.array("axial_load_N", t.size),
                                              f.optional_array("speed_rpm", t.size)))
        series = {name: f.array(name, t.size) for name in _SERIES}
        return f.build(lambda: cls(
            profile=profile, spec=ScheduleSpec.from_fields(f), constant_preload_N=f.number("constant_preload_N"),
            friction_energy_J=f.number("friction_energy"),
            constant_friction_energy_J=f.number("constant_friction_energy"), energy_units=f.text("energy_units"),
            status=f.text("status"), **series))

    def plot(self) -> Figure:
        """Load profile, the two preloads, and rigidity against the requirement, on three axes: a Figure."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.0, 6.0), layout="constrained")
        axes = fig.subplots(3, 1, sharex=True)
        t = self.profile.time_s
        axes[0].plot(t, self.profile.axial_load_N, color="0.3")
        axes[0].set_ylabel("axial load (N)")
        axes[1].plot(t, self.preload_N, label="schedule")
        axes[1].axhline(self.constant_preload_N, color="C1", ls="--", label="best constant")
        axes[1].set_ylabel("preload (N)")
        axes[1].legend(fontsize="small")
        axes[2].plot(t, self.rigidity_N_per_um, label="schedule")
        axes[2].plot(t, self.constant_rigidity_N_per_um, "--", label="best constant")
        axes[2].plot(t, self.required_N_per_um, ":", color="k", label="required")
        axes[2].set_ylabel("rigidity (N/um)")
        axes[2].set_xlabel("time (s)")
        axes[2].legend(fontsize="small")
        return fig
