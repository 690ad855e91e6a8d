"""What each stage of a study's run reports: one typed summary per stage, as ``pipeline.json`` records it.

A stage of ``piezopreload run`` (:mod:`piezopreload.pipeline`) returns its outputs and one of these records; the
manifest (:class:`~piezopreload.artifacts.manifest.StudyRunManifest`) holds each done stage's under ``summary``,
and every reader (the run's headline, the sweep's rows, the report, the pipeline's own checks) reads the record,
not the JSON. Each record's fields are declared once (:mod:`piezopreload.core.records`): its reader
(``from_dict``, every field checked and a bad one named), its writer (``to_dict``, the keys ``pipeline.json`` has
always had) and its documentation come from that declaration. :data:`SUMMARIES` maps each stage's name to its record.

This module is a seam between the application layer (which builds the records from the steps' results) and the
floors that read a run (the report); it holds no computation.
"""

from __future__ import annotations

from typing import Any, ClassVar

from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.responses import ReproductionRow
from piezopreload.artifacts.sensitivity import SensitivityRecord
from piezopreload.artifacts.system import (
    MarginBasis,
    MarginPass,
    PreCycle,
    ScheduleBound,
    SystemRecord,
    TrackingNumbers,
)
from piezopreload.artifacts.thermal import ThermalSummary
from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Raw, Record, entry, record

__all__ = ["StageSummary", "DesignSummary", "PlantSummary", "IdentifySummary", "TuneSummary", "ValidateSummary",
           "CompareSummary", "LearnSummary", "BeforeLearning", "SystemSummary", "ExportSummary", "RigTrip",
           "RigSummary", "ReportSummary", "SUMMARIES", "read_summary"]

_AGAIN = "run the study again with --force"


class StageSummary(Record):
    """What every stage's summary has: the stage it belongs to and the requirements it checked (none, unless it
    checks some)."""

    STAGE: ClassVar[str] = ""
    AGAIN: ClassVar[str] = _AGAIN

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        """The requirements the stage checked."""
        return ()


@record
class DesignSummary(StageSummary):
    """The design stage: the optimum's objective and rigidity, the constraints that bind, the fronts traced, the
    preload schedule's saving against the best constant preload."""

    STAGE: ClassVar[str] = "design"
    objective: str = entry("The design's objective.")
    stiffness_N_per_um: float = entry("The optimum's least rigidity.", unit="N/um")
    binding: tuple[str, ...] = entry("The constraints (and bounds) that bind at the optimum.")
    fronts: tuple[str, ...] = entry("The Pareto fronts traced.")
    schedule_saving_fraction: float = entry("The friction energy the schedule saves against the best constant "
                                            "preload, as a fraction.")
    constant_preload_N: float = entry("The best constant preload.", unit="N")
    constant_friction_energy: float = entry("Its friction energy per cycle (in ``energy_units``).")
    energy_units: str = entry("The unit of the energies.")
    robust_cost: dict[str, Any] | None = entry(
        "A robust design's cost against the nominal design (``[design] robust``: the objective's figure of each at the "
        "study's assumptions and at the worst case, the cost, what the nominal design misses at the worst case).",
        default=None, omit=True)


@record
class PlantSummary(StageSummary):
    """The plant stage: the designed plant's origin, the stacks' share of the preload and the coupling's local
    stiffness at the bolts' preload and at the top (``at_bolts``, ``at_max``)."""

    STAGE: ClassVar[str] = "plant"
    design_sha256: str = entry("The design artifact's SHA-256.")
    stack_force_max_N: float = entry("The stacks' share of the preload at the top.", unit="N")
    local_stiffness_N_per_um: dict[str, float] = entry("The coupling's local stiffness, by where.", unit="N/um")
    bolt_preload_N: float = entry("The bolts' preload.", unit="N")


@record
class IdentifySummary(StageSummary):
    """The identify stage: where the loop came from, the model's operators, its fit and the open-loop check."""

    STAGE: ClassVar[str] = "identify"
    source: str = entry("Where the loop came from (``simulated`` or ``measured``).")
    data_sha256: str = entry("The loop's SHA-256.")
    operators: int = entry("The model's play operators.", ge=0)
    fit_rms_pct: float = entry("The model's RMS error on the loop.", unit="% of the span")
    fit_max_pct: float = entry("Its largest error.", unit="% of the span")
    compensation_rms_N: float | None = entry("The plant driven through the inverse in open loop: its RMS error.",
                                             unit="N")


@record
class TuneSummary(StageSummary):
    """The tune stage: the gains (SI), the controller's form, Ms, the gains on their bounds (sentences), the
    minimum-time bound and the tuned settling over it, how the search ended, and where a gain schedule was tuned,
    what was chosen (``gain_schedule``: ``schedule`` or ``robust``)."""

    STAGE: ClassVar[str] = "tune"
    Kc_V_per_N: float = entry("The proportional gain.", unit="V/N")
    Ti_s: float = entry("The integral time.", unit="s")
    Td_s: float = entry("The derivative time.", unit="s")
    Tf_s: float = entry("The derivative filter's time constant.", unit="s")
    b: float = entry("The setpoint weight.")
    form: str = entry("The controller's form (PID, PI).")
    ms: float = entry("The maximum sensitivity.")
    active_bounds: tuple[str, ...] = entry("The gains on an end of their range, in words.")
    minimum_time_s: float | None = entry("The least settling time any command reaches.", unit="s")
    tuned_over_bound_ratio: float | None = entry("The tuned settling over that bound.")
    search: str = entry("How the search ended.")
    gain_schedule: str | None = entry("Where a gain schedule was tuned: what was chosen.", default=None, omit=True)


@record
class ValidateSummary(StageSummary):
    """The validate stage: the gain set's status and content hash, the Monte Carlo plants, the worst settling and
    overshoot, and every requirement of the validation with its verdict."""

    STAGE: ClassVar[str] = "validate"
    status: str = entry("The gain set's status (``validated`` or ``candidate``).")
    content_sha256: str = entry("The gain set's content hash.")
    plants: int = entry("The Monte Carlo plants.", ge=0)
    worst_settling_s: float | None = entry("The worst settling time.", unit="s")
    worst_overshoot_N: float | None = entry("The worst overshoot.", unit="N")
    checked: tuple[Requirement, ...] = entry("Every requirement of the validation with its verdict.",
                                             name="requirements", default=(), required=True)

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        return self.checked

    @property
    def validated(self) -> bool:
        """Whether the gain set passed (the export and the rig take validated sets only)."""
        return self.status == "validated"


@record
class CompareSummary(StageSummary):
    """The compare stage: the tuned gains' settling with the feedforward, and the published step numbers beside the
    simulation's where the study declares them."""

    STAGE: ClassVar[str] = "compare"
    tuned_settling_s: float | None = entry("The tuned gains' settling time with the feedforward.", unit="s")
    reproduction: tuple[ReproductionRow, ...] = entry("The published step numbers beside the simulation's.")


@record
class LearnSummary(StageSummary):
    """The learn stage: the last pass's error after and before learning, the trials (each pass's), the method,
    whether it converged, the passes and the contraction where known, and the margin the last pass planned."""

    STAGE: ClassVar[str] = "learn"
    tracking_rms_N: float = entry("The last pass's RMS error after learning.", unit="N")
    tracking_rms_pct_of_range: float = entry("The same, in % of the range.", unit="%")
    before_learning_rms_N: float = entry("Its RMS error before learning.", unit="N")
    before_learning_pct_of_range: float = entry("The same, in % of the range.", unit="%")
    iterations: int = entry("The last pass's trials.", ge=0)
    trials: int = entry("Every pass's trials.", ge=0)
    trials_per_pass: tuple[int, ...] = entry("The trials of each pass.", ge=0)
    trials_to_within_1p1_per_pass: tuple[int | None, ...] = entry(
        "Each pass's first trial within 1.1 times its best (null: none).")
    method: str = entry("The learning law.")
    converged: bool = entry("Whether the last pass converged.")
    passes: int = entry("The margin passes learned.", ge=0)
    contraction_over_range: float | None = entry("The law's contraction over the range, where known.")
    preload_margin_N: float = entry("The margin the last pass planned.", unit="N")


@record
class BeforeLearning(Record):
    """Where the learn stage ran, what the system stage reports of the error before learning, and the trials."""

    tracking_rms_N_before_learning: float = entry("The RMS error before learning.", unit="N")
    tracking_rms_pct_of_range_before_learning: float = entry("The same, in % of the range.", unit="%")
    learning_iterations: int = entry("The last pass's trials.", ge=0)
    learning_trials: int = entry("Every pass's trials.", ge=0)


@record
class SystemSummary(StageSummary):
    """The system stage: the whole system's numbers along the schedule (:class:`TrackingNumbers`), its requirements
    with their verdicts (``requirements_met`` beside them in the document), what stops a missed one (``bounds``),
    the pre-cycle, the margin passes, the cycles run; the shift's thermal figures where the study has a
    ``[thermal]`` table (``thermal``: as the system artifact's summary writes them, each figure
    ``{"schedule": ..., "constant": ...}``); where the schedule was learned, the error before learning
    (``before``)."""

    STAGE: ClassVar[str] = "system"
    numbers: TrackingNumbers = entry("The whole system's numbers along the schedule.", inline=True)
    checked: tuple[Requirement, ...] = entry("The requirements with their verdicts.", name="requirements")
    bounds: tuple[ScheduleBound, ...] = entry("What stops a missed requirement.")
    pre_cycle: PreCycle = entry("The pre-cycle.")
    preload_margin_N: float = entry("The margin the schedule was planned with.", unit="N")
    cycles: int = entry("The machining cycles run.", ge=0)
    passes: tuple[MarginPass, ...] = entry("The margin passes.")
    thermal: ThermalSummary | None = entry("The shift's thermal figures (schedule and constant preload).",
                                           default=None, omit=True)
    before: BeforeLearning | None = entry("Where the schedule was learned: the error before learning.",
                                          default=None, inline=True, omit=True)
    basis: MarginBasis | None = entry("What the margins rest on: the rigidity in the machine and at the table, the "
                                      "axis stiffness at the table, the deflections, the physical lift-off.",
                                      default=None, omit=True)
    sensitivity: SensitivityRecord | None = entry("The verdicts under the modelling assumptions' ranges.",
                                                  default=None, omit=True)

    @classmethod
    def of(cls, system: SystemRecord, before: BeforeLearning | None = None) -> SystemSummary:
        """The summary of a system artifact (no series): its numbers, verdicts, bounds, pre-cycle, margin, cycles,
        passes and thermal figures; ``before``: the error before learning, where the schedule was learned.

        Parameters
        ----------
        system : SystemRecord
            The system artifact.
        before : BeforeLearning or None
            The tracking error before learning and the trials, where the schedule was learned; None otherwise.

        Returns
        -------
        SystemSummary
            The system's numbers, requirements and thermal figures, without the time series.
        """
        return cls(system.numbers, system.requirements, system.bounds, system.pre_cycle, system.preload_margin_N,
                   system.cycles, system.passes, None if system.thermal is None else system.thermal.summary(),
                   before, system.basis, system.sensitivity)

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        return self.checked

    @property
    def requirements_met(self) -> bool:
        """Whether every requirement the system stage checked is met."""
        return all(r.met for r in self.checked)

    def to_dict(self) -> dict[str, Any]:
        """The declared fields, with ``requirements_met`` (derived from the requirements) before them.

        Returns
        -------
        dict
            The document's object: the declared fields, ``requirements_met`` just before ``requirements``.
        """
        out: dict[str, Any] = {}
        for key, value in super().to_dict().items():
            if key == "requirements":
                out["requirements_met"] = self.requirements_met
            out[key] = value
        return out

    def _check_document(self, raw: Raw) -> None:
        if raw.get("requirements_met") is not self.requirements_met:
            raise raw.fail("requirements_met", "does not agree with the field 'requirements'")


@record
class ExportSummary(StageSummary):
    """The export stage: the formats the validated gain set was written in."""

    STAGE: ClassVar[str] = "export"
    formats: tuple[str, ...] = entry("The formats written.")


@record
class RigTrip(Record):
    """What stopped a rig run: the interlock, its words, when, and the voltage held then."""

    cause: str = entry("The interlock.")
    detail: str = entry("What it saw, in words.")
    t_s: float = entry("When.", unit="s")
    voltage_V: float = entry("The voltage held then.", unit="V")


_STEP_FIGURES = ("settling_s", "overshoot_N", "tracking_rms_N", "learned_tracking_rms_measured_N")


@record
class RigSummary(StageSummary):
    """The rig stage: how the run ended, its cycles and step, the loop's timing against the stall limit and the force
    limit; a tripped run's ``trip`` (and no step figures), a completed run's settling, overshoot and tracking (and
    where a learned signal was played, its tracking as measured)."""

    STAGE: ClassVar[str] = "rig"
    status: str = entry("How the run ended.")
    cycles: int = entry("The loop's cycles.", ge=0)
    controller_step: str = entry("Which controller step ran (``c``, ``python``).")
    missed_deadlines: int = entry("The cycles that missed their deadline.", ge=0)
    stalls: int = entry("The stalls.", ge=0)
    held_max_s: float = entry("The longest hold.", unit="s")
    stall_limit_s: float | None = entry("The stall limit.", unit="s")
    force_max_N: float | None = entry("The force limit.", unit="N")
    trip: RigTrip | None = entry("What stopped a tripped run.", default=None, omit=True)
    settling_s: float | None = entry("A completed run's settling time.", unit="s", default=None)
    overshoot_N: float | None = entry("Its overshoot.", unit="N", default=None)
    tracking_rms_N: float | None = entry("Its RMS tracking error.", unit="N", default=None)
    learned_tracking_rms_measured_N: float | None = entry("Where a learned signal was played: its tracking error as "
                                                          "measured.", unit="N", default=None)

    def to_dict(self) -> dict[str, Any]:
        """The declared fields; a tripped run's without the step figures."""
        out = super().to_dict()
        return {k: v for k, v in out.items() if k not in _STEP_FIGURES} if self.trip is not None else out


@record
class ReportSummary(StageSummary):
    """The report stage: the figures drawn, the PDF's size and the sections' titles."""

    STAGE: ClassVar[str] = "report"
    figures: tuple[str, ...] = entry("The figures drawn.")
    pdf_bytes: int = entry("The PDF's size.", unit="bytes", ge=0)
    sections: tuple[str, ...] = entry("The sections' titles.")


#: each stage's summary record, by the stage's name
SUMMARIES: dict[str, type[StageSummary]] = {cls.STAGE: cls for cls in (
    DesignSummary, PlantSummary, IdentifySummary, TuneSummary, ValidateSummary, CompareSummary, LearnSummary,
    SystemSummary, ExportSummary, RigSummary, ReportSummary)}


def read_summary(stage: str, doc: Any, shown: str, path: str = "") -> StageSummary:
    """The summary of ``stage`` from its JSON (at ``path`` in its document); an :class:`ArtifactError` names the
    file and the field.

    Parameters
    ----------
    stage : str
        The stage's name.
    doc : dict
        The summary's object.
    shown : str
        What the messages call the document (its file).
    path : str
        Where the summary sits in the document (``stages.tune.summary``).

    Returns
    -------
    StageSummary
        The stage's record.
    """
    if stage not in SUMMARIES:
        raise ArtifactError(f"{shown}: field '{path or stage}': no stage '{stage}' (stages: {', '.join(SUMMARIES)})")
    return SUMMARIES[stage].from_dict(doc, shown, path=path)
