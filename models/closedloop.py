"""The closed-loop simulation: the loop of :mod:`piezopreload.models.loop` over a reference.

Timing of one sample ``k`` (``t_k = k dt``), as a LabVIEW loop with an A/D and a D/A card runs:
the A/D reads the force (noise, quantisation), the controller computes the command from the
reading and the reference at ``t_k``, the command is written to the D/A and reaches the
amplifier after the rig's ``delay_samples``, and the rig advances to ``t_{k+1}``. The loop runs
compiled where a C compiler works and in numpy elsewhere, with the same numbers.

The same function simulates one plant or a batch (a :class:`~piezopreload.models.actuator.Plant`
with array fields): every array carries the batch in its leading axes and time last.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Rig
from piezopreload.models.controller import Controller
from piezopreload.models.loop import LOOP_OUTPUTS, OPEN_LOOP_OUTPUTS, LoopModel, OpenLoopModel, run
from piezopreload.models.metrics import Signal, StepMetrics, step_metrics
from piezopreload.models.ops import NUMPY

__all__ = ["Interpolation", "INTERPOLATIONS", "Reference", "ClosedLoopRun", "TrackingError", "simulate",
           "simulate_open_loop", "triangle", "PAPER_BAND_N"]


class Interpolation(StrEnum):
    """How a reference goes between its points: each level held (steps) or ramped linearly to the next (its value is
    what a reference's document writes)."""

    HOLD = "hold"
    LINEAR = "linear"


#: how a reference goes between its points, in its order
INTERPOLATIONS = tuple(Interpolation)

#: The paper's error band for rise, peak and settling time (Section 4.2).
PAPER_BAND_N = 1.5


@dataclass(frozen=True, eq=False)
class Reference:
    """A force reference: ``levels_N[i]`` from ``times_s[i]`` on, held (``interpolation="hold"``,
    piecewise constant) or ramped linearly to the next point (``"linear"``, piecewise linear;
    the last level held to the end).

    ``times_s[0]`` must be 0 (the level the rig rests at before the first change).

    Parameters
    ----------
    times_s : ndarray
        The times of the points, strictly increasing from 0 (s).
    levels_N : ndarray
        The force at each point (N).
    duration_s : float
        The reference's length, beyond its last point (s).
    interpolation : Interpolation
        Between points: hold each level, or ramp linearly to the next (given as its string, ``"hold"`` or
        ``"linear"``, it is held as the member).
    """

    times_s: Array
    levels_N: Array
    duration_s: float
    interpolation: Interpolation = Interpolation.HOLD

    def __post_init__(self) -> None:
        t = np.asarray(self.times_s, float)
        lv = np.asarray(self.levels_N, float)
        if t.ndim != 1 or t.shape != lv.shape or t.size < 1:
            raise ValueError(f"times_s and levels_N must be 1-D of equal length >= 1, got {t.shape} and {lv.shape}.")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(lv))):
            raise ValueError("times_s and levels_N must be finite.")
        if t[0] != 0 or np.any(np.diff(t) <= 0):
            raise ValueError(f"times_s must start at 0 and increase, got {t.tolist()}.")
        if not (np.isfinite(self.duration_s) and self.duration_s > t[-1]):
            raise ValueError(f"duration_s must be after the last change ({t[-1]} s), got {self.duration_s!r}.")
        if not isinstance(self.interpolation, str) or self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {self.interpolation!r}.")
        object.__setattr__(self, "interpolation", Interpolation(self.interpolation))
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "levels_N", lv)

    @classmethod
    def step(cls, initial_N: float, final_N: float, t_step_s: float = 0.5, duration_s: float = 10.0) -> Reference:
        """A step from ``initial_N`` to ``final_N`` at ``t_step_s``.

        Parameters
        ----------
        initial_N : float
            The force before the step, in N.
        final_N : float
            The force after it, in N.
        t_step_s : float
            When it steps, in s.
        duration_s : float
            The reference's length, in s.

        Returns
        -------
        Reference
            A held (piecewise constant) reference of two levels.
        """
        return cls(np.array([0.0, t_step_s]), np.array([initial_N, final_N]), duration_s)

    @classmethod
    def staircase(
        cls, initial_N: float, levels_N: ArrayLike, hold_s: float, t_start_s: float = 0.5
    ) -> Reference:
        """Rest at ``initial_N``, then each of ``levels_N`` for ``hold_s``.

        Parameters
        ----------
        initial_N : float
            The force before the first level, in N.
        levels_N : array_like
            The levels, in N, in order.
        hold_s : float
            How long each level is held, in s.
        t_start_s : float
            When the first level begins, in s.

        Returns
        -------
        Reference
            A held reference, ``t_start_s + hold_s * len(levels_N)`` long.
        """
        levels = np.asarray(levels_N, float)
        times = np.concatenate([[0.0], t_start_s + hold_s * np.arange(levels.size)])
        return cls(times, np.concatenate([[initial_N], levels]), t_start_s + hold_s * levels.size)

    @classmethod
    def ramps(cls, times_s: ArrayLike, levels_N: ArrayLike, duration_s: float | None = None) -> Reference:
        """Piecewise linear through the points ``(times_s[i], levels_N[i])``; the last level held until
        ``duration_s`` (default: one more interval of the last).

        Parameters
        ----------
        times_s : array_like
            The points' times, in s, increasing.
        levels_N : array_like
            The force at each time, in N.
        duration_s : float or None
            The reference's length, in s (None: the last interval once more, or 1 s after a single point).

        Returns
        -------
        Reference
            A linearly interpolated reference.
        """
        t = np.asarray(times_s, float)
        if duration_s is None:
            duration_s = float(t[-1] + (t[-1] - t[-2])) if t.size > 1 else float(t[-1] + 1.0)
        return cls(t, np.asarray(levels_N, float), float(duration_s), Interpolation.LINEAR)

    def repeat(self, cycles: int) -> Reference:
        """The reference ``cycles`` times in a row (a machining cycle run again and again).

        Parameters
        ----------
        cycles : int
            How many times, at least 1.

        Returns
        -------
        Reference
            The reference repeated, ``cycles`` times as long, its interpolation kept.

        Raises
        ------
        InputError
            Where ``cycles`` is not an integer of at least 1.
        """
        if not (isinstance(cycles, int | np.integer) and cycles >= 1):
            raise InputError(f"cycles must be an integer >= 1, got {cycles!r}")
        t = np.concatenate([self.times_s + k * self.duration_s for k in range(cycles)])
        return Reference(t, np.tile(self.levels_N, cycles), self.duration_s * cycles, self.interpolation)

    def at(self, t: ArrayLike) -> Array:
        """The reference's force at the times ``t``.

        Parameters
        ----------
        t : array_like
            The times, in s.

        Returns
        -------
        ndarray
            The force at each time, in N: the level last reached for a held reference (the first before it begins),
            interpolated for a linear one.
        """
        t = np.asarray(t, float)
        if self.interpolation is Interpolation.LINEAR:
            level: Array = np.interp(t, self.times_s, self.levels_N)
            return level
        idx = np.searchsorted(self.times_s, t, side="right") - 1
        return self.levels_N[np.clip(idx, 0, None)]

    @property
    def is_step(self) -> bool:
        """Whether the reference is one held step (two levels)."""
        return self.times_s.size == 2 and self.interpolation is Interpolation.HOLD

    @property
    def range_N(self) -> float:
        """The span of the reference's levels (what a tracking error is read against, in %)."""
        return float(self.levels_N.max() - self.levels_N.min())

    def to_dict(self) -> dict[str, Any]:
        """The reference as its document holds it.

        Returns
        -------
        dict
            ``times_s``, ``levels_N``, ``duration_s``, and ``interpolation`` where it is not ``hold``.
        """
        out = {"times_s": self.times_s.tolist(), "levels_N": self.levels_N.tolist(), "duration_s": self.duration_s}
        return out if self.interpolation is Interpolation.HOLD else {**out, "interpolation": str(self.interpolation)}

    @classmethod
    def from_dict(cls, data: Any) -> Reference:
        """The inverse of :meth:`to_dict`; an :class:`InputError` (a ValueError) names what is missing or wrong.

        Parameters
        ----------
        data : dict
            The document's object: ``times_s``, ``levels_N``, ``duration_s`` and, optionally, ``interpolation``.

        Returns
        -------
        Reference
            The reference.

        Raises
        ------
        InputError
            Where a key is missing or a value is wrong.
        """
        if not isinstance(data, dict):
            raise InputError("a reference is an object with times_s, levels_N and duration_s, "
                             f"got {type(data).__name__}")
        missing = [k for k in ("times_s", "levels_N", "duration_s") if k not in data]
        if missing:
            raise InputError(f"{missing[0]} is missing (a reference has times_s, levels_N and duration_s)")
        try:
            return cls(np.asarray(data["times_s"], float), np.asarray(data["levels_N"], float),
                       float(data["duration_s"]), data.get("interpolation", Interpolation.HOLD))
        except (TypeError, ValueError) as exc:
            raise InputError(str(exc)) from exc


@dataclass(frozen=True, eq=False)
class TrackingError:
    """A run's tracking error (:meth:`ClosedLoopRun.tracking_error`): its RMS and its largest magnitude, and the share
    of the scored samples left out with the command at a limit of the range given; numbers for one plant, arrays with
    one per plant for a batch."""

    rms_N: float | Array
    max_N: float | Array
    saturated_fraction: float | Array


@dataclass(frozen=True, eq=False)
class ClosedLoopRun:
    """A simulated run: samples with time last, batch (if any) in the leading axes.

    ``force_N`` is the true force at each sample, ``measured_N`` what the A/D read,
    ``command_V`` the controller output (after its clamp) and ``p_V, i_V, d_V, ff_V`` its
    parts, ``voltage_V`` the amplifier output; ``engine`` which simulation ran (``"c"`` or
    ``"numpy"``: the same numbers).

    Parameters
    ----------
    t_s : ndarray
        The sample times (s).
    reference_N : ndarray
        The reference at each sample (N).
    force_N : ndarray
        The true force (N).
    measured_N : ndarray
        The force the A/D read, noise and quantisation included (N).
    command_V : ndarray
        The controller's output after its clamp (V).
    voltage_V : ndarray
        The amplifier's output, what the stacks see (V).
    p_V, i_V, d_V, ff_V : ndarray
        The command's proportional, integral, derivative and feedforward parts (V).
    reference : Reference
        The reference the run followed.
    seed : int
        The seed of the run's noise.
    engine : {'numpy', 'c'}
        Which simulation ran.
    """

    t_s: Array
    reference_N: Array
    force_N: Array
    measured_N: Array
    command_V: Array
    voltage_V: Array
    p_V: Array
    i_V: Array
    d_V: Array
    ff_V: Array
    reference: Reference
    seed: int
    engine: str = "numpy"

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The shape of the batch of plants the run simulated: ``()`` for one plant."""
        return self.force_N.shape[:-1]

    def __repr__(self) -> str:
        levels = " -> ".join(f"{x:g}" for x in self.reference.levels_N[:6])
        more = " ..." if self.reference.levels_N.size > 6 else ""
        batch = f", {int(np.prod(self.batch_shape))} plants" if self.batch_shape else ""
        return (f"{type(self).__name__}({self.t_s.size} samples over {self.t_s[-1]:.3g} s, reference {levels}{more} N"
                f"{batch}, seed {self.seed}, engine {self.engine})")

    def _repr_html_(self) -> str:
        err = np.asarray(self.reference_N) - np.asarray(self.force_N)
        rows = (("samples", f"{self.t_s.size} over {self.t_s[-1]:.4g} s"),
                ("reference levels (N)", ", ".join(f"{x:g}" for x in self.reference.levels_N[:12])),
                ("tracking error of the true force, RMS (N)", f"{float(np.sqrt(np.mean(err ** 2))):.4g}"),
                ("peak command (V)", f"{float(np.max(self.command_V)):.4g}"), ("seed", str(self.seed)))
        body = "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)
        return f"<p><b>{type(self).__name__}</b></p><table>{body}</table>"

    def step_metrics(self, band_N: float | None = PAPER_BAND_N, *, which: int = 1,
                     signal: Signal | str = "force_N") -> StepMetrics | list[StepMetrics]:
        """Metrics of the reference's ``which``-th change (1: the first step), per plant.

        The window runs from that change to the next (or to the end); ``band_N=None`` gives the
        conventional 10-90 % / 2 % definitions. ``signal`` picks the true force (default) or
        what the sensor read (``"measured_N"``).

        Parameters
        ----------
        band_N : float or None
            The settling band, in N (the paper's by default); None: the conventional 2 % band and 10-90 % rise.
        which : int
            Which change of the reference, from 1.
        signal : Signal or str
            The signal scored: :attr:`Signal.FORCE` (``"force_N"``, the true force) or :attr:`Signal.MEASURED`
            (``"measured_N"``, what the sensor read).

        Returns
        -------
        StepMetrics or list of StepMetrics
            The step's rise, settling, overshoot and the like: one for a single plant, one per plant (the batch
            flattened) for a batch.

        Raises
        ------
        ValueError
            Where ``which`` names no change of the reference, or ``signal`` no :class:`Signal`.
        """
        scored = Signal(signal)
        ref = self.reference
        if not 1 <= which < ref.times_s.size:
            raise ValueError(f"which must be 1..{ref.times_s.size - 1}, got {which}.")
        t0 = ref.times_s[which]
        t1 = ref.times_s[which + 1] if which + 1 < ref.times_s.size else np.inf
        k0 = int(np.searchsorted(self.t_s, t0 - 1e-12))
        mask = (self.t_s >= self.t_s[k0]) & (self.t_s < t1)
        if np.count_nonzero(mask) < 2:  # the next change within a sample (a ramp, sampled): to the end
            mask = self.t_s >= self.t_s[k0]
        y = self.measured_N if scored is Signal.MEASURED else self.force_N
        initial, t_step, final = float(ref.levels_N[which - 1]), float(self.t_s[k0]), float(ref.levels_N[which])
        if y.ndim == 1:
            return step_metrics(self.t_s[mask], y[mask], final, initial=initial, t_step=t_step, band=band_N)
        flat = y.reshape(-1, y.shape[-1])
        return [step_metrics(self.t_s[mask], row[mask], final, initial=initial, t_step=t_step, band=band_N)
                for row in flat]

    def tracking_error(self, t_from_s: float | None = None, *, after_change_s: float = 0.0,
                       u_range: tuple[float, float] | None = None) -> TrackingError:
        """RMS and maximum of reference minus true force from ``t_from_s`` (default the first change).

        ``after_change_s`` leaves out that long after every change of the reference: the
        transport no controller can avoid when the reference jumps (see
        ``tuning.pid.minimum_time``), so what remains is the error a controller can act on.
        ``u_range`` leaves out, per plant, the samples whose command sits at a limit of that
        range: there the plant is out of the controller's authority (a reference it cannot
        reach within the voltage range); ``saturated_fraction`` says how much that removed.

        Parameters
        ----------
        t_from_s : float or None
            The time scoring begins, in s (None: the reference's first change).
        after_change_s : float
            How long after every change of a held reference to leave out, in s.
        u_range : (float, float) or None
            The command's range, in V: samples whose command sits at either end are left out (None: none left out).

        Returns
        -------
        TrackingError
            The RMS and the largest error, in N, and the fraction of the samples left out as saturated, per plant.

        Raises
        ------
        ValueError
            Where no samples are left to score.
        """
        t_from = (self.reference.times_s[1] if t_from_s is None and self.reference.times_s.size > 1
                  else (t_from_s or 0.0))
        mask = self.t_s >= t_from
        if after_change_s > 0 and self.reference.interpolation is Interpolation.HOLD:  # a ramped reference has no jumps
            changes = self.reference.times_s[1:]
            last = changes[np.maximum(np.searchsorted(changes, self.t_s, side="right") - 1, 0)]
            mask &= ~((self.t_s >= last) & (self.t_s < last + after_change_s))
        if not mask.any():
            raise ValueError("no samples left to score the tracking error on.")
        e = self.reference_N - self.force_N
        keep = np.broadcast_to(mask, e.shape)
        if u_range is not None:
            lo, hi = u_range
            saturated = keep & ((self.command_V <= lo + 1e-9) | (self.command_V >= hi - 1e-9))
            fraction = saturated.sum(axis=-1) / mask.sum()
            keep = keep & ~saturated
        else:
            fraction = np.zeros(e.shape[:-1])
        n = np.maximum(keep.sum(axis=-1), 1)
        rms = np.sqrt(np.where(keep, e**2, 0.0).sum(axis=-1) / n)
        peak = np.where(keep, np.abs(e), 0.0).max(axis=-1)
        if self.force_N.ndim == 1:
            return TrackingError(float(rms), float(peak), float(fraction))
        return TrackingError(rms, peak, fraction)

    def columns(self) -> dict[str, Array]:
        """The run as named columns (one plant), for CSV export.

        Returns
        -------
        dict of str to ndarray
            ``time_s``, the reference, true and measured force (N), the command and the voltage (V), and the P, I, D and
            feedforward parts of the command (V), one value per sample.

        Raises
        ------
        ValueError
            Where the run is a batch of plants.
        """
        if self.force_N.ndim != 1:
            raise ValueError("columns() needs a single-plant run; index the batch first.")
        return {
            "time_s": self.t_s,
            "reference_N": self.reference_N,
            "force_N": self.force_N,
            "measured_N": self.measured_N,
            "command_V": self.command_V,
            "voltage_V": self.voltage_V,
            "p_V": self.p_V,
            "i_V": self.i_V,
            "d_V": self.d_V,
            "ff_V": self.ff_V,
        }


def simulate(
    rig: Rig,
    controller: Controller,
    reference: Reference,
    *,
    seed: int = 0,
    batch: tuple[int, ...] = (),
    engine: str = "auto",
    ff_extra_V: ArrayLike | None = None,
) -> ClosedLoopRun:
    """Run ``controller`` against ``rig`` over ``reference``; deterministic for ``seed``.

    The rig starts at rest at 0 V (the bolt preload alone) and the controller bumplessly at
    0 V with its setpoint at the reference's first level. ``batch`` adds leading axes beyond
    those of the rig's parameters (identical plants with independent noise). The sensor noise
    is drawn here, sample by sample in time order (each sample one draw per plant), and passed
    to the loop, so the run does not depend on the engine: ``"auto"`` runs the compiled loop
    where a C compiler works and numpy elsewhere, ``"c"`` insists on the compiled loop,
    ``"numpy"`` runs the reference (:func:`piezopreload.models.loop.run`). ``ff_extra_V``
    (one value per sample, or per sample and plant) is added to the feedforward: a learned or
    previewed correction.
    """
    dt = rig.dt_s
    if not np.isclose(controller.dt_s, dt, rtol=1e-9, atol=0.0):
        raise ValueError(f"the controller samples every {controller.dt_s} s but the rig every {dt} s.")
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n, dtype=np.float64) * dt
    r = reference.at(t)
    shape = np.broadcast_shapes(tuple(batch), rig.params.batch_shape)
    model = LoopModel(rig.model, controller.model)
    params = model.parameters(rig.parameter_vector, controller.parameter_vector())
    extra = np.zeros(n) if ff_extra_V is None else np.asarray(ff_extra_V, float)
    if extra.shape[:1] != (n,):
        raise InputError(f"ff_extra_V needs one value per sample ({n}), got shape {extra.shape}.")
    x0 = model.start(NUMPY, params, r[0], extra[0])
    x0 = np.broadcast_to(x0, shape + x0.shape[-1:])
    noise = np.random.default_rng(seed).standard_normal((n,) + shape)
    y, _, used = run(model, params, x0, {"reference_N": r, "noise": noise, "ff_extra_V": extra}, n, engine=engine)
    out = LOOP_OUTPUTS.unpack(np.moveaxis(y, -2, -1))
    return ClosedLoopRun(
        t_s=t,
        reference_N=r,
        force_N=out.force_N,
        measured_N=out.measured_N,
        command_V=out.command_V,
        voltage_V=out.voltage_V,
        p_V=out.p_V,
        i_V=out.i_V,
        d_V=out.d_V,
        ff_V=out.ff_V,
        reference=reference,
        seed=int(seed),
        engine=used,
    )


def triangle(v_max_V: float, frequency_Hz: float, cycles: int, dt_s: float,
             v_min_V: float = 0.0) -> tuple[Array, Array]:
    """A triangle wave ``v_min -> v_max -> v_min``, ``cycles`` times: the usual loop measurement."""
    if not (frequency_Hz > 0 and cycles >= 1 and dt_s > 0 and v_max_V > v_min_V):
        raise ValueError("need frequency_Hz > 0, cycles >= 1, dt_s > 0 and v_max_V > v_min_V.")
    t = np.arange(int(round(cycles / frequency_Hz / dt_s)) + 1, dtype=np.float64) * float(dt_s)
    phase = (t * frequency_Hz) % 1.0
    tri = np.where(phase < 0.5, 2.0 * phase, 2.0 - 2.0 * phase)
    return t, np.asarray(v_min_V + (v_max_V - v_min_V) * tri, dtype=np.float64)


def simulate_open_loop(rig: Rig, command_V: ArrayLike, *, seed: int = 0, engine: str = "auto") -> dict[str, Array]:
    """Drive the rig with a command sequence (one per sample) and record what a rig would.

    Returns ``time_s``, ``command_V``, ``voltage_V`` (amplifier output), ``force_N`` (true)
    and ``measured_N`` (A/D): a simulated hysteresis measurement. ``engine`` as :func:`simulate`.
    """
    u = np.asarray(command_V, float)
    if u.ndim != 1 or not np.all(np.isfinite(u)):
        raise ValueError("command_V must be a finite 1-D sequence.")
    model = OpenLoopModel(rig.model)
    params = rig.parameter_vector
    shape = rig.params.batch_shape
    x0 = model.start(NUMPY, params)
    x0 = np.broadcast_to(x0, shape + x0.shape[-1:])
    noise = np.random.default_rng(seed).standard_normal((u.size,) + shape)
    y, _, _ = run(model, params, x0, {"command_V": u, "noise": noise}, u.size, engine=engine)
    out = OPEN_LOOP_OUTPUTS.unpack(np.moveaxis(y, -2, -1))
    return {"time_s": np.arange(u.size) * rig.dt_s, "command_V": u, "voltage_V": out.voltage_V,
            "force_N": out.force_N, "measured_N": out.measured_N}
