"""What each stage of a study's run reports: one typed summary per stage, as ``pipeline.json`` records it.

A stage of ``piezopreload run`` (:mod:`piezopreload.pipeline`) returns its outputs and one of these records; the
manifest (:class:`~piezopreload.artifacts.manifest.StudyRunManifest`) holds each done stage's under ``summary``,
and every reader (the run's headline, the sweep's rows, the report, the pipeline's own checks) reads the record,
not the JSON. ``to_dict`` is the record's JSON (the keys ``pipeline.json`` has always had); ``from_fields`` reads it
back, each field checked and a bad one named. :data:`SUMMARIES` maps each stage's name to its record.

This module is a seam between the application layer (which builds the records from the steps' results) and the
floors that read a run (the report); it holds no computation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

from piezopreload.artifacts._fields import Fields
from piezopreload.artifacts.requirements import Requirement, requirements_from_dict
from piezopreload.artifacts.responses import ReproductionRow
from piezopreload.artifacts.system import PassRecord, PreCycle, ScheduleBound, TrackingNumbers
from piezopreload.core.errors import ArtifactError

__all__ = ["StageSummary", "DesignSummary", "PlantSummary", "IdentifySummary", "TuneSummary", "ValidateSummary",
           "CompareSummary", "LearnSummary", "SystemSummary", "ExportSummary", "RigTrip", "RigSummary",
           "ReportSummary", "SUMMARIES", "read_summary"]

T = TypeVar("T")


def _optional(f: Fields, key: str, read: Callable[[str], T]) -> T | None:
    """A field that may be null or absent."""
    return read(key) if f.has(key) else None


def _counts(f: Fields, key: str) -> tuple[int | None, ...]:
    """A list of whole numbers >= 0, each may be null."""
    raw = f.raw(key)
    if not isinstance(raw, list) or not all(x is None or (isinstance(x, int) and not isinstance(x, bool) and x >= 0)
                                            for x in raw):
        raise f.fail(key, f"must be a list of whole numbers >= 0 (or null), got {raw!r}")
    return tuple(raw)


def _requirements(f: Fields) -> tuple[Requirement, ...]:
    return requirements_from_dict(f.raw("requirements"), f"{f.shown}: field '{f.path('requirements')}'")


class StageSummary:
    """What every stage's summary has: the stage it belongs to, its JSON, and a reader of that JSON."""

    STAGE: ClassVar[str]

    def to_dict(self) -> dict[str, Any]:
        """The summary as ``pipeline.json`` records it."""
        raise NotImplementedError

    @classmethod
    def from_fields(cls, f: Fields) -> StageSummary:
        """The summary read back from its JSON (``f``), every field checked."""
        raise NotImplementedError

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        """The requirements the stage checked (none, unless it checks some)."""
        return ()


@dataclass(frozen=True)
class DesignSummary(StageSummary):
    """The design stage: the optimum's objective and rigidity, the constraints that bind, the fronts traced, the
    preload schedule's saving against the best constant preload."""

    STAGE: ClassVar[str] = "design"
    objective: str
    stiffness_N_per_um: float
    binding: tuple[str, ...]
    fronts: tuple[str, ...]
    schedule_saving_fraction: float
    constant_preload_N: float
    constant_friction_energy: float
    energy_units: str

    def to_dict(self) -> dict[str, Any]:
        return {"objective": self.objective, "stiffness_N_per_um": self.stiffness_N_per_um,
                "binding": list(self.binding), "fronts": list(self.fronts),
                "schedule_saving_fraction": self.schedule_saving_fraction,
                "constant_preload_N": self.constant_preload_N,
                "constant_friction_energy": self.constant_friction_energy, "energy_units": self.energy_units}

    @classmethod
    def from_fields(cls, f: Fields) -> DesignSummary:
        return cls(f.text("objective"), f.number("stiffness_N_per_um"), f.texts("binding"), f.texts("fronts"),
                   f.number("schedule_saving_fraction"), f.number("constant_preload_N"),
                   f.number("constant_friction_energy"), f.text("energy_units"))


@dataclass(frozen=True)
class PlantSummary(StageSummary):
    """The plant stage: the designed plant's origin, the stacks' share of the preload and the coupling's local
    stiffness at the bolts' preload and at the top (``at_bolts``, ``at_max``)."""

    STAGE: ClassVar[str] = "plant"
    design_sha256: str
    stack_force_max_N: float
    local_stiffness_N_per_um: dict[str, float]
    bolt_preload_N: float

    def to_dict(self) -> dict[str, Any]:
        return {"design_sha256": self.design_sha256, "stack_force_max_N": self.stack_force_max_N,
                "local_stiffness_N_per_um": dict(self.local_stiffness_N_per_um), "bolt_preload_N": self.bolt_preload_N}

    @classmethod
    def from_fields(cls, f: Fields) -> PlantSummary:
        k = f.sub("local_stiffness_N_per_um")
        return cls(f.text("design_sha256"), f.number("stack_force_max_N"),
                   {name: k.number(name) for name in k.doc}, f.number("bolt_preload_N"))


@dataclass(frozen=True)
class IdentifySummary(StageSummary):
    """The identify stage: where the loop came from, the model's operators, its fit and the open-loop check."""

    STAGE: ClassVar[str] = "identify"
    source: str
    data_sha256: str
    operators: int
    fit_rms_pct: float
    fit_max_pct: float
    compensation_rms_N: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "data_sha256": self.data_sha256, "operators": self.operators,
                "fit_rms_pct": self.fit_rms_pct, "fit_max_pct": self.fit_max_pct,
                "compensation_rms_N": self.compensation_rms_N}

    @classmethod
    def from_fields(cls, f: Fields) -> IdentifySummary:
        return cls(f.text("source"), f.text("data_sha256"), f.integer("operators"), f.number("fit_rms_pct"),
                   f.number("fit_max_pct"), f.optional_number("compensation_rms_N"))


@dataclass(frozen=True)
class TuneSummary(StageSummary):
    """The tune stage: the gains (SI), the controller's form, Ms, the gains on their bounds (sentences), the
    minimum-time bound and the tuned settling over it, how the search ended, and where a gain schedule was tuned,
    what was chosen (``gain_schedule``: ``schedule`` or ``robust``)."""

    STAGE: ClassVar[str] = "tune"
    Kc_V_per_N: float
    Ti_s: float
    Td_s: float
    Tf_s: float
    b: float
    form: str
    ms: float
    active_bounds: tuple[str, ...]
    minimum_time_s: float | None
    tuned_over_bound_ratio: float | None
    search: str
    gain_schedule: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "Kc_V_per_N": self.Kc_V_per_N, "Ti_s": self.Ti_s, "Td_s": self.Td_s, "Tf_s": self.Tf_s, "b": self.b,
            "form": self.form, "ms": self.ms, "active_bounds": list(self.active_bounds),
            "minimum_time_s": self.minimum_time_s, "tuned_over_bound_ratio": self.tuned_over_bound_ratio,
            "search": self.search}
        if self.gain_schedule is not None:  # written only where a schedule was tuned
            out["gain_schedule"] = self.gain_schedule
        return out

    @classmethod
    def from_fields(cls, f: Fields) -> TuneSummary:
        return cls(f.number("Kc_V_per_N"), f.number("Ti_s"), f.number("Td_s"), f.number("Tf_s"), f.number("b"),
                   f.text("form"), f.number("ms"), f.texts("active_bounds"), f.optional_number("minimum_time_s"),
                   f.optional_number("tuned_over_bound_ratio"), f.text("search"),
                   _optional(f, "gain_schedule", f.text))


@dataclass(frozen=True)
class ValidateSummary(StageSummary):
    """The validate stage: the gain set's status and content hash, the Monte Carlo plants, the worst settling and
    overshoot, and every requirement of the validation with its verdict."""

    STAGE: ClassVar[str] = "validate"
    status: str
    content_sha256: str
    plants: int
    worst_settling_s: float | None
    worst_overshoot_N: float | None
    checked: tuple[Requirement, ...] = field(default=())

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        return self.checked

    @property
    def validated(self) -> bool:
        """Whether the gain set passed (the export and the rig take validated sets only)."""
        return self.status == "validated"

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status, "content_sha256": self.content_sha256, "plants": self.plants,
                "worst_settling_s": self.worst_settling_s, "worst_overshoot_N": self.worst_overshoot_N,
                "requirements": [r.to_dict() for r in self.checked]}

    @classmethod
    def from_fields(cls, f: Fields) -> ValidateSummary:
        return cls(f.text("status"), f.text("content_sha256"), f.integer("plants"),
                   f.optional_number("worst_settling_s"), f.optional_number("worst_overshoot_N"), _requirements(f))


@dataclass(frozen=True)
class CompareSummary(StageSummary):
    """The compare stage: the tuned gains' settling with the feedforward, and the published step numbers beside the
    simulation's where the study declares them."""

    STAGE: ClassVar[str] = "compare"
    tuned_settling_s: float | None
    reproduction: tuple[ReproductionRow, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"tuned_settling_s": self.tuned_settling_s, "reproduction": [r.to_dict() for r in self.reproduction]}

    @classmethod
    def from_fields(cls, f: Fields) -> CompareSummary:
        raw = f.raw("reproduction")
        if not isinstance(raw, list):
            raise f.fail("reproduction", f"must be a list, got {type(raw).__name__}")
        return cls(f.optional_number("tuned_settling_s"),
                   tuple(ReproductionRow.from_dict(r, f"{f.shown}: field '{f.path('reproduction')}[{i}]'")
                         for i, r in enumerate(raw)))


@dataclass(frozen=True)
class LearnSummary(StageSummary):
    """The learn stage: the last pass's error after and before learning, the trials (each pass's), the method,
    whether it converged, the passes and the contraction where known, and the margin the last pass planned."""

    STAGE: ClassVar[str] = "learn"
    tracking_rms_N: float
    tracking_rms_pct_of_range: float
    before_learning_rms_N: float
    before_learning_pct_of_range: float
    iterations: int
    trials: int
    trials_per_pass: tuple[int, ...]
    trials_to_within_1p1_per_pass: tuple[int | None, ...]
    method: str
    converged: bool
    passes: int
    contraction_over_range: float | None
    preload_margin_N: float

    def to_dict(self) -> dict[str, Any]:
        return {"tracking_rms_N": self.tracking_rms_N, "tracking_rms_pct_of_range": self.tracking_rms_pct_of_range,
                "before_learning_rms_N": self.before_learning_rms_N,
                "before_learning_pct_of_range": self.before_learning_pct_of_range, "iterations": self.iterations,
                "trials": self.trials, "trials_per_pass": list(self.trials_per_pass),
                "trials_to_within_1p1_per_pass": list(self.trials_to_within_1p1_per_pass), "method": self.method,
                "converged": self.converged, "passes": self.passes,
                "contraction_over_range": self.contraction_over_range, "preload_margin_N": self.preload_margin_N}

    @classmethod
    def from_fields(cls, f: Fields) -> LearnSummary:
        per_pass = _counts(f, "trials_per_pass")
        if None in per_pass:
            raise f.fail("trials_per_pass", f"must be a list of whole numbers >= 0, got {list(per_pass)!r}")
        return cls(f.number("tracking_rms_N"), f.number("tracking_rms_pct_of_range"),
                   f.number("before_learning_rms_N"), f.number("before_learning_pct_of_range"),
                   f.integer("iterations"), f.integer("trials"), tuple(int(k or 0) for k in per_pass),
                   _counts(f, "trials_to_within_1p1_per_pass"), f.text("method"), f.flag("converged"),
                   f.integer("passes"), f.optional_number("contraction_over_range"), f.number("preload_margin_N"))


@dataclass(frozen=True)
class BeforeLearning:
    """Where the learn stage ran, what the system stage reports of the error before learning, and the trials."""

    tracking_rms_N_before_learning: float
    tracking_rms_pct_of_range_before_learning: float
    learning_iterations: int
    learning_trials: int

    def to_dict(self) -> dict[str, Any]:
        return {"tracking_rms_N_before_learning": self.tracking_rms_N_before_learning,
                "tracking_rms_pct_of_range_before_learning": self.tracking_rms_pct_of_range_before_learning,
                "learning_iterations": self.learning_iterations, "learning_trials": self.learning_trials}

    @classmethod
    def from_fields(cls, f: Fields) -> BeforeLearning:
        return cls(f.number("tracking_rms_N_before_learning"), f.number("tracking_rms_pct_of_range_before_learning"),
                   f.integer("learning_iterations"), f.integer("learning_trials"))


@dataclass(frozen=True)
class SystemSummary(StageSummary):
    """The system stage: the whole system's numbers along the schedule (:class:`TrackingNumbers`), its requirements
    with their verdicts, what stops a missed one (``bounds``), the pre-cycle, the margin passes, the cycles run; the
    shift's thermal figures where the study has a ``[thermal]`` table (``thermal``: as the system artifact's summary
    writes them, each figure ``{"schedule": ..., "constant": ...}``); where the schedule was learned, the error
    before learning (``before``)."""

    STAGE: ClassVar[str] = "system"
    numbers: TrackingNumbers
    checked: tuple[Requirement, ...]
    bounds: tuple[ScheduleBound, ...]
    pre_cycle: PreCycle
    preload_margin_N: float
    cycles: int
    passes: tuple[PassRecord, ...]
    thermal: dict[str, Any] | None = None
    before: BeforeLearning | None = None

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        return self.checked

    @property
    def requirements_met(self) -> bool:
        return all(r.met for r in self.checked)

    def thermal_figure(self, name: str) -> tuple[float | None, float | None]:
        """A thermal figure (``heat_mean_W``, ``growth_max_um``, ...) for the schedule and for the constant preload;
        (None, None) where the study has no ``[thermal]`` table."""
        pair = (self.thermal or {}).get(name) or {}
        return pair.get("schedule"), pair.get("constant")

    def to_dict(self) -> dict[str, Any]:
        return {**self.numbers.to_dict(), "requirements_met": self.requirements_met,
                "requirements": [r.to_dict() for r in self.checked], "bounds": [b.to_dict() for b in self.bounds],
                "pre_cycle": self.pre_cycle.to_dict(), "preload_margin_N": self.preload_margin_N,
                "cycles": self.cycles, "passes": [p.to_dict() for p in self.passes],
                **({} if self.thermal is None else {"thermal": dict(self.thermal)}),
                **({} if self.before is None else self.before.to_dict())}

    @classmethod
    def from_fields(cls, f: Fields) -> SystemSummary:
        summary = cls(TrackingNumbers.from_fields(f), _requirements(f), f.items("bounds", ScheduleBound.from_fields),
                      PreCycle.from_fields(f.sub("pre_cycle")), f.number("preload_margin_N"), f.integer("cycles"),
                      f.items("passes", PassRecord.from_fields), _optional(f, "thermal", f.mapping),
                      BeforeLearning.from_fields(f) if f.has("learning_trials") else None)
        if f.flag("requirements_met") != summary.requirements_met:
            raise f.fail("requirements_met", "does not agree with the field 'requirements'")
        return summary


@dataclass(frozen=True)
class ExportSummary(StageSummary):
    """The export stage: the formats the validated gain set was written in."""

    STAGE: ClassVar[str] = "export"
    formats: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"formats": list(self.formats)}

    @classmethod
    def from_fields(cls, f: Fields) -> ExportSummary:
        return cls(f.texts("formats"))


@dataclass(frozen=True)
class RigTrip:
    """What stopped a rig run: the interlock, its words, when, and the voltage held then."""

    cause: str
    detail: str
    t_s: float
    voltage_V: float

    def to_dict(self) -> dict[str, Any]:
        return {"cause": self.cause, "detail": self.detail, "t_s": self.t_s, "voltage_V": self.voltage_V}

    @classmethod
    def from_fields(cls, f: Fields) -> RigTrip:
        return cls(f.text("cause"), f.text("detail"), f.number("t_s"), f.number("voltage_V"))


@dataclass(frozen=True)
class RigSummary(StageSummary):
    """The rig stage: how the run ended, its cycles and step, the loop's timing against the stall limit and the force
    limit; a tripped run's ``trip`` (and no step figures), a completed run's settling, overshoot and tracking (and
    where a learned signal was played, its tracking as measured)."""

    STAGE: ClassVar[str] = "rig"
    status: str
    cycles: int
    controller_step: str
    missed_deadlines: int
    stalls: int
    held_max_s: float
    stall_limit_s: float | None
    force_max_N: float | None
    trip: RigTrip | None = None
    settling_s: float | None = None
    overshoot_N: float | None = None
    tracking_rms_N: float | None = None
    learned_tracking_rms_measured_N: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "status": self.status, "cycles": self.cycles, "controller_step": self.controller_step,
            "missed_deadlines": self.missed_deadlines, "stalls": self.stalls, "held_max_s": self.held_max_s,
            "stall_limit_s": self.stall_limit_s, "force_max_N": self.force_max_N}
        if self.trip is not None:  # a tripped run has no step figures
            return {**out, "trip": self.trip.to_dict()}
        return {**out, "settling_s": self.settling_s, "overshoot_N": self.overshoot_N,
                "tracking_rms_N": self.tracking_rms_N,
                "learned_tracking_rms_measured_N": self.learned_tracking_rms_measured_N}

    @classmethod
    def from_fields(cls, f: Fields) -> RigSummary:
        head = (f.text("status"), f.integer("cycles"), f.text("controller_step"), f.integer("missed_deadlines"),
                f.integer("stalls"), f.number("held_max_s"), f.optional_number("stall_limit_s"),
                f.optional_number("force_max_N"))
        if f.has("trip"):
            return cls(*head, trip=RigTrip.from_fields(f.sub("trip")))
        return cls(*head, settling_s=f.optional_number("settling_s"), overshoot_N=f.optional_number("overshoot_N"),
                   tracking_rms_N=f.optional_number("tracking_rms_N"),
                   learned_tracking_rms_measured_N=f.optional_number("learned_tracking_rms_measured_N"))


@dataclass(frozen=True)
class ReportSummary(StageSummary):
    """The report stage: the figures drawn, the PDF's size and the sections' titles."""

    STAGE: ClassVar[str] = "report"
    figures: tuple[str, ...]
    pdf_bytes: int
    sections: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"figures": list(self.figures), "pdf_bytes": self.pdf_bytes, "sections": list(self.sections)}

    @classmethod
    def from_fields(cls, f: Fields) -> ReportSummary:
        return cls(f.texts("figures"), f.integer("pdf_bytes"), f.texts("sections"))


#: each stage's summary record, by the stage's name
SUMMARIES: dict[str, type[StageSummary]] = {cls.STAGE: cls for cls in (
    DesignSummary, PlantSummary, IdentifySummary, TuneSummary, ValidateSummary, CompareSummary, LearnSummary,
    SystemSummary, ExportSummary, RigSummary, ReportSummary)}


def read_summary(stage: str, doc: Any, shown: str, prefix: str = "") -> StageSummary:
    """The summary of ``stage`` from its JSON; an :class:`ArtifactError` names the file and the field."""
    if stage not in SUMMARIES:
        raise ArtifactError(f"{shown}: field '{prefix or stage}': no stage '{stage}' (stages: "
                            f"{', '.join(SUMMARIES)})")
    return SUMMARIES[stage].from_fields(Fields(doc, shown, prefix))
