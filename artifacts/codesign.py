"""The co-design artifact (kind ``codesign``): the sequential and the co-designed answer, and their two fronts.

:func:`piezopreload.codesign.codesign_fronts` computes it where a study's design step is the co-design
(``[design] method = "codesign"``; the design stage writes ``design/codesign.json``) and the benchmark prints it;
the report's co-design section reads it. Each front is a sweep of design-and-controller pairs, every one tuned at
the study's Ms limit, in thermal growth over the shift (the design's duty-cycle estimate) against the nominal
tracking RMS along the preload schedule (the machining cycle's reference the loop follows):

* the **sequential** front: the design NLP alone trading its objective for heat (its ``stiffness:growth`` front,
  swept over the least rigidity), each point then tuned;
* the **co-designed** front: the co-design swept over its objective's weight (the growth's share against the
  tracking's), each weight's answer.

:meth:`CodesignRecord.front_dominates` judges the fronts as computed: every sequential point at the study's Ms is
weakly dominated (no worse in growth and in tracking, within a relative tolerance) by a co-designed one.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from piezopreload.artifacts.requirements import Sense
from piezopreload.core.records import Record, SavedArtifact, entry, hold_members, record

__all__ = ["FrontPoint", "RequirementRow", "CodesignRecord", "KIND", "FRONT_RTOL", "nondominated"]

KIND = "codesign"
#: the relative tolerance of the fronts' comparison: the tuning's own (IPOPT's 1e-8 on the scaled gains leaves the
#: tracking RMS reproducible to about 1e-4 between warm starts), so two answers equal within it are not ranked
FRONT_RTOL = 1e-3


@record
class FrontPoint(Record):
    """One design-and-controller pair of a front: what was swept to reach it, and what it achieves."""

    label: str = entry('What the sweep set ("rigidity at least 1,293 N/um", "growth weight 0.5").')
    swept: float = entry("The swept value (the least rigidity in N/um, or the growth's weight).")
    growth_um: float = entry("The screw's largest thermal growth over the shift, the design's duty-cycle estimate.",
                             unit="um")
    tracking_rms_N: float = entry("The nominal plant's RMS tracking error along the preload schedule.", unit="N")
    ms: float = entry("The tuned loop's largest sensitivity peak over the tuning's variants and slopes.")
    peak_voltage_V: float = entry("The stacks' peak command over the step and the staircase.", unit="V")
    stiffness_N_per_um: float = entry("The design's least rigidity over the duty.", unit="N/um")
    contact_angle_deg: float = entry("The design's contact angle.", unit="deg")
    feasible: bool = entry("Whether the pair meets the co-design's constraints (the staircase's tracking RMS, the "
                           "settling, the schedule's requirements along the cycle).")
    settling_s: float | None = entry("The nominal step's settling time (null: it never settled).", unit="s",
                                     default=None, required=True)
    why: str = entry("What it misses (empty where feasible).", default="")

    def at(self) -> tuple[float, float]:
        """``(growth_um, tracking_rms_N)``: where it sits on the fronts' plane.

        Returns
        -------
        tuple of float
            The growth and the tracking RMS.
        """
        return self.growth_um, self.tracking_rms_N


@record
class RequirementRow(Record):
    """One requirement, the sequential answer's and the co-designed answer's figure in its unit."""

    requirement: str = entry("The requirement, in words.")
    unit: str = entry("Its unit (empty: a ratio).")
    kind: Sense = entry("``min`` (at least the limit) or ``max`` (at most).")
    sequential: float = entry("The sequential answer's figure.")
    codesigned: float = entry("The co-designed answer's figure.")
    limit: float | None = entry("Its limit (null: none; the figure is shown, not judged).", default=None,
                                required=True)

    def __post_init__(self) -> None:
        hold_members(self)

    def met(self, which: str) -> bool | None:
        """Whether ``which`` (``sequential`` or ``codesigned``) meets the limit (None: no limit).

        Parameters
        ----------
        which : str
            ``"sequential"`` or ``"codesigned"``.

        Returns
        -------
        bool or None
            The verdict.
        """
        if self.limit is None:
            return None
        x = float(getattr(self, which))
        return self.kind.meets(x, self.limit)


def _dominates(a: FrontPoint, b: FrontPoint, rtol: float) -> bool:
    """``a`` no worse than ``b`` in growth and in tracking, within ``rtol``."""
    return a.growth_um <= b.growth_um * (1.0 + rtol) and a.tracking_rms_N <= b.tracking_rms_N * (1.0 + rtol)


def nondominated(points: tuple[FrontPoint, ...] | list[FrontPoint], rtol: float = FRONT_RTOL) -> list[FrontPoint]:
    """The feasible points no other feasible point dominates (no worse in both, better in one beyond ``rtol``),
    by growth; points equal within ``rtol`` are kept once.

    Parameters
    ----------
    points : sequence of FrontPoint
        The sweep's points.
    rtol : float
        The relative tolerance.

    Returns
    -------
    list of FrontPoint
        The front, by increasing growth.
    """
    pool = sorted((p for p in points if p.feasible), key=lambda p: (p.growth_um, p.tracking_rms_N))
    out: list[FrontPoint] = []
    for p in pool:
        if not any(_dominates(q, p, rtol) for q in out):
            out.append(p)
    return out


@record
class CodesignRecord(SavedArtifact):
    """The co-design of a study beside its sequential answer: the two answers requirement by requirement, what
    changed, and the two fronts of thermal growth against tracking RMS at the study's Ms."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the co-design"
    AGAIN: ClassVar[str] = "run the design stage again"

    study: str = entry("The study's name.")
    strategy: str = entry("How the co-design was solved.", choices=("nested", "simultaneous"))
    strategy_why: str = entry("Why that strategy, in words.")
    weights: dict[str, float] = entry("The objective's weights by term (growth, friction, tracking, voltage).")
    ms_max: float = entry("The study's Ms limit every pair is tuned under ([tuning] ms_max).")
    objective_ratio: float = entry("The co-designed answer's weighted objective over the sequential one's.")
    changed: tuple[str, ...] = entry("What the co-design changed in the design, in the design's units.")
    coupling: str = entry("Which coupling bought the difference, in words.")
    controller: str = entry("What the co-design chose of the controller, in words.")
    requirements: tuple[RequirementRow, ...] = entry("Each requirement, sequential against co-designed.")
    plants: int = entry("The Monte Carlo plants each answer was validated on (0: none).", ge=0)
    sequential_front: tuple[FrontPoint, ...] = entry("The sequential front's sweep (the design alone, then tuned).")
    codesigned_front: tuple[FrontPoint, ...] = entry("The co-designed front's sweep (the co-design per weight).")
    passed_sequential: bool | None = entry("Whether every Monte Carlo plant met every limit with the sequential "
                                           "answer (null: not run).", default=None, required=True)
    passed_codesigned: bool | None = entry("The same for the co-designed answer.", default=None, required=True)
    inputs: dict[str, Any] = entry("The hashes it came from.", default={}, required=True)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.ms_max) and self.ms_max > 1.0):
            raise ValueError(f"CodesignRecord.ms_max must be a finite number > 1, got {self.ms_max!r}")

    def at_ms(self, points: tuple[FrontPoint, ...], rtol: float = FRONT_RTOL) -> list[FrontPoint]:
        """The feasible points tuned at the study's Ms (their Ms at most ``ms_max`` within ``rtol``).

        Parameters
        ----------
        points : tuple of FrontPoint
            A front's sweep.
        rtol : float
            The relative tolerance on the Ms limit.

        Returns
        -------
        list of FrontPoint
            Those points.
        """
        return [p for p in points if p.feasible and p.ms <= self.ms_max * (1.0 + rtol)]

    def front_dominates(self, rtol: float = FRONT_RTOL) -> bool:
        """Whether the co-designed front is nowhere worse than the sequential one at the same Ms: every feasible
        sequential point at the study's Ms is weakly dominated by a co-designed point at it (no worse in growth and
        in tracking, within ``rtol``). False where the co-designed front has no such point.

        Parameters
        ----------
        rtol : float
            The relative tolerance.

        Returns
        -------
        bool
            The verdict.
        """
        co = self.at_ms(self.codesigned_front, rtol)
        return bool(co) and all(any(_dominates(q, p, rtol) for q in co)
                                for p in self.at_ms(self.sequential_front, rtol))

    def strictly_dominated(self, rtol: float = FRONT_RTOL) -> int:
        """How many sequential points a co-designed point beats in both growth and tracking by more than ``rtol``.

        Parameters
        ----------
        rtol : float
            The relative tolerance.

        Returns
        -------
        int
            The count.
        """
        co = self.at_ms(self.codesigned_front, rtol)
        return sum(any(q.growth_um < p.growth_um * (1 - rtol) and q.tracking_rms_N < p.tracking_rms_N * (1 - rtol)
                       for q in co) for p in self.at_ms(self.sequential_front, rtol))
