"""The study a script works on: :class:`Study`, a study file parsed once into typed tables, with the steps that
take it.

:class:`Study` is a :class:`~piezopreload.spec.StudySpec` (the typed tables, the plant and what the tables make,
the design, the feedforward's identification, the schedule's tracking and learning) with the steps of the
application layer as methods: :meth:`Study.tune`, :meth:`Study.simulate` and :meth:`Study.reproduce`
(:mod:`piezopreload.results`), :meth:`Study.run` (:mod:`piezopreload.pipeline`), :meth:`Study.codesign`
(:mod:`piezopreload.codesign`) and :meth:`Study.sweep` (:mod:`piezopreload.sweep`). Each is a function of its
module that takes any study; the pipeline and the sweep
compose them without this module, which sits above them and which only the CLI imports.

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

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from piezopreload import codesign as codesigns
from piezopreload import pipeline, results
from piezopreload import sweep as sweeps
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.sweep import DEFAULT_SWEEP_OUT, Scalar
from piezopreload.codesign import CodesignResult, CodesignWeights
from piezopreload.models.controller import PIDGains
from piezopreload.outcome import StudyResult
from piezopreload.pipeline import DEFAULT_OUT
from piezopreload.progress import ProgressLike
from piezopreload.results import StudyReproduction, StudyRun, TuningResult
from piezopreload.spec import DEFAULT_STUDY, PAPER_STUDY, StudySpec, default_study, paper_study, shipped_studies
from piezopreload.sweep import SweepResult
from piezopreload.tuning.feedforward import IdentifiedFeedforward

__all__ = ["Study", "load_study", "default_study", "paper_study", "shipped_studies", "DEFAULT_STUDY", "PAPER_STUDY"]


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
    controller, reference, simulation, export : table
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
    gains : PIDGains
        The starting gains the tables make.
    references : dict of str to Reference
        The step and the trajectory the tables make.
    design_spec : DesignSpec or None
        The preload design the tables make (None: the study has no design).
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

    def tune(self, feedforward: IdentifiedFeedforward | None = None, *, seed: int | None = None,
             progress: ProgressLike | None = None, iterations: Callable[[int], None] | None = None) -> TuningResult:
        """Tune the PID around :attr:`plant` compensated by ``feedforward`` (default: :meth:`identify_feedforward`);
        compare it with the study's and SIMC's gains and bound it: :func:`piezopreload.results.tune`.

        Parameters
        ----------
        feedforward : IdentifiedFeedforward, optional
            The feedforward the PID is tuned around (default: the study's, identified).
        seed : int, optional
            The comparison's noise seed (default: the study's).
        progress : ProgressLike, optional
            Where the steps are said.
        iterations : callable, optional
            Given IPOPT's iteration count as it goes.

        Returns
        -------
        TuningResult
            The tuned gains, compared and bounded; ``.validate()`` judges them.
        """
        return results.tune(self, feedforward, seed=seed, progress=progress, iterations=iterations)

    def simulate(self, gains: GainSet | PIDGains | None = None, *, controller: str = "ff+pid", reference: str = "step",
                 feedforward: IdentifiedFeedforward | None = None, seed: int | None = None) -> StudyRun:
        """One controller on :attr:`plant` over one of the study's references: :func:`piezopreload.results.simulate`.

        Parameters
        ----------
        gains : GainSet or PIDGains, optional
            A gain set (its feedforward too, unless ``feedforward`` is given), PID gains, or None for the study's
            ``[controller]``.
        controller : {"ff+pid", "pid"}
            With the feedforward or the PID alone.
        reference : {"step", "trajectory"}
            Which of the study's references.
        feedforward : IdentifiedFeedforward, optional
            The feedforward to invert.
        seed : int, optional
            The noise seed (default: the study's).

        Returns
        -------
        StudyRun
            The run (``.step_metrics()``, ``.plot()``, ``.to_dict()``).
        """
        return results.simulate(self, gains, controller=controller, reference=reference, feedforward=feedforward,
                                seed=seed)

    def reproduce(self, *, seed: int | None = None, repeats: int = 1,
                  feedforward: IdentifiedFeedforward | None = None) -> StudyReproduction:
        """The study's published step numbers beside the simulation's on :attr:`plant`:
        :func:`piezopreload.results.reproduce`.

        Parameters
        ----------
        seed : int, optional
            The noise seed (default: the study's).
        repeats : int
            Noise draws; each number is the median over them.
        feedforward : IdentifiedFeedforward, optional
            The feedforward (default: the study's, identified).

        Returns
        -------
        StudyReproduction
            One row per controller and metric (published, simulated, their ratio, within 25 % or not, the range over
            the noise draws) and what ran (``.to_dict()``: what ``reproduce --json`` prints).
        """
        return results.reproduce(self, feedforward, seed=seed, repeats=repeats)

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
                 progress: ProgressLike | None = None) -> CodesignResult:
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
        progress : ProgressLike, optional
            Where the steps are said.

        Returns
        -------
        CodesignResult
            Both answers, the objective of each, what changed and what it bought, the requirements side by side.
        """
        return codesigns.codesign(self, weights, budget=budget, validate_plants=plants, progress=progress)

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
