"""The Monte Carlo verdict on a gain set: its gains, feedforward, plant, criteria and references, validated.

One body for both ways a gain set is judged: the tuned gains written as a candidate and
validated for the first time (``piezopreload tune``, the study's validate stage), and a gain
set validated again on a new Monte Carlo set (``piezopreload validate``). The gain set that
comes back is ``validated`` only if every Monte Carlo requirement of its study holds: every
plant met every criterion over the whole range and, for a gain schedule, at each preload level
(the tuning's Monte Carlo there, which chose the set); else ``candidate``. It carries those
requirements with their margins (``GainSet.requirements``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.tuning import GainScheduleRecord
from piezopreload.artifacts.validation import ValidationResult
from piezopreload.core.errors import InputError
from piezopreload.core.parallel import Pool
from piezopreload.core.progress import Bar
from piezopreload.tuning.schedule import level_requirements
from piezopreload.tuning.validate import SchedulerError, executor, validate

__all__ = ["validate_gain_set", "level_requirements_of"]


def validate_gain_set(gain_set: GainSet, *, n_plants: int, seed: int, workers: int = 1,
                      scheduler: str | None = None, pool: Pool | None = None,
                      bar: Bar | None = None,
                      inputs: dict[str, Any] | None = None) -> tuple[GainSet, ValidationResult]:
    """Validate ``gain_set`` on ``n_plants`` plants drawn around its plant (noise and draw ``seed``).

    The plants run on the Dask cluster at ``scheduler`` where given, else on ``pool`` (the run's worker
    processes) where given, else on ``workers`` local processes of this call's own.
    Returns the gain set with this validation, its status and ``inputs`` added (not yet
    saved: its ``content_sha256`` is None), and the per-plant result.
    """
    if n_plants < 1:
        raise InputError(f"n_plants: must be >= 1, got {n_plants}")
    if gain_set.plant is None:
        raise InputError("the gain set names no plant (field 'plant.rig'); write it again with 'piezopreload tune'")
    if gain_set.criteria is None:
        raise InputError("the gain set names no criteria (field 'criteria'); write it again with 'piezopreload tune'")
    criteria = gain_set.criteria
    step, trajectory = gain_set.reference("step"), gain_set.reference("trajectory")
    try:
        with executor(workers, scheduler, pool) as (run, pool_name):
            result = validate(gain_set.gains, gain_set.feedforward, gain_set.plant, criteria, n_plants=n_plants,
                              seed=seed, step=step, trajectory=trajectory, pool=run, pool_name=pool_name,
                              bar=bar)
    except SchedulerError as exc:
        raise InputError(f"--scheduler: {exc}") from None
    requirements = result.requirements + level_requirements_of(gain_set)
    met = result.passed and all(r.met for r in requirements)
    judged = replace(gain_set, status="validated" if met else "candidate", validation=result,
                     inputs={**gain_set.inputs, **(inputs or {}), "seed": seed}, requirements=requirements,
                     content_sha256=None)
    return judged, result


def level_requirements_of(gain_set: GainSet) -> tuple[Requirement, ...]:
    """A gain schedule's Monte Carlo requirements at each preload level, as its tuning judged the chosen set there
    (:func:`~piezopreload.tuning.schedule.level_requirements`); none where the tuning chose between no sets."""
    schedule = (gain_set.tuning or {}).get("schedule")
    if not isinstance(schedule, dict):
        return ()
    return level_requirements(GainScheduleRecord.from_dict(schedule, "the gain set's tuning", path="tuning.schedule"))
