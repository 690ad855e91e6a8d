"""The tuning's tables of a study file: ``[tuning]`` (the PID tuning's specification) and ``[validation]``
(the Monte Carlo set and its limits), as frozen records with their keys as fields and their defaults
from :class:`~piezopreload.tuning.pid.TuningSpec` and :class:`~piezopreload.tuning.validate.Criteria`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

from piezopreload.core.config import Table
from piezopreload.core.errors import InputError
from piezopreload.models.controller import SCHEDULE_MAX
from piezopreload.tuning.ilc import METHODS
from piezopreload.tuning.pid import TuningSpec, scaled_references
from piezopreload.tuning.validate import Criteria

__all__ = ["TuningTable", "ValidationTable", "LearningTable", "CRITERIA_LIMITS"]

#: the [validation] keys that are :class:`Criteria`'s limits
CRITERIA_LIMITS = ("settling_max_s", "overshoot_max_N", "tracking_rms_max_N", "peak_voltage_max_V")


@dataclass(frozen=True)
class TuningTable(Table):
    """[tuning]: the PID tuning's specification (tuning.pid.TuningSpec)."""

    overshoot_margin_N: float = TuningSpec.overshoot_margin_N
    ms_max: float = TuningSpec.ms_max
    noise_gain_max_V_per_N: float = TuningSpec.noise_gain_max_V_per_N
    tune_setpoint_weight: bool = TuningSpec.tune_setpoint_weight
    step_N: tuple[float, float] | None = None            # (from, to); None: TuningSpec's (the paper's scale)
    trajectory_N: tuple[float, ...] | None = None        # rest level, then the levels; None: TuningSpec's
    schedule_levels: int = 0     # entries of a gain schedule on the preload level (tuning.schedule); 0: one set
    schedule_plants: int = 50    # Monte Carlo plants per level and set when choosing between schedule and robust set

    def spec(self, band_N: float, u_min_V: float, u_max_V: float) -> TuningSpec:
        """The tuning's specification for the study's error band and output range; a ValueError where it is not valid."""
        if self.schedule_levels != 0 and not 2 <= self.schedule_levels <= SCHEDULE_MAX:
            raise ValueError(f"schedule_levels must be 0 (one set) or 2..{SCHEDULE_MAX}, got {self.schedule_levels}")
        if not 1 <= self.schedule_plants <= 100_000:
            raise ValueError(f"schedule_plants must be in 1..100000, got {self.schedule_plants}")
        return TuningSpec(band_N=band_N, u_min_V=u_min_V, u_max_V=u_max_V, **scaled_references(self.step_N, self.trajectory_N),
                          **{k: (bool(x) if k == "tune_setpoint_weight" else float(x)) for k, x in asdict(self).items()
                             if k not in ("step_N", "trajectory_N", "schedule_levels", "schedule_plants")})


@dataclass(frozen=True)
class ValidationTable(Table):
    """[validation]: the Monte Carlo set (``seed`` None: the simulation's) and the limits every plant must meet."""

    plants: int = 200
    seed: int | None = None
    workers: int | None = None
    settling_max_s: float = Criteria.settling_max_s
    overshoot_max_N: float = Criteria.overshoot_max_N
    tracking_rms_max_N: float = Criteria.tracking_rms_max_N
    peak_voltage_max_V: float = Criteria.peak_voltage_max_V

    def checked(self, default_seed: int, fail: Callable[[str, str], InputError]) -> ValidationTable:
        """The table checked, its seed ``default_seed`` (the simulation's) where it gives none; ``fail(key, message)``
        makes the error naming the file and line."""
        if not 1 <= self.plants <= 100_000:
            raise fail("validation.plants", f"must be in 1..100000, got {self.plants}")
        if self.workers is not None and self.workers < 1:
            raise fail("validation.workers", f"must be >= 1, got {self.workers}")
        return self if self.seed is not None else ValidationTable(**{**asdict(self), "seed": default_seed})

    def criteria(self, band_N: float) -> Criteria:
        """The limits every plant must meet; a ValueError where they are not valid."""
        return Criteria(band_N=band_N, **{k: float(getattr(self, k)) for k in CRITERIA_LIMITS})


@dataclass(frozen=True)
class LearningTable(Table):
    """[learning]: learning control on the whole system's repeated schedule (the pipeline's learn stage, which runs
    where the study has this table and its plant is its design): at most ``iterations`` learning trials per pass of
    the schedule (fewer where more no longer pay), ``preview_s`` the preview (None:
    :func:`~piezopreload.tuning.preview.default_preview_s`, 0: none), ``method`` the law
    (:data:`~piezopreload.tuning.ilc.METHODS`: the norm-optimal law by default, ``p-type`` the model-free option)."""

    iterations: int = 6
    preview_s: float | None = None
    method: str = METHODS[0]

    def checked(self, fail: Callable[[str, str], InputError]) -> LearningTable:
        """The table checked; ``fail(key, message)`` makes the error naming the file and line."""
        if not 0 <= self.iterations <= 100:
            raise fail("learning.iterations", f"must be in 0..100, got {self.iterations}")
        if self.preview_s is not None and not (0.0 <= self.preview_s < float("inf")):
            raise fail("learning.preview_s", f"must be a finite number >= 0 (0: no preview), got {self.preview_s}")
        if self.method not in METHODS:
            raise fail("learning.method", f"must be one of {', '.join(METHODS)}, got {self.method!r}")
        return self
