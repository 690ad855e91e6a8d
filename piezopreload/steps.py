"""The study's steps: each a function of the parsed study (:class:`~piezopreload.spec.StudySpec`) and of what the
steps before it produced, held by a :class:`Solved`.

:class:`Solved` is what a study's steps have solved so far and keep for the steps after: the design's optimum
(solved once, saying so, or given: a design artifact, a co-design's point), the designed plant, the plant every
control step runs on and the preload schedule. A :class:`~piezopreload.study.Study` holds one (its
``plant``, ``designed_plant`` and ``preload_schedule`` are read from it); a pipeline run holds one made from its
design stage's record. The spec itself holds nothing solved.

The steps: :func:`design` (the ball-screw preload design, its optimum kept), :func:`measured_loop` and
:func:`identify` (the feedforward's P-I model), :func:`tune` (the PID, compared and bounded: a
:class:`~piezopreload.artifacts.tuning.TuningResult`), :func:`validate` (the Monte Carlo verdict on a
:func:`candidate` gain set), :func:`learn` (over one of the study's references) and :func:`learn_schedule` (along
the preload schedule, each margin pass), :func:`track_schedule` (the controlled preload along the schedule, the
shift's thermal budget and the robustness study), :func:`simulate` and :func:`reproduce`. Each is called once, by
:class:`~piezopreload.study.Study`'s method of that name or by the pipeline's stage; the domain computations are
the floors' (:mod:`piezopreload.design`, :mod:`piezopreload.tuning`).

>>> from piezopreload.spec import StudySpec
>>> spec = StudySpec.load("paper2021")
>>> Solved(spec).plant().bolt_preload_N                       # [rig] is the plant: nothing to solve
25.0
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.design import DesignPoint, DesignRecord
from piezopreload.artifacts.gainset import REFERENCES, GainSet, GainsTable
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.artifacts.tuning import MinimumTimeBound, TrackingFloor, TuningResult, warm_start_gains
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.parallel import Pool, default_workers
from piezopreload.core.progress import Bar
from piezopreload.core.quantities import number, quantity
from piezopreload.core.tables import MeasuredRecord, read_record
from piezopreload.design.preload import DesignInfeasible, DesignOptimum, DesignSpec, optimise
from piezopreload.design.sensitivity import sensitivity
from piezopreload.design.study import DesignResult, design_study, plan_schedule, read_profile
from piezopreload.design.system import SystemRun
from piezopreload.design.tables import DesignMethod, DesignTable, PlantTable, ScheduleTable
from piezopreload.design.thermal import duty_growth_um, thermal_budget
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference
from piezopreload.models.closedloop import simulate as simulate_loop
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.progress import ProgressLike, say_of
from piezopreload.results import SimulationInfo, StudyReproduction, StudyRun
from piezopreload.spec import Say, StudySpec, design_spec_of_tables
from piezopreload.tuning.bounds import minimum_time, tracking_floor
from piezopreload.tuning.calibrate import CONTROLLERS
from piezopreload.tuning.calibrate import reproduce as reproduce_paper
from piezopreload.tuning.compare import compare_gains, published_rows, tracking_improvement
from piezopreload.tuning.feedforward import FeedforwardInfo, IdentifiedFeedforward, identify_feedforward, loop_covers
from piezopreload.tuning.pid import TuningInfeasible, tune_pid
from piezopreload.tuning.schedule import schedule_levels, tune_schedule
from piezopreload.tuning.tables import LearningTable
from piezopreload.tuning.verdict import validate_gain_set

if TYPE_CHECKING:  # learning loads its solvers when a study learns, not when one is read
    from collections.abc import Callable

    from piezopreload.schedule import ScheduleLearning
    from piezopreload.tuning.learning import LearningResult

__all__ = ["Solved", "design", "measured_loop", "identify", "tune", "candidate", "validate", "learn", "learn_schedule",
           "track_schedule", "simulate", "reproduce", "design_spec_of"]


def design_spec_of(spec: StudySpec, what: str) -> DesignSpec:
    """The study's design (its ``[ballscrew]`` and the tables around it), or an error saying ``what`` needs it."""
    design = design_spec_of_tables(spec)
    if design is None:
        raise InputError(f"{spec.path}: {what} needs the design's tables: the study has no [ballscrew] (see "
                         "studies/machine_axis.toml)")
    return design


def _solve_point(spec: StudySpec, say: Say) -> DesignOptimum:
    """The design's optimum of the study's own objective, solved (its cost said)."""
    table = spec.design_table or DesignTable()
    if table.method is DesignMethod.CODESIGN:  # never the sequential design in its place
        raise InputError(f"{spec.path}: [design] method = \"codesign\": the design is chosen with its "
                         "controller by the co-design, which this step does not run; run the study "
                         "('piezopreload run', whose design stage runs it), or give it the co-designed design: "
                         "study.with_design(piezopreload.codesign.codesign_optimum(study))")
    say(f"solving the design's optimum ({table.objective}) once, for the plant and the preload schedule; every "
        "later step keeps it ...")
    t0 = time.perf_counter()
    try:
        optimum = optimise(design_spec_of(spec, "the design's optimum"), table.objective)
    except DesignInfeasible as exc:
        raise InfeasibleError(f"{spec.path}: {exc}") from exc
    p = optimum.point
    say(f"design optimum in {time.perf_counter() - t0:.1f} s: bolts' preload {p.bolt_preload_N:.0f} N, "
        f"stacks' reach {p.max_preload_N:.0f} N, least rigidity {p.stiffness_N_per_um:.0f} N/um")
    return optimum


class Solved:
    """What a study's steps have solved, kept for the steps after them: the design's optimum (solved once where a
    step needs it, or given), the designed plant, the plant and the preload schedule.

    Parameters
    ----------
    spec : StudySpec
        The study.
    design : DesignRecord, DesignResult, DesignOptimum or DesignPoint, optional
        The design's optimum given instead of solved (a design artifact, say: its own schedule is kept as recorded,
        so the best constant preload has one source).
    design_sha256 : str
        The design artifact's hash, which the designed plant records.
    """

    def __init__(self, spec: StudySpec, design: DesignRecord | DesignResult | DesignOptimum | DesignPoint | None = None,
                 design_sha256: str = "") -> None:
        self.spec = spec
        self.optimum: DesignOptimum | None = None
        self.point: DesignPoint | None = None
        self.design_sha256 = design_sha256
        self._designed: DesignedPlant | None = None
        self._plant: Plant | None = None
        self._schedule: PreloadSchedule | None = None
        self._feedforward: IdentifiedFeedforward | None = None
        if design is not None:
            design_spec_of(spec, "a design")
            self.point = design.point if isinstance(design, DesignRecord | DesignResult | DesignOptimum) else design
            self.optimum = (design.optimum if isinstance(design, DesignResult)
                            else design if isinstance(design, DesignOptimum) else None)
            if isinstance(design, DesignRecord):
                self._schedule = design.schedule

    def __repr__(self) -> str:
        held = [name for name, value in (("design", self.point), ("designed plant", self._designed),
                                         ("plant", self._plant), ("schedule", self._schedule),
                                         ("feedforward", self._feedforward)) if value is not None]
        return f"Solved({self.spec.name!r}: {', '.join(held) or 'nothing yet'})"

    def keeping_design(self, spec: StudySpec) -> Solved:
        """A context for ``spec`` (a changed copy of this study whose design is the same) holding this one's design."""
        kept = Solved(spec, design_sha256=self.design_sha256)
        kept.optimum, kept.point = self.optimum, self.point
        return kept

    def design_point(self, progress: Say | None = None) -> DesignPoint:
        """The design's optimum, solved once (its cost said through ``progress``, or the study's)."""
        if self.point is None:
            self.optimum = _solve_point(self.spec, progress or self.spec.say)
            self.point = self.optimum.point
        return self.point

    def designed(self, progress: Say | None = None) -> DesignedPlant:
        """The designed preload system on the design's optimum (``[plant] from_design``)."""
        if not self.spec.plant_from_design:
            raise InputError(f"{self.spec.path}: the plant is [rig] ([plant] from_design is not true): there is no "
                             "designed plant")
        if self._designed is None:
            table = self.spec.plant_table or PlantTable()
            self._designed = table.plant(design_spec_of(self.spec, "the designed plant"), self.design_point(progress),
                                         self.spec.rig, self.design_sha256)
        return self._designed

    def plant(self, progress: Say | None = None) -> Plant:
        """The plant every control step runs on: ``[rig]``, or the designed plant's rig."""
        if self._plant is None:
            self._plant = self.designed(progress).rig if self.spec.plant_from_design else self.spec.rig
        return self._plant

    def schedule(self) -> PreloadSchedule:
        """The study's least-friction preload schedule (``[schedule]``) on the screw of the design's optimum."""
        if self._schedule is None:
            s = self.spec.schedule or ScheduleTable()
            path = self.spec.resolve(s.profile)
            self._schedule, _, _ = plan_schedule(design_spec_of(self.spec, "the preload schedule"), self.design_point(),
                                                 None if path is None else read_profile(path), profile_name=str(path),
                                                 **s.limits())
        return self._schedule

    def feedforward(self, progress: Say | None = None) -> IdentifiedFeedforward:
        """The study's feedforward, identified once (:func:`identify`) where a step needs it and none is given."""
        if self._feedforward is None:
            self._feedforward = identify(self.spec, self, progress)
        return self._feedforward

    def designed_for(self, what: str, progress: Say | None) -> DesignedPlant:
        """The designed plant, or an error saying ``what`` needs a study whose plant is its design."""
        if not self.spec.plant_from_design:
            raise InputError(f"{self.spec.path}: {what} needs a study whose plant is its design ([plant] from_design "
                             "= true, with the design's tables); this study's plant is its [rig]")
        return self.designed(progress)


# --------------------------------------------------------------------------------------
# the design
# --------------------------------------------------------------------------------------
def design(spec: StudySpec, solved: Solved, *, objective: str | None = None, pareto: list[str] | None = None,
           points: int | None = None, schedule: str | Path | None = None, progress: ProgressLike | None = None,
           bar: Callable[[int, int], None] | None = None, optimum: DesignOptimum | None = None) -> DesignResult:
    """The ball-screw preload design: the optimum for ``objective`` (the study's: solved once and kept in ``solved``,
    shared with its plant), the Pareto fronts ``pareto`` (default: ``[design] pareto``; ``[]`` for none) and the
    preload schedule for a load profile (``schedule``, a CSV; default: the study's, or a machining cycle).

    Parameters
    ----------
    spec : StudySpec
        The study.
    solved : Solved
        What its steps solved: the study's optimum, where one was, is taken from it, and the one solved here kept.
    objective : str, optional
        The optimum's objective (default: ``[design] objective``).
    pareto : list of str, optional
        The fronts to trace (default: ``[design] pareto``).
    points : int, optional
        Points per front (default: ``[design] pareto_points``).
    schedule : str or Path, optional
        A load profile (CSV) to plan the schedule on (default: the study's).
    progress : ProgressLike, optional
        Where the steps are said.
    bar : callable, optional
        Given (done, total) as the fronts are traced.
    optimum : DesignOptimum, optional
        The optimum already chosen (a co-design's, where ``[design] method = "codesign"``: the design stage gives
        it), kept as the study's.

    Returns
    -------
    DesignResult
        The optimum, the fronts and the schedule.
    """
    dspec = design_spec_of(spec, "the design")
    d, s = spec.design_table or DesignTable(), spec.schedule or ScheduleTable()
    objective = objective or d.objective
    profile_path = Path(schedule) if schedule is not None else spec.resolve(s.profile)
    pairs = list(d.pareto if pareto is None else pareto)
    if "stiffness:growth" in pairs and spec.thermal is None:
        raise InputError(f"{spec.path}: the Pareto front stiffness:growth needs a [thermal] table (the shift the "
                         "growth is read over)")
    table = spec.thermal
    if optimum is not None:  # chosen already (by the co-design): the record names what chose it
        objective = optimum.objective
    if optimum is None and objective == d.objective and d.method is DesignMethod.CODESIGN:
        solved.design_point(say_of(progress))  # refused: the co-design is the application layer's (codesign_optimum)
    try:
        result = design_study(
            dspec, objective, pairs, d.pareto_points if points is None else points,
            profile=None if profile_path is None else read_profile(profile_path), profile_name=str(profile_path),
            **s.limits(), progress=say_of(progress), bar=bar,
            optimum=optimum if optimum is not None else solved.optimum if objective == d.objective else None,
            growth=None if table is None else lambda point: duty_growth_um(dspec, point, table))
    except DesignInfeasible as exc:
        raise InfeasibleError(f"{spec.path}: {exc}") from exc
    if optimum is not None or (objective == d.objective and solved.point is None):
        solved.optimum, solved.point = result.optimum, result.point
    return result


# --------------------------------------------------------------------------------------
# the feedforward
# --------------------------------------------------------------------------------------
def measured_loop(spec: StudySpec, progress: ProgressLike | None = None) -> MeasuredRecord | None:
    """``[feedforward] data`` read, and refused if its forces do not cover the references (before any design
    or tuning: a measured loop's range is known from the file).

    Parameters
    ----------
    spec : StudySpec
        The study.
    progress : ProgressLike, optional
        Where reading the file is said (default: nowhere).

    Returns
    -------
    MeasuredRecord or None
        The measured loop; None where the study simulates it.
    """
    data = spec.resolve(spec.feedforward.data)
    if data is None:
        return None
    say = say_of(progress) or (lambda _m: None)
    say(f"reading the measured loop {data}")
    record = read_record(data)
    loop_covers(record, *spec.reference_range_N, f"the study's references ({spec.path})")
    return record


def identify(spec: StudySpec, solved: Solved, progress: ProgressLike | None = None) -> IdentifiedFeedforward:
    """The feedforward's P-I model: from ``[feedforward] data`` (a measured V -> N loop) when the study names
    one, else from the loop measurement simulated on the plant; with its open-loop compensation check.

    Parameters
    ----------
    spec : StudySpec
        The study.
    solved : Solved
        What its steps solved (the plant, its design solved first where it is the design and was not).
    progress : ProgressLike, optional
        Where the steps are said.

    Returns
    -------
    IdentifiedFeedforward
        The model, its fit and its check.
    """
    said = say_of(progress)
    say = said or (lambda _m: None)
    record = measured_loop(spec, said)  # refused before the design if it does not cover the references
    plant = solved.plant(said)
    ex, (low, high) = spec.feedforward, spec.reference_range_N
    if record is None:
        say(f"simulating the {ex.v_max_V:g} V, {ex.frequency_Hz:g} Hz loop measurement on the plant's truth model")
    ff = identify_feedforward(plant, ex, record, check_range_N=(low, high))
    say(f"P-I model ({ff.model.kind}): {ff.model.n_operators} operators, fit RMS {ff.fit.rms_pct:.2f} % "
        f"(max {ff.fit.max_pct:.2f} %) of the force span, identified over {number(ff.record.output_range[0], 'N')} "
        f"to {quantity(ff.record.output_range[1], 'N')}")
    ff.covers(low, high, f"the study's references ({spec.path})")
    return ff


def _controller(spec: StudySpec, solved: Solved, gains: GainSet | None, progress: Say | None) -> Controller:
    """The gain set's controller, or the study's [controller] gains with the identified feedforward."""
    if gains is not None:
        return gains.controller()
    return Controller(spec.controller, solved.plant(progress).sample_period_s, solved.feedforward(progress).inverse())


# --------------------------------------------------------------------------------------
# learning and the schedule
# --------------------------------------------------------------------------------------
def learn(spec: StudySpec, solved: Solved, gains: GainSet | None = None, *, reference: str | Reference = "trajectory",
          iterations: int | None = None, preview_s: float | None = None, method: str | None = None,
          plants: int | None = None, seed: int | None = None, after_change_weight: float = 0.0,
          progress: ProgressLike | None = None) -> LearningResult:
    """Preview and iterative learning control over a repeated reference on the study's plant.

    Parameters
    ----------
    spec : StudySpec
        The study (``[learning]``: the defaults of ``iterations``, ``preview_s`` and ``method``).
    solved : Solved
        What its steps solved (the plant).
    gains : GainSet, optional
        A gain set (its controller), or None: the study's ``[controller]`` with the identified feedforward.
    reference : str or Reference
        A name of the study's references, or a :class:`~piezopreload.models.closedloop.Reference`
        (along the preload schedule: :func:`learn_schedule`).
    iterations : int, optional
        The most learning trials (fewer where more no longer pay).
    preview_s : float, optional
        The preview (0: none).
    method : str, optional
        The learning law.
    plants : int, optional
        N learns on N Monte Carlo plants (each its own learning; the result reports the worst).
    seed : int, optional
        The noise seed (default: the study's).
    after_change_weight : float
        How the plan places each change (:func:`~piezopreload.tuning.learning.learn`).
    progress : ProgressLike, optional
        Where the trials are said.

    Returns
    -------
    LearningResult
        ``.ff_extra_V``, ``.history``, ``.plot()``.
    """
    from piezopreload.models.actuator import Rig
    from piezopreload.tuning.learning import learn as learn_loop

    table = spec.learning or LearningTable()
    if not isinstance(reference, Reference):
        if reference == "schedule":
            raise InputError("learn: the preload schedule is learned by learn_schedule (study.learn_schedule(gains)),"
                             " each margin pass on its own reference; learn takes one of the study's references ("
                             f"{', '.join(REFERENCES)}) or a Reference")
        if reference not in REFERENCES:
            raise InputError(f"reference must be one of {', '.join(REFERENCES)} or a Reference, got "
                             f"{reference!r} (along the preload schedule: learn_schedule)")
        reference = spec.reference.references()[reference]
    said = say_of(progress)
    return learn_loop(_controller(spec, solved, gains, said), Rig(solved.plant(said)), reference,
                      iterations=table.iterations if iterations is None else iterations,
                      preview_s=table.preview_s if preview_s is None else preview_s,
                      method=table.method if method is None else method, plants=plants,
                      seed=spec.seed if seed is None else seed, after_change_weight=after_change_weight, progress=said)


def learn_schedule(spec: StudySpec, solved: Solved, gains: GainSet | None = None, *, iterations: int | None = None,
                   preview_s: float | None = None, method: str | None = None, seed: int | None = None,
                   progress: ProgressLike | None = None) -> ScheduleLearning:
    """Learning along the design's preload schedule, as the pipeline's learn stage does: each margin pass of
    :func:`track_schedule` learned on its own repeated reference, on the designed plant itself.

    Parameters
    ----------
    spec : StudySpec
        A study whose plant is its design (``[learning]``: the defaults).
    solved : Solved
        What its steps solved (the designed plant, the schedule).
    gains : GainSet, optional
        A gain set, or None: the study's ``[controller]`` with the identified feedforward.
    iterations, preview_s, method : optional
        As :func:`learn` has them.
    seed : int, optional
        The noise seed (default: the study's).
    progress : ProgressLike, optional
        Where the passes are said.

    Returns
    -------
    ScheduleLearning
        Each pass's learning and the last pass's tracking of the schedule.
    """
    from piezopreload.schedule import ScheduleLearning
    from piezopreload.tuning.learning import schedule_learner

    table = spec.learning or LearningTable()
    said = say_of(progress)
    seed = spec.seed if seed is None else seed
    designed = solved.designed_for("learning along the preload schedule", said)
    controller = _controller(spec, solved, gains, said)
    learned, passes = schedule_learner(designed.rig, controller,
                                       iterations=table.iterations if iterations is None else iterations,
                                       preview_s=table.preview_s if preview_s is None else preview_s,
                                       method=table.method if method is None else method, seed=seed, progress=said)
    system = (spec.plant_table or PlantTable()).track(designed, controller, solved.schedule(), seed=seed,
                                                      settle_s=spec.validation.settling_max_s, ff_extra_V=learned,
                                                      progress=said)
    return ScheduleLearning(system, tuple(passes))


def track_schedule(spec: StudySpec, solved: Solved, gains: GainSet | None = None, *, ff_extra_V: Any = None,
                   progress: ProgressLike | None = None) -> SystemRun:
    """The gains following the preload schedule on the designed plant for ``[plant] cycles`` after a pre-cycle to its
    first level (held the validated settling time, ``[validation] settling_max_s``), the schedule planned again with
    local margins while a requirement is missed (:func:`piezopreload.design.system.track_schedule`); with the shift's
    thermal budget (``[thermal]``) and the robustness study.

    Parameters
    ----------
    spec : StudySpec
        A study whose plant is its design.
    solved : Solved
        What its steps solved (the designed plant, the schedule).
    gains : GainSet, optional
        A gain set, or None: the study's ``[controller]`` with the identified feedforward.
    ff_extra_V : array or callable, optional
        A correction added to the feedforward (one array, or one per pass's reference: a callable).
    progress : ProgressLike, optional
        Where the steps are said.

    Returns
    -------
    SystemRun
        The run along the schedule, its thermal budget and its sensitivity.
    """
    from piezopreload.tuning.validate import DEFAULT_SPREAD

    said = say_of(progress)
    designed = solved.designed_for("tracking the schedule", said)
    controller = _controller(spec, solved, gains, said)
    # the physical lift-off over the validation's Monte Carlo plants (its spread and seed; the nominal is the run)
    drawn = spec.validation.plants - 1
    seed = spec.validation.seed if spec.validation.seed is not None else spec.seed
    scatter = designed.rig.vary(drawn, DEFAULT_SPREAD, seed=seed) if drawn > 0 else None
    dspec = design_spec_of(spec, "tracking the schedule")
    run = (spec.plant_table or PlantTable()).track(designed, controller, solved.schedule(), seed=spec.seed,
                                                   settle_s=spec.validation.settling_max_s, ff_extra_V=ff_extra_V,
                                                   design=dspec, scatter=scatter, progress=said)
    if spec.thermal is not None:
        budget = thermal_budget(run, dspec.feed_drive, spec.thermal,
                                command_range_V=(controller.gains.u_min_V, controller.gains.u_max_V))
        if said is not None:
            said(f"thermal: {budget.record.sentence()}")
        run = replace(run, thermal=budget)
    studied = sensitivity(run, dspec.feed_drive, spec.thermal)
    if said is not None:
        said(f"robustness: {studied.sentence()}")
    return replace(run, sensitivity=studied)


# --------------------------------------------------------------------------------------
# tuning, simulating, reproducing
# --------------------------------------------------------------------------------------
def _minimum_time_bound(bounding: Any, settle: float | None, say: Callable[[str], None]) -> MinimumTimeBound:
    """The minimum-time bound from its worker, beside the tuned settling (a missing bound says why)."""
    try:
        bound = bounding.result()
    except InfeasibleError as exc:  # the bound is a comparison, not a requirement: say why it is missing
        say(f"no minimum-time bound: {exc}")
        return MinimumTimeBound(settling_s=None, tuned_over_bound_ratio=None, reason=str(exc))
    ratio = None if settle is None else settle / bound.settling_s
    tuned = ("the tuned gains' true force does not settle" if settle is None or ratio is None else
             f"the tuned gains settle the true force in {quantity(settle, 's')}, {number(ratio)} times it")
    say(f"minimum-time bound: {quantity(bound.settling_s, 's')} ({bound.seconds:.1f} s to compute); {tuned}")
    return MinimumTimeBound(settling_s=bound.settling_s, tuned_over_bound_ratio=ratio, samples=bound.samples,
                            hold_s=bound.hold_s, seconds=bound.seconds)


def tune(study: StudySpec, solved: Solved, feedforward: IdentifiedFeedforward | None = None, *,
         seed: int | None = None, progress: ProgressLike | None = None,
         iterations: Callable[[int], None] | None = None, pool: Pool | None = None) -> TuningResult:
    """Tune the PID around the study's plant compensated by ``feedforward``; compare it with the study's and SIMC's
    gains and bound it (``study.tune()``).

    Parameters
    ----------
    study : StudySpec
        The study: its references, its ``[tuning]`` and ``[validation]`` tables.
    solved : Solved
        What its steps solved: its plant (the design solved first where the plant is the design and was not).
    feedforward : IdentifiedFeedforward, optional
        The feedforward the PID is tuned around (default: the study's, identified); one that does not cover the
        study's references is refused before the design and the tuning run.
    seed : int, optional
        The noise seed of the comparison (default: the study's).
    progress : ProgressLike, optional
        Where the steps are said: a function given each line, or a :class:`~piezopreload.progress.Progress`.
    iterations : callable, optional
        Given IPOPT's iteration count as it goes.
    pool : Pool, optional
        The run's worker processes (the bound and the gain schedule's work go to them); default: a pool of
        this call's own, of :func:`~piezopreload.core.parallel.default_workers` processes.

    Returns
    -------
    TuningResult
        The tuned gains, compared and bounded; :func:`validate` judges them.
    """
    if pool is None:  # called on its own: this call is the run, with processes of its own
        with Pool(default_workers()) as own:
            return tune(study, solved, feedforward, seed=seed, progress=progress, iterations=iterations, pool=own)
    said = say_of(progress)
    if feedforward is not None:  # refused before the design and the tuning, with both ranges
        feedforward.covers(*study.reference_range_N, f"the study's references ({study.path})")
    else:
        measured_loop(study, said)
    plant = solved.plant(said)
    feedforward = feedforward or solved.feedforward(said)
    say = said or (lambda _m: None)
    seed = study.seed if seed is None else seed
    spec, criteria, step, trajectory = (study.tuning, study.validation, study.reference.step.reference(),
                                        study.reference.trajectory.reference())
    say("tuning the PID around the compensated plant (CasADi + IPOPT), the minimum-time bound beside it ...")
    bounding = pool.beside(minimum_time, plant, initial_N=float(step.levels_N[0]), final_N=float(step.levels_N[1]),
                      band_N=study.band_N, u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    known = {"the study's [controller] gains": study.controller}
    warm = study.files().get("tuning.warm_start")
    warm_gains = None if warm is None else warm_start_gains(warm)
    if warm is not None and warm_gains is not None:
        known[f"the warm start ({warm.name})"] = warm_gains
    try:
        tuned = tune_pid(plant, feedforward.inverse(), spec, counter=iterations, known=known)
    except TuningInfeasible as exc:
        bounding.discard()
        raise InfeasibleError(f"{study.path}: {exc}") from exc
    g, baseline = tuned.found(), tuned.start()
    say(f"tuned in {tuned.seconds:.0f} s: {tuned.form} Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s, "
        f"Tf {g.Tf_s:.4g} s, b {g.b:.3g}")
    if tuned.stopped_on_limit:
        say(f"  the search stopped on IPOPT's iteration limit: {tuned.search}")
    for b in tuned.active_bounds:
        say(f"  {b.sentence()}")
    schedule = None
    if study.tuning.schedule_levels >= 2:  # a gain schedule on the preload level, or the robust set if it does as well
        span = np.concatenate([step.levels_N, trajectory.levels_N])
        sched = tune_schedule(plant, feedforward.model, spec, criteria, g, step=step, trajectory=trajectory,
                              levels_N=schedule_levels(span.min(), span.max(), study.tuning.schedule_levels),
                              n_plants=study.tuning.schedule_plants, seed=seed, progress=say, pool=pool,
                              known=None if warm_gains is None else warm_gains.schedule)
        g, schedule = sched.chosen(g), sched
    floor = tracking_floor(plant, trajectory)
    say("comparing the study's, SIMC's and the tuned gains on the nominal plant ...")
    table = compare_gains(plant, step, trajectory, {"study": study.controller, "simc": baseline, "tuned": g},
                          feedforward.model, criteria, seed)
    row = next(r for r in table if r.gains == "tuned" and r.feedforward)
    inputs = {"study": study.path, "study_sha256": study.sha256, "seed": seed}
    if feedforward.model_sha256:
        inputs["feedforward_sha256"] = feedforward.model_sha256
    solve = replace(tuned, schedule=schedule)
    criteria_doc = criteria.to_dict()
    return TuningResult(
        gains=g, simc_baseline=baseline, solve=solve, table=table,
        minimum_time=_minimum_time_bound(bounding, row.settling_s, say),
        tracking_floor=TrackingFloor(floor.rms_N, floor.rate_N_per_s, row.tracking_rms_N / floor.rms_N),
        active_bounds=tuned.active_bounds,
        # how the table was scored (the validation's limits are the validate step's)
        criteria={k: criteria_doc[k] for k in ("band_N", "signal", "tracking_after_change_s")},
        tracking_improvement=tracking_improvement(table), inputs=inputs,
        published=None if study.published is None else {"ff+pid": study.published.step()["ff+pid"]})



def candidate(spec: StudySpec, solved: Solved, tuned: TuningResult, feedforward: IdentifiedFeedforward | None = None,
              inputs: dict[str, Any] | None = None) -> GainSet:
    """The tuned gains as a gain set not yet validated: the feedforward, the plant, the references, the criteria and
    the rig's interlock settings of the study's ``[rig_run]``; its tuning record names the gains on their bounds
    (``active_bounds``) and the controller's form.

    Parameters
    ----------
    spec : StudySpec
        The study the gains were tuned for.
    solved : Solved
        What its steps solved (the plant the gains were tuned on).
    tuned : TuningResult
        The tune step's result.
    feedforward : IdentifiedFeedforward, optional
        The feedforward the gains were tuned with (default: the study's, identified once).
    inputs : dict, optional
        More of the inputs' names and hashes to record.

    Returns
    -------
    GainSet
        A ``candidate`` gain set.
    """
    ff, plant = feedforward or solved.feedforward(), solved.plant()
    tuning = {**tuned.solve.to_dict(), "simc_baseline": GainsTable.from_value(tuned.simc_baseline).to_dict(),
              "active_bounds": [b.to_dict() for b in tuned.active_bounds]}
    return GainSet(gains=tuned.gains, status="candidate", feedforward=ff.model, feedforward_info=ff.info(),
                   plant=plant, preset=spec.name, references=spec.reference.references(),
                   criteria=spec.validation, tuning=tuning,
                   inputs={"study": spec.path, "study_sha256": spec.sha256, **(inputs or {})},
                   rig_interlocks=spec.rig_run.interlocks(plant, spec.path))


def validate(spec: StudySpec, solved: Solved, tuned: TuningResult, feedforward: IdentifiedFeedforward | None = None,
             *, plants: int | None = None, seed: int | None = None, workers: int | None = None,
             scheduler: str | None = None, progress: ProgressLike | None = None,
             bar: Bar | None = None, inputs: dict[str, Any] | None = None,
             pool: Pool | None = None) -> GainSet:
    """Validate the tuned gains by Monte Carlo on the study's nonlinear rig (``[validation]`` by default).

    Parameters
    ----------
    spec : StudySpec
        The study the gains were tuned for.
    solved : Solved
        What its steps solved (the plant).
    tuned : TuningResult
        The tune step's result.
    feedforward : IdentifiedFeedforward, optional
        The feedforward the gains were tuned with (default: the study's, identified once).
    plants : int, optional
        Monte Carlo plants (default: ``[validation] plants``).
    seed : int, optional
        Their seed (default: ``[validation] seed``, else the study's).
    workers : int, optional
        Local worker processes (default: ``[validation] workers``).
    scheduler : str, optional
        A Dask scheduler's address.
    progress : ProgressLike, optional
        Where the steps are said.
    bar : callable, optional
        Given (done, total) as the chunks of plants are run.
    inputs : dict, optional
        More of the inputs' names and hashes the gain set records.
    pool : Pool, optional
        The run's worker processes, used where neither ``workers`` nor the study's ``[validation] workers`` asks
        for another count (None: processes of this call's own).

    Returns
    -------
    GainSet
        ``validated`` only if every plant met every criterion, else ``candidate``; its ``validation`` holds the
        per-plant result. Save it with ``.save()``.
    """
    v = spec.validation
    workers = v.workers if workers is None else workers
    if pool is not None and workers is not None and workers != pool.workers:
        pool = None  # a count of its own: processes of its own, for the validation alone
    plants = v.plants if plants is None else plants
    say = say_of(progress) or (lambda _m: None)
    gain_set = candidate(spec, solved, tuned, feedforward, inputs)
    say(f"validating on {plants} plants ...")
    judged, _ = validate_gain_set(gain_set, n_plants=plants,
                                  seed=(spec.seed if v.seed is None else v.seed) if seed is None else seed,
                                  workers=workers if workers is not None else 1 if pool is not None
                                  else default_workers(), scheduler=scheduler, pool=pool,
                                  bar=bar or (lambda i, n: say(f"  chunk {i}/{n}")))
    return judged


def simulate(study: StudySpec, solved: Solved, gains: GainSet | PIDGains | None = None, *, controller: str = "ff+pid",
             reference: str = "step", feedforward: IdentifiedFeedforward | None = None,
             seed: int | None = None) -> StudyRun:
    """One controller on the study's plant over one of its references (``study.simulate()``).

    Parameters
    ----------
    study : StudySpec
        The study: its references, band and signal.
    solved : Solved
        What its steps solved: its plant.
    gains : GainSet or PIDGains, optional
        A gain set (its feedforward too, unless ``feedforward`` is given), PID gains, or None for the study's
        ``[controller]``.
    controller : {"ff+pid", "pid"}
        With the inverse-P-I feedforward or the PID alone.
    reference : {"step", "trajectory"}
        Which of the study's references.
    feedforward : IdentifiedFeedforward, optional
        The feedforward to invert (default: the gain set's, else the study's, identified).
    seed : int, optional
        The noise seed (default: the study's).

    Returns
    -------
    StudyRun
        The run, scored as the study says (``.step_metrics()``, ``.plot()``, ``.to_dict()``).
    """
    if controller not in CONTROLLERS:
        raise InputError(f"controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}")
    if reference not in REFERENCES:
        raise InputError(f"reference must be one of {', '.join(REFERENCES)}, got {reference!r}")
    status = None
    if isinstance(gains, GainSet):
        pid, source, status = gains.gains, f"gain set {(gains.content_sha256 or '')[:12]}", gains.status
    elif isinstance(gains, PIDGains):
        pid, source = gains, "given"
    else:
        pid, source = study.controller, f"{study.path} [controller], read as {study.controller_units}"
    rig = Rig(solved.plant())
    inverse, ff_info = None, None
    if controller == "ff+pid":
        if feedforward is None and isinstance(gains, GainSet) and gains.feedforward is not None:
            inverse = gains.feedforward.inverse()
            ff_info = FeedforwardInfo("the gain set's", gains.feedforward.kind, gains.feedforward.n_operators)
        else:
            ff = feedforward or solved.feedforward()
            inverse, ff_info = ff.inverse(), ff.describe()
    seed = study.seed if seed is None else seed
    run = simulate_loop(rig, Controller(pid, rig.dt_s, inverse), study.reference.references()[reference], seed=seed)
    published = None  # the study's published numbers for this run, where it declares them (the step alone)
    if study.published is not None and reference == "step":
        published = {"source": study.published.source, **study.published.step()[controller]}
    info = SimulationInfo(study.ref, controller, reference, pid, source, rig.dt_s, ff_info, status, published)
    return StudyRun(**{f.name: getattr(run, f.name) for f in fields(run)}, band_N=study.band_N, signal=study.signal,
                    info=info)



def reproduce(study: StudySpec, solved: Solved, feedforward: IdentifiedFeedforward | None = None, *,
              seed: int | None = None, repeats: int = 1) -> StudyReproduction:
    """The body of :meth:`Study.reproduce`: the paper's six step numbers beside the simulation's, both controllers.

    With ``repeats`` > 1, each number is the median over that many noise realisations, with its range.

    Parameters
    ----------
    study : StudySpec
        The study (its ``[published]`` numbers, its step, its ``[controller]`` gains).
    solved : Solved
        What its steps solved (the plant).
    feedforward : IdentifiedFeedforward, optional
        The feedforward (default: the study's, identified).
    seed : int, optional
        The noise seed (default: the study's).
    repeats : int
        Noise draws; each number is the median over them.

    Returns
    -------
    StudyReproduction
        One row per controller and metric (published, simulated, their ratio, within 25 % or not, the range over
        the noise draws) and what ran (``.to_dict()``: what ``reproduce --json`` prints).

    Raises
    ------
    InputError
        Where ``repeats`` < 1, or the study declares no published numbers.
    """
    if repeats < 1:
        raise InputError(f"repeats: must be >= 1, got {repeats}")
    if study.published is None:
        raise InputError(f"{study.path}: the study declares no published step numbers (a [published] table, as "
                         "studies/paper2021.toml has); reproduce sets a study's simulation beside published numbers")
    feedforward = feedforward or solved.feedforward()
    t0 = time.perf_counter()
    step = study.reference.step.reference()
    rep = reproduce_paper(solved.plant(), study.controller, step=step, excitation=study.feedforward,
                          seed=study.seed if seed is None else seed, band_N=study.band_N, signal=study.signal,
                          repeats=repeats, feedforward=feedforward.model,
                          feedforward_fit=feedforward.fit.to_dict())
    return StudyReproduction(study.ref, study.controller, study.controller_units, study.band_N, study.signal,
                             study.published.source, tuple(float(x) for x in step.levels_N),
                             published_rows(rep, study.published.step()),
                             {c: rep.metrics[c]["overshoot_N"] for c in rep.metrics}, dict(rep.feedforward_fit),
                             rep.repeats, time.perf_counter() - t0)
