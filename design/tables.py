"""The design's tables of a study file: ``[ballscrew]``, ``[feed_drive]``, ``[duty]``, ``[design]``,
``[schedule]``, ``[plant]`` and ``[thermal]``, as frozen records whose fields declare their keys (type, default,
unit, range, doc: :func:`piezopreload.core.config.key`).

The defaults are :class:`~piezopreload.design.preload.DesignSpec`'s; a key left at None means what
its doc says (no limit, the design's value). :func:`~piezopreload.design.study.design_spec_from_tables`
makes the design's specification from them; :class:`PlantTable` makes the designed plant and tracks
a schedule on it with its settings.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypedDict

from piezopreload.artifacts.design import DesignPoint
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.core.config import Invalid, Table, key
from piezopreload.core.progress import ProgressLike
from piezopreload.design.plant import plant_from_design
from piezopreload.design.preload import PARETO_PAIRS, DesignSpec, Objective
from piezopreload.design.system import SystemRun, track_schedule
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller
from piezopreload.models.feed_drive import Mounting
from piezopreload.models.thermal import (
    CONTACT_CALIBRATION,
    FEEDBACKS,
    VG_GRADES,
    Feedback,
    HeatModel,
    ThermalMounting,
    rexroth_seal_torque_Nm,
)


class DesignMethod(StrEnum):
    """How ``[design] method`` chooses the optimum: the design NLP alone, the tuning after it on its plant, or with
    its controller by the nested co-design (its value is what a study file writes)."""

    SEQUENTIAL = "sequential"
    CODESIGN = "codesign"


#: how ``[design] method`` chooses the optimum, in its order
DESIGN_METHODS = tuple(DesignMethod)

__all__ = ["BallscrewTable", "FeedDriveTable", "DutyTable", "DesignTable", "ScheduleTable", "ScheduleLimits",
           "PlantTable", "ThermalTable", "FEEDBACKS"]

_SPEC = DesignSpec()  # the defaults


@dataclass(frozen=True)
class BallscrewTable(Table):
    """[ballscrew]: what the machine fixes of the screw (its nominal diameter and lead) and the design variables'
    bounds (low, high); the design chooses each variable inside its bounds."""

    nominal_diameter_mm: float = key(_SPEC.nominal_diameter_mm, "nominal diameter of the screw", unit="mm", gt=0)
    lead_mm: float = key(_SPEC.lead_mm, "lead of the screw", unit="mm", gt=0)
    contact_angle_deg: tuple[float, float] = key(_SPEC.contact_angle_deg, "bounds of the balls' contact angle",
                                                 unit="deg", ge=20, le=70, increasing=True)
    ball_mm: tuple[float, float] = key(_SPEC.ball_mm, "bounds of the ball diameter", unit="mm", gt=0, increasing=True)
    conformity: tuple[float, float] = key(_SPEC.conformity, "bounds of the grooves' conformity (groove radius over "
                                          "ball diameter)", ge=0.505, le=0.6, increasing=True)
    turns: tuple[int, int] = key(_SPEC.turns, "bounds of the loaded turns per nut", ge=1, increasing=True)
    load_sharing: float = key(_SPEC.load_sharing, "effective share of the balls that carry load (the calibrated "
                              "default: docs/ballscrew.md)", gt=0, le=1)
    rigidity_in_machine_factor: float = key(
        _SPEC.rigidity_in_machine_factor, "share of the nut's table rigidity it keeps mounted in the machine: HIWIN "
        "and THK state that their table rigidity leaves out the nut's mounting and that about 80 % of it holds in a "
        "machine (HIWIN: K_n = 0.8 K (F_p / 0.1 C)^(1/3)); the nut law is calibrated on those tables "
        "(docs/ballscrew.md). Rexroth's DIN 69051-5 and Steinmeyer's corrected figures carry no such factor: for a "
        "nut judged by them set 1. The schedule's rigidity and deflection requirements hold in the machine; the "
        "table figure is reported beside", gt=0, le=1)


@dataclass(frozen=True)
class FeedDriveTable(Table):
    """[feed_drive]: the axis the screw drives: its table, the screw between its bearings, the travel."""

    table_mass_kg: float = key(_SPEC.feed_drive.table_mass_kg, "mass of the table and its load", unit="kg", gt=0)
    screw_length_mm: float = key(_SPEC.feed_drive.screw_length_mm, "screw length between the bearings", unit="mm",
                                 gt=0)
    bearing_stiffness_N_per_um: float = key(_SPEC.feed_drive.bearing_stiffness_N_per_um, "axial stiffness of each "
                                            "end bearing", unit="N/um", gt=0)
    travel_mm: tuple[float, float] = key(_SPEC.feed_drive.travel_mm, "the nut centre's travel from bearing A (start, "
                                         "end), inside the screw length", unit="mm", gt=0, increasing=True)
    mounting: Mounting = key(_SPEC.feed_drive.mounting, "how the screw's ends are held")

    def check(self) -> None:
        if not self.travel_mm[0] < self.travel_mm[1] < self.screw_length_mm:
            raise Invalid("travel_mm", f"must lie inside the screw (0 < start < end < screw_length_mm = "
                                       f"{self.screw_length_mm:g} mm), got {list(self.travel_mm)!r}")


@dataclass(frozen=True)
class DutyTable(Table):
    """[duty]: the duty cycle's cases, one entry per case in each list (all three lists, or none: the default
    cycle of roughing, finishing and rapid traverse)."""

    axial_load_N: tuple[float, ...] | None = key(None, "each case's axial load (its sign: the direction)", unit="N",
                                                 min_length=1)
    speed_rpm: tuple[float, ...] | None = key(None, "each case's screw speed", unit="rpm", ge=0, min_length=1)
    time_share: tuple[float, ...] | None = key(None, "each case's share of the time", gt=0, min_length=1)

    def check(self) -> None:
        lists = {"axial_load_N": self.axial_load_N, "speed_rpm": self.speed_rpm, "time_share": self.time_share}
        given = {k: v for k, v in lists.items() if v is not None}
        if given and (len(given) < 3 or len({len(v) for v in given.values()}) != 1):
            name = next((k for k, v in lists.items() if v is None), "time_share")
            raise Invalid(name, "must be given with the other two lists of [duty], each with one entry per case; got "
                                + ", ".join(f"{k} with {len(v)}" for k, v in given.items()))

    def cases(self) -> tuple[tuple[float, float, float], ...] | None:
        """Each case's (axial load, speed, time share), or None for the default cycle."""
        if self.axial_load_N is None or self.speed_rpm is None or self.time_share is None:
            return None
        return tuple(zip(self.axial_load_N, self.speed_rpm, self.time_share))


@dataclass(frozen=True)
class DesignTable(Table):
    """[design]: the objective, the Pareto fronts the design stage traces, and the constraints' limits."""

    objective: Objective = key(Objective.STIFFNESS, "what the optimum maximises (stiffness: the least rigidity over "
                               "the duty cycle) or minimises (drag: the mean drag torque; life: as rating life)")
    pareto: tuple[str, ...] = key(PARETO_PAIRS[:3], "the Pareto fronts ``piezopreload design`` and the design stage "
                                  "trace (none is traced to make the plant; stiffness:growth, the least heat's growth "
                                  "over the shift, needs [thermal])", choices=PARETO_PAIRS)
    pareto_points: int = key(50, "points on each front", ge=2, le=500)
    method: DesignMethod = key(DesignMethod.SEQUENTIAL, "how the optimum is chosen: sequential (the design NLP alone; "
                               "the tuning after it on its plant) or codesign (the contact angle and conformity "
                               "chosen with the PID gains, nested: ``piezopreload codesign``, docs/codesign.md)")
    codesign_budget: int = key(9, "with method = codesign: the most inner problems (a design with its tuning) the "
                               "co-design's outer search solves after the sequential start, and each weight of its "
                               "front's sweep", ge=0)
    axial_load_max_N: float = key(_SPEC.axial_load_max_N, "largest axial load: no lift-off up to it at the highest "
                                  "preload, the contact pressure at it", unit="N", gt=0)
    failsafe_load_N: float = key(_SPEC.failsafe_load_N, "load the bolts alone hold without lift-off with the stacks "
                                 "off: it sets the bolts' least preload", unit="N", ge=0)
    lift_off_margin: float = key(_SPEC.lift_off_margin, "safety factor on the lift-off loads", gt=0)
    preload_fraction_max: float = key(_SPEC.preload_fraction_max, "highest preload as a fraction of the dynamic "
                                      "rating C_dyn", gt=0)
    contact_pressure_max_MPa: float = key(_SPEC.contact_pressure_max_MPa, "peak Hertz pressure at axial_load_max_N",
                                          unit="MPa", gt=0)
    life_min_h: float = key(_SPEC.life_min_h, "least rating life over the duty cycle", unit="h", gt=0)
    drag_torque_max_Nm: float = key(_SPEC.drag_torque_max_Nm, "drag torque at the highest preload", unit="N m", gt=0)
    frequency_min_Hz: float = key(_SPEC.frequency_min_Hz, "least first axial natural frequency (weakest table "
                                  "position)", unit="Hz", gt=0)
    stiffness_min_N_per_um: float = key(_SPEC.stiffness_min_N_per_um, "least rigidity in every duty case",
                                        unit="N/um", ge=0)
    nut_length_max_mm: float = key(_SPEC.nut_length_max_mm, "longest nut (turns times lead)", unit="mm", gt=0)
    ball_lead_ratio_max: float = key(_SPEC.ball_lead_ratio_max, "largest ball diameter over the lead", gt=0)
    load_factor: float = key(_SPEC.load_factor, "factor on the duty loads for the rating life", gt=0)
    stack_drive_V: float = key(_SPEC.actuator.drive_V, "the stacks' drive voltage at the highest preload", unit="V",
                               gt=0, le=_SPEC.actuator.stack.v_max_V)
    amp_current_limit_A: float = key(_SPEC.actuator.amp_current_limit_A, "the amplifier's current limit (the "
                                     "preload's slew rate; the designed plant's amplifier)", unit="A", gt=0)
    robust: bool = key(False, "design against the worst case of the modelling assumptions' ranges: the rigidity and "
                       "the natural frequency at every corner of the contact angle's (+-5 deg) and the conformity's "
                       "(+-0.01) tolerance box, the drag and the heat at K_p's high end (0.3); the cost against the "
                       "nominal design is reported (docs/system.md)")


class ScheduleLimits(TypedDict):
    """What a preload schedule must keep, as :func:`~piezopreload.design.study.plan_schedule` takes it."""

    stiffness_min_N_per_um: float
    deflection_max_um: float
    lift_off_margin: float | None


@dataclass(frozen=True)
class ScheduleTable(Table):
    """[schedule]: the load profile the least-friction preload schedule is planned for and what it must keep."""

    profile: str | None = key(None, "a CSV of time_s, axial_load_N[, speed_rpm], relative to the study file "
                              "(not set: a machining cycle)")
    stiffness_min_N_per_um: float = key(0.0, "least rigidity while cutting", unit="N/um", ge=0)
    deflection_max_um: float | None = key(None, "largest axial deflection under the cutting load (not set: no "
                                          "limit)", unit="um", gt=0)
    lift_off_margin: float | None = key(None, "safety factor on lift-off along the profile (not set: [design]'s)",
                                        gt=0)

    def limits(self) -> ScheduleLimits:
        """What the schedule must keep, as :func:`~piezopreload.design.study.plan_schedule` takes it."""
        return ScheduleLimits(
            stiffness_min_N_per_um=self.stiffness_min_N_per_um,
            deflection_max_um=math.inf if self.deflection_max_um is None else self.deflection_max_um,
            lift_off_margin=self.lift_off_margin)


@dataclass(frozen=True)
class PlantTable(Table):
    """[plant]: the designed preload system as the plant. With ``from_design = true`` the design sets the stacks,
    the amplifier's current limit and the coupling (design/plant.py; ``[rig]`` gives the rest of the hardware and
    may not set those), and the schedule is tracked for ``cycles``, planned again with a margin at most ``passes``
    times (design/system.py). Its other keys apply to the designed plant only."""

    from_design: bool = key(True, "the plant is the design's optimum (true) or the [rig] table (false)")
    sleeve_stiffness_N_per_um: float | None = key(None, "the sleeve and bolts in series with the nuts (not set: "
                                                  "rigid)", unit="N/um", gt=0)
    cycles: int = key(2, "machining cycles the schedule is tracked for", ge=1)
    passes: int = key(3, "most times the schedule is planned (again with a margin while a requirement is missed)",
                      ge=1)
    margin_factor: float = key(1.25, "factor on the shortfall that makes the next pass's preload margin", ge=1)
    stack_contact_N: float = key(0.0, "least force the stacks keep on the nuts (they are not bonded to them)",
                                 unit="N", ge=0)

    def plant(self, spec: DesignSpec, point: DesignPoint, hardware: Plant, design_sha256: str = "") -> DesignedPlant:
        """The plant of the design ``point`` with this table's sleeve
        (:func:`~piezopreload.design.plant.plant_from_design`)."""
        sleeve = math.inf if self.sleeve_stiffness_N_per_um is None else float(self.sleeve_stiffness_N_per_um)
        return plant_from_design(spec, point, hardware, design_sha256=design_sha256, sleeve_stiffness_N_per_um=sleeve)

    def track(self, plant: DesignedPlant, controller: Controller, schedule: PreloadSchedule, *, seed: int,
              settle_s: float = 0.5, ff_extra_V: Any = None, design: DesignSpec | None = None,
              scatter: Plant | None = None, progress: ProgressLike | None = None) -> SystemRun:
        """``controller`` following ``schedule`` on ``plant`` for this table's cycles, passes and margin, after a
        pre-cycle held ``settle_s`` at the first level (:func:`~piezopreload.design.system.track_schedule`; with
        ``design`` and ``scatter`` it says what its margins rest on)."""
        return track_schedule(plant, controller, schedule, cycles=self.cycles, seed=seed, passes=self.passes,
                              margin_factor=self.margin_factor, contact_N=self.stack_contact_N, settle_s=settle_s,
                              ff_extra_V=ff_extra_V, design=design, scatter=scatter, progress=progress)


@dataclass(frozen=True)
class ThermalTable(Table):
    """[thermal]: the heat the preload makes over a shift, the axis' temperature and the screw's growth, and the
    limits on growth and on the positioning error (design/thermal.py; the model and its sources: docs/thermal.md).
    Every key has a default; the limits are requirements only where set."""

    heat_model: HeatModel = key(HeatModel.CATALOGUE, "the nut's heat the verdicts use: catalogue (drag torque times "
                                "speed) or contact (Jungnickel's rolling-contact loss); the other is shown beside it "
                                "as a bound")
    lubricant_vg: int = key(68, "the lubricant's ISO VG grade (10, 22, 32, 46, 68, 100, 150 or 220): the contact "
                            "model's and the support bearings' viscosity")
    sealed: bool = key(True, "the nut has contact (lip) seals: their torque seal_torque_Nm adds T_s omega to the nut's "
                       "heat in either model (false: an open nut or non-contact seals, no seal torque)")
    seal_torque_Nm: float | None = key(None, "idle torque of the nut's seals, independent of the preload (not set: "
                                       "Rexroth's table of the two lip seals of a nut, single or double alike, by "
                                       "nominal diameter and lead, 0.25 N m for 32 mm: docs/thermal.md; sealed = "
                                       "false: 0)", unit="N m", ge=0)
    contact_calibration: float = key(CONTACT_CALIBRATION, "factor on Jungnickel's rolling-contact loss (the contact "
                                     "model): the default brings it to published measured drag torques at the "
                                     "vendors' measuring speed (docs/thermal.md); set your own from a measurement",
                                     gt=0)
    contact_temperature_C: float = key(40.0, "the lubricant's temperature at the contacts (its viscosity)",
                                       unit="degC", ge=-20, le=150)
    ambient_C: float = key(20.0, "the air's temperature around the axis (the rises are above it)", unit="degC",
                           ge=-20, le=60)
    nut_heat_share: float = key(0.5, "share of the nut's heat that enters the screw under its loaded turns (the "
                                "rest heats the nut's body): an assumption, no share is published; measured axes run "
                                "hottest at the nut, and the record says which runs warmer (docs/thermal.md)", ge=0,
                                le=1)
    spacer_length_mm: float = key(40.0, "the spacer (the stacks' sleeve) between the two nuts", unit="mm", gt=0)
    bearing_preload_N: float = key(2000.0, "axial preload of each end's support bearing set (a fixed-free screw's "
                                   "far end has none)", unit="N", ge=0)
    bearing_dm_mm: float | None = key(None, "the support bearings' pitch diameter (not set: the screw's nominal "
                                      "diameter + 10 mm)", unit="mm", gt=0)
    bearing_f0: float = key(2.0, "Palmgren's lubrication factor f0 of each end's bearing set", gt=0)
    bearing_f1: float = key(0.001, "Palmgren's load factor f1", ge=0)
    bearing_heat_share: float = key(0.5, "share of the bearings' heat that enters the screw's end (the rest their "
                                    "housing)", ge=0, le=1)
    bearing_W_per_K: float = key(1.0, "conductance from each end of the screw into its bearing's housing",
                                 unit="W/K", ge=0)
    convection_factor: float = key(1.0, "factor on the air's film coefficients the correlations give (the rotating "
                                   "screw's Nusselt number, free convection on the nut and the screw at rest): the "
                                   "convection assumption, about 0.6-1.3 by the free-convection figures' and the "
                                   "correlations' scatter (docs/thermal.md)", gt=0, le=5)
    free_convection_W_per_m2K: float = key(8.0, "free convection's film coefficient: the screw at rest (the "
                                           "rotating shaft's is higher), the nut", unit="W/m^2 K", gt=0)
    flange_mass_kg: float = key(2.0, "the nut's flange and bracket (a lumped body)", unit="kg", gt=0)
    nut_flange_W_per_K: float = key(10.0, "conductance from the nut into its flange", unit="W/K", ge=0)
    flange_table_W_per_K: float = key(10.0, "conductance from the flange into the table (at the ambient)",
                                      unit="W/K", ge=0)
    bore_mm: float | None = key(None, "a hollow screw's bore (not set: solid)", unit="mm", gt=0)
    coolant_flow_l_per_min: float | None = key(None, "water through the bore (not set: no coolant; needs "
                                               "bore_mm)", unit="l/min", gt=0)
    coolant_C: float | None = key(None, "the coolant's temperature (not set: the ambient)", unit="degC", ge=-20,
                                  le=60)
    mounting: ThermalMounting | None = key(None, "how the screw's ends hold its growth (not set: [feed_drive] "
                                           "mounting's, fixed-supported being fixed-free); pretensioned needs "
                                           "pretension_K")
    pretension_K: float = key(0.0, "the temperature rise the pretension takes up (mounting = pretensioned)",
                              unit="K", ge=0)
    feedback: Feedback = key(Feedback.SEMI_CLOSED, "the position loop's feedback: semi-closed (the motor's encoder: "
                             "the growth is a positioning error) or linear-scale (the growth is not)")
    stroke_mm: tuple[float, float] | None = key(None, "the nut's stroke in a cycle, from bearing A (not set: "
                                                "[feed_drive] travel_mm)", unit="mm", gt=0, increasing=True)
    shift_h: float = key(8.0, "the shift: the cycle repeated from a cold axis", unit="h", gt=0, le=24)
    volumes: int = key(60, "finite volumes along the screw", ge=4, le=400)
    thermal_growth_max_um: float | None = key(None, "largest thermal growth at the table's positions over the "
                                              "shift (not set: no requirement)", unit="um", gt=0)
    positioning_error_max_um: float | None = key(None, "largest positioning error over the shift: the deflection "
                                                 "under the cutting load, the growth and the force loop's share "
                                                 "(not set: no requirement)", unit="um", gt=0)

    def check(self) -> None:
        if self.lubricant_vg not in VG_GRADES:
            raise Invalid("lubricant_vg", f"must be an ISO VG grade, one of {', '.join(map(str, VG_GRADES))}; got "
                                          f"{self.lubricant_vg!r}")
        pretensioned = self.mounting is ThermalMounting.PRETENSIONED
        if pretensioned != (self.pretension_K > 0):
            name = "pretension_K" if pretensioned else "mounting"
            raise Invalid(name, "a pretension needs mounting = \"pretensioned\" and pretension_K > 0 together; got "
                                f"mounting = {None if self.mounting is None else str(self.mounting)!r}, "
                                f"pretension_K = {self.pretension_K:g}")
        if not self.sealed and self.seal_torque_Nm is not None and self.seal_torque_Nm > 0:
            raise Invalid("seal_torque_Nm", f"= {self.seal_torque_Nm:g} N m needs seals: sealed = false is an open "
                                            "nut (no seal torque); set sealed = true or leave seal_torque_Nm unset")
        if self.coolant_flow_l_per_min is not None and self.bore_mm is None:
            raise Invalid("coolant_flow_l_per_min", "needs a hollow screw: set bore_mm")
        if self.coolant_C is not None and self.coolant_flow_l_per_min is None:
            raise Invalid("coolant_C", "needs a coolant: set coolant_flow_l_per_min")

    def seal_torque(self, nominal_diameter_mm: float, lead_mm: float) -> float:
        """The seals' torque (N m) for a screw of this size: the key's, Rexroth's table's where it is unset, 0 for an
        open nut (:func:`~piezopreload.models.thermal.rexroth_seal_torque_Nm`)."""
        if not self.sealed:
            return 0.0
        if self.seal_torque_Nm is not None:
            return float(self.seal_torque_Nm)
        return rexroth_seal_torque_Nm(nominal_diameter_mm, lead_mm)

    def against(self, drive: Any, fail: Callable[[str, str], Exception]) -> None:
        """The rules between this table and the axis (:class:`~piezopreload.models.feed_drive.FeedDrive`):
        the mounting agrees with the axis' ends, the stroke lies inside the screw."""
        if self.mounting is not None and (self.mounting is ThermalMounting.FIXED_FREE) != (
                drive.mounting is Mounting.FIXED_SUPPORTED):
            raise fail("thermal.mounting", f"= {str(self.mounting)!r} does not hold the ends [feed_drive] mounting = "
                                           f"{str(drive.mounting)!r} gives (fixed-supported floats: fixed-free; "
                                           "fixed-fixed holds both: fixed-fixed or pretensioned)")
        if self.stroke_mm is not None and not self.stroke_mm[1] < drive.screw_length_mm:
            raise fail("thermal.stroke_mm", f"must lie inside the screw (end < screw_length_mm = "
                                            f"{drive.screw_length_mm:g} mm), got {list(self.stroke_mm)!r}")
