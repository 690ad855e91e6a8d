"""The steps that take a study, and what they return: :func:`tune` (a :class:`TuningResult`), :func:`simulate`
(a :class:`StudyRun`) and :func:`reproduce`; :class:`~piezopreload.study.Study`'s methods of those names call them.

Each result carries its numbers, ``to_dict()`` (what ``--json`` prints or the artifact
holds) and ``plot()`` (a matplotlib Figure, no pyplot state). The domain computations are the
floors': the tuning (:mod:`piezopreload.tuning.pid`, its record :mod:`piezopreload.artifacts.tuning`), the comparison
(:mod:`piezopreload.tuning.compare`), the verdict (:mod:`piezopreload.tuning.verdict`).
"""

from __future__ import annotations

import html
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.gainset import REFERENCES, GainSet, GainsTable
from piezopreload.artifacts.manifest import StudyRef
from piezopreload.artifacts.tuning import (
    ActiveBound,
    ComparisonRow,
    MinimumTimeBound,
    TrackingFloor,
    TuningRecord,
    TuningSolve,
    warm_start_gains,
)
from piezopreload.artifacts.validation import ValidationResult
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.parallel import Pool, default_workers
from piezopreload.core.quantities import number, quantity
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import ClosedLoopRun
from piezopreload.models.closedloop import simulate as simulate_loop
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.metrics import StepMetrics, run_numbers
from piezopreload.progress import ProgressLike, say_of
from piezopreload.spec import StudySpec
from piezopreload.tuning.bounds import minimum_time, tracking_floor
from piezopreload.tuning.calibrate import CONTROLLERS
from piezopreload.tuning.calibrate import reproduce as reproduce_paper
from piezopreload.tuning.compare import (
    PublishedRow,
    ReproductionSummary,
    compare_gains,
    reproduction_summary,
    tracking_improvement,
)
from piezopreload.tuning.feedforward import FeedforwardInfo, IdentifiedFeedforward
from piezopreload.tuning.pid import TuningInfeasible, tune_pid
from piezopreload.tuning.schedule import schedule_levels, tune_schedule
from piezopreload.tuning.verdict import validate_gain_set

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["TuningResult", "StudyRun", "SimulationInfo", "StudyReproduction", "tune", "simulate", "reproduce"]

_STEP_KEYS = ("rise_s", "peak_s", "settling_s", "overshoot_N")
_TRACK_KEYS = ("tracking_rms_N", "tracking_max_N")


@dataclass(frozen=True, eq=False)
class TuningResult:
    """Tuned PID gains around a study's compensated rig, compared and bounded; :meth:`validate` judges them.

    ``record`` is the tune stage's artifact (:class:`~piezopreload.artifacts.tuning.TuningRecord`): the
    study's ``[controller]``, SIMC's and the tuned gains on the nominal plant, PID alone and with the feedforward
    (``table``), the gains on the ends of their search range (``active_bounds``), the least settling time any command
    reaches (``minimum_time``, the tuned over it ``tuned_over_bound_ratio``) and the trajectory's least RMS error any
    causal controller reaches (``tracking_floor``).

    Parameters
    ----------
    study : Study
        The study the gains were tuned for.
    feedforward : IdentifiedFeedforward
        The feedforward the gains were tuned with.
    record : TuningRecord
        The tune stage's artifact.
    """

    study: StudySpec
    feedforward: IdentifiedFeedforward
    record: TuningRecord

    @property
    def gains(self) -> PIDGains:
        """The tuned PID gains."""
        return self.record.gains

    @property
    def simc(self) -> PIDGains:
        """SIMC's gains on the FOPDT fit: the baseline the tuned gains are compared with."""
        return self.record.simc_baseline

    @property
    def solve(self) -> TuningSolve:
        """What the NLP did (status, iterations, Ms reached, binding constraints, the gain schedule's record)."""
        return self.record.solve

    @property
    def table(self) -> tuple[ComparisonRow, ...]:
        """The comparison table: each gain set, with and without feedforward, and its step and tracking figures."""
        return self.record.table

    @property
    def active_bounds(self) -> tuple[ActiveBound, ...]:
        """The gains that ended on a bound of the search, each with its bound."""
        return self.record.active_bounds

    @property
    def minimum_time(self) -> MinimumTimeBound:
        """The least settling time any command reaches on the tuning model, beside the tuned loop's."""
        return self.record.minimum_time

    @property
    def tracking_floor(self) -> TrackingFloor:
        """The least RMS tracking error of any causal controller without preview, beside the tuned loop's."""
        return self.record.tracking_floor

    @property
    def improvement(self) -> dict[str, float | None]:
        """The study's starting gains' tracking RMS over the tuned gains', by reference (None where not measured)."""
        return self.record.tracking_improvement

    def row(self, gains: str = "tuned", feedforward: bool = True) -> ComparisonRow:
        """One row of the comparison table.

        Parameters
        ----------
        gains : str
            Which gain set: ``tuned``, or another of the table's (``simc``, ``study``).
        feedforward : bool
            The row with the feedforward (True) or without it.

        Returns
        -------
        ComparisonRow
            That row of :attr:`table`.
        """
        return self.record.row(gains, feedforward)

    def to_dict(self) -> dict[str, Any]:
        """The tuning artifact's body.

        Returns
        -------
        dict
            The tuning artifact's document, without its envelope.
        """
        return self.record.to_dict()

    def save(self, path: str | Path) -> Path:
        """Write the tuning artifact.

        Parameters
        ----------
        path : str or Path
            The file (``tuning.json``).

        Returns
        -------
        Path
            The path written.
        """
        return self.record.save(path)

    @classmethod
    def load(cls, path: str | Path, study: StudySpec, feedforward: IdentifiedFeedforward) -> TuningResult:
        """A tuning artifact read back, for the study and feedforward it was tuned with.

        Parameters
        ----------
        path : str or Path
            The tuning artifact's file.
        study : StudySpec
            The study the gains were tuned for.
        feedforward : IdentifiedFeedforward
            The feedforward they were tuned with.

        Returns
        -------
        TuningResult
            The tuning's result, as :meth:`Study.tune` returned it.
        """
        return cls(study, feedforward, TuningRecord.load(path))

    def __repr__(self) -> str:
        g, m = self.gains, self.minimum_time
        bound = "none" if m.settling_s is None else f"{m.settling_s:.4g} s"
        return (f"TuningResult({self.study.name}: {self.solve.form} Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, "
                f"Td {g.Td_s:.4g} s, Tf {g.Tf_s:.4g} s, b {g.b:.3g}; Ms {self.solve.ms:.3g}; tuned settling "
                f"{_fmt(self.row().settling_s)} s, minimum-time bound {bound}; "
                f"{len(self.active_bounds)} gain(s) on a bound)")

    def _repr_html_(self) -> str:
        head = "".join(f"<th>{h}</th>" for h in ("gains", "feedforward", "settling (s)", "overshoot (N)",
                                                 "tracking RMS (N)", "peak command (V)"))
        rows = "".join(f"<tr><td>{r.gains}</td><td>{'yes' if r.feedforward else 'no'}</td>"
                       f"<td>{_fmt(r.settling_s)}</td><td>{r.overshoot_N:.3g}</td><td>{r.tracking_rms_N:.3g}</td>"
                       f"<td>{r.peak_command_V:.3g}</td></tr>" for r in self.table)
        bounds = "".join(f"<li>{html.escape(b.sentence())}</li>" for b in self.active_bounds)
        return (f"<p><b>Tuned {self.solve.form}</b> for study {html.escape(self.study.name)}: "
                f"<code>{html.escape(repr(self))}</code></p><table><tr>{head}</tr>{rows}</table>"
                + (f"<p>Gains on a bound:</p><ul>{bounds}</ul>" if bounds else ""))

    def candidate(self, inputs: dict[str, Any] | None = None) -> GainSet:
        """The tuned gains as a gain set not yet validated: feedforward, plant, references, criteria, the rig's
        interlock settings of the study's ``[rig_run]``; its tuning record names the gains on their bounds
        (``active_bounds``) and the controller's form.

        Parameters
        ----------
        inputs : dict or None
            The hashes of the files the gains came from, by name, added to the study's path and hash.

        Returns
        -------
        GainSet
            A gain set of status ``candidate``.
        """
        s, ff = self.study, self.feedforward
        tuning = {**self.solve.to_dict(), "simc_baseline": GainsTable.from_value(self.simc).to_dict(),
                  "active_bounds": [b.to_dict() for b in self.active_bounds]}
        return GainSet(gains=self.gains, status="candidate", feedforward=ff.model, feedforward_info=ff.info(),
                       plant=s.plant, preset=s.name, references={k: s.references[k] for k in REFERENCES},
                       criteria=s.validation, tuning=tuning,
                       inputs={"study": s.path, "study_sha256": s.sha256, **(inputs or {})},
                       rig_interlocks=s.rig_run.interlocks(s.plant, s.path))

    def validation(self, *, plants: int | None = None, seed: int | None = None, workers: int | None = None,
                   scheduler: str | None = None, progress: ProgressLike | None = None,
                   bar: Callable[[int, int], None] | None = None, inputs: dict[str, Any] | None = None,
                   pool: Pool | None = None) -> tuple[GainSet, ValidationResult]:
        """:meth:`validate`, also returning the per-plant result.

        Parameters
        ----------
        plants : int or None
            How many Monte Carlo plants (None: ``[validation] plants``).
        seed : int or None
            The seed of the plants' draw (None: ``[validation] seed``, else the study's).
        workers : int or None
            How many processes share the plants (None: ``[validation] workers``, else the run's ``pool``, else
            :func:`~piezopreload.core.parallel.default_workers`).
        scheduler : str or None
            A Dask scheduler's address (``tcp://HOST:PORT``) to run the plants on a cluster (None: local processes).
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).
        bar : callable or None
            Called with (chunk, chunks) as each chunk of plants is done; None: a progress line per chunk.
        inputs : dict or None
            The hashes of the files the gains came from, by name.
        pool : Pool or None
            The run's worker processes, used where neither ``workers`` nor the study's ``[validation] workers`` asks
            for another count (None: processes of this call's own).

        Returns
        -------
        gain_set : GainSet
            The gain set, ``validated`` only where every plant met every criterion.
        result : ValidationResult
            Every plant's metrics, the failures and the verdict.
        """
        v = self.study.validation
        workers = v.workers if workers is None else workers
        if pool is not None and workers is not None and workers != pool.workers:
            pool = None  # a count of its own: processes of its own, for the validation alone
        plants = v.plants if plants is None else plants
        say = say_of(progress) or (lambda _m: None)
        say(f"validating on {plants} plants ...")
        return validate_gain_set(self.candidate(inputs), n_plants=plants,
                                 seed=(self.study.seed if v.seed is None else v.seed) if seed is None else seed,
                                 workers=workers if workers is not None else 1 if pool is not None
                                 else default_workers(), scheduler=scheduler, pool=pool,
                                 progress=bar or (lambda i, n: say(f"  chunk {i}/{n}")))

    def validate(self, plants: int | None = None, seed: int | None = None, *, workers: int | None = None,
                 scheduler: str | None = None, progress: ProgressLike | None = None) -> GainSet:
        """Validate the tuned gains by Monte Carlo on the study's nonlinear rig (``[validation]`` by default):
        a :class:`GainSet`, ``validated`` only if every plant met every criterion. Save it with ``.save()``.

        Parameters
        ----------
        plants : int or None
            How many Monte Carlo plants (None: ``[validation] plants``).
        seed : int or None
            The seed of the plants' draw (None: ``[validation] seed``, else the study's).
        workers : int or None
            How many processes share the plants (None: ``[validation] workers``).
        scheduler : str or None
            A Dask scheduler's address (``tcp://HOST:PORT``) to run the plants on a cluster (None: local processes).
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).

        Returns
        -------
        GainSet
            The gain set with its validation (:meth:`validation`'s first item).
        """
        return self.validation(plants=plants, seed=seed, workers=workers, scheduler=scheduler, progress=progress)[0]

    def plot(self) -> Figure:
        """The comparison table as bars (settling time, tracking RMS): a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            Bars of each row of :attr:`table`: settling time (s) and tracking RMS (N).
        """
        from piezopreload.reports import figures  # matplotlib only when drawing

        return figures.gains_comparison([r.to_dict() for r in self.table])


def _fmt(x: float | None) -> str:
    return "none" if x is None else f"{x:.4g}"


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


def tune(study: StudySpec, feedforward: IdentifiedFeedforward | None = None, *, seed: int | None = None,
         progress: ProgressLike | None = None, iterations: Callable[[int], None] | None = None,
         pool: Pool | None = None) -> TuningResult:
    """Tune the PID around the study's plant compensated by ``feedforward``; compare it with the study's and SIMC's
    gains and bound it (``study.tune()``).

    Parameters
    ----------
    study : StudySpec
        The study: its plant, its references, its ``[tuning]`` and ``[validation]`` tables.
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
        The tuned gains, compared and bounded; ``.validate()`` judges them.
    """
    if pool is None:  # called on its own: this call is the run, with processes of its own
        with Pool(default_workers()) as own:
            return tune(study, feedforward, seed=seed, progress=progress, iterations=iterations, pool=own)
    said = say_of(progress)
    if feedforward is not None:  # refused before the design and the tuning, with both ranges
        feedforward.covers(*study.reference_range_N, f"the study's references ({study.path})")
    else:
        study.measured_loop(said)
    study.solved_plant(said)
    feedforward = feedforward or study.identify_feedforward(said)
    say = said or (lambda _m: None)
    seed = study.seed if seed is None else seed
    spec, criteria, step, trajectory = (study.tuning, study.validation, study.references["step"],
                                        study.references["trajectory"])
    say("tuning the PID around the compensated plant (CasADi + IPOPT), the minimum-time bound beside it ...")
    bounding = pool.beside(minimum_time, study.plant, initial_N=float(step.levels_N[0]),
                           final_N=float(step.levels_N[1]), band_N=study.band_N, u_min_V=spec.u_min_V,
                           u_max_V=spec.u_max_V)
    known = {"the study's [controller] gains": study.gains}
    warm = study.files().get("tuning.warm_start")
    warm_gains = None if warm is None else warm_start_gains(warm)
    if warm is not None and warm_gains is not None:
        known[f"the warm start ({warm.name})"] = warm_gains
    try:
        tuned = tune_pid(study.plant, feedforward.inverse(), spec, progress=iterations, known=known)
    except TuningInfeasible as exc:
        bounding.discard()
        raise InfeasibleError(f"{study.path}: {exc}") from exc
    g = tuned.gains
    say(f"tuned in {tuned.seconds:.0f} s: {tuned.form} Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s, "
        f"Tf {g.Tf_s:.4g} s, b {g.b:.3g}")
    if tuned.stopped_on_limit:
        say(f"  the search stopped on IPOPT's iteration limit: {tuned.search}")
    for b in tuned.active_bounds:
        say(f"  {b.sentence()}")
    schedule = None
    if study.tuning.schedule_levels >= 2:  # a gain schedule on the preload level, or the robust set if it does as well
        span = np.concatenate([study.references[k].levels_N for k in ("step", "trajectory")])
        sched = tune_schedule(study.plant, feedforward.model, spec, criteria, g, step=step, trajectory=trajectory,
                              levels_N=schedule_levels(span.min(), span.max(), study.tuning.schedule_levels),
                              n_plants=study.tuning.schedule_plants, seed=seed, progress=say, pool=pool,
                              known=None if warm_gains is None else warm_gains.schedule)
        g, schedule = sched.gains, sched.to_dict()
    floor = tracking_floor(study.plant, trajectory)
    say("comparing the study's, SIMC's and the tuned gains on the nominal plant ...")
    table = compare_gains(study.plant, step, trajectory, {"study": study.gains, "simc": tuned.baseline, "tuned": g},
                          feedforward.model, criteria, seed)
    row = next(r for r in table if r.gains == "tuned" and r.feedforward)
    inputs = {"study": study.path, "study_sha256": study.sha256, "seed": seed}
    if feedforward.model_sha256:
        inputs["feedforward_sha256"] = feedforward.model_sha256
    solve = TuningSolve.from_dict({**tuned.to_dict(), "spec": spec.to_dict(), "schedule": schedule})
    criteria_doc = criteria.to_dict()
    record = TuningRecord(
        gains=g, simc_baseline=tuned.baseline, solve=solve, table=table,
        minimum_time=_minimum_time_bound(bounding, row.settling_s, say),
        tracking_floor=TrackingFloor(floor.rms_N, floor.rate_N_per_s, row.tracking_rms_N / floor.rms_N),
        active_bounds=tuned.active_bounds,
        # how the table was scored (the validation's limits are the validate step's)
        criteria={k: criteria_doc[k] for k in ("band_N", "signal", "tracking_after_change_s")},
        tracking_improvement=tracking_improvement(table), inputs=inputs,
        published=None if study.published is None else {"ff+pid": study.published.step()["ff+pid"]})
    return TuningResult(study, feedforward, record)


_STUDY = object()  # step_metrics' default: the study's band and signal


@dataclass(frozen=True)
class SimulationInfo:
    """What a study's simulation ran: the study, the controller and the reference, the gains and where they came from
    (``gains_source``; a gain set's ``gains_status``), the feedforward (None: the PID alone), the sample period, and
    the study's published numbers for this run (``published``: its source and the numbers by name; None where it
    declares none).

    Parameters
    ----------
    study : StudyRef
        Which study.
    controller : str
        ``pid`` or ``ff+pid``.
    reference : str
        ``step`` or ``trajectory``.
    gains : PIDGains
        The gains that ran.
    gains_source : str
        Where they came from, in words (or the gain set's file).
    sample_period_s : float
        The loop's sample period (s).
    feedforward : FeedforwardInfo or None
        The feedforward (None: the PID alone).
    gains_status : str or None
        A gain set's status.
    published : dict or None
        The study's published numbers for this run, with their source.
    """

    study: StudyRef
    controller: str
    reference: str
    gains: PIDGains
    gains_source: str
    sample_period_s: float
    feedforward: FeedforwardInfo | None = None
    gains_status: str | None = None
    published: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """What ran, as ``simulate --json`` prints it.

        Returns
        -------
        dict
            ``study``, ``controller``, ``reference``, ``gains`` (the gains' table with their source and status),
            ``feedforward`` (None without one), ``sample_period_s`` (s) and ``published``.
        """
        source = {"source": self.gains_source, **({} if self.gains_status is None else {"status": self.gains_status})}
        return {"study": self.study.to_dict(), "controller": self.controller, "reference": self.reference,
                "gains": {**GainsTable.from_value(self.gains).to_dict(), **source},
                "feedforward": None if self.feedforward is None else self.feedforward.to_dict(),
                "sample_period_s": self.sample_period_s, "published": self.published}


@dataclass(frozen=True, eq=False, kw_only=True)
class StudyRun(ClosedLoopRun):
    """A closed-loop run of one plant, scored as its study says (``band_N``, ``signal``); ``info`` says what ran.

    Parameters
    ----------
    t_s, reference_N, force_N, measured_N, command_V, voltage_V, p_V, i_V, d_V, ff_V, reference, seed, engine
        As :class:`~piezopreload.models.closedloop.ClosedLoopRun` has them.
    band_N : float
        The study's error band of the step metrics (N).
    signal : str
        The signal the study scores (the true force or the measured one).
    info : SimulationInfo
        What ran: the study, the controller, the reference, the gains, the feedforward, the sample period and the
        study's published numbers for the run.
    """

    band_N: float
    signal: str
    info: SimulationInfo

    def step_metrics(self, band_N: Any = _STUDY, *, which: int = 1, signal: str | None = None) -> StepMetrics:
        """Rise, peak and settling time and overshoot of the reference's ``which``-th change, in the study's band
        on the study's signal unless given (``band_N=None``: the 10-90 % / 2 % definitions).

        Parameters
        ----------
        band_N : float or None
            The settling band, in N (default: the study's); None: the conventional 2 % band and 10-90 % rise.
        which : int
            Which change of the reference, from 1.
        signal : str or None
            The signal scored, ``force_N`` or ``measured_N`` (None: the study's).

        Returns
        -------
        StepMetrics
            The step's rise, peak and settling times (s) and overshoot (N).
        """
        m = super().step_metrics(self.band_N if band_N is _STUDY else band_N, which=which, signal=signal or self.signal)
        if not isinstance(m, StepMetrics):  # pragma: no cover - a study's run is one plant
            raise InputError("step_metrics of a batch: index the batch first")
        return m

    def to_dict(self) -> dict[str, Any]:
        """What ``piezopreload simulate --json`` prints: what ran, the step numbers, tracking, and the study's published
        numbers for this run where it declares them (``published``: None otherwise).

        Returns
        -------
        dict
            :meth:`SimulationInfo.to_dict`'s keys, ``reference_levels_N``, ``band_N``, ``signal``, ``seed``, ``samples``
            and :meth:`numbers`.
        """
        return {
            **self.info.to_dict(), "reference_levels_N": self.reference.levels_N.tolist(), "band_N": self.band_N,
            "signal": self.signal, "seed": self.seed, "samples": int(self.t_s.size), **self.numbers(),
        }

    def numbers(self) -> dict[str, float | None]:
        """The step numbers (rise, peak, settling, overshoot) and the peak command, and over the trajectory the
        tracking errors, in the study's band on its signal (None: a time never reached).

        Returns
        -------
        dict of str to float or None
            The step's times (s) and overshoot (N), ``peak_command_V`` (V) and, over a trajectory, the tracking errors
            (N).
        """
        numbers = run_numbers(self, self.band_N, self.signal)
        tracking = self.info.reference == "trajectory"
        return {k: numbers[k] for k in (*_STEP_KEYS, "peak_command_V", *(_TRACK_KEYS if tracking else ()))}

    def plot(self) -> Figure:
        """Reference and force (top), command and amplifier voltage (bottom): a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The reference and the force (N) above, the command and the amplifier's voltage (V) below, against time.
        """
        from piezopreload.reports import figures  # matplotlib only when drawing

        title = (f"{self.info.controller.replace('ff+pid', 'FF + PID').replace('pid', 'PID')}, "
                 f"{self.info.reference}")
        return figures.closed_loop(self.columns(), self.band_N, self.signal, title)


def simulate(study: StudySpec, gains: GainSet | PIDGains | None = None, *, controller: str = "ff+pid",
             reference: str = "step", feedforward: IdentifiedFeedforward | None = None,
             seed: int | None = None) -> StudyRun:
    """One controller on the study's plant over one of its references (``study.simulate()``).

    Parameters
    ----------
    study : StudySpec
        The study: its plant, references, band and signal.
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
        pid, source = study.gains, f"{study.path} [controller], read as {study.controller.units}"
    rig = Rig(study.plant)
    inverse, ff_info = None, None
    if controller == "ff+pid":
        if feedforward is None and isinstance(gains, GainSet) and gains.feedforward is not None:
            inverse = gains.feedforward.inverse()
            ff_info = FeedforwardInfo("the gain set's", gains.feedforward.kind, gains.feedforward.n_operators)
        else:
            ff = feedforward or study.identify_feedforward()
            inverse, ff_info = ff.inverse(), ff.describe()
    seed = study.seed if seed is None else seed
    run = simulate_loop(rig, Controller(pid, rig.dt_s, inverse), study.references[reference], seed=seed)
    published = None  # the study's published numbers for this run, where it declares them (the step alone)
    if study.published is not None and reference == "step":
        published = {"source": study.published.source, **study.published.step()[controller]}
    info = SimulationInfo(study.ref, controller, reference, pid, source, rig.dt_s, ff_info, status, published)
    return StudyRun(**{f.name: getattr(run, f.name) for f in fields(run)}, band_N=study.band_N, signal=study.signal,
                    info=info)


@dataclass(frozen=True)
class StudyReproduction:
    """A study's published step numbers beside its simulation's, with the PID alone and with the feedforward
    (:meth:`Study.reproduce <piezopreload.study.Study.reproduce>`): the study, its gains (and how its
    ``[controller]`` was read), the step, the band, the signal judged, and the comparison
    (:class:`~piezopreload.tuning.compare.ReproductionSummary`: one row per controller and metric).

    Parameters
    ----------
    study : StudyRef
        Which study.
    gains : PIDGains
        The study's gains.
    read_as : str
        How its ``[controller]`` was read (the time unit of Ti and Td).
    band_N : float
        The settling band (N).
    signal : str
        The signal the step numbers are read on.
    published : str
        Where the published numbers come from.
    step_levels_N : tuple of float
        The step's levels (N).
    comparison : ReproductionSummary
        The published numbers beside the simulated ones.
    seconds : float
        The time the simulations took (s).
    """

    study: StudyRef
    gains: PIDGains
    read_as: str
    band_N: float
    signal: str
    published: str
    step_levels_N: tuple[float, ...]
    comparison: ReproductionSummary
    seconds: float

    @property
    def rows(self) -> tuple[PublishedRow, ...]:
        """Each published figure against the reproduced one."""
        return self.comparison.rows

    @property
    def repeats(self) -> int:
        """Over how many noise realisations each simulated number is the median."""
        return self.comparison.repeats

    @property
    def feedforward_fit(self) -> dict[str, float]:
        """The identified P-I model's fit error, in % of the force span (``rms_pct``, ``max_pct``)."""
        return self.comparison.feedforward_fit

    @property
    def all_within_25pct(self) -> bool:
        """Whether every reproduced figure is within 25 % of the published one."""
        return self.comparison.all_within_25pct

    def row(self, controller: str, metric: str) -> PublishedRow:
        """The row of ``controller`` (``pid``, ``ff+pid``) and ``metric`` (``rise_s``, ``peak_s``, ``settling_s``).

        Parameters
        ----------
        controller : str
            ``pid`` or ``ff+pid``.
        metric : str
            ``rise_s``, ``peak_s`` or ``settling_s``.

        Returns
        -------
        PublishedRow
            The published and the simulated number (s; None: never reached), their ratio, whether it lies within
            25 % of the published one, and its range over the noise realisations.
        """
        return self.comparison.row(controller, metric)

    def to_dict(self) -> dict[str, Any]:
        """What ``reproduce --json`` prints.

        Returns
        -------
        dict
            ``study``, ``gains`` (and how they were read), ``band_N``, ``signal``, ``published``, ``step``, the
            comparison's rows and fit, and ``seconds``.
        """
        return {"study": self.study.to_dict(),
                "gains": {**GainsTable.from_value(self.gains).to_dict(), "read_as": self.read_as},
                "band_N": self.band_N, "signal": self.signal, "published": self.published,
                "step": " -> ".join(f"{x:g}" for x in self.step_levels_N) + " N", **self.comparison.to_dict(),
                "seconds": self.seconds}

    def __repr__(self) -> str:
        within = sum(r.within_25pct for r in self.rows)
        return (f"StudyReproduction({self.study.name!r}: {within} of {len(self.rows)} step numbers within 25 % of "
                f"{self.published}; {self.repeats} noise draw(s))")


def reproduce(study: StudySpec, feedforward: IdentifiedFeedforward | None = None, *, seed: int | None = None,
              repeats: int = 1) -> StudyReproduction:
    """The body of :meth:`Study.reproduce`: the paper's six step numbers beside the simulation's, both controllers.

    With ``repeats`` > 1, each number is the median over that many noise realisations, with its range.
    """
    if repeats < 1:
        raise InputError(f"repeats: must be >= 1, got {repeats}")
    if study.published is None:
        raise InputError(f"{study.path}: the study declares no published step numbers (a [published] table, as "
                         "studies/paper2021.toml has); reproduce sets a study's simulation beside published numbers")
    feedforward = feedforward or study.identify_feedforward()
    t0 = time.perf_counter()
    rep = reproduce_paper(study.plant, study.gains, step=study.references["step"], excitation=study.feedforward,
                          seed=study.seed if seed is None else seed, band_N=study.band_N, signal=study.signal,
                          repeats=repeats, feedforward=feedforward.model,
                          feedforward_fit=feedforward.fit.to_dict())
    comparison = reproduction_summary(rep, study.published.step())
    return StudyReproduction(study.ref, study.gains, study.controller.units, study.band_N, study.signal,
                             study.published.source, tuple(float(x) for x in study.references["step"].levels_N),
                             comparison, time.perf_counter() - t0)
