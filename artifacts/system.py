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

from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.sensitivity import SensitivityRecord
from piezopreload.artifacts.thermal import ThermalRecord
from piezopreload.core._typing import Array
from piezopreload.core.records import Raw, Record, SavedArtifact, entry, record

__all__ = ["TrackingNumbers", "MarginBasis", "PreCycle", "MarginPass", "ScheduleBound", "PlannedSchedule",
           "SystemSeries", "SystemRecord", "KIND"]

KIND = "system"


@record
class TrackingNumbers(Record):
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

    tracking_rms_N: float = entry("The RMS tracking error of the stacks' share over the machining cycles.", unit="N")
    tracking_max_N: float = entry("The worst tracking error.", unit="N")
    tracking_rms_pct_of_range: float = entry("The RMS tracking error in % of the schedule's range.", unit="%")
    schedule_range_N: float = entry("The schedule's range.", unit="N")
    rigidity_min_cutting_N_per_um: float = entry("The least rigidity while cutting.", unit="N/um")
    rigidity_required_at_min_N_per_um: float = entry("The rigidity required at that moment.", unit="N/um")
    rigidity_min_t_s: float = entry("Its time.", unit="s")
    rigidity_ratio_min: float = entry("The least ratio of the rigidity to its requirement.")
    rigidity_at_worst_ratio_N_per_um: float = entry("The rigidity at that sample.", unit="N/um")
    rigidity_required_at_worst_ratio_N_per_um: float = entry("The requirement at that sample.", unit="N/um")
    rigidity_worst_t_s: float = entry("Its time.", unit="s")
    rigidity_below_requirement_s: float = entry("The time below the requirement.", unit="s")
    deflection_max_um: float = entry("The largest axial deflection while cutting.", unit="um")
    deflection_limit_um: float | None = entry("Its limit (None: no limit).", unit="um", absent=None)
    lift_off_ratio_min: float = entry("The least ratio of the achieved preload to the lift-off bound.")
    lift_off_margin: float = entry("The ratio required.")
    preload_shortfall_max_N: float = entry("The largest shortfall of the achieved preload below the least preload "
                                           "each sample's requirements need.", unit="N")
    friction_energy_per_cycle: float = entry("The friction energy per cycle achieved, in ``energy_units``.")
    planned_friction_energy_per_cycle: float = entry("The friction energy per cycle planned, in ``energy_units``.")
    friction_saved_fraction: float = entry("The fraction the achieved friction energy saves against the design's "
                                           "best constant preload.")
    energy_units: str = entry("The friction energy's unit.")
    peak_voltage_V: float = entry("The peak voltage.", unit="V")
    cycle_start_error_N: float = entry("The error when the first cut begins (after the pre-cycle).", unit="N")


@record
class PreCycle(Record):
    """Before the first cut: the stacks at rest (0 N) for ``rest_s`` (room for a learned feedforward to lead the
    ramp), then to the schedule's first level ``level_N`` (their share) on a ramp at the slew limit
    ``slew_N_per_s`` (``ramp_s``), then held ``settle_s`` for the loop to settle."""

    level_N: float = entry("The schedule's first level (the stacks' share).", unit="N")
    slew_N_per_s: float = entry("The ramp's slew.", unit="N/s")
    ramp_s: float = entry("The ramp's time.", unit="s")
    settle_s: float = entry("The hold for the loop to settle.", unit="s")
    rest_s: float = entry("The stacks at rest before the ramp.", unit="s", default=0.0)

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
        """Its fields and its duration.

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "duration_s": self.duration_s}


@record
class MarginPass(Record):
    """One margin pass: the largest local margin it planned with and what the loop achieved on it."""

    number: int = entry("The pass's number (from 1).", name="pass", ge=0)
    preload_margin_N: float = entry("The largest local margin it planned with.", unit="N")
    tracking_rms_N: float = entry("The RMS tracking error.", unit="N")
    tracking_rms_pct_of_range: float = entry("The same, in % of the schedule's range.", unit="%")
    rigidity_ratio_min: float = entry("The least ratio of the rigidity to its requirement.")
    lift_off_ratio_min: float = entry("The least ratio of the preload to the lift-off bound.")
    requirements_met: bool = entry("Whether every requirement held.")
    preload_shortfall_max_N: float = entry("The largest shortfall below the least preload needed.", unit="N")
    friction_energy_per_cycle: float = entry("The friction energy per cycle.")


@record
class ScheduleBound(Record):
    """What stops a requirement: where the loop's error needs a margin above the requirement's least preload that the
    stacks' reach cannot give (``kind="reach"``), or where the margin passes ran out first (``kind="passes"``).

    At ``t_s`` (into the cycle) the requirement ``requirement`` needs ``needed_N`` of preload and the
    loop's error a margin of ``margin_N`` above it; the stacks reach ``reach_N``.
    """

    requirement: str = entry("The requirement it stops.")
    t_s: float = entry("When, into the cycle.", unit="s")
    needed_N: float = entry("The preload the requirement needs there.", unit="N")
    margin_N: float = entry("The margin the loop's error needs above it.", unit="N")
    reach_N: float = entry("The preload the stacks reach.", unit="N")
    kind: str = entry("``reach`` (the stacks cannot give the margin) or ``passes`` (the margin passes ran out).",
                      choices=("reach", "passes"), default="reach")

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
        """Its fields, how far the stacks fall short and the sentence.

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "short_N": self.short_N, "sentence": self.sentence()}


@record(eq=False)
class PlannedSchedule(Record):
    """The schedule the last pass planned, on the load profile's samples: the preload, each sample's margin (the
    room left for the loop; local: only where its error needed it), the margin the stacks' reach could not give,
    and its friction energy per cycle."""

    time_s: Array = entry("The samples' times.", unit="s")
    preload_N: Array = entry("The planned preload.", unit="N", size="time_s")
    margin_N: Array = entry("Each sample's margin.", unit="N", size="time_s")
    margin_short_N: Array = entry("The margin the stacks' reach could not give.", unit="N", size="time_s")
    friction_energy: float = entry("Its friction energy per cycle, in ``energy_units``.")
    energy_units: str = entry("The friction energy's unit.")
    status: str = entry("The solver's status.")

    def to_dict(self) -> dict[str, Any]:
        """Its fields and its range, largest margin and samples.

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "preload_min_N": float(np.min(self.preload_N)),
                "preload_max_N": float(np.max(self.preload_N)), "preload_margin_N": float(np.max(self.margin_N)),
                "samples": int(self.time_s.size)}


@record(eq=False)
class SystemSeries(Record):
    """The run's time series (total preload planned and achieved, the load, the rigidity and its requirement, the
    deflection, the voltage, and whether the axis cuts); the pre-cycle is in them, not cutting."""

    time_s: Array = entry("The samples' times.", unit="s")
    planned_N: Array = entry("The planned preload.", unit="N", size="time_s")
    achieved_N: Array = entry("The achieved preload.", unit="N", size="time_s")
    axial_load_N: Array = entry("The axial load.", unit="N", size="time_s")
    rigidity_N_per_um: Array = entry("The rigidity.", unit="N/um", size="time_s")
    required_N_per_um: Array = entry("The rigidity required.", unit="N/um", size="time_s")
    planned_rigidity_N_per_um: Array = entry("The rigidity the plan gives.", unit="N/um", size="time_s")
    deflection_um: Array = entry("The axial deflection.", unit="um", size="time_s")
    voltage_V: Array = entry("The stacks' voltage.", unit="V", size="time_s")
    cutting: NDArray[np.bool_] = entry("Whether the axis cuts (1) or not (0).", size="time_s")


@record
class MarginBasis(Record):
    """What the schedule's margins rest on (design/system.py, :func:`~piezopreload.design.system.margin_basis`).

    **Rigidity.** The verdict's rigidity is the nut's in the machine: the nut law's table figure (HIWIN's and THK's
    tables, on which it is calibrated) times ``rigidity_in_machine_factor``; the table-comparable figure is beside it.
    The axis stiffness at the table is the nut (in the machine) in series with the screw and the bearings, at the
    verdict's sample, over the travel. **Deflections**: the nut axial deflection is the nut's alone (the deflection
    requirement's); the axis deflection at the table adds the screw and the bearings (at the weakest position).
    **Lift-off**: the schedule's bound (``lift_off_margin |F_a| / 2^(3/2)``) is the design's own constraint; the
    physical margin is the nut law's lift-off load rho(sigma) F_p at the achieved preload against the cutting load,
    on the nominal plant and the worst of the Monte Carlo plants (the validation's spread), beside the catalogue
    rule's 2^(3/2) F_p at the same sample.
    """

    rigidity_in_machine_factor: float = entry("The share of the table rigidity the nut keeps in the machine.")
    rigidity_in_machine_N_per_um: float = entry("The nut's rigidity in the machine at the verdict's sample.",
                                                unit="N/um")
    rigidity_table_N_per_um: float = entry("The same without the factor: the table-comparable figure.", unit="N/um")
    rigidity_required_N_per_um: float = entry("The requirement at that sample.", unit="N/um")
    axis_stiffness_min_N_per_um: float = entry("The axis stiffness at the table (nut in the machine, screw, "
                                               "bearings in series) at that sample, the least over the travel.",
                                               unit="N/um")
    axis_stiffness_max_N_per_um: float = entry("The same, the most over the travel.", unit="N/um")
    nut_axial_deflection_max_um: float = entry("The nut axial deflection (the nut alone, in the machine), the "
                                               "largest while cutting.", unit="um")
    axis_deflection_max_um: float = entry("The axis deflection at the table (nut, screw, bearings) at the weakest "
                                          "position, the largest while cutting.", unit="um")
    lift_off_law: str = entry("The law the physical lift-off is judged by.")
    lift_off_ratio: float = entry("The law's lift-off load over the preload at the worst sample (rho).")
    lift_off_plants: int = entry("The plants the physical lift-off is judged on (the nominal first).", ge=1)
    lift_off_worst_plant: int = entry("The worst of them (0: the nominal).", ge=0)
    lift_off_preload_N: float = entry("The achieved preload at the worst sample of the worst plant.", unit="N")
    lift_off_axial_load_N: float = entry("The cutting load's size there.", unit="N")
    lift_off_load_N: float = entry("The law's lift-off load there.", unit="N")
    lift_off_margin_physical_pct: float = entry("The physical lift-off margin, the worst over the plants: the lift-off "
                                                "load over the cutting load, less 1.", unit="%")
    lift_off_margin_physical_nominal_pct: float = entry("The same on the nominal plant.", unit="%")
    lift_off_margin_catalogue_pct: float = entry("The catalogue rule's (2^(3/2) F_p) margin at the worst sample.",
                                                 unit="%")


@record(eq=False)
class SystemRecord(SavedArtifact):
    """The system artifact: the numbers, the requirements as verdicts, the bounds, the pre-cycle, the margin passes,
    the schedule the last pass planned, the series, the cycles run and the inputs' hashes."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the system"
    AGAIN: ClassVar[str] = "run the system stage again"

    numbers: TrackingNumbers = entry("The numbers of the run (at the document's top level).", inline=True)
    requirements: tuple[Requirement, ...] = entry("The requirements as verdicts.")
    bounds: tuple[ScheduleBound, ...] = entry("What stops a requirement no schedule within the stacks' force meets.")
    pre_cycle: PreCycle = entry("Before the first cut.")
    passes: tuple[MarginPass, ...] = entry("The margin passes.")
    schedule: PlannedSchedule = entry("The schedule the last pass planned.")
    series: SystemSeries = entry("The run's time series.")
    cycles: int = entry("The machining cycles run.", ge=0)
    inputs: dict[str, Any] = entry("The inputs' hashes.", default={}, required=True)
    thermal: ThermalRecord | None = entry("The shift's thermal budget, where the study has a ``[thermal]`` table.",
                                          default=None, omit=True)
    basis: MarginBasis | None = entry("What the margins rest on (rigidity in the machine and at the table, the axis "
                                      "stiffness, the physical lift-off), where the run was given the design.",
                                      default=None, omit=True)
    sensitivity: SensitivityRecord | None = entry("The verdicts under the modelling assumptions' ranges.",
                                                  default=None, omit=True)

    @property
    def requirements_met(self) -> bool:
        """Whether every requirement is met."""
        return all(r.met for r in self.requirements)

    @property
    def missed(self) -> tuple[Requirement, ...]:
        """The requirements the system missed (a negative margin), in the order of :attr:`requirements`."""
        return tuple(r for r in self.requirements if not r.met)

    @property
    def preload_margin_N(self) -> float:
        """The largest margin the last pass's schedule left the loop (it is local: see ``schedule.margin_N``)."""
        return float(np.max(self.schedule.margin_N))

    def to_dict(self) -> dict[str, Any]:
        """The artifact's body: the fields, the verdict over the requirements and the largest margin.

        Returns
        -------
        dict
            The document's body.
        """
        return {**super().to_dict(), "requirements_met": self.requirements_met,
                "preload_margin_N": self.preload_margin_N}

    def _check_document(self, raw: Raw) -> None:
        said = raw.get("requirements_met")
        if not isinstance(said, bool):
            raise raw.fail("requirements_met", f"must be true or false, got {said!r}")
        if said != self.requirements_met:
            raise raw.fail("requirements_met", "does not agree with its 'requirements'")
