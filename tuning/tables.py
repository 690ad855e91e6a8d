"""The tuning's tables of a study file: ``[tuning]`` read straight into
:class:`~piezopreload.tuning.pid.TuningSpec`, ``[validation]`` into
:class:`~piezopreload.artifacts.validation.Criteria` (each key declared once, on the type, with its range and
its rules), and ``[learning]``.
"""

from __future__ import annotations

from dataclasses import dataclass

from piezopreload.artifacts.learned import LearningMethod
from piezopreload.artifacts.validation import Criteria
from piezopreload.core.config import Table, key
from piezopreload.core.records import TableOf
from piezopreload.tuning.pid import TUNING_KEYS, TuningSpec

__all__ = ["TUNING", "VALIDATION", "LearningTable"]

#: [tuning]: the PID tuning's specification, the error band and the output range from [simulation] and [controller]
TUNING = TableOf(TuningSpec, "[tuning]: the PID tuning's specification (tuning/pid.py, ``TuningSpec``) and the gain "
                             "schedule's.", TUNING_KEYS)

#: [validation]: the Monte Carlo set and the limits every plant must meet, the error band from [simulation]
VALIDATION = TableOf(Criteria, "[validation]: the Monte Carlo set and the limits every plant must meet for the gain "
                               "set to be validated (artifacts/validation.py, ``Criteria``).",
                     ("plants", "seed", "workers", *Criteria.LIMITS))


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
    method: LearningMethod = key(LearningMethod.NORM_OPTIMAL, "the learning law: norm-optimal, or p-type (model-free)")
