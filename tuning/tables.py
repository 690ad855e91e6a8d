"""The tuning's tables of a study file: ``[tuning]`` (the PID tuning's specification), ``[validation]``
(the Monte Carlo set and its limits) and ``[learning]``, as frozen records whose fields declare their
keys (type, default, unit, range, doc: :func:`piezopreload.core.config.key`), with their defaults from
:class:`~piezopreload.tuning.pid.TuningSpec` and :class:`~piezopreload.tuning.validate.Criteria`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from piezopreload.artifacts.validation import Criteria
from piezopreload.core.config import Invalid, Table, key
from piezopreload.models.controller import SCHEDULE_MAX
from piezopreload.tuning.ilc import METHODS
from piezopreload.tuning.pid import TuningSpec, scaled_references

__all__ = ["TuningTable", "ValidationTable", "LearningTable", "CRITERIA_LIMITS"]

#: the [validation] keys that are :class:`Criteria`'s limits
CRITERIA_LIMITS = ("settling_max_s", "overshoot_max_N", "tracking_rms_max_N", "peak_voltage_max_V")


@dataclass(frozen=True)
class TuningTable(Table):
    """[tuning]: the PID tuning's specification (tuning/pid.py, ``TuningSpec``) and the gain schedule's."""

    overshoot_margin_N: float = key(TuningSpec.overshoot_margin_N, "the noise-free step stays this far inside the "
                                    "error band ([simulation] band_N, which it must be below)", unit="N", gt=0)
    ms_max: float = key(TuningSpec.ms_max, "largest maximum sensitivity over the plant variants", gt=1)
    noise_gain_max_V_per_N: float = key(TuningSpec.noise_gain_max_V_per_N, "the controller's largest gain at the "
                                        "Nyquist frequency (sensor noise into the command)", unit="V/N", gt=0)
    tune_setpoint_weight: bool = key(TuningSpec.tune_setpoint_weight, "tune the setpoint weight b too (false: "
                                     "[controller] b)")
    step_N: tuple[float, float] | None = key(None, "the tuning's step (from, to) (not set: the paper's 25 -> 60 N)",
                                             unit="N")
    trajectory_N: tuple[float, ...] | None = key(None, "the tuning's staircase: its rest level, then its levels (not "
                                                 "set: the paper's)", unit="N", min_length=2)
    schedule_levels: int = key(0, f"entries of a gain schedule on the preload level (0: one gain set; else "
                               f"2..{SCHEDULE_MAX})", ge=0, le=SCHEDULE_MAX)
    schedule_plants: int = key(50, "Monte Carlo plants per level and gain set when choosing between the schedule "
                               "and the robust set", ge=1, le=100_000)
    warm_start: str | None = key(None, "a tuning record or gain set (JSON, relative to the study file) whose gains the "
                                 "tuning starts from and keeps unless it finds better: a tighter problem's, the last "
                                 "run's (not set: the study's [controller] gains and SIMC's only)")

    def check(self) -> None:
        if self.schedule_levels == 1:
            raise Invalid("schedule_levels", f"must be 0 (one gain set) or 2..{SCHEDULE_MAX}, got 1")

    def spec(self, band_N: float, u_min_V: float, u_max_V: float) -> TuningSpec:
        """The tuning's specification for the study's error band and output range (both checked by the study)."""
        if not self.overshoot_margin_N < band_N:
            raise Invalid("overshoot_margin_N", f"must be below [simulation] band_N ({band_N:g} N), got "
                                                f"{self.overshoot_margin_N:g}")
        return TuningSpec(band_N=band_N, u_min_V=u_min_V, u_max_V=u_max_V,
                          **scaled_references(self.step_N, self.trajectory_N),
                          **{k: x for k, x in asdict(self).items()
                             if k not in ("step_N", "trajectory_N", "schedule_levels", "schedule_plants",
                                          "warm_start")})


@dataclass(frozen=True)
class ValidationTable(Table):
    """[validation]: the Monte Carlo set and the limits every plant must meet for the gain set to be validated."""

    plants: int = key(200, "Monte Carlo plants", ge=1, le=100_000)
    seed: int | None = key(None, "the Monte Carlo draw's seed (not set: [simulation] seed)", ge=0)
    workers: int | None = key(None, "local worker processes (not set: the CPU count)", ge=1)
    settling_max_s: float = key(Criteria.settling_max_s, "longest settling time of the true force into the band",
                                unit="s", gt=0)
    overshoot_max_N: float = key(Criteria.overshoot_max_N, "largest overshoot", unit="N", gt=0)
    tracking_rms_max_N: float = key(Criteria.tracking_rms_max_N, "largest RMS tracking error on the trajectory "
                                    "(outside 0.1 s after each jump and the saturated samples)", unit="N", gt=0)
    peak_voltage_max_V: float | None = key(None, "highest command voltage: the headroom the loop must keep below "
                                           "the clamp on its command, [controller] u_max_V, so it must be below it "
                                           "(not set: no such requirement; the clamp bounds the command)", unit="V",
                                           gt=0)

    def criteria(self, band_N: float) -> Criteria:
        """The limits every plant must meet, in the study's error band."""
        limits: dict[str, Any] = {k: None if getattr(self, k) is None else float(getattr(self, k))
                                  for k in CRITERIA_LIMITS}
        return Criteria(band_N=band_N, **limits)


@dataclass(frozen=True)
class LearningTable(Table):
    """[learning]: learning control over a repeated reference (``study.learn``'s defaults; on a study whose plant
    is its design, the pipeline's learn stage along the schedule, each margin pass learned): at most ``iterations``
    learning trials (fewer where more no longer pay), the norm-optimal law by default, ``p-type`` the model-free
    option."""

    iterations: int = key(6, "the most learning trials (per pass of the schedule); fewer where more no longer pay",
                          ge=0, le=100)
    preview_s: float | None = key(None, "how far the learning reads the reference ahead (not set: the delay, the "
                                  "amplifier's lag and the largest change's slew time; 0: no preview)", unit="s", ge=0)
    method: str = key(METHODS[0], "the learning law: norm-optimal, or p-type (model-free)", choices=METHODS)
