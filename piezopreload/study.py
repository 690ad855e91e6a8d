"""The study a script works on: :class:`Study`, a study file parsed once into typed tables, with the steps that
take it.

:class:`Study` is a :class:`~piezopreload.spec.StudySpec` (the typed tables and what the tables make) with the steps
that take it as methods, each one call of a function: :meth:`Study.design`, :meth:`Study.identify_feedforward`,
:meth:`Study.tune`, :meth:`Study.validate`, :meth:`Study.learn`, :meth:`Study.learn_schedule`,
:meth:`Study.track_schedule`, :meth:`Study.simulate` and :meth:`Study.reproduce` (:mod:`piezopreload.steps`),
:meth:`Study.run` (:mod:`piezopreload.pipeline`), :meth:`Study.codesign` (:mod:`piezopreload.codesign`) and
:meth:`Study.sweep` (:mod:`piezopreload.sweep`). It holds what its steps solved (:attr:`Study.solved`, a
:class:`~piezopreload.steps.Solved`: the design's optimum solved once, :attr:`Study.plant`); the spec holds nothing
solved. The pipeline and the sweep compose the steps without this module, which sits above them and which only the
CLI imports.

>>> import piezopreload as pp
>>> study = pp.load_study("paper2021")                 # the paper's study, shipped: its [rig] is the plant
>>> study.rig.bolt_preload_N, study.plant.bolt_preload_N
(25.0, 25.0)
>>> study.replace(rig={"bolt_preload_N": 30.0}).plant.bolt_preload_N
30.0
>>> axis = pp.load_study()                             # the machine axis: its plant is its design
>>> "bolt_preload_N" in axis.tables()["rig"]           # the design sets it; [rig] may not
False
>>> axis.replace(rig={"bolt_preload_N": 30.0})  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
piezopreload.core.errors.InputError: ...: 'rig.bolt_preload_N' is set by the design where [plant] from_design = true ...
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace as _replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self, TypeVar

from piezopreload import codesign as codesigns
from piezopreload import pipeline, steps
from piezopreload import sweep as sweeps
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.sweep import DEFAULT_SWEEP_OUT, Scalar
from piezopreload.artifacts.tuning import TuningResult
from piezopreload.codesign import CodesignResult, CodesignWeights
from piezopreload.models.controller import PIDGains
from piezopreload.outcome import StudyResult
from piezopreload.pipeline import DEFAULT_OUT
from piezopreload.progress import ProgressLike, say_of
from piezopreload.results import StudyReproduction, StudyRun
from piezopreload.spec import DEFAULT_STUDY, PAPER_STUDY, StudySpec, default_study, paper_study, shipped_studies
from piezopreload.steps import Solved
from piezopreload.sweep import SweepResult
from piezopreload.tuning.feedforward import IdentifiedFeedforward

if TYPE_CHECKING:
    from piezopreload.artifacts.design import DesignPoint, DesignRecord
    from piezopreload.artifacts.plant import DesignedPlant
    from piezopreload.artifacts.schedule import PreloadSchedule
    from piezopreload.core.tables import MeasuredRecord
    from piezopreload.design.preload import DesignOptimum
    from piezopreload.design.study import DesignResult
    from piezopreload.design.system import SystemRun
    from piezopreload.models.actuator import Plant
    from piezopreload.models.closedloop import Reference
    from piezopreload.schedule import ScheduleLearning
    from piezopreload.tuning.learning import LearningResult

__all__ = ["Study", "load_study", "default_study", "paper_study", "shipped_studies", "DEFAULT_STUDY", "PAPER_STUDY"]


_M = TypeVar("_M", bound=Callable[..., Any])
#: a numpydoc section's heading: its name on one line, dashes under it
_HEADING = re.compile(r"^(\w[\w ]*)\n-+\n", re.MULTILINE)


def _parameter_entries(doc: str) -> dict[str, tuple[tuple[str, ...], str]]:
    """A numpydoc docstring's ``Parameters`` entries by each name they document: (the entry's names, its text)."""
    headings = list(_HEADING.finditer(doc))
    start = next((h for h in headings if h.group(1) == "Parameters"), None)
    if start is None:
        return {}
    end = next((h.start() for h in headings if h.start() > start.start()), len(doc))
    out: dict[str, tuple[tuple[str, ...], str]] = {}
    entries = re.split(r"\n(?=\S)", doc[start.end():end].strip("\n"))
    for text in entries:
        names = tuple(n.strip().lstrip("*") for n in text.split("\n")[0].split(" : ")[0].split(","))
        for name in names:
            out[name] = (names, text.rstrip())
    return out


def _parameters_of(step: Callable[..., Any]) -> Callable[[_M], _M]:
    """Give the decorated method of :class:`Study` the ``Parameters`` section of ``step``, the function of
    :mod:`piezopreload.steps` it calls: the entries of the method's own parameters, in the method's order, written
    once, on the function, so that the two cannot drift. The method's docstring keeps its summary and its
    ``Returns``; a parameter of the method the function does not document is refused when the module is imported.

    Parameters
    ----------
    step : callable
        The steps function whose ``Parameters`` section documents the method's parameters.

    Returns
    -------
    callable
        The decorator.
    """
    entries = _parameter_entries(inspect.getdoc(step) or "")

    def give(method: _M) -> _M:
        names = [n for n in inspect.signature(method).parameters if n != "self"]
        missing = [n for n in names if n not in entries]
        if missing:
            raise TypeError(f"{method.__qualname__}: {step.__module__}.{step.__qualname__} documents no "
                            f"{', '.join(missing)}; document it there, once")
        lines: list[str] = []
        for name in names:
            grouped, text = entries[name]
            if len(grouped) > 1:  # "a, b : type": the names this method takes, written once
                if name != next(n for n in grouped if n in names):
                    continue
                header, _, rest = text.partition("\n")
                text = ", ".join(n for n in grouped if n in names) + " : " + header.split(" : ", 1)[1] + \
                    (f"\n{rest}" if rest else "")
            lines.append(text)
        own = inspect.cleandoc(method.__doc__ or "")
        if any(h.group(1) == "Parameters" for h in _HEADING.finditer(own + "\n")):
            raise TypeError(f"{method.__qualname__}: its Parameters come from {step.__qualname__}; write none of its "
                            "own")
        section = "Parameters\n----------\n" + "\n".join(lines) + "\n\n"
        at = own.find("Returns\n-------")
        method.__doc__ = (own[:at] + section + own[at:]) if at >= 0 else (own + "\n\n" + section).rstrip() + "\n"
        return method

    return give


class Study(StudySpec):
    """A loaded, validated study: its tables (typed, as in the file), its plant, what the tables make, and the steps
    that take it.

    Make one with :func:`load_study`, a changed copy with :meth:`replace`. The ``[design]`` table is
    ``design_table`` (``design()`` runs it), the ``[plant]`` table ``plant_table`` (``plant`` is the
    plant itself, a :class:`~piezopreload.models.actuator.Plant`).

    Parameters
    ----------
    path : str
        The study's file.
    sha256 : str
        The SHA-256 of the file as read.
    name, title : str
        The study's name and title (its ``[study]`` table).
    rig : Plant
        ``[rig]``: the plant's hardware, read into the plant itself (the model's defaults where it gives none).
    feedforward : LoopExcitation
        ``[feedforward]``: the loop the feedforward is identified on.
    controller : PIDGains
        ``[controller]``: the starting gains, read straight into them (``Ti`` and ``Td`` held in seconds, whatever
        the file's ``units``: :attr:`controller_units` says which it entered).
    reference, simulation, export : table
        The tables of those names, typed as the file gives them (defaults where it gives none).
    tuning : TuningSpec
        ``[tuning]``: what the tuning requires (with ``[simulation]``'s band and ``[controller]``'s output range).
    validation : Criteria
        ``[validation]``: what the validation requires of every plant, over how many plants.
    rig_run : RigRunPlan
        The ``[rig_run]`` table: the rig stage's plan.
    ballscrew, feed_drive, duty, design_table, schedule, plant_table, learning, published : table or None
        The optional tables (``[design]`` is ``design_table``, ``[plant]`` ``plant_table``); None where the file
        has none.
    where : object
        The file and its lines, for the messages.
    source_text : bytes
        The file as read, or as :meth:`replace` wrote it.
    given : dict
        The tables and keys the file gives, as it gives them.
    description : str
        The study's description.
    thermal : table or None
        The ``[thermal]`` table: the shift's heat, temperature and growth (None: none).
    say : callable
        Where the study says what it does when a step is given no progress of its own.
    """

    # ---- what its steps solved ---------------------------------------------------------------------
    @cached_property
    def solved(self) -> Solved:
        """What this study's steps have solved and keep (:class:`~piezopreload.steps.Solved`): the design's optimum,
        solved once where a step needs it (saying so), the designed plant, the plant and the preload schedule."""
        return Solved(self)

    @property
    def plant(self) -> Plant:
        """The plant every control step runs on: ``[rig]``, or the plant of the design's optimum where
        ``[plant] from_design = true`` (the design solved once, saying so through the study's progress, and kept)."""
        return self.solved.plant()

    @property
    def designed_plant(self) -> DesignedPlant:
        """Where the plant is the design: the designed preload system (its rig, :attr:`plant`; its screw, its
        preload range and where it comes from, the design's hash)."""
        return self.solved.designed()

    @property
    def preload_schedule(self) -> PreloadSchedule:
        """The study's least-friction preload schedule (``[schedule]``) on the screw of the design's optimum."""
        return self.solved.schedule()

    def solved_plant(self, progress: ProgressLike | None = None) -> Plant:
        """:attr:`plant`, its design solved first where the plant is the design and it has not been, saying so
        through ``progress`` (default: the study's own).

        Parameters
        ----------
        progress : ProgressLike, optional
            Where the design's solve is said.

        Returns
        -------
        Plant
            The plant every control step runs on.
        """
        return self.solved.plant(say_of(progress))

    def with_design(self, design: DesignRecord | DesignResult | DesignOptimum | DesignPoint,
                    design_sha256: str = "") -> Self:
        """This study with its design's optimum given (a design artifact, say) instead of solved.

        Parameters
        ----------
        design : DesignRecord, DesignResult, DesignOptimum or DesignPoint
            The design: its plant, designed plant and preload schedule are made from it; a design artifact's own
            schedule is kept as recorded, so the best constant preload has one source.
        design_sha256 : str
            The design artifact's hash, which the designed plant records.

        Returns
        -------
        Study
            A copy holding the design.
        """
        study = _replace(self)
        study.__dict__["solved"] = Solved(study, design, design_sha256)  # the copy's own context, given its design
        return study

    def replace(self, **changes: dict[str, Any] | None) -> Self:
        """A validated copy with some keys changed (:meth:`StudySpec.replace
        <piezopreload.spec.StudySpec.replace>`); the design solved for this study is kept where the copy's design
        is the same.

        Parameters
        ----------
        **changes : dict or None
            Each table's keys to change (None: remove).

        Returns
        -------
        Study
            The copy.
        """
        study = super().replace(**changes)
        if "solved" in self.__dict__ and self.same_design(study):
            study.__dict__["solved"] = self.solved.keeping_design(study)
        return study

    # ---- the steps ---------------------------------------------------------------------------------
    @_parameters_of(steps.design)
    def design(self, *, objective: str | None = None, pareto: list[str] | None = None, points: int | None = None,
               schedule: str | Path | None = None, progress: ProgressLike | None = None,
               bar: Callable[[int, int], None] | None = None, optimum: DesignOptimum | None = None) -> DesignResult:
        """The ball-screw preload design, its optimum kept for :attr:`plant`: :func:`piezopreload.steps.design`.

        Returns
        -------
        DesignResult
            The optimum, the fronts and the schedule.
        """
        return steps.design(self, self.solved, objective=objective, pareto=pareto, points=points, schedule=schedule,
                            progress=progress, bar=bar, optimum=optimum)

    @_parameters_of(steps.measured_loop)
    def measured_loop(self, progress: ProgressLike | None = None) -> MeasuredRecord | None:
        """``[feedforward] data`` read and checked against the references: :func:`piezopreload.steps.measured_loop`.

        Returns
        -------
        MeasuredRecord or None
            The measured loop; None where the study simulates it.
        """
        return steps.measured_loop(self, progress)

    @_parameters_of(steps.identify)
    def identify_feedforward(self, progress: ProgressLike | None = None) -> IdentifiedFeedforward:
        """The feedforward's P-I model on :attr:`plant`: :func:`piezopreload.steps.identify`.

        Returns
        -------
        IdentifiedFeedforward
            The model, its fit and its check.
        """
        return steps.identify(self, self.solved, progress)

    @_parameters_of(steps.learn)
    def learn(self, gains: GainSet | None = None, *, reference: str | Reference = "trajectory",
              iterations: int | None = None, preview_s: float | None = None, method: str | None = None,
              plants: int | None = None, seed: int | None = None, after_change_weight: float = 0.0,
              progress: ProgressLike | None = None) -> LearningResult:
        """Preview and iterative learning control over a repeated reference on :attr:`plant`:
        :func:`piezopreload.steps.learn` (along the preload schedule: :meth:`learn_schedule`).

        Returns
        -------
        LearningResult
            ``.ff_extra_V``, ``.history``, ``.plot()``.
        """
        return steps.learn(self, self.solved, gains, reference=reference, iterations=iterations, preview_s=preview_s,
                           method=method, plants=plants, seed=seed, after_change_weight=after_change_weight,
                           progress=progress)

    @_parameters_of(steps.learn_schedule)
    def learn_schedule(self, gains: GainSet | None = None, *, iterations: int | None = None,
                       preview_s: float | None = None, method: str | None = None, seed: int | None = None,
                       progress: ProgressLike | None = None) -> ScheduleLearning:
        """Learning along the design's preload schedule, each margin pass on its own reference, as the pipeline's
        learn stage: :func:`piezopreload.steps.learn_schedule`.

        Returns
        -------
        ScheduleLearning
            Each pass's learning (``.passes``) and the last pass's tracking of the schedule (``.system``).
        """
        return steps.learn_schedule(self, self.solved, gains, iterations=iterations, preview_s=preview_s,
                                    method=method, seed=seed, progress=progress)

    @_parameters_of(steps.track_schedule)
    def track_schedule(self, gains: GainSet | None = None, *, ff_extra_V: Any = None,
                       progress: ProgressLike | None = None) -> SystemRun:
        """The gains following the preload schedule on the designed plant: :func:`piezopreload.steps.track_schedule`.

        Returns
        -------
        SystemRun
            The run along the schedule, its thermal budget and its sensitivity.
        """
        return steps.track_schedule(self, self.solved, gains, ff_extra_V=ff_extra_V, progress=progress)

    @_parameters_of(steps.tune)
    def tune(self, feedforward: IdentifiedFeedforward | None = None, *, seed: int | None = None,
             progress: ProgressLike | None = None, iterations: Callable[[int], None] | None = None) -> TuningResult:
        """Tune the PID around :attr:`plant` compensated by ``feedforward`` (default: :meth:`identify_feedforward`);
        compare it with the study's and SIMC's gains and bound it: :func:`piezopreload.steps.tune`.

        Returns
        -------
        TuningResult
            The tuned gains, compared and bounded (the tune stage's artifact); :meth:`validate` judges them.
        """
        return steps.tune(self, self.solved, feedforward, seed=seed, progress=progress, iterations=iterations)

    @_parameters_of(steps.validate)
    def validate(self, tuned: TuningResult, feedforward: IdentifiedFeedforward | None = None, *,
                 plants: int | None = None, seed: int | None = None, workers: int | None = None,
                 scheduler: str | None = None, progress: ProgressLike | None = None) -> GainSet:
        """Validate tuned gains by Monte Carlo on the study's nonlinear rig (``[validation]`` by default):
        :func:`piezopreload.steps.validate`.

        Returns
        -------
        GainSet
            ``validated`` only if every plant met every criterion; save it with ``.save()``.
        """
        return steps.validate(self, self.solved, tuned, feedforward, plants=plants, seed=seed, workers=workers,
                              scheduler=scheduler, progress=progress)

    @_parameters_of(steps.simulate)
    def simulate(self, gains: GainSet | PIDGains | None = None, *, controller: str = "ff+pid", reference: str = "step",
                 feedforward: IdentifiedFeedforward | None = None, seed: int | None = None) -> StudyRun:
        """One controller on :attr:`plant` over one of the study's references: :func:`piezopreload.steps.simulate`.

        Returns
        -------
        StudyRun
            The run (``.step_metrics()``, ``.plot()``, ``.to_dict()``).
        """
        return steps.simulate(self, self.solved, gains, controller=controller, reference=reference,
                                feedforward=feedforward, seed=seed)

    @_parameters_of(steps.reproduce)
    def reproduce(self, *, seed: int | None = None, repeats: int = 1,
                  feedforward: IdentifiedFeedforward | None = None) -> StudyReproduction:
        """The study's published step numbers beside the simulation's on :attr:`plant`:
        :func:`piezopreload.steps.reproduce`.

        Returns
        -------
        StudyReproduction
            One row per controller and metric (published, simulated, their ratio, within 25 % or not, the range over
            the noise draws) and what ran (``.to_dict()``: what ``reproduce --json`` prints).
        """
        return steps.reproduce(self, self.solved, feedforward, seed=seed, repeats=repeats)

    def run(self, out: str | Path = DEFAULT_OUT, *, force: bool = False, progress: ProgressLike | None = None,
            overwrite: bool = False) -> StudyResult:
        """The whole study, as ``piezopreload run``: :func:`piezopreload.pipeline.run_study`.

        Parameters
        ----------
        out : str or Path
            The output folder; a folder holding another study's outputs is refused by name.
        force : bool
            Run every stage again, changed or not.
        progress : ProgressLike, optional
            Where the stage lines go (default: standard error).
        overwrite : bool
            Replace another study's outputs in ``out`` instead of refusing them.

        Returns
        -------
        StudyResult
            The stages, the headline figures and every requirement's verdict.
        """
        return pipeline.run_study(self, out, force=force, progress=progress, overwrite=overwrite)

    def codesign(self, weights: CodesignWeights | None = None, *, budget: int = 9, plants: int | None = None,
                 schedule: bool | None = None, progress: ProgressLike | None = None) -> CodesignResult:
        """The sequential design and tuning, then the design and the PID chosen together (nested), both validated by
        the same Monte Carlo, as ``piezopreload codesign``: :func:`piezopreload.codesign.codesign`.

        Parameters
        ----------
        weights : CodesignWeights, optional
            The objective's weights (default: what the study states, :meth:`CodesignWeights.of_study`).
        budget : int
            The most inner solves (a design, its plant and its tuning) of the outer search.
        plants : int, optional
            Monte Carlo plants for each answer (default: the study's ``[validation] plants``; 0: none).
        schedule : bool, optional
            The controller compared: None (default) as the study's tune stage makes it (the gain schedule's entries
            where ``[tuning] schedule_levels`` is at least 2, else one robust set); True the entries; False one robust
            set.
        progress : ProgressLike, optional
            Where the steps are said.

        Returns
        -------
        CodesignResult
            Both answers, the objective of each, what changed and what it bought, the requirements side by side.
        """
        return codesigns.codesign(self, weights, budget=budget, validate_plants=plants, schedule=schedule,
                                  progress=progress)

    def sweep(self, vary: Mapping[str, Sequence[Scalar]], *, mode: str = "grid", out: str | Path = DEFAULT_SWEEP_OUT,
              workers: int | None = None, scheduler: str | None = None, force: bool = False,
              progress: ProgressLike | None = None, report: bool = True, where: str = "Study.sweep") -> SweepResult:
        """The whole study at every point of ``vary`` (``{"rig.bolt_preload_N": [20.0, 25.0, 30.0]}``), as
        ``piezopreload sweep``: :func:`piezopreload.sweep.sweep`.

        Parameters
        ----------
        vary : mapping of str to list
            ``{"TABLE.KEY": [V1, V2, ...]}``.
        mode : {"grid", "zip"}
            Every combination, or the i-th values together.
        out : str or Path
            The sweep's folder.
        workers, scheduler : int or str, optional
            Local worker processes, or a Dask scheduler's address.
        force : bool
            Run every stage of every point again.
        progress : ProgressLike, optional
            Where each point's line goes.
        report : bool
            Typeset the sweep's report at the end.
        where : str
            How errors name the caller.

        Returns
        -------
        SweepResult
            One row per point (``.rows``, ``.plot(x, y)``, ``.to_dataframe()``).
        """
        return sweeps.sweep(self, vary, mode=mode, out=out, workers=workers, scheduler=scheduler, force=force,
                            progress=progress, report=report, where=where)


def load_study(study: str | Path | None = None, *, progress: ProgressLike | None = None) -> Study:
    """Read and validate a study: None for the default (``machine_axis``), a shipped study's name (``"paper2021"``),
    or a file.

    Parameters
    ----------
    study : str or Path, optional
        The study file, or a shipped study's name; None: the default study.
    progress : ProgressLike, optional
        What the study says where a step is given no progress of its own (solving the design for the plant,
        say); default: a line on standard error.

    Returns
    -------
    Study
        The study, every key checked; an :class:`~piezopreload.core.errors.InputError` names the file, the key's
        line and the key.
    """
    return Study.load(study, progress=progress)
