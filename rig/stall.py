"""The stall limit from the plant: how long the output may be held without an update.

When the loop stalls (the host does not run it, a backend call blocks), the D/A holds the last
command: the amplifier goes on towards it, the stacks' hysteresis follows the amplifier and
creep goes on relaxing, so the force drifts. The stall interlock
(:data:`~piezopreload.rig.interlocks.INTERLOCKS`, cause ``stall``) trips when the output has
been held longer than the plant tolerates; a shorter stall is counted and logged, not tripped.

What the plant tolerates (:func:`derive_stall_limit`): the nominal run of the reference (the
gain set's controller on its plant, :func:`~piezopreload.models.closedloop.simulate`, the
command clamped to the interlocks' voltage range as the executor clamps it) passes through
the plant's states; from each of them (all of them, or an even spread and the states with the
largest pending amplifier change where there are more than :data:`MAX_STARTS`), the command of
that sample is held and the plant runs on alone (the compiled open-loop plant step,
:class:`~piezopreload.models.loop.OpenLoopModel`) for ``horizon_s``. The limit is the shortest
hold after which the true force comes within ``sigmas`` sensor noise of a force interlock
(above ``force_max_N`` or below the bolt preload less its margin): a reading there could trip,
and the true force could be beyond the limit before the loop sees it. Where no hold leaves
that margin within ``horizon_s``, the plant sets no limit inside the horizon and the horizon is
the limit: a stall that long leaves the run's timeline so far behind that it trips whatever
the plant would do.

The result (:class:`~piezopreload.artifacts.rigrun.StallLimit`) records the derivation: the
binding hold (when on the nominal run, at which force and voltage, with what margin left), the
largest drift up and down over the horizon, and a sentence saying how.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from piezopreload.artifacts.rigrun import StallLimit
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller
from piezopreload.models.loop import OpenLoopModel, run
from piezopreload.rig.compiled import PlantStep

__all__ = ["derive_stall_limit", "HORIZON_S", "SIGMAS", "MAX_STARTS"]

#: how long a hold is followed; also the longest stall limit
HORIZON_S = 1.0
#: the sensor noise (in standard deviations) the held force must stay inside the force interlocks by
SIGMAS = 5.0
#: at most this many states of the nominal run are held (an even spread and the largest pending changes)
MAX_STARTS = 2000


def _nominal(plant: Plant, controller: Controller, reference: Reference, v_range: tuple[float, float],
             ff_extra_V: np.ndarray | None, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The commands the loop writes on the nominal run and the plant's state at each sample (before its write)."""
    rig = Rig(plant)
    nominal = simulate(rig, controller, reference, seed=seed, ff_extra_V=ff_extra_V)
    u = np.clip(np.asarray(nominal.command_V, float), *v_range)
    step = PlantStep(plant)
    step.reset(0.0)
    states = np.empty((u.size, step.model.state.size))
    for k, command in enumerate(u.tolist()):
        states[k] = step.state
        step.write(command)
    return u, states


def _starts(u: np.ndarray, states: np.ndarray, amp_index: int) -> np.ndarray:
    """The samples whose states are held: every one, or an even spread and the largest pending amplifier changes."""
    n = u.size
    if n <= MAX_STARTS:
        return np.arange(n)
    pending = np.abs(u - states[:, amp_index])
    biggest = np.argsort(pending)[-MAX_STARTS // 4:]
    spread = np.linspace(0, n - 1, MAX_STARTS - biggest.size).round().astype(int)
    return np.unique(np.concatenate([spread, biggest]))


def _held_forces(plant: Plant, states: np.ndarray, held_V: np.ndarray, steps: int) -> np.ndarray:
    """The true force of each state held at its command, for ``steps + 1`` samples (rows: starts)."""
    rig = Rig(plant)
    model = OpenLoopModel(rig.model)
    commands = np.broadcast_to(held_V, (steps + 1, held_V.size))
    y, _, _ = run(model, rig.parameter_vector, states, {"command_V": commands, "noise": 0.0}, steps + 1)
    return y[:, model.outputs.index("force_N"), :]


def derive_stall_limit(plant: Plant, controller: Controller, reference: Reference, *, force_low_N: float,
                       force_max_N: float, v_range: tuple[float, float], reference_name: str = "the reference",
                       ff_extra_V: np.ndarray | None = None, seed: int = 0, sigmas: float = SIGMAS,
                       horizon_s: float = HORIZON_S) -> StallLimit:
    """The longest hold of the output the plant tolerates on this run (see the module docstring).

    Parameters
    ----------
    plant, controller, reference
        The gain set's plant and controller and the reference the run follows (with
        ``ff_extra_V``, a learned signal's, where one plays back).
    force_low_N, force_max_N
        The force interlocks (the bolt preload less its margin; the highest force).
    v_range
        The interlocks' voltage range the executor clamps the command to.
    sigmas, horizon_s
        The noise margin in standard deviations of ``plant.noise_N``; how long a hold is followed.
    """
    key = (plant, controller, reference)  # cached by content: the same run derives the same limit
    extra = None if ff_extra_V is None else tuple(np.asarray(ff_extra_V, float).tolist())
    return _derive(_Key(key), float(force_low_N), float(force_max_N), (float(v_range[0]), float(v_range[1])),
                   reference_name, extra, int(seed), float(sigmas), float(horizon_s))


class _Key:
    """Holds unhashable inputs for the cache, compared by their JSON documents."""

    def __init__(self, parts: tuple[Plant, Controller, Reference]) -> None:
        self.parts = parts
        plant, controller, reference = parts
        self.identity = (repr(sorted(plant.to_dict().items())), controller.parameter_vector().tobytes(),
                    repr(controller.model), repr(reference.to_dict()), controller.dt_s)

    def __hash__(self) -> int:
        return hash(self.identity)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Key) and other.identity == self.identity


@lru_cache(maxsize=32)
def _derive(key: _Key, force_low_N: float, force_max_N: float, v_range: tuple[float, float], reference_name: str,
            extra: tuple[float, ...] | None, seed: int, sigmas: float, horizon_s: float) -> StallLimit:
    plant, controller, reference = key.parts
    dt = float(plant.sample_period_s)
    u, states = _nominal(plant, controller, reference, v_range, None if extra is None else np.asarray(extra), seed)
    amp = Rig(plant).model.state.index("v_amp")
    starts = _starts(u, states, amp)
    steps = max(1, int(math.ceil(horizon_s / dt)))
    forces = _held_forces(plant, states[starts], u[starts], steps)
    noise = float(plant.noise_N)
    hi, lo = force_max_N - sigmas * noise, force_low_N + sigmas * noise
    margin = np.minimum(hi - forces, forces - lo)        # N left inside the interlocks, per start and held sample
    margin[:, 0] = np.inf                                # the loop reads the force at the hold's start itself
    outside = margin < 0.0
    first = np.where(outside.any(axis=1), outside.argmax(axis=1), steps + 1)
    if first.min() <= steps:
        j = int(first.argmin())
        held = int(first[j])
        plant_limit: float | None = (held - 1) * dt
    else:
        j = int(np.unravel_index(np.argmin(margin), margin.shape)[0])
        held, plant_limit = int(np.argmin(margin[j])), None
    drift = forces - forces[:, :1]
    k = int(starts[j])
    limit = max(dt, plant_limit) if plant_limit is not None else steps * dt
    return StallLimit(
        limit_s=limit, source="the plant", how=_how(plant_limit, limit, k * dt, forces[j, 0], u[k], held * dt, sigmas,
                                                     noise, horizon_s, reference_name),
        plant_limit_s=plant_limit, horizon_s=steps * dt, sigmas=sigmas, noise_N=noise, force_low_N=force_low_N,
        force_max_N=force_max_N, reference=reference_name, worst_t_s=k * dt, worst_force_N=float(forces[j, 0]),
        worst_held_V=float(u[k]), worst_margin_N=float(margin[j, 1:].min()),
        drift_up_N=float(max(0.0, drift.max())), drift_down_N=float(max(0.0, -drift.min())))


def _how(plant_limit: float | None, limit: float, t_s: float, force_N: float, held_V: float, at_s: float,
         sigmas: float, noise_N: float, horizon_s: float, reference_name: str) -> str:
    margin = f"{sigmas:g} x the sensor's {noise_N:.3g} N noise inside the force interlocks"
    if plant_limit is None:
        return (f"holding the command from every state of the nominal run of {reference_name}, the plant's force "
                f"stays {margin} for the whole {horizon_s:g} s examined; the limit is that horizon")
    return (f"holding {held_V:.4g} V from t = {t_s:.3f} s of the nominal run of {reference_name} (force "
            f"{force_N:.4g} N), the plant's force leaves {margin} after {at_s * 1e3:.1f} ms; the limit is "
            f"{limit * 1e3:.1f} ms")
