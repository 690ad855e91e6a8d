"""Iterative learning control (ILC) of the preload force over a known, repeated reference: the trials.

A machining cycle repeats, so the error of one cycle can correct the next. The loop follows the
preview's plan (:func:`~piezopreload.tuning.preview.plan_preview`); the learned signal ``u`` enters
it as ``ff_extra`` and starts, in trial 0, as the previewed feedforward. After each trial a law
makes the next signal from the trial's error: the norm-optimal law, the default
(:mod:`piezopreload.tuning.norm_optimal`: the Riccati form on the loop's linearised lifted model,
its gain and Q-filter chosen on the model's uncertainty set), or the Q-filtered P-type law, the
model-free option (:mod:`piezopreload.tuning.ilc`).

The error is read on the *measured* force, as a rig would (and not learned where the command sat
at a limit); the reported errors are of the true force. Each trial on a machine is a machining
cycle, so learning stops as soon as more trials no longer pay (:func:`more_trials_pay`: the
error, extrapolated from the last three trials, would not fall by more than ``stop_gain`` of
itself, or is already within that of the sensor's noise) and keeps the best trial; a divergence
guard stops a plant whose error grows past its best by ``grow_tol`` and the noise floor. On Monte Carlo plants each
plant learns with the nominal law and stops on its own; :attr:`LearningResult.monotone` records,
per plant, whether its error never rose by more than the noise floor from one trial to the next.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.learned import LearnedSignal, LearningMethod, reference_sha256
from piezopreload.artifacts.learning import LearningRecord, PassRecord, TrialRecord
from piezopreload.core._typing import Array, BoolArray, IntArray
from piezopreload.core.errors import InputError, InternalError
from piezopreload.core.progress import ProgressLike, say_of
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import ClosedLoopRun, Reference, simulate
from piezopreload.models.controller import Controller
from piezopreload.tuning.ilc import METHODS, LearningModel, learning_model_over
from piezopreload.tuning.norm_optimal import NormOptimalLaw, norm_optimal_law
from piezopreload.tuning.preview import (
    AFTER_CHANGE_S,
    PLAN_SLEW_FRACTION,
    Preview,
    feedforward_lead,
    plan_preview,
    preview_feedforward,
)
from piezopreload.tuning.validate import DEFAULT_SPREAD

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["METHODS", "Iteration", "LearningResult", "LearnedWritten", "learn", "law_for", "more_trials_pay",
           "within_1p1", "schedule_learner", "learn_from_run", "learn_from_log", "save_passes", "played_passes",
           "learned_by_reference", "STOP_GAIN"]

Law = LearningModel | NormOptimalLaw

#: another trial pays while it is expected to lower the measured error by more than this share of it
STOP_GAIN = 0.1


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Iteration:
    """One trial: the error of the true force (whole trajectory, and outside the transport after each
    jump) against the reference, and of the measured force against the plan (what the law sees).
    Arrays over the plants for a batch."""

    iteration: int
    tracking_rms_N: Any
    tracking_rms_after_change_N: Any
    measured_rms_N: Any

    def to_dict(self) -> dict[str, Any]:
        def plain(x: Any) -> Any:
            return float(x) if np.ndim(x) == 0 else np.asarray(x, float).tolist()
        return {"iteration": self.iteration, "tracking_rms_N": plain(self.tracking_rms_N),
                "tracking_rms_after_change_N": plain(self.tracking_rms_after_change_N),
                "measured_rms_N": plain(self.measured_rms_N)}


def within_1p1(errors: Array) -> Array:
    """Per plant (columns; one row per trial), the first trial whose error is within 1.1 times the plant's best."""
    rows = np.asarray(errors, float).reshape(len(errors), -1)
    return np.argmax(rows <= 1.1 * np.min(rows, axis=0) + 1e-12, axis=0)


@dataclass(frozen=True)
class LearnedWritten:
    """Where a learning wrote its signal.

    Parameters
    ----------
    out : str
        The learned signal the rig plays (``learned.json``).
    content_sha256 : str or None
        Its content hash.
    learning : str or None
        For a schedule's passes, the learning record of every pass (``learning.json``); None for one learning.
    """

    out: str
    content_sha256: str | None
    learning: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """Where the learning wrote its signal, as ``learn --json`` prints it.

        Returns
        -------
        dict
            ``out``, ``learning`` (only for a schedule's passes) and ``content_sha256``.
        """
        return {"out": self.out, **({} if self.learning is None else {"learning": self.learning}),
                "content_sha256": self.content_sha256}


@dataclass(frozen=True, eq=False)
class LearningResult:
    """What :func:`learn` returns.

    ``ff_extra_V`` is the best trial's learned signal (it starts as the previewed feedforward) per
    sample (``(plants, n)`` for a batch), ``history`` the error per trial, ``best`` the best trial
    per plant (by the measured error, what a rig knows), ``trials`` the learning trials each plant
    ran after trial 0 (it stops when more no longer pay, or diverges), ``run`` the best trial's run
    scored against the reference, ``converged``/``diverged``/``monotone`` per plant, ``noise_floor_N``
    the RMS difference of the true force between two runs of trial 0's signal under other sensor
    noise (the worst plant's: by the triangle inequality their RMS errors may differ that much with
    no learning at all), ``preview`` the plan and its floors, ``law`` the learning law.

    Parameters
    ----------
    ff_extra_V : ndarray
        The best trial's learned signal per sample, ``(plants, n)`` for a batch (V).
    history : list of Iteration
        The error per trial, trial 0 first.
    best : ndarray of int
        The best trial per plant, by the measured error.
    trials : ndarray of int
        The learning trials each plant ran after trial 0.
    stop_reason : list of str
        Why each plant stopped learning.
    converged, diverged, monotone : ndarray of bool
        Per plant: whether its learning converged, diverged, and lowered the error at every trial.
    run : ClosedLoopRun
        The best trial's run, scored against the reference.
    preview : Preview
        The previewed plan: the reference, the setpoint the loop follows, its floors.
    method : LearningMethod
        The learning method (one of :data:`METHODS`).
    law : object
        The learning law it ran.
    plants : int or None
        The Monte Carlo plants it learned on (None: the rig itself).
    noise_floor_N : float
        The RMS difference of the true force between two runs of trial 0's signal under other sensor noise,
        the worst plant's (N).
    seconds : float
        The wall-clock time it took (s).
    info : dict
        Further figures (the plan's error after a change, the warm start, the error outside transitions).
    """

    ff_extra_V: Array
    history: list[Iteration]
    best: IntArray
    trials: IntArray
    stop_reason: list[str]
    converged: BoolArray
    diverged: BoolArray
    monotone: BoolArray
    run: ClosedLoopRun
    preview: Preview
    method: LearningMethod
    law: Any
    plants: int | None
    noise_floor_N: float
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def reference(self) -> Reference:
        """The reference the signal was learned on."""
        return self.preview.reference

    @property
    def setpoint_N(self) -> Array:
        """The force per sample the learning aims at, in N (the preview's plan)."""
        return self.preview.target_N

    @property
    def causal_floor_N(self) -> float:
        """The least RMS error a loop without preview can reach on the reference, in N."""
        return self.preview.causal_floor_N

    @property
    def preview_floor_N(self) -> float:
        """The least RMS error a loop with preview can reach on the reference (set by its steepest slope), in N."""
        return self.preview.floor_N

    @property
    def preview_s(self) -> float:
        """How far ahead the feedforward reads the reference, in s (0: no preview)."""
        return self.preview.preview_s

    def _rows(self, key: str) -> Array:
        return np.array([np.atleast_1d(getattr(h, key)) for h in self.history])  # (trials, plants)

    def _best(self, key: str) -> Array:
        rows = self._rows(key)
        return rows[np.asarray(self.best).reshape(-1), np.arange(rows.shape[1])]

    @property
    def tracking_rms_N(self) -> float:
        """The worst plant's whole-trajectory RMS of the true force at its best trial."""
        return float(np.max(self._best("tracking_rms_N")))

    @property
    def tracking_rms_after_change_N(self) -> float:
        """The worst plant's RMS of the true force at its best trial, leaving out the time just after each jump, in
        N.
        """
        return float(np.max(self._best("tracking_rms_after_change_N")))

    @property
    def trials_to_within_1p1(self) -> int:
        """The worst plant's first trial within 1.1 times its best error (true force, whole trajectory)."""
        return int(np.max(within_1p1(self._rows("tracking_rms_N"))))

    def signal(self, gain_set_sha256: str | None, inputs: dict[str, Any] | None = None,
               plant: int = 0) -> LearnedSignal:
        """The learned signal as an artifact (of plant ``plant`` for a batch).

        Parameters
        ----------
        gain_set_sha256 : str or None
            The hash of the gain set the signal was learned with (None: unsaved gains).
        inputs : dict or None
            The hashes of the files the learning came from, by name (None: none).
        plant : int
            Which plant of a batch (0 for one plant).

        Returns
        -------
        LearnedSignal
            The learned feedforward correction (V), its setpoint (N), sample period, reference and best trial.
        """
        u = self.ff_extra_V if self.ff_extra_V.ndim == 1 else self.ff_extra_V[plant]
        best = int(np.asarray(self.best).reshape(-1)[plant])
        return LearnedSignal(u, self.setpoint_N, float(self.run.t_s[1] - self.run.t_s[0]), self.reference,
                             gain_set_sha256, best, self.preview_s, self.method, [h.to_dict() for h in self.history],
                             dict(inputs or {}))

    def save(self, folder: str | Path, gain_set_sha256: str | None,
             inputs: dict[str, Any] | None = None) -> LearnedWritten:
        """Write the learned signal (``learned.json``, :meth:`signal`) and the figure
        (``learning.png``) to ``folder``.

        Parameters
        ----------
        folder : str or Path
            The folder the files are written into.
        gain_set_sha256 : str or None
            The hash of the gain set the signal was learned with (None: unsaved gains).
        inputs : dict or None
            The hashes of the files the learning came from, by name (None: none).

        Returns
        -------
        LearnedWritten
            The learned signal's path and its hash.
        """
        folder = Path(folder)
        saved = self.signal(gain_set_sha256, inputs).save(folder / "learned.json")
        self.plot().savefig(folder / "learning.png", dpi=120)
        return LearnedWritten(str(folder / "learned.json"), saved.content_sha256)

    def to_dict(self) -> dict[str, Any]:
        """What ``learn --json`` prints.

        Returns
        -------
        dict
            The tracking RMS (N, and in % of the reference's range), the causal and preview floors (N), the trials and
            how the learning stopped, how many plants converged, diverged or fell monotonically, the best trial per
            plant, the preview, the learning law, every trial's history, ``seconds``, and the preview's and the run's
            information.
        """
        span = float(np.ptp(self.reference.levels_N)) or 1.0
        floor = self.preview_floor_N
        return {
            "tracking_rms_N": self.tracking_rms_N, "tracking_rms_after_change_N": self.tracking_rms_after_change_N,
            "tracking_rms_pct_of_range": 100.0 * self.tracking_rms_N / span,
            # the whole trajectory scored from t = 0 (the score above starts at the first change, as the
            # causal floor's; a previewed ramp that starts before it is not counted there)
            "tracking_rms_from_start_N": float(np.max(self.run.tracking_error(0.0).rms_N)),
            "causal_floor_N": self.causal_floor_N, "preview_floor_N": floor,
            "over_preview_floor_ratio": self.tracking_rms_N / floor if floor > 0 else None,
            "iterations": len(self.history) - 1, "trials": int(np.max(self.trials)),
            "trials_per_plant": np.asarray(self.trials).reshape(-1).tolist(),
            "trials_to_within_1p1": self.trials_to_within_1p1, "stop_reason": self.stop_reason,
            "converged": bool(np.all(self.converged)), "converged_plants": int(np.sum(self.converged)),
            "diverged_plants": int(np.sum(self.diverged)), "monotone_plants": int(np.sum(self.monotone)),
            "plants": self.plants, "noise_floor_N": self.noise_floor_N,
            "best_iteration": np.asarray(self.best).reshape(-1).tolist(),
            "preview_s": self.preview_s, "method": str(self.method), "learning": self.law.to_dict(),
            "history": [h.to_dict() for h in self.history], "seconds": self.seconds,
            **self.preview.to_dict(), **self.info,
        }

    def plot(self) -> Figure:
        """The error per trial (left) and the best trial's force against the reference (right): a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The worst plant's RMS error per trial (N, log scale) with both floors; the best trial's force, the plan and
            the reference against time.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(9.0, 3.6), layout="constrained")
        a, b = fig.subplots(1, 2)
        it = [h.iteration for h in self.history]
        for key, label in (("tracking_rms_N", "whole trajectory"),
                           ("tracking_rms_after_change_N", "outside 0.1 s after jumps")):
            a.semilogy(it, [float(np.max(np.atleast_1d(getattr(h, key)))) for h in self.history], "o-", label=label)
        a.axhline(self.preview_floor_N, color="0.4", ls="--", label="preview floor")
        a.axhline(self.causal_floor_N, color="0.7", ls=":", label="causal floor")
        a.set(xlabel="trial (0: the preview alone)", ylabel="RMS error of the true force (N)")
        a.legend(fontsize="small")
        run = self.run
        force = run.force_N if run.force_N.ndim == 1 else run.force_N.reshape(-1, run.t_s.size)[0]
        b.plot(run.t_s, run.reference_N, color="0.35", ls="--", label="reference")
        b.plot(run.t_s, self.setpoint_N, color="0.6", lw=0.8, label="plan")
        b.plot(run.t_s, force, lw=0.8, label="force")
        b.set(xlabel="time (s)", ylabel="force (N)")
        b.legend(fontsize="small")
        return fig

    def __repr__(self) -> str:
        return (f"LearningResult({self.method}, {len(self.history) - 1} trials, best {self.tracking_rms_N:.4g} N RMS, "
                f"within 1.1x of it at trial {self.trials_to_within_1p1}, preview floor {self.preview_floor_N:.4g} N)")


# --------------------------------------------------------------------------------------
# when more trials no longer pay
# --------------------------------------------------------------------------------------
def more_trials_pay(measured: Array, floor_N: Any = 0.0, stop_gain: float = STOP_GAIN) -> BoolArray:
    """Per plant (columns; a row per trial so far): whether another trial is expected to lower the measured RMS error
    by more than ``stop_gain`` of it.

    The error's limit is extrapolated from the last three trials (Aitken's delta-squared: a geometric
    approach to a limit) and held at least at ``floor_N`` (the sensor's noise, which no trial removes);
    with two trials only the floor bounds it. A trial that did not improve on the one before does not pay.
    """
    rows = np.asarray(measured, float).reshape(len(measured), -1)
    now = rows[-1]
    limit = np.broadcast_to(np.asarray(floor_N, float), now.shape).copy()
    if rows.shape[0] >= 3:
        a, b = rows[-3], rows[-2]
        curve = now - 2.0 * b + a
        with np.errstate(divide="ignore", invalid="ignore"):
            aitken = np.where((curve > 0) & (now < b), now - (now - b) ** 2 / curve, now)
        limit = np.maximum(limit, aitken)
    pays = now > (1.0 + stop_gain) * limit
    if rows.shape[0] >= 2:
        pays &= now < rows[-2] / (1.0 + 0.25 * stop_gain)  # no gain on the last trial: none expected from the next
    return pays


# --------------------------------------------------------------------------------------
# the trials
# --------------------------------------------------------------------------------------
def _method(method: LearningMethod | str) -> LearningMethod:
    """The learning law ``method`` names (a member, or its value as a caller writes it); an :class:`InputError`
    where it names none."""
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return LearningMethod(method)


def law_for(method: LearningMethod | str, params: Plant, controller: Controller, preview: Preview, *, seed: int = 0,
            spread: dict[str, float] | None = None) -> Law:
    """The learning law ``method`` for ``controller`` on the nominal plant ``params`` along ``preview``'s plan."""
    if _method(method) is LearningMethod.P_TYPE:
        return learning_model_over(params, controller)
    return norm_optimal_law(params, controller, preview.target_N, preview.ff_extra_V, spread=spread, seed=seed)


@dataclass
class _Trials:
    """The trial loop's book-keeping for a batch of plants."""

    u: Array
    noise_floor_N: Array
    sensor_N: Array
    grow_tol: float
    stop_gain: float
    history: list[Iteration] = field(default_factory=list)
    measured: list[Array] = field(default_factory=list)

    def __post_init__(self) -> None:
        shape = self.u.shape[:-1]
        self.best_err = np.full(shape, np.inf)
        self.best_u = self.u.copy()
        self.best_it = np.zeros(shape, int)
        self.active = np.ones(shape, bool)
        self.diverged = np.zeros(shape, bool)
        self.settled = np.zeros(shape, bool)
        self.trials = np.zeros(shape, int)
        self.best_run: ClosedLoopRun | None = None

    def record(self, k: int, scored: ClosedLoopRun, measured: Array) -> BoolArray:
        """Book trial ``k``; returns which plants improved on their best."""
        whole = scored.tracking_error().rms_N
        after = scored.tracking_error(after_change_s=AFTER_CHANGE_S).rms_N
        self.history.append(Iteration(k, whole, after, measured))
        self.measured.append(np.where(self.active, measured, np.nan))
        self.trials = np.where(self.active, k, self.trials)
        improved = self.active & (measured < self.best_err)
        self.best_err = np.where(improved, measured, self.best_err)
        self.best_it = np.where(improved, k, self.best_it)
        self.best_u[improved] = self.u[improved]
        self.best_run = scored if self.best_run is None else _merge_runs(self.best_run, scored, improved)
        # (a rise within the noise floor is the sensor's noise shaking the stacks' hysteresis, not divergence)
        grew = self.active & (measured > (1.0 + self.grow_tol) * self.best_err + self.noise_floor_N)
        self.diverged |= grew
        self.active &= ~grew
        return improved

    def stop_when_no_longer_paying(self) -> None:
        rows = np.array([np.where(np.isnan(m), np.inf, m) for m in self.measured])
        done = self.active & ~more_trials_pay(rows, self.sensor_N, self.stop_gain).reshape(self.active.shape)
        self.settled |= done
        self.active &= ~done

    def monotone(self) -> BoolArray:
        """Per plant: its true error never rose by more than the noise floor from one trial to the next."""
        rows = np.array([np.atleast_1d(h.tracking_rms_N) for h in self.history])  # (trials, plants)
        trials = np.asarray(self.trials).reshape(-1)
        ok = []
        for j in range(rows.shape[1]):
            seq = rows[: trials[j] + 1, j]
            ok.append(bool(np.all(np.diff(seq) <= np.asarray(self.noise_floor_N).reshape(-1)[j] + 1e-12)))
        return np.array(ok).reshape(self.active.shape)

    def reasons(self, iterations: int) -> list[str]:
        out = []
        for d, s in zip(np.atleast_1d(self.diverged), np.atleast_1d(self.settled), strict=True):
            out.append("diverged" if d else "no longer pays" if s else f"trial limit ({iterations})")
        return out


def _noise_floor(rig: Rig, controller: Controller, setpoint: Reference, u: Array, seed: int,
                 first: ClosedLoopRun) -> Array:
    """Per plant: the RMS difference of the true force between two runs of the same signal under other sensor noise.
    By the triangle inequality the two runs' RMS errors may differ by that much with no learning at all."""
    again = simulate(rig, controller, setpoint, seed=seed + 7919, ff_extra_V=np.moveaxis(u, -1, 0))
    return np.sqrt(np.mean((again.force_N - first.force_N) ** 2, axis=-1))


def learn(controller: Controller, rig: Rig, reference: Reference, *, iterations: int = 10,
          preview_s: float | None = None, method: LearningMethod | str = METHODS[0], plants: int | None = None,
          seed: int = 0,
          spread: dict[str, float] | None = None, law: Law | None = None, grow_tol: float = 0.05,
          stop_gain: float | None = STOP_GAIN, after_change_weight: float = 0.0,
          slew_fraction: float = PLAN_SLEW_FRACTION, initial_V: Array | None = None,
          progress: ProgressLike | None = None) -> LearningResult:
    """Learn a feedforward correction for ``controller`` on ``rig`` over ``reference``, with preview.

    Parameters
    ----------
    controller, rig, reference
        The loop and the repeated reference (``rig`` one plant: the nominal).
    iterations : int
        The most learning trials after trial 0 (the preview alone); fewer where more no longer pay.
    preview_s : float or None
        The preview horizon; None for :func:`~piezopreload.tuning.preview.default_preview_s`, 0 for none.
    method : LearningMethod or str
        ``"norm-optimal"`` (the default: the Riccati form, a sparse QP where the limits bind) or
        ``"p-type"`` (Q-filtered, with lead: the model-free option).
    plants : int or None
        Learn on that many Monte Carlo plants around ``rig`` (each its own learning, the nominal
        law); None learns on ``rig`` itself.
    seed : int
        Of the plants' draw, the law's uncertainty set and the sensor noise (trial ``k`` uses ``seed + k``).
    spread : dict or None
        The plants' relative spread (the validation's by default).
    law : LearningModel or NormOptimalLaw or None
        A law to use instead of :func:`law_for`'s (the same law for several references, say).
    grow_tol : float
        A plant stops when its measured error exceeds its best by ``grow_tol`` of it and the noise floor
        (diverged; its best trial is kept).
    stop_gain : float or None
        A plant stops when another trial is not expected to lower its measured error by more than
        this share (:func:`more_trials_pay`); None runs every trial.
    after_change_weight, slew_fraction : float
        How the plan places and ramps each change (:func:`~piezopreload.tuning.preview.plan_preview`).
    initial_V : array or None
        A correction learned before (on a pass of a schedule close to this one, say), added to trial 0's signal.
    """
    t0 = time.perf_counter()
    say = say_of(progress) or (lambda _m: None)
    if not (isinstance(iterations, int | np.integer) and iterations >= 0):
        raise InputError(f"iterations must be an integer >= 0, got {iterations!r}")
    if plants is not None and not (isinstance(plants, int | np.integer) and plants >= 1):
        raise InputError(f"plants must be a positive integer or None, got {plants!r}")
    if rig.params.batch_shape:
        raise InputError("learn: give the nominal rig (one plant); plants=N draws the Monte Carlo batch")
    preview = plan_preview(rig.params, controller, reference, preview_s, after_change_weight=after_change_weight,
                           slew_fraction=slew_fraction)
    law = law if law is not None else law_for(method, rig.params, controller, preview, seed=seed, spread=spread)
    sim_rig = Rig(rig.params.vary(plants, spread or DEFAULT_SPREAD, seed)) if plants else rig
    batch = sim_rig.params.batch_shape
    start = preview.ff_extra_V if initial_V is None else preview.ff_extra_V + _initial(initial_V, preview)
    trials = _run_trials(controller, sim_rig, preview, law, np.broadcast_to(start, batch + start.shape).copy(),
                         iterations, seed, grow_tol, stop_gain, say)
    result = _result(trials, preview, law, plants, time.perf_counter() - t0, iterations, initial_V is not None)
    if initial_V is not None:  # trial 0 carried a correction: the loop without one, run once, is "before learning"
        run = simulate(sim_rig, controller, preview.setpoint, seed=seed,
                       ff_extra_V=np.moveaxis(np.broadcast_to(preview.ff_extra_V, batch + start.shape), -1, 0))
        result.info["before_learning_rms_N"] = float(np.max(_scored(run, reference).tracking_error().rms_N))
    return result


def _initial(initial_V: Array, preview: Preview) -> Array:
    x = np.asarray(initial_V, float)
    if x.shape != preview.ff_extra_V.shape:
        raise InputError(f"initial_V has shape {x.shape}; the reference has {preview.ff_extra_V.size} samples")
    return x


def _run_trials(controller: Controller, rig: Rig, preview: Preview, law: Law, u: Array, iterations: int, seed: int,
                grow_tol: float, stop_gain: float | None, say: Callable[[str], None]) -> _Trials:
    """Trial 0 and up to ``iterations`` learning trials on every plant of ``rig``."""
    lo, hi = controller.gains.u_min_V, controller.gains.u_max_V
    scored_from = preview.reference.times_s[min(1, preview.reference.times_s.size - 1)]
    sensor = np.broadcast_to(np.asarray(rig.params.noise_N, float), u.shape[:-1])
    book: _Trials | None = None
    for k in range(iterations + 1):
        run = simulate(rig, controller, preview.setpoint, seed=seed + k, ff_extra_V=np.moveaxis(u, -1, 0))
        e = preview.target_N - run.measured_N
        measured = np.sqrt(np.mean(e[..., preview.t_s >= scored_from] ** 2, axis=-1))
        if book is None:
            book = _Trials(u, _noise_floor(rig, controller, preview.setpoint, u, seed, run), sensor, grow_tol,
                           STOP_GAIN if stop_gain is None else float(stop_gain))
        book.u = u
        book.record(k, _scored(run, preview.reference), measured)
        whole, after = book.history[-1].tracking_rms_N, book.history[-1].tracking_rms_after_change_N
        say(f"trial {k}: {float(np.max(whole)):.4g} N RMS (true force), "
            f"{float(np.max(after)):.4g} N outside {AFTER_CHANGE_S:g} s after jumps")
        if k >= 1 and stop_gain is not None:
            book.stop_when_no_longer_paying()
        if k == iterations or not book.active.any():
            break
        # where the command sat at a limit the plant was out of the loop's authority: nothing to learn there
        e_learn = np.where((run.command_V <= lo + 1e-9) | (run.command_V >= hi - 1e-9), 0.0, e)
        u = np.where(book.active[..., None], law.update(u, e_learn, run.command_V, run.voltage_V), u)
    if book is None:  # pragma: no cover - the loop runs at least once
        raise InternalError("learn: no trial ran")
    if stop_gain is None:  # every trial ran: would the rule have stopped at the last one?
        book.stop_when_no_longer_paying()
    return book


def _result(book: _Trials, preview: Preview, law: Law, plants: int | None, seconds: float, iterations: int,
            warm: bool) -> LearningResult:
    best_run = book.best_run
    if best_run is None:  # pragma: no cover - the loop runs at least once
        raise InternalError("learn: no trial ran")
    ref = preview.reference
    # with preview a change starts before its jump: what the after-change score counts of the plan itself, and the
    # score outside whole transitions (from the preview before each jump to 0.1 s after it)
    plan_run = replace(best_run, force_N=preview.target_N, reference=ref, reference_N=ref.at(preview.t_s))
    plan_after = float(plan_run.tracking_error(after_change_s=AFTER_CHANGE_S).rms_N)
    outside = replace(best_run, reference=preview.shifted_reference()).tracking_error(
        after_change_s=AFTER_CHANGE_S + preview.preview_s).rms_N
    converged = ~book.diverged & book.settled
    monotone = book.monotone()
    method = LearningMethod.P_TYPE if isinstance(law, LearningModel) else LearningMethod.NORM_OPTIMAL
    return LearningResult(book.best_u, book.history, book.best_it, book.trials, book.reasons(iterations),
                          converged & monotone, book.diverged, monotone, best_run, preview, method, law, plants,
                          float(np.max(book.noise_floor_N)), seconds,
                          {"plan_rms_after_change_N": plan_after, "warm_start": warm,
                           "tracking_rms_outside_transitions_N": float(np.max(outside))})


def _scored(run: ClosedLoopRun, reference: Reference) -> ClosedLoopRun:
    return replace(run, reference=reference, reference_N=reference.at(run.t_s))


def _merge_runs(old: ClosedLoopRun, new: ClosedLoopRun, take: BoolArray) -> ClosedLoopRun:
    """Per plant, the new run's samples where ``take``, else the old's."""
    if not np.any(take):
        return old
    if old.force_N.ndim == 1:
        return new
    changes = {}
    for name in ("force_N", "measured_N", "command_V", "voltage_V", "p_V", "i_V", "d_V", "ff_V"):
        changes[name] = np.where(take[..., None], getattr(new, name), getattr(old, name))
    return replace(old, **changes)


# --------------------------------------------------------------------------------------
# one update from a rig run
# --------------------------------------------------------------------------------------
def learn_from_log(signal: LearnedSignal, log: dict[str, Array], gain_set: GainSet,
                   shown: str = "the learned signal") -> LearnedSignal:
    """:func:`learn_from_run` from a rig run log's columns (the controlled samples) of ``signal`` played with
    ``gain_set`` (whose plant and controller give the law); a signal of another gain set is refused."""
    signal.check(gain_set.content_sha256, None, shown)
    if gain_set.plant is None:
        raise InputError("the gain set names no plant to build the learning law on; write it again with 'tune'")
    keep = log["mode"] == 0
    controller = gain_set.controller()
    if signal.method is LearningMethod.P_TYPE:
        law: Law = learning_model_over(gain_set.plant, controller)  # the law learn() uses
    else:  # learning started from the previewed feedforward of the signal's plan
        lead = feedforward_lead(gain_set.plant) if signal.preview_s > 0 else 0
        law = norm_optimal_law(gain_set.plant, controller, signal.setpoint_N,
                               preview_feedforward(controller, signal.setpoint_N, lead))
    return learn_from_run(signal, log["measured_N"][keep], log["command_V"][keep], law, log["voltage_V"][keep])


def learn_from_run(signal: LearnedSignal, measured_N: Array, command_V: Array, law: Law,
                   voltage_V: Array | None = None) -> LearnedSignal:
    """One learning update from a rig run of ``signal``: its measured force, command and amplifier voltage per
    sample give the next trial's signal (without the voltage its limit is read from the command)."""
    y, c = np.asarray(measured_N, float), np.asarray(command_V, float)
    v = c if voltage_V is None else np.asarray(voltage_V, float)
    n = signal.ff_extra_V.size
    if y.shape != (n,) or c.shape != (n,) or v.shape != (n,):
        raise InputError(f"the run has {y.size} samples; the learned signal {n}: run the whole reference")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(c)) and np.all(np.isfinite(v))):
        raise InputError("the run's measured force, command or voltage is not finite everywhere (a tripped run?)")
    e = signal.setpoint_N - y
    lo, hi = law.u_range_V
    e = np.where((c <= lo + 1e-9) | (c >= hi - 1e-9), 0.0, e)  # no learning where the command sat at a limit
    u = law.update(signal.ff_extra_V, e, c, v)
    rms = float(np.sqrt(np.mean(e**2)))
    history = [*signal.history, {"iteration": signal.iteration, "measured_rms_N": rms, "source": "rig run"}]
    return replace(signal, ff_extra_V=u, iteration=signal.iteration + 1, history=history, content_sha256=None)


# --------------------------------------------------------------------------------------
# learning over a schedule's passes (the whole system's learn stage)
# --------------------------------------------------------------------------------------
def schedule_learner(params: Plant, controller: Controller, *, iterations: int, preview_s: float | None,
                     method: LearningMethod | str, seed: int, progress: ProgressLike | None = None,
                     warm_start: bool = True, stop_gain: float | None = STOP_GAIN
                     ) -> tuple[Callable[[Reference], Array], list[LearningResult]]:
    """A learner for each pass of a schedule on one plant (``params``): called with a pass's repeated
    reference it learns on it (:func:`learn`) and returns the best signal; the list collects each pass's
    :class:`LearningResult`. With ``warm_start`` a pass starts from the correction the pass before learned
    (where the references have as many samples: a pass is the schedule planned again with a margin);
    ``stop_gain`` as :func:`learn`'s."""
    results: list[LearningResult] = []
    p_type = learning_model_over(params, controller) if _method(method) is LearningMethod.P_TYPE else None  # one law

    def learned(reference: Reference) -> Array:
        before = results[-1] if results and warm_start else None
        initial = None
        if before is not None and before.ff_extra_V.shape == before.preview.ff_extra_V.shape:
            n = int(round(reference.duration_s / params.sample_period_s)) + 1
            if n == before.ff_extra_V.size:
                initial = before.ff_extra_V - before.preview.ff_extra_V
        results.append(learn(controller, Rig(params), reference, iterations=iterations, law=p_type, method=method,
                             preview_s=preview_s, seed=seed, progress=progress, initial_V=initial, stop_gain=stop_gain))
        return results[-1].ff_extra_V

    return learned, results


def _pass_record(k: int, result: LearningResult, signal: str) -> PassRecord:
    d = result.to_dict()
    span = float(np.ptp(result.reference.levels_N)) or 1.0
    before = float(result.info.get("before_learning_rms_N", np.max(result.history[0].tracking_rms_N)))
    return PassRecord(k, signal, reference_sha256(result.reference), before, 100.0 * before / span,
                      d["tracking_rms_N"], d["tracking_rms_pct_of_range"], d["trials"], d["trials_to_within_1p1"],
                      result.stop_reason[0] if len(result.stop_reason) == 1
                      else "; ".join(sorted(set(result.stop_reason))),
                      d["converged"], d["best_iteration"], d["causal_floor_N"],
                      d["preview_floor_N"], d["noise_floor_N"], d["preview_s"], d["method"],
                      bool(result.info.get("warm_start", False)), d["learning"],
                      [TrialRecord.from_dict(h) for h in d["history"]], d["tracking_rms_from_start_N"])


def save_passes(passes: list[LearningResult], folder: str | Path, gain_set_sha256: str | None,
                inputs: dict[str, Any]) -> tuple[dict[str, Path], LearningRecord]:
    """Write the learning of each pass of a schedule (one per margin the schedule was planned with) into ``folder``.

    ``learned-pass<k>.json`` holds pass ``k``'s learned signal (tied to ``gain_set_sha256`` and that
    pass's reference); ``learning.json`` the :class:`~piezopreload.artifacts.learning.LearningRecord`.
    Returns the paths by label (``learning``, ``learned``: the last pass's signal, what the rig plays,
    ``pass<k>``) and the record.
    """
    if not passes:
        raise InputError("save_passes: no pass was learned (the schedule's tracking ran without learning)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("learned-pass*.json"):  # a pass the schedule no longer needs
        stale.unlink()
    paths: dict[str, Path] = {}
    records = []
    for k, result in enumerate(passes, start=1):
        path = folder / f"learned-pass{k}.json"
        result.signal(gain_set_sha256, {**inputs, "pass": k}).save(path)
        paths[f"pass{k}"] = path
        records.append(_pass_record(k, result, path.name))
    paths["learned"] = paths[f"pass{len(passes)}"]
    record = LearningRecord(records, paths["learned"].name, dict(inputs))
    paths["learning"] = record.save(folder / "learning.json")
    return paths, record


def played_passes(learning_path: str | Path, gain_set_sha256: str | None) -> tuple[Callable[[Reference], Array],
                                                                                  LearningRecord]:
    """From a schedule's ``learning.json`` (:func:`save_passes`): the learned signal for each pass's reference
    (:func:`learned_by_reference`) and the record."""
    record = LearningRecord.load(learning_path)
    return learned_by_reference(record.signal_paths(Path(learning_path).parent), gain_set_sha256), record


def learned_by_reference(paths: list[Path], gain_set_sha256: str | None) -> Callable[[Reference], Array]:
    """``ff_extra_V`` for a reference from the learned signals at ``paths`` (:func:`save_passes`'): the one learned on
    that very reference, for that gain set. A reference none was learned on is refused (the learning is stale)."""
    signals = {}
    for path in paths:
        signal = LearnedSignal.load(path)
        signal.check(gain_set_sha256, None, str(path))
        signals[signal.reference_sha256] = signal

    def ff_extra(reference: Reference) -> Array:
        key = reference_sha256(reference)
        if key not in signals:
            raise InputError(f"no learned signal was learned on reference {key} (learned on: {', '.join(signals)}); "
                             "run the learn stage again ('piezopreload run --force')")
        return signals[key].ff_extra_V

    return ff_extra
