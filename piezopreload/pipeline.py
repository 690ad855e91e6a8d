"""The one-command study: ``piezopreload run [STUDY.toml] [--out DIR] [--force]``, ``study.run(out=...)``.

A study goes through its stages (:data:`STAGES`), each a call of one of the study's steps writing
versioned artifacts into the output folder:

==========  ==================================================================  ==========================
stage       what it does                                                        writes
==========  ==================================================================  ==========================
design      ball-screw preload optimum, Pareto fronts, preload schedule          design/design.json + CSVs
plant       the designed preload system as the plant (``[plant] from_design``)   plant.json
identify    the feedforward's P-I model from the loop measurement (simulated    feedforward/model.json,
            on the plant's truth model, or the study's ``[feedforward] data``)   feedforward/loop.csv
tune        PID gains around the compensated plant (CasADi), compared, bounded; tuning.json
            a gain schedule on the preload level or the robust set (``[tuning]``)
validate    the tuned gains on a Monte Carlo set of nonlinear rigs              gains.json, validation.json
compare     step and trajectory, the study's and the tuned gains, with/without  responses/
            FF (and the published step numbers where the study declares them)
learn       learning control on the repeated schedule, each margin pass on its  learn/learning.json,
            own reference (``[learning]``; the margin from the learned error)   learn/learned-pass*.json
system      the controlled preload along the design's schedule (learned where   system/system.json,
            learn ran): rigidity and deflection while cutting, friction energy; system/reference.csv
            the shift's heat, temperature and growth (``[thermal]``)
export      the validated gain set in the study's controller formats            exports/
rig         the validated gains on the rig executor (simulated by default)      runs/run-*.csv + .json
report      figures and the PDF (Typst)                                          report/, report.pdf
==========  ==================================================================  ==========================

A study without ``[plant] from_design`` (the paper's) runs on its ``[rig]``: plant and system do
not apply. With it, identify, tune, validate and compare run on the designed plant (the plant of the design stage's
optimum, held by the run's :class:`~piezopreload.steps.Solved`: the plant stage writes it as ``plant.json``), and
their keys include the plant's hash: a changed design makes another plant and everything after it runs again. With
a ``[learning]`` table too, the learn stage learns on each margin pass of the schedule and the system stage
plays each pass's signal (:func:`~piezopreload.steps.track_schedule`'s ``ff_extra_V``): its summary is after
learning, with the error before learning beside it; the rig stage plays the last pass's signal.

Every stage has a key: the SHA-256 of its study tables, of the artifacts it reads, of the
files the study names for it and of the code it runs. ``pipeline.json`` records each stage's
key and the hashes of what it wrote; a stage whose key and outputs are unchanged is not run
again. ``force`` reruns everything. A failing stage stops the study with its name; what the
stages before it wrote stays, and the manifest records the failure. A new stage is a
:class:`Stage` in :data:`STAGES`: its tables, the stages it reads, its code and its body. The
keying, the records and the loop that runs stages are :mod:`piezopreload.core.stages`; what is
here is what makes them a study's.

Several output folders can share their stages' outputs through a
:class:`~piezopreload.core.stagecache.StageCache` (``run_study(..., cache=...)``; a design sweep
gives every point's folder the same one): a stage whose key another folder has computed is
restored from the store instead of run (its artifacts are byte for byte that folder's, naming
the study that computed them), and one being computed by another process is waited for. The rig
and report stages are not shared (``Stage.shared``): each records its own folder's run.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from piezopreload import steps
from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.manifest import MANIFEST, STUDY_COPY, StageRecord, StudyRef, StudyRunManifest
from piezopreload.artifacts.requirements import missed
from piezopreload.artifacts.responses import RESPONSE_FIGURES, ResponseRun, ResponsesRecord
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.artifacts.summaries import (
    BeforeLearning,
    CompareSummary,
    DesignSummary,
    ExportSummary,
    IdentifySummary,
    LearnSummary,
    PlantSummary,
    RigSummary,
    RigTrip,
    StageSummary,
    SystemSummary,
    TuneSummary,
    ValidateSummary,
)
from piezopreload.artifacts.system import SystemRecord
from piezopreload.artifacts.tuning import TuningResult
from piezopreload.codesign import codesign_design
from piezopreload.core.artifacts import atomic_write_bytes, package_version
from piezopreload.core.errors import InputError
from piezopreload.core.parallel import Pool, default_workers
from piezopreload.core.stagecache import StageCache
from piezopreload.core.stages import (
    Partial,
    StageCrashed,
    StageFailed,
    code_hash,
    content_key,
    locked,
    outputs_intact,
    run_stages,
    sha256_file,
    upstream_hashes,
    utc,
)
from piezopreload.core.tables import write_csv
from piezopreload.design.tables import DesignMethod, DesignTable, PlantTable
from piezopreload.outcome import Headline, RunSummary, StageOutcome, StudyResult
from piezopreload.progress import Progress, ProgressLike, as_progress
from piezopreload.reports.study_report import STAGES_READ, Published, ReportStudy, render_report
from piezopreload.rig.export import write_exports
from piezopreload.spec import StudySpec, design_spec_of_tables
from piezopreload.steps import Solved
from piezopreload.tuning.compare import creep_effect, reproduction, responses
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.learning import played_passes, save_passes

__all__ = ["Stage", "STAGES", "StageFailed", "StageCrashed", "run_study", "rerender_report", "read_template",
           "run_summary", "DEFAULT_OUT", "Produced"]

DEFAULT_OUT = "piezopreload-out"
#: what a stage's body returns: its outputs (label -> path in the folder) and its summary
Produced = tuple[dict[str, Path], StageSummary]


# --------------------------------------------------------------------------------------
# the stages
# --------------------------------------------------------------------------------------
@dataclass
class _Ctx:
    study: StudySpec
    out: Path
    progress: Progress
    records: dict[str, dict[str, Any]]
    source: str = ""                         # the study file as the user named it
    template: str | None = None              # a Typst template's text to use instead of the shipped one
    cache: StageCache | None = None          # stage outputs shared with other folders
    pool: Pool = field(default_factory=Pool)  # the run's worker processes (one: none, each job here)
    _solved: Solved | None = None

    def record(self, stage: str) -> StageRecord | None:
        """The record of ``stage`` so far in this run (None: not reached)."""
        raw = self.records.get(stage)
        return None if raw is None else StageRecord.read(stage, raw, str(self.out / MANIFEST))

    def done(self, stage: str) -> bool:
        record = self.record(stage)
        return record is not None and record.done

    def _output(self, stage: str, label: str) -> tuple[str, str]:
        record = self.record(stage)
        o = None if record is None else record.outputs.get(label)
        if o is None:
            raise StageFailed(stage, f"it recorded no output '{label}'; run the study again with --force")
        return o.path, o.sha256

    def output(self, stage: str, label: str) -> Path:
        return self.out / self._output(stage, label)[0]

    def sha256(self, stage: str, label: str) -> str:
        return self._output(stage, label)[1]

    def manifest(self) -> StudyRunManifest:
        """The stages' records so far, typed (what ``pipeline.json`` holds)."""
        return StudyRunManifest.from_records(StudyRef(self.source or self.study.path, self.study.sha256,
                                                      self.study.name), "", self.records, tuple(_BY_NAME),
                                             str(self.out / MANIFEST))

    def rel(self, path: Path) -> str:
        return Path(path).resolve().relative_to(self.out.resolve()).as_posix()

    def feedforward(self) -> IdentifiedFeedforward:
        return IdentifiedFeedforward.load(self.output("identify", "model"))

    def design(self) -> DesignRecord:
        """The design stage's record (the optimum, the fronts, the schedule: the one source of the best constant)."""
        return DesignRecord.load(self.output("design", "design"))

    def schedule(self) -> PreloadSchedule:
        """The design's preload schedule, as the design stage recorded it."""
        return self.design().schedule

    def solved(self) -> Solved:
        """What the stages after the design run on: where the plant is the design, the design stage's optimum given
        (the plant, the designed plant and the preload schedule are made from it, not solved again)."""
        if self._solved is None:
            self._solved = (Solved(self.study, self.design(), self.sha256("design", "design"))
                            if self.study.plant_from_design else Solved(self.study))
        return self._solved


@dataclass(frozen=True)
class Stage:
    """One stage: its study tables, the stages whose outputs it reads, the code its key covers, its body."""

    name: str
    what: str
    tables: tuple[str, ...]
    needs: tuple[str, ...]
    code: tuple[str, ...]
    run: Callable[[_Ctx], Produced]
    files: tuple[str, ...] = ()  # the study's file keys it reads (hashed into its key)
    applies: Callable[[StudySpec], str | None] = field(default=lambda study: None)  # why it does not apply, or None
    validated_only: bool = False  # runs only on a validated gain set (export, the rig)
    reads: Callable[[StudySpec], tuple[str, ...]] = field(default=lambda study: ())  # more tables, as the study asks
    shared: bool = True  # its outputs may be restored from a StageCache (False: they record this folder's own run)


def _stage_identify(ctx: _Ctx) -> Produced:
    ff = steps.identify(ctx.study, ctx.solved(), progress=ctx.progress.say)
    paths = ff.save(ctx.out / "feedforward", inputs={"study_sha256": ctx.study.sha256})
    return paths, IdentifySummary(ff.record.data.kind, ff.record.data.sha256, ff.model.n_operators, ff.fit.rms_pct,
                                  ff.fit.max_pct, None if ff.check is None else ff.check.rms_N)


def _stage_design(ctx: _Ctx) -> Produced:
    d = ctx.out / "design"
    for stale in d.glob("design.pareto-*.csv"):  # a front the study no longer asks for
        stale.unlink()
    optimum, codesigned = None, None
    inputs = {"study": ctx.study.path, "study_sha256": ctx.study.sha256}
    (d / "codesign.json").unlink(missing_ok=True)  # a co-design the study no longer asks for
    if (ctx.study.design_table or DesignTable()).method is DesignMethod.CODESIGN:  # chosen with its controller
        ctx.progress.say("[design] method = codesign: the design is chosen with its controller (nested co-design)")
        optimum, codesigned = codesign_design(ctx.study, progress=ctx.progress.say, inputs=inputs)
    result = steps.design(ctx.study, Solved(ctx.study), progress=ctx.progress.say,
                          bar=ctx.progress.bar("Pareto fronts"), optimum=optimum)
    written = result.save(d / "design.json", inputs)
    outputs = {"design": written[0], **{p.stem.rpartition(".")[2]: p for p in written[1:]}}
    if codesigned is not None:
        outputs["codesign"] = codesigned.save(d / "codesign.json")
    s = result.schedule
    return outputs, DesignSummary(result.optimum.objective, result.point.stiffness_N_per_um,
                                  tuple(result.optimum.binding), tuple(f.pair for f in result.fronts),
                                  s.saving_fraction, s.constant_preload_N, s.constant_friction_energy_J,
                                  s.energy_units, None if result.robust_cost is None else result.robust_cost.to_dict())


def _stage_tune(ctx: _Ctx) -> Produced:
    tuned = steps.tune(ctx.study, ctx.solved(), ctx.feedforward(), progress=ctx.progress.say,
                 iterations=ctx.progress.counter("IPOPT iterations", every=10),
                       pool=ctx.pool)
    g, sched, bound = tuned.gains, tuned.solve.schedule, tuned.minimum_time
    return {"tuning": tuned.save(ctx.out / "tuning.json")}, TuneSummary(
        g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b, tuned.solve.form, tuned.solve.ms,
        tuple(b.sentence() for b in tuned.active_bounds), bound.settling_s, bound.tuned_over_bound_ratio,
        tuned.solve.search, None if sched is None else sched.choice)


def _stage_validate(ctx: _Ctx) -> Produced:
    study = ctx.study
    gain_set = steps.validate(study, ctx.solved(), TuningResult.load(ctx.output("tune", "tuning")), ctx.feedforward(),
                              inputs={"tuning_sha256": ctx.sha256("tune", "tuning")}, progress=ctx.progress.say,
                              bar=ctx.progress.bar(f"Monte Carlo, {study.validation.plants} plants"),
                              pool=ctx.pool)
    result = gain_set.validation
    if result is None:  # pragma: no cover - a validation always judges the set it returns
        raise StageFailed("validate", "the validation returned a gain set without its verdict")
    gains_path, validation_path = ctx.out / "gains.json", ctx.out / "validation.json"
    gain_set = gain_set.save(gains_path)
    replace(result, gain_set_sha256=gain_set.content_sha256,
            inputs={"gain_set": "gains.json", "study_sha256": study.sha256}).save(validation_path)
    if not gain_set.validated:  # a verdict, not a failure: the study goes on, export and the rig take validated sets
        ctx.progress.say(f"{gains_path.name} is a {gain_set.verdict()}")
    return {"gains": gains_path, "validation": validation_path}, ValidateSummary(
        gain_set.status, gain_set.content_sha256 or "", result.n_plants, result.worst.settling_s,
        result.worst.overshoot_N, tuple(gain_set.requirements))


def _stage_compare(ctx: _Ctx) -> Produced:
    study, ff, plant = ctx.study, ctx.feedforward(), ctx.solved().plant()
    gain_set = GainSet.load(ctx.output("validate", "gains"))
    references, gains = study.reference.references(), {"study": study.controller, "tuned": gain_set.gains}
    runs = responses(plant, references, gains, ff.model,
                     seed=study.seed, band_N=study.band_N, signal=study.signal,
                     after_change_s=study.validation.tracking_after_change_s,
                     bar=ctx.progress.bar("closed-loop runs"))
    d = ctx.out / "responses"
    outputs: dict[str, Path] = {}
    rows = []
    for r in runs:
        path = outputs[r.label] = d / f"{r.label}.csv"
        write_csv(path, r.run.columns(), f"piezopreload {package_version()} run: study {study.name}, {r.gains} gains, "
                                         f"{r.controller}, {r.reference}, seed {study.seed}")
        rows.append(ResponseRun(r.gains, r.controller, r.reference, ctx.rel(path),
                                **{k: r.numbers.get(k) for k in RESPONSE_FIGURES}))
    table = [] if study.published is None else reproduction(runs, study.published.step())
    creep = None if ff.without_creep is None else creep_effect(  # FF + PID with and without creep compensation
        plant, references, gains, ff.model, ff.without_creep,
        seed=study.seed, band_N=study.band_N, signal=study.signal,
        after_change_s=study.validation.tracking_after_change_s)
    record = ResponsesRecord(
        tuple(rows), study.band_N, study.signal, study.seed, tuple(table), tuple(creep or ()),
        {"gain_set_sha256": gain_set.content_sha256, "study_sha256": study.sha256,
         "feedforward_sha256": ctx.sha256("identify", "model")})
    outputs["responses"] = record.save(d / "responses.json")
    return outputs, CompareSummary(record.run("tuned", "ff+pid", "step").settling_s, tuple(table))


def _stage_plant(ctx: _Ctx) -> Produced:
    plant = ctx.solved().designed()
    path = plant.save(ctx.out / "plant.json", {"design": ctx.rel(ctx.output("design", "design")),
                                               "design_sha256": plant.design_sha256, "study_sha256": ctx.study.sha256})
    k = plant.local_stiffness_N_per_um()
    ctx.progress.say(f"{plant.rig.n_stacks} x {plant.rig.stack.name}, stacks' share 0-{plant.stack_force_max_N:.0f} N, "
                     f"{k['at_bolts']:.0f}-{k['at_max']:.0f} N/um of stroke over the range, "
                     f"slew {float(plant.rig.slew_V_per_s):.0f} V/s")
    return {"plant": path}, PlantSummary(plant.design_sha256, plant.stack_force_max_N, k, plant.bolt_preload_N)


def _stage_learn(ctx: _Ctx) -> Produced:
    study, gain_set = ctx.study, GainSet.load(ctx.output("validate", "gains"))
    learned = steps.learn_schedule(study, ctx.solved(), gain_set, progress=ctx.progress.say)
    inputs = {"gain_set_sha256": gain_set.content_sha256, "plant_sha256": ctx.sha256("plant", "plant"),
              "study_sha256": study.sha256}
    outputs, record = save_passes(list(learned.passes), ctx.out / "learn", gain_set.content_sha256, inputs)
    last = record.last
    cycles = (study.plant_table or PlantTable()).cycles
    ctx.progress.say(f"{record.trials} learning trials over {len(record.passes)} pass(es) "
                     f"({', '.join(str(t) for t in record.trials_per_pass)}; each trial {cycles} machining "
                     f"cycle(s)), the last pass within 1.1 x its best from trial {last.trials_to_within_1p1}")
    contraction = last.learning.get("contraction_over_range")
    return outputs, LearnSummary(
        last.tracking_rms_N, last.tracking_rms_pct_of_range, last.before_learning_rms_N,
        last.before_learning_pct_of_range, last.trials, record.trials, tuple(record.trials_per_pass),
        tuple(p.trials_to_within_1p1 for p in record.passes), last.method, last.converged, len(record.passes),
        None if contraction is None else float(contraction), learned.system.margin_N)


def _stage_system(ctx: _Ctx) -> Produced:
    study, gain_set = ctx.study, GainSet.load(ctx.output("validate", "gains"))
    extra, before = None, None
    if ctx.done("learn"):  # each pass plays the signal learned on its reference
        extra, record = played_passes(ctx.output("learn", "learning"), gain_set.content_sha256)
        before = BeforeLearning(record.last.before_learning_rms_N, record.last.before_learning_pct_of_range,
                                record.last.trials, record.trials)
    result = steps.track_schedule(study, ctx.solved(), gain_set, ff_extra_V=extra, progress=ctx.progress.say)
    paths = result.save(ctx.out / "system", {
        "gain_set_sha256": gain_set.content_sha256, "design_sha256": ctx.sha256("design", "design"),
        "plant_sha256": ctx.sha256("plant", "plant"), "study_sha256": study.sha256,
        **({"learned": ctx.rel(ctx.output("learn", "learning"))} if extra is not None else {})})
    system = SystemRecord.load(paths["system"])
    for r in system.missed:
        ctx.progress.say(f"requirement missed: {r.sentence()}")
    for b in system.bounds:
        ctx.progress.say(f"what stops it: {b.sentence()}")
    return paths, SystemSummary.of(system, before)


def _stage_export(ctx: _Ctx) -> Produced:
    formats = list(ctx.study.export.formats)
    outputs = write_exports(GainSet.load(ctx.output("validate", "gains")), ctx.out / "exports", formats)
    for fmt, path in outputs.items():
        ctx.progress.say(f"{fmt}: {ctx.rel(path)}")
    return {fmt: Path(p) for fmt, p in outputs.items()}, ExportSummary(tuple(formats))


def _stage_rig(ctx: _Ctx) -> Produced:
    from piezopreload.rig import session  # with the OPC UA push: loaded when the stage runs, not on every rerun

    plan = ctx.study.rig_run
    reference: str | None = str(ctx.study.files().get("rig_run.reference", plan.reference))
    learned = None
    if reference == "schedule":
        if not ctx.done("system"):
            raise StageFailed("rig", "[rig_run] reference = 'schedule' needs the system stage (a study whose "
                                     "[plant] is its design's)")
        reference = str(ctx.output("system", "reference"))
        if ctx.done("learn"):  # the schedule, learned: the signal's own reference
            learned, reference = ctx.output("learn", "learned"), None
    ctx.progress.say(f"backend '{plan.backend}', reference {Path(reference or learned or '').name}"
                     f"{' (learned)' if learned else ''}, {'real time' if plan.realtime else 'back to back'}")
    s = session.run(ctx.output("validate", "gains"), backend=plan.backend, reference=reference,
                    realtime=bool(plan.realtime), log_dir=ctx.out / "runs", safety=plan.safety(), seed=plan.seed,
                    learned=learned, safety_source=f"the study's [rig_run] ({ctx.study.path})",
                    say=ctx.progress.say).summary
    outputs = {"log_csv": Path(s["log_csv"]), "log_json": Path(s["log_json"])}
    record = RigRunRecord.load(outputs["log_json"])
    summary = _rig_summary(record)
    if record.trip is not None:
        trip = record.trip
        raise StageFailed("rig", f"the run was stopped by the interlock '{trip.cause}' at t = {trip.t_s:.3f} s with "
                                 f"{trip.voltage_V:.4g} V held: {trip.detail}; the log is {s['log_csv']}",
                          exit_code=session.EXIT_TRIPPED) from Partial(outputs, summary.to_dict())
    ctx.progress.say(f"{record.status}: {summary.cycles} cycles; log {ctx.rel(outputs['log_csv'])}")
    return outputs, summary


def _rig_summary(record: RigRunRecord) -> RigSummary:
    """The rig stage's summary from the run's sidecar: a tripped run's trip (no step figures), a completed run's
    figures; both with the loop's timing against the stall limit."""
    out = record.summary
    if out is None:
        raise StageFailed("rig", f"the run's sidecar says '{record.status}' and holds no outcome")
    head = RigSummary(record.status, out.cycles, out.controller_step, out.timing.missed_deadlines, out.timing.stalls,
                      out.timing.held_max_s, out.timing.stall_limit_s, record.safety.force_max_N)
    if out.trip is not None:
        return replace(head, trip=RigTrip(out.trip.cause, out.trip.detail, out.trip.t_s, out.trip.voltage_V))
    m = out.metrics
    learned = record.learned or {}
    return replace(head, settling_s=None if m is None else m.settling_s,
                   overshoot_N=None if m is None else m.overshoot_N,
                   tracking_rms_N=None if m is None else m.tracking_rms_N,
                   learned_tracking_rms_measured_N=learned.get("tracking_rms_measured_N"))


def _stage_report(ctx: _Ctx) -> Produced:
    study = ctx.study
    b, d = study.ballscrew, design_spec_of_tables(study)
    pub = study.published
    plant = ctx.solved().plant()  # the design stage's: not solved again
    facts = ReportStudy(study.name, study.title, study.path, study.sha256, ctx.source or study.path, study.description,
                        None if b is None or d is None else (d.nominal_diameter_mm, d.lead_mm),
                        (plant.n_stacks, plant.stack.name), None if d is None else d.frequency_min_Hz,
                        None if pub is None else Published(pub.source, pub.gains_label, pub.step()),
                        "the study's gains" if pub is None else pub.gains_label)
    return render_report(ctx.out, ctx.manifest(), facts, say=ctx.progress.say, bar=ctx.progress.bar("figures"),
                         template=ctx.template, pool=ctx.pool)


def _design_applies(study: StudySpec) -> str | None:
    return None if study.ballscrew is not None else "the study has no [ballscrew] table"


def _plant_applies(study: StudySpec) -> str | None:
    return None if study.plant_from_design else "the study's [rig] is the plant ([plant] from_design is not set)"


def _learn_applies(study: StudySpec) -> str | None:
    return _plant_applies(study) or (None if study.learning is not None else "the study has no [learning] table")


#: the tables a co-designed design (``[design] method = "codesign"``) reads beyond the design's: the plant, the
#: feedforward, the tuning and the validation limits it is chosen with
_CODESIGN_READS = ("rig", "plant", "controller", "feedforward", "reference", "simulation", "tuning", "validation")


def _design_reads(study: StudySpec) -> tuple[str, ...]:
    table = study.design_table or DesignTable()
    return (("thermal",) if "stiffness:growth" in table.pareto else ()) + (
        _CODESIGN_READS if table.method is DesignMethod.CODESIGN else ())


STAGES: tuple[Stage, ...] = (
    Stage("design", "ball-screw preload design, Pareto fronts, schedule",
          ("ballscrew", "feed_drive", "duty", "design", "schedule"), (),
          ("models", "artifacts", "design"), _stage_design, files=("schedule.profile",), applies=_design_applies,
          reads=_design_reads),
    Stage("plant", "the designed preload system as the plant", ("rig", "plant"), ("design",),
          ("models", "artifacts", "design"),
          _stage_plant, applies=_plant_applies),
    Stage("identify", "the feedforward's P-I model", ("rig", "feedforward", "reference"), ("plant",),
          ("models", "artifacts", "tuning"), _stage_identify, files=("feedforward.data",)),
    Stage("tune", "PID gains around the compensated plant (CasADi + IPOPT)",
          ("rig", "controller", "reference", "simulation", "tuning"), ("plant", "identify"),
          ("models", "artifacts", "tuning"), _stage_tune, files=("tuning.warm_start",),
          reads=lambda study: ("validation",) if study.tuning.schedule_levels >= 2 else ()),
    Stage("validate", "Monte Carlo on nonlinear rigs", ("study", "rig", "reference", "simulation", "validation"),
          ("plant", "identify", "tune"), ("models", "artifacts", "tuning"), _stage_validate),
    Stage("compare", "step and trajectory: the study's and the tuned gains, with and without feedforward",
          ("study", "rig", "controller", "reference", "simulation", "published"), ("plant", "identify", "validate"),
          ("models", "artifacts", "tuning"), _stage_compare),
    Stage("learn", "learning control on the repeated schedule (each margin pass learned)",
          ("rig", "plant", "schedule", "simulation", "learning", "validation"), ("design", "plant", "validate"),
          ("models", "artifacts", "design", "tuning"), _stage_learn, files=("schedule.profile",),
          applies=_learn_applies),
    Stage("system", "the controlled preload along the schedule: rigidity and deflection while cutting, energy",
          ("rig", "plant", "schedule", "simulation", "learning", "validation", "thermal", "feed_drive"),
          ("design", "plant", "validate", "learn"), ("models", "artifacts", "design", "tuning"), _stage_system,
          files=("schedule.profile",), applies=_plant_applies),
    Stage("export", "the gain set in the controllers' formats", ("export",), ("validate",),
          ("models", "artifacts", "rig"), _stage_export, validated_only=True),
    Stage("rig", "the validated gains on the rig executor", ("rig_run",), ("validate", "system", "learn"),
          ("models", "artifacts", "rig"), _stage_rig, files=("rig_run.reference",), validated_only=True,
          shared=False),  # a run log of its own, with its time and paths
    Stage("report", "figures and the PDF", ("study", "ballscrew", "design", "published"), STAGES_READ,
          ("models", "artifacts", "reports"),
          _stage_report, shared=False),  # the folder's provenance, its date
)
_BY_NAME = {s.name: s for s in STAGES}


def _stage_key(stage: Stage, study: StudySpec, records: dict[str, dict[str, Any]]) -> str:
    """The stage's content key. A file the study names enters by its key and its content, not its path: the same
    file in two folders (a sweep's points warm-started from equal tunings) is the same input."""
    files = {}
    tables = copy.deepcopy(study.tables())
    for key, path in study.files().items():
        table, _, name = key.rpartition(".")
        if name in tables.get(table, {}):
            tables[table][name] = "(a file: its content is in the key's files)"
        if key in stage.files:
            try:
                files[key] = sha256_file(path)
            except OSError as exc:
                raise InputError(f"{study.path}: cannot read {path} ({exc.strerror or exc})") from None
    code = code_hash(("piezopreload",) + tuple(f"piezopreload.{p}" for p in stage.code))
    return content_key({"stage": stage.name, "version": package_version(), "code": code,
                        "tables": {t: tables.get(t) for t in stage.tables + stage.reads(study)},
                        "upstream": upstream_hashes(stage.needs, records), "files": files})


# --------------------------------------------------------------------------------------
# the manifest and the lock
# --------------------------------------------------------------------------------------
def _write_manifest(out: Path, study: StudySpec, records: dict[str, dict[str, Any]], started: str, source: str) -> None:
    """``pipeline.json``: the stages' records as :func:`~piezopreload.core.stages.run_stages` keeps them, read into
    their types (a summary that would not read back fails here, where it is written) and saved."""
    StudyRunManifest.from_records(StudyRef(source, study.sha256, study.name), started, records, tuple(_BY_NAME),
                                  str(out / MANIFEST)).save(out)


def _locked(out: Path) -> AbstractContextManager[None]:
    """One run at a time per output folder (advisory lock; where flock exists)."""
    return locked(out, f"{out}: another 'piezopreload run' or 'report' is writing this folder; "
                       "wait for it or give another --out")


# --------------------------------------------------------------------------------------
# running
# --------------------------------------------------------------------------------------
def _applies(stage: Stage, ctx: _Ctx) -> str | None:
    """Why ``stage`` does not apply to the study (or to its gain set's verdict), or None."""
    reason = stage.applies(ctx.study)
    if reason is None and stage.validated_only:
        validate = ctx.manifest().summary(ValidateSummary)
        if validate is not None and not validate.validated:
            names = [r.name for r in missed(validate.requirements)]
            reason = f"the gain set is a candidate: it missed the validation's {', '.join(names) or 'limits'}"
    return reason


def _execute(stages: list[Stage], ctx: _Ctx, force: bool, started: str) -> list[StageOutcome]:
    keys: dict[str, str] = {}

    def key(stage: Stage) -> str:
        keys[stage.name] = _stage_key(stage, ctx.study, ctx.records)
        return keys[stage.name]

    def body(stage: Stage) -> tuple[dict[str, Path], dict[str, Any]]:
        outputs, summary = stage.run(ctx)
        return outputs, summary.to_dict()  # the records (and the store) keep the summary's JSON

    def run(stage: Stage) -> tuple[dict[str, Path], dict[str, Any]]:
        if ctx.cache is None or not stage.shared:
            return body(stage)
        return ctx.cache.run(stage.name, keys[stage.name], ctx.out, lambda: body(stage), say=ctx.progress.say)

    return run_stages(stages, ctx.records, ctx.out, ctx.progress, force=force, key=key,
                      applies=lambda stage: _applies(stage, ctx), run=run,
                      save=lambda: _write_manifest(ctx.out, ctx.study, ctx.records, started, ctx.source))


def _previous(out: Path, progress: Progress) -> dict[str, dict[str, Any]]:
    if not (out / MANIFEST).exists():
        return {}
    try:
        return {name: record.to_dict() for name, record in StudyRunManifest.load(out).stages.items()}
    except InputError as exc:
        progress.say(f"warning: {exc}; every stage runs again")
        return {}


def _outputs_of(out: Path, manifest: StudyRunManifest) -> list[Path]:
    """Every file a study's run wrote into ``out``: its stages' outputs as its manifest records them, the rig's logs
    (one pair per run, the earlier runs' too), the study's copy and the manifest."""
    files = [out / path for path in manifest.files()]
    logs = sorted((out / "runs").glob("run-*.csv")) + sorted((out / "runs").glob("run-*.json"))
    return [*files, *logs, out / STUDY_COPY, out / MANIFEST]


def _one_study_per_folder(out: Path, study: StudySpec, overwrite: bool, progress: Progress) -> None:
    """A folder holds one study's outputs: a folder holding another study's (by its ``[study] name``) is refused by
    name, or with ``overwrite`` cleared of them (the files its manifest records, its rig logs, then the folders
    left empty) before this study runs. The same study, changed, runs into its folder as ever (changed stages
    again)."""
    if not (out / MANIFEST).is_file():
        return
    try:
        manifest = StudyRunManifest.load(out)
    except InputError:
        return  # unreadable: every stage runs again (_previous says so) and writes over it
    held = manifest.study
    if held.name == study.name:
        return
    if not overwrite:
        raise InputError(f"{out}: holds the outputs of the study '{held.name}' ({held.path}), not of "
                         f"'{study.name}'; give another --out (say --out {study.name}-out), or --overwrite to replace "
                         "them (in Python: study.run(out=..., overwrite=True))")
    removed = 0
    for path in _outputs_of(out, manifest):
        if path.is_file():
            path.unlink()
            removed += 1
    for folder in sorted((p for p in out.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        if not any(folder.iterdir()):
            folder.rmdir()
    progress.say(f"--overwrite: removed the {removed} files of the study '{held.name}' from {out}")


def run_study(study: StudySpec | str | Path | None = None, out: str | Path = DEFAULT_OUT, *, force: bool = False,
              progress: ProgressLike | None = None, cache: StageCache | None = None,
              overwrite: bool = False, workers: int | None = None) -> StudyResult:
    """Run a study's stages into ``out``; a stage whose key and outputs are unchanged is not run again.

    ``cache``: a store of stage outputs shared with other folders (see the module docstring); with ``force``
    the stages run again but a shared one is restored where the store holds its key (empty the store to
    compute those again too). A folder holding another study's outputs is refused by name; ``overwrite`` clears
    them first (:func:`_one_study_per_folder`): one folder never mixes two studies. ``progress``:
    :data:`~piezopreload.progress.ProgressLike`. ``workers``: the run's worker processes, one pool made here,
    handed to the stages and shut at the end (default: :func:`~piezopreload.core.parallel.default_workers`; 1:
    every stage's work here, one job after another).
    """
    reporter = as_progress(progress)
    t0 = time.perf_counter()
    study = study if isinstance(study, StudySpec) else StudySpec.load(study)
    study.check_files()
    out = Path(out)
    pool = Pool(default_workers() if workers is None else workers)
    with _locked(out), pool:
        _one_study_per_folder(out, study, overwrite, reporter)
        copy = out / STUDY_COPY
        if not copy.is_file() or copy.read_bytes() != study.source_text:
            atomic_write_bytes(copy, study.source_text)
        ctx = _Ctx(study, out, reporter, _previous(out, reporter), study.path, cache=cache, pool=pool)
        stages = _execute(list(STAGES), ctx, force, utc())
    ran = [s.stage for s in stages if s.ran]
    seconds = time.perf_counter() - t0
    reporter.write(f"{'ran ' + ', '.join(ran) if ran else 'nothing to run: every stage is up to date'} "
                   f"({seconds:.1f} s)\nthe study's outputs are in {out.resolve()}/ (report: {out / 'report.pdf'})\n")
    return _result(out, study, stages, seconds)


def read_template(template: str | Path | None) -> str | None:
    """The text of a report template given on the command line (``--template``), or None for the shipped one."""
    if template is None:
        return None
    try:
        return Path(template).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--template {template}: cannot read it ({exc})") from None


def rerender_report(out: str | Path, progress: ProgressLike | None = None,
                    template: str | Path | None = None, workers: int | None = None) -> StudyResult:
    """Render the report again from the artifacts in ``out`` (``piezopreload report DIR``); nothing else runs.

    ``template``: a Typst file to typeset instead of the shipped template (a copy of
    ``DIR/report/report.typ``, edited); it reads ``report.json`` and ``figures/`` as the shipped one does.
    ``workers``: the processes that draw the figures (default: :func:`~piezopreload.core.parallel.default_workers`).
    """
    reporter = as_progress(progress)
    t0 = time.perf_counter()
    out = Path(out)
    template_text = read_template(template)
    if not (out / MANIFEST).is_file():
        raise InputError(f"{out}: no {MANIFEST}; this is not a study's output folder (run 'piezopreload run' first)")
    manifest = StudyRunManifest.load(out)
    records = {name: record.to_dict() for name, record in manifest.stages.items()}
    report = _BY_NAME["report"]
    missing = [name for name in report.needs if manifest.status(name) not in ("done", "not applicable")]
    if missing:
        raise InputError(f"{out}: the stage(s) {', '.join(missing)} have not completed; "
                         f"run 'piezopreload run {out / STUDY_COPY} --out {out}' first")
    broken = [name for name in report.needs if not outputs_intact(out, records[name])]
    if broken:
        raise InputError(f"{out}: the outputs of {', '.join(broken)} changed or went missing since they were written; "
                         f"run 'piezopreload run {out / STUDY_COPY} --out {out}' to make them again")
    study = StudySpec.load(out / STUDY_COPY)
    with _locked(out), Pool(default_workers() if workers is None else workers) as pool:
        ctx = _Ctx(study, out, reporter, records, manifest.study.path, template_text, pool=pool)
        stages = _execute([report], ctx, True, manifest.started_utc)
    seconds = time.perf_counter() - t0
    reporter.write(f"the report is {out / 'report.pdf'} ({seconds:.1f} s)\n")
    return _result(out, study, stages, seconds)


def _result(out: Path, study: StudySpec, stages: list[StageOutcome], seconds: float) -> StudyResult:
    manifest = StudyRunManifest.load(out)
    out = out.resolve()

    def existing(path: Path) -> Path | None:
        return path if path.is_file() else None

    validate, log = manifest.summary(ValidateSummary), manifest.output("rig", "log_csv")
    return StudyResult(
        out=out, study=study.ref, stages=tuple(stages), seconds=seconds, headline=Headline.from_manifest(manifest),
        requirements=manifest.requirements, report=existing(out / "report.pdf"),
        gain_set=existing(out / "gains.json"), gain_set_sha256=None if validate is None else validate.content_sha256,
        rig_log=None if log is None else out / log.path)


def run_summary(out: str | Path) -> RunSummary:
    """The headline numbers and the verdicts of the run in ``out`` (``run --json``'s ``summary``), read from its
    ``pipeline.json``: also for a run that stopped at a failing stage (what the stages before it recorded)."""
    manifest = StudyRunManifest.load(out)
    return RunSummary(Headline.from_manifest(manifest), manifest.requirements)
