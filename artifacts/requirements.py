"""A study's requirements as verdicts: what was required, what was achieved, and by how much it is met or missed.

A :class:`Requirement` is one limit a study sets (the least rigidity while cutting, the largest
deflection, the validation's limits, ...) beside the value its run achieved. The floor that
checks a requirement builds it; the artifacts that record it hold a tuple of them; ``run``
prints the missed ones and exits with :data:`EXIT_REQUIREMENT_MISSED` when any is.

>>> r = Requirement("rigidity while cutting", 761.0, 1000.0, "N/um", "min", "[schedule] stiffness_min_N_per_um")
>>> r.met, round(r.margin, 1)
(False, -239.0)
>>> r.sentence()
'rigidity while cutting: 761 N/um against at least 1,000 N/um ([schedule] stiffness_min_N_per_um), missed by 239 N/um (23.9 %)'
>>> r.key, round(r.margin_pct, 1)
('schedule.stiffness_min_N_per_um', -23.9)
"""  # noqa: E501 (a doctest's expected output is one line)

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from enum import StrEnum
from typing import Any, ClassVar

from piezopreload.core.errors import ArtifactError
from piezopreload.core.quantities import number
from piezopreload.core.records import Record, entry, hold_members, record

__all__ = ["Sense", "Requirement", "AtBound", "OffBounds", "BASES", "EXIT_REQUIREMENT_MISSED",
           "requirements_from_dict", "missed", "least_margin", "own_constraints", "unaccepted"]

#: the exit code of a study that ran but missed a requirement (0 done, 1 internal, 2 bad input, 3 rig stopped)
EXIT_REQUIREMENT_MISSED = 4

class Sense(StrEnum):
    """Which side of its limit a requirement's value must lie: at least the limit (``min``), or at most (``max``)."""

    AT_LEAST = "min"
    AT_MOST = "max"

    @property
    def words(self) -> str:
        """``at least`` or ``at most``, as a verdict says it."""
        return "at least" if self is Sense.AT_LEAST else "at most"

    @property
    def symbol(self) -> str:
        """``>=`` or ``<=``."""
        return ">=" if self is Sense.AT_LEAST else "<="

    @property
    def sign(self) -> str:
        """``≥`` or ``≤``, as a table prints it."""
        return "≥" if self is Sense.AT_LEAST else "≤"

    def margin(self, value: float, limit: float) -> float:
        """How far ``value`` lies inside ``limit``, in their unit: >= 0 met, < 0 missed by that much.

        Parameters
        ----------
        value : float
            What was achieved.
        limit : float
            The required bound.

        Returns
        -------
        float
            ``value - limit`` at least the limit, ``limit - value`` at most.
        """
        return value - limit if self is Sense.AT_LEAST else limit - value

    def meets(self, value: float, limit: float) -> bool:
        """Whether ``value`` lies on the required side of ``limit`` (the limit itself included).

        Parameters
        ----------
        value : float
            What was achieved.
        limit : float
            The required bound.

        Returns
        -------
        bool
            The verdict: its :meth:`margin` is zero or more.
        """
        return bool(self.margin(value, limit) >= 0.0)


#: what a requirement rests on: ``design`` the design's own constraint (the design is built to sit on it: its margin
#: is the loop's error, not physics), ``physics`` what the physics grants
BASES = ("design", "physics")


@record
class AtBound(Record):
    """A design variable the optimum left at a bound of its range: its study key, its value and which bound, and the
    value the requirement was judged at without it (the range's middle)."""

    key: str = entry('The variable\'s study key ("ballscrew.contact_angle_deg").')
    value: float = entry("The design's value, at the bound.")
    bound: str = entry("``low`` or ``high``.", choices=("low", "high"))
    instead: float = entry("The value the requirement was judged at without the bound (its range's middle).")


@record
class OffBounds(Record):
    """A requirement judged again with the design's variables moved off their bounds (each continuous one at a bound
    to its range's middle, the balls and turns kept): the variables at their bounds, the value and margin it would
    have without them."""

    at_bounds: tuple[AtBound, ...] = entry("The design variables at a bound of their range.")
    value: float = entry("The value without them (the variables at their ranges' middles), in the requirement's unit.")
    margin_pct: float | None = entry("The margin without them, in % of the limit (negative: a miss).", unit="%")
    met: bool = entry("Whether the requirement holds without them.")


@record
class Requirement(Record):
    """One requirement and what was achieved."""

    NOUN: ClassVar[str] = "the requirement"

    name: str = entry('What is required, in words ("rigidity while cutting").')
    value: float = entry("What the run achieved (the worst case over the run), in ``unit``.")
    limit: float = entry("The required bound, in ``unit``.")
    unit: str = entry('The unit of ``value`` and ``limit`` ("N/um").')
    sense: Sense = entry("``min``: the value must be at least the limit; ``max``: at most.")
    source: str = entry('Where the limit is set ("[schedule] stiffness_min_N_per_um").', default="")
    key: str = entry("A short name a user gives to accept a missed requirement (``validation.overshoot_max_N@2000N``); "
                     "where not given, the source's table and key (``schedule.stiffness_min_N_per_um``), else the "
                     "name's words.", default="")
    basis: str | None = entry("What the requirement rests on: ``design`` (the design's own constraint, which the "
                              "design is built to sit on), ``physics`` (what the physics grants); None where it is "
                              "simply the study's limit.", choices=BASES, default=None, omit=True)
    off_bounds: OffBounds | None = entry("Where the design left variables at their bounds: the requirement judged "
                                         "without them.", default=None, omit=True)

    def __post_init__(self) -> None:
        if not self.key:  # the source's table and key: "[schedule] deflection_max_um" -> "schedule.deflection_max_um"
            match = re.match(r"\[([\w.]+)\]\s+(\w+)", self.source)
            object.__setattr__(self, "key", f"{match.group(1)}.{match.group(2)}" if match
                               else re.sub(r"\W+", "_", self.name).strip("_"))
        hold_members(self)
        for label in ("value", "limit"):
            if not math.isfinite(getattr(self, label)):
                raise ValueError(f"Requirement '{self.name}': {label} must be finite, got {getattr(self, label)!r}")

    @property
    def margin(self) -> float:
        """How far the value is inside the limit, in its unit: >= 0 met, < 0 missed by that much."""
        return self.sense.margin(self.value, self.limit)

    @property
    def margin_pct(self) -> float | None:
        """The margin as a share of the limit, in %: a verdict met by 0.5 % is missed on the next machine, one met
        by 20 % holds. None where the limit is 0."""
        return None if self.limit == 0 else 100.0 * self.margin / abs(self.limit)


    @property
    def met(self) -> bool:
        """Whether the requirement is met: its :attr:`margin` is zero or more."""
        return self.margin >= 0.0

    def sentence(self, source: bool = True) -> str:
        """The verdict in words: achieved against required, and the margin, each figure by the one rule of its
        unit (:func:`~piezopreload.core.quantities.number`); ``source=False`` leaves out the key that sets it.

        Parameters
        ----------
        source : bool
            Whether to name the study key that sets the limit, in parentheses.

        Returns
        -------
        str
            ``NAME: VALUE UNIT against at least|at most LIMIT UNIT (SOURCE), met with M UNIT to spare (P %)``, or
            ``missed by M UNIT`` where the margin is negative.
        """
        bound = self.sense.words
        where = f" ({self.source})" if self.source and source else ""
        u = self.unit
        head = f"{self.name}: {number(self.value, u)} {u} against {bound} {number(self.limit, u)} {u}{where}"
        pct = "" if self.margin_pct is None else f" ({number(abs(self.margin_pct), '%')} %)"
        if self.met:
            return f"{head}, met with {number(self.margin, u)} {u} to spare{pct}"
        return f"{head}, missed by {number(-self.margin, u)} {u}{pct}"

    def figures(self) -> str:
        """Achieved against required in symbols, each figure by its unit's rule: ``1,126 N/um >= 800 N/um``.

        Returns
        -------
        str
            The achieved value, ``>=`` or ``<=`` by :attr:`sense`, and the limit, each with its unit.
        """
        u = self.unit
        return f"{number(self.value, u)} {u} {self.sense.symbol} {number(self.limit, u)} {u}"

    def line(self, label: str = "", width: int = 0) -> str:
        """One line of a table of verdicts: ``met``/``MISSED``, the margin as a share of the limit, the figures
        (padded to ``width``) and ``label`` (default: the name).

        Parameters
        ----------
        label : str
            The line's label ("": the requirement's :attr:`name`).
        width : int
            The width the figures are padded to, in characters, so that a table's labels align (0: unpadded).

        Returns
        -------
        str
            ``met`` or ``MISSED``, the signed margin in % of the limit, the figures (:meth:`figures`) and the label.
        """
        share = "" if self.margin_pct is None else f"{'+' if self.margin_pct >= 0 else '-'}" \
                                                   f"{number(abs(self.margin_pct), '%')} %"
        return f"{'met   ' if self.met else 'MISSED'} {share:>8s}  {self.figures():{width}s}  {label or self.name}"

    def to_dict(self) -> dict[str, Any]:
        """The fields, and the verdict they give (``met``, ``margin``, ``margin_pct``), as an artifact holds them.

        Returns
        -------
        dict
            The requirement's object.
        """
        return {**super().to_dict(), "met": self.met, "margin": self.margin, "margin_pct": self.margin_pct}


def requirements_from_dict(docs: Any, where: str = "requirements") -> tuple[Requirement, ...]:
    """The requirements of a list of their objects (a stage's summary in a run's manifest).

    Parameters
    ----------
    docs : list of dict
        The requirements' objects.
    where : str
        What the messages call the list.

    Returns
    -------
    tuple of Requirement
        One per object, in order.

    Raises
    ------
    ArtifactError
        Naming the entry and its field that is missing or wrong.
    """
    if not isinstance(docs, list):
        raise ArtifactError(f"{where} must be a list of requirements, got {type(docs).__name__}")
    return tuple(Requirement.from_dict(d, f"{where}[{i}]") for i, d in enumerate(docs))


def missed(requirements: Iterable[Requirement]) -> tuple[Requirement, ...]:
    """The requirements not met, in their order."""
    return tuple(r for r in requirements if not r.met)


def least_margin(requirements: Iterable[Requirement]) -> Requirement | None:
    """The requirement with the least margin as a share of its limit (the one nearest to being missed), or None.

    The design's own constraints (``basis == "design"``: a bound the design is built to sit on, so its margin is
    small by construction and says nothing of what the physics grants) are left aside where any other requirement
    has a margin; :func:`own_constraints` lists them."""
    rs = [r for r in requirements if r.margin_pct is not None]
    granted = [r for r in rs if r.basis != "design"] or rs
    return min(granted, key=lambda r: r.margin_pct or 0.0) if granted else None


def own_constraints(requirements: Iterable[Requirement]) -> tuple[Requirement, ...]:
    """The design's own constraints among ``requirements`` (``basis == "design"``), in order."""
    return tuple(r for r in requirements if r.basis == "design")


def unaccepted(missed_ones: Iterable[Requirement], accepted: Iterable[str]) -> tuple[Requirement, ...]:
    """The missed requirements a user has not accepted by name (:attr:`Requirement.key`)."""
    names = set(accepted)
    return tuple(r for r in missed_ones if r.key not in names)
