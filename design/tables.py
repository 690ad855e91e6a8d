"""The design's tables of a study file: ``[ballscrew]``, ``[feed_drive]``, ``[duty]``, ``[design]``,
``[schedule]`` and ``[plant]``, as frozen records with their keys as fields.

A key not given is None where the domain's default applies (:class:`~piezopreload.design.preload.DesignSpec`'s,
the design's lift-off margin). :func:`~piezopreload.design.study.design_spec_from_tables` makes the
design's specification from them; :class:`PlantTable` checks itself, makes the designed plant and
tracks a schedule on it with its settings.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from piezopreload.core.config import Table
from piezopreload.core.errors import InputError
from piezopreload.design.plant import DesignedPlant, plant_from_design
from piezopreload.design.preload import PARETO_PAIRS, DesignPoint, DesignSpec
from piezopreload.design.schedule import PreloadSchedule
from piezopreload.design.system import SystemRun, track_schedule
from piezopreload.models.actuator import RigParams
from piezopreload.models.controller import Controller

__all__ = ["BallscrewTable", "FeedDriveTable", "DutyTable", "DesignTable", "ScheduleTable", "PlantTable"]


@dataclass(frozen=True)
class BallscrewTable(Table):
    """[ballscrew]: what the machine fixes and the design variables' bounds (low, high)."""

    nominal_diameter_mm: float | None = None
    lead_mm: float | None = None
    contact_angle_deg: tuple[float, float] | None = None
    ball_mm: tuple[float, float] | None = None
    conformity: tuple[float, float] | None = None
    turns: tuple[int, int] | None = None
    load_sharing: float | None = None


@dataclass(frozen=True)
class FeedDriveTable(Table):
    table_mass_kg: float | None = None
    screw_length_mm: float | None = None
    bearing_stiffness_N_per_um: float | None = None
    travel_mm: tuple[float, float] | None = None
    mounting: str | None = None


@dataclass(frozen=True)
class DutyTable(Table):
    """[duty]: the duty cycle's cases, one entry per case in each list."""

    axial_load_N: tuple[float, ...] | None = None
    speed_rpm: tuple[float, ...] | None = None
    time_share: tuple[float, ...] | None = None


@dataclass(frozen=True)
class DesignTable(Table):
    """[design]: the objective, the fronts, and the constraints' limits (None: DesignSpec's default)."""

    objective: str = "stiffness"
    pareto: tuple[str, ...] = PARETO_PAIRS
    pareto_points: int = 50
    axial_load_max_N: float | None = None
    failsafe_load_N: float | None = None
    lift_off_margin: float | None = None
    preload_fraction_max: float | None = None
    contact_pressure_max_MPa: float | None = None
    life_min_h: float | None = None
    drag_torque_max_Nm: float | None = None
    frequency_min_Hz: float | None = None
    stiffness_min_N_per_um: float | None = None
    nut_length_max_mm: float | None = None
    ball_lead_ratio_max: float | None = None
    load_factor: float | None = None
    stack_drive_V: float | None = None
    amp_current_limit_A: float | None = None


@dataclass(frozen=True)
class ScheduleTable(Table):
    """[schedule]: the load profile (a CSV; None: a machining cycle) and what the schedule must keep."""

    profile: str | None = None
    stiffness_min_N_per_um: float = 0.0
    deflection_max_um: float | None = None  # None: no limit
    lift_off_margin: float | None = None  # None: the design's

    def limits(self) -> dict[str, Any]:
        """What the schedule must keep, as :func:`~piezopreload.design.study.plan_schedule` takes it."""
        return {"stiffness_min_N_per_um": self.stiffness_min_N_per_um,
                "deflection_max_um": math.inf if self.deflection_max_um is None else self.deflection_max_um,
                "lift_off_margin": self.lift_off_margin}


@dataclass(frozen=True)
class PlantTable(Table):
    """[plant]: the designed preload system as the plant: the design sets the stacks, the amplifier's current limit
    and the coupling, ``[rig]`` the rest of the hardware (design/plant.py); the schedule is tracked for ``cycles``,
    planned again with a margin at most ``passes`` times (design/system.py)."""

    from_design: bool = True
    sleeve_stiffness_N_per_um: float | None = None  # None: a rigid sleeve
    cycles: int = 2
    passes: int = 3
    margin_factor: float = 1.25
    stack_contact_N: float = 0.0  # the least force the stacks keep on the nuts (not bonded to them)

    def check(self, has_design: bool, fail: Callable[[str, str], InputError]) -> None:
        """Check the table's values (``has_design``: the study has the design's tables); ``fail(key, message)``
        makes the error naming the file and line."""
        if self.from_design and not has_design:
            raise fail("plant.from_design", "needs the design's tables ([ballscrew], ...) to make the plant from")
        for key, low in (("cycles", 1), ("passes", 1)):
            if getattr(self, key) < low:
                raise fail(f"plant.{key}", f"must be >= {low}, got {getattr(self, key)!r}")
        if not self.stack_contact_N >= 0.0:
            raise fail("plant.stack_contact_N", f"must be >= 0, got {self.stack_contact_N!r}")
        if not self.margin_factor >= 1.0:
            raise fail("plant.margin_factor", f"must be >= 1, got {self.margin_factor!r}")
        if self.sleeve_stiffness_N_per_um is not None and not self.sleeve_stiffness_N_per_um > 0:
            raise fail("plant.sleeve_stiffness_N_per_um", f"must be > 0, got {self.sleeve_stiffness_N_per_um!r}")

    def plant(self, spec: DesignSpec, point: DesignPoint, hardware: RigParams, design_sha256: str = "") -> DesignedPlant:
        """The plant of the design ``point`` with this table's sleeve (:func:`~piezopreload.design.plant.plant_from_design`)."""
        sleeve = math.inf if self.sleeve_stiffness_N_per_um is None else float(self.sleeve_stiffness_N_per_um)
        return plant_from_design(spec, point, hardware, design_sha256=design_sha256, sleeve_stiffness_N_per_um=sleeve)

    def track(self, plant: DesignedPlant, controller: Controller, schedule: PreloadSchedule, *, seed: int,
              settle_s: float = 0.5, ff_extra_V: Any = None,
              progress: Callable[[str], None] | None = None) -> SystemRun:
        """``controller`` following ``schedule`` on ``plant`` for this table's cycles, passes and margin, after a
        pre-cycle held ``settle_s`` at the first level (:func:`~piezopreload.design.system.track_schedule`)."""
        return track_schedule(plant, controller, schedule, cycles=self.cycles, seed=seed, passes=self.passes,
                              margin_factor=self.margin_factor, contact_N=self.stack_contact_N, settle_s=settle_s,
                              ff_extra_V=ff_extra_V, progress=progress)
