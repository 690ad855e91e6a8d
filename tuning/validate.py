"""Validation of candidate gains on the nonlinear rig simulation, by Monte Carlo.

The gains and the identified feedforward run on a batch of plants drawn around the nominal
rig (:meth:`Plant.vary`), each with the truth hysteresis, creep, sensor noise,
quantisation, the amplifier's limits and the controller's clamp, over the step and the
trajectory. A gain set passes only if every plant meets every criterion.

The criteria and the result are one type each, on the artifacts floor
(:class:`~piezopreload.artifacts.validation.Criteria`,
:class:`~piezopreload.artifacts.validation.ValidationResult`): the gain set carries the result
and ``validation.json`` holds it.

The batch is cut into chunks run on a ``concurrent.futures``-style executor: inline for one
worker, local processes (:class:`~concurrent.futures.ProcessPoolExecutor`) by default, or a
Dask cluster's executor when a scheduler address is given. Each chunk has its own noise seed
derived from the run's seed and the chunk's index, so the results do not depend on the
executor or the number of workers.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from piezopreload.artifacts.validation import METRICS, Criteria, ValidationResult
from piezopreload.core.errors import InputError, PiezopreloadError
from piezopreload.core.parallel import Pool
from piezopreload.core.progress import Bar
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, inverse_at
from piezopreload.models.metrics import Signal

__all__ = ["DEFAULT_SPREAD", "evaluate", "validate", "executor", "SchedulerError"]

#: Relative standard deviations of the Monte Carlo plants (normal, truncated at 2 sigma): the
#: 2-sigma extremes sit inside the corners the tuning is robust to (tuning.pid.TuningSpec).
DEFAULT_SPREAD: dict[str, float] = {
    "coupling_stiffness_N_per_um": 0.075,
    "amp_bandwidth_Hz": 0.1,
    "amp_current_limit_A": 0.1,
    "bw_alpha": 0.1,
    "bw_beta_per_V": 0.1,
    "bw_kappa": 0.1,
    "creep_per_decade": 0.15,
    "noise_N": 0.1,
}

class SchedulerError(PiezopreloadError, RuntimeError):
    """The Dask scheduler cannot be used (not installed, or not reachable)."""


@dataclass(frozen=True)
class _Chunk:
    gains: PIDGains
    feedforward: HysteresisModel | CreepPI | None
    plants: Plant
    step: Reference
    trajectory: Reference
    criteria: Criteria
    seed: int


def evaluate(gains: PIDGains, feedforward: HysteresisModel | CreepPI | None, plants: Plant, step_ref: Reference,
             trajectory: Reference, criteria: Criteria, seed: int) -> dict[str, np.ndarray]:
    """The metrics the criteria judge, per plant: the step (noise ``seed``) and the trajectory (``seed + 1``).

    ``plants`` is one plant or a batch; every value is an array over the plants.
    """
    rig = Rig(plants)
    inverse = inverse_at(feedforward, rig.dt_s) if feedforward is not None else None
    controller = Controller(gains, rig.dt_s, inverse)
    step = simulate(rig, controller, step_ref, seed=seed)
    band, signal = criteria.band_N, criteria.signal
    by_signal = {}
    for name in Signal:
        m = step.step_metrics(band, signal=name)
        by_signal[name] = m if isinstance(m, list) else [m]
    ms, mt, mm = by_signal[signal], by_signal[Signal.FORCE], by_signal[Signal.MEASURED]
    traj = simulate(rig, controller, trajectory, seed=seed + 1)
    te = traj.tracking_error()
    te_after = traj.tracking_error(after_change_s=criteria.tracking_after_change_s,
                                   u_range=(gains.u_min_V, gains.u_max_V))
    peak = np.maximum(np.max(step.command_V, axis=-1), np.max(traj.command_V, axis=-1))
    return {
        "rise_s": np.array([m.rise_s for m in ms], float),
        "settling_s": np.array([m.settling_s for m in ms], float),
        "settling_measured_s": np.array([m.settling_s for m in mm], float),
        "overshoot_N": np.array([max(m.overshoot, 0.0) for m in mt], float),
        "tracking_rms_N": np.atleast_1d(np.asarray(te_after.rms_N, float)),
        "saturated_fraction": np.atleast_1d(np.asarray(te_after.saturated_fraction, float)),
        "tracking_rms_all_N": np.atleast_1d(np.asarray(te.rms_N, float)),
        "tracking_max_N": np.atleast_1d(np.asarray(te.max_N, float)),
        "peak_voltage_V": np.atleast_1d(peak),
    }


def run_chunk(chunk: _Chunk) -> dict[str, np.ndarray]:
    """Simulate one chunk of plants (a batch): :func:`evaluate` on the chunk's data."""
    return evaluate(chunk.gains, chunk.feedforward, chunk.plants, chunk.step, chunk.trajectory, chunk.criteria,
                    chunk.seed)


@contextlib.contextmanager
def executor(workers: int = 1, scheduler: str | None = None,
             pool: Pool | None = None) -> Iterator[tuple[cf.Executor, str]]:
    """A ``concurrent.futures`` executor and its description.

    ``scheduler`` (``tcp://HOST:PORT``) uses a Dask distributed cluster (the optional ``dask``
    extra); else ``pool``, the run's worker processes, where given (left open: the run shuts it);
    else a :class:`~piezopreload.core.parallel.Pool` of ``workers`` local processes for this
    block alone (1 runs inline).
    """
    if scheduler is not None:
        try:
            from distributed import Client
        except ImportError:
            raise SchedulerError(
                "--scheduler needs Dask distributed: pip install 'piezopreload[dask]'"
            ) from None
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client.get_executor(), f"dask {scheduler}"
        finally:
            client.close()
        return
    if pool is not None:
        yield pool, pool.description
        return
    with Pool(workers) as own:
        yield own, own.description


def validate(
    gains: PIDGains,
    feedforward: HysteresisModel | CreepPI | None,
    plant: Plant,
    criteria: Criteria | None = None,
    *,
    n_plants: int = 200,
    spread: dict[str, float] | None = None,
    seed: int = 0,
    step: Reference | None = None,
    trajectory: Reference | None = None,
    chunk_size: int = 50,
    pool: cf.Executor | None = None,
    pool_name: str = "inline",
    bar: Bar | None = None,
) -> ValidationResult:
    """Run the gains on ``n_plants`` plants around ``plant``; see the module docstring.

    ``feedforward`` is the forward P-I model the controller inverts (None: PID alone). The
    first plant is the nominal one; the others are drawn with ``spread`` (relative standard
    deviations, :data:`DEFAULT_SPREAD` by default).
    """
    if n_plants < 1 or chunk_size < 1:
        raise ValueError("n_plants and chunk_size must be >= 1.")
    if plant.batch_shape:
        raise ValueError("validate takes one nominal plant; the batch is drawn from it.")
    spread = dict(DEFAULT_SPREAD if spread is None else spread)
    criteria = criteria or Criteria()
    if criteria.peak_voltage_max_V is not None and criteria.peak_voltage_max_V >= gains.u_max_V:
        raise InputError(f"criteria.peak_voltage_max_V = {criteria.peak_voltage_max_V:g} V is at or above the clamp on "
                         f"the command, gains.u_max_V = {gains.u_max_V:g} V: the highest command cannot exceed it, so "
                         "the requirement could not fail; set it below the clamp (the headroom the loop keeps), or "
                         "None for no such requirement")
    step = step or Reference.step(25.0, 60.0, 0.5, 3.0)
    trajectory = trajectory or Reference.staircase(25.0, [60.0, 80.0, 100.0, 80.0, 60.0], 2.0, t_start_s=0.5)
    t0 = time.perf_counter()
    drawn = plant.vary(n_plants, spread, seed=seed)
    # the nominal plant first: a validation set must contain the plant the gains were tuned on
    batch_fields: dict[str, Any] = {n: np.asarray(getattr(drawn, n), float).copy() for n in spread}
    for n in batch_fields:
        batch_fields[n][0] = float(getattr(plant, n))
    plants = replace(drawn, **batch_fields)
    chunks = []
    for c, start in enumerate(range(0, n_plants, chunk_size)):
        sub = plants.take(slice(start, min(start + chunk_size, n_plants)))
        chunks.append(_Chunk(gains, feedforward, sub, step, trajectory, criteria, seed * 1000 + 2 * c))
    run = pool or Pool(1)
    futures = [run.submit(run_chunk, ch) for ch in chunks]
    results = []
    for i, fut in enumerate(futures):
        results.append(fut.result())
        if bar is not None:
            bar(i + 1, len(futures))
    metrics = {k: np.concatenate([r[k] for r in results]) for k in METRICS}
    return ValidationResult(metrics=metrics, criteria=criteria, n_plants=n_plants, seed=seed, spread=spread,
                            seconds=time.perf_counter() - t0, workers=pool_name)
