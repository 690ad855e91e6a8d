"""The verdicts under the modelling assumptions, as the system artifact records them (``system.json``'s
``sensitivity``).

:func:`piezopreload.design.sensitivity.sensitivity` computes it: the designed system as built (the design's
screw, the last pass's schedule and the preload the force loop achieved along it) judged again with one
modelling assumption at a time at the low and the high end of its stated range, every other at the study's
value. One :class:`SensitivityRow` per assumption and requirement it moves: the margin (in % of the limit) at
the study's value and at both ends, and the value at which the verdict flips (null where it does not flip
within the assumption's admissible domain). A verdict is robust only where it is the same at both ends of every
range; :attr:`SensitivityRecord.verdict_robust` holds for the whole run.
"""

from __future__ import annotations

from typing import Any

from piezopreload.core.records import Raw, Record, entry, record

__all__ = ["SensitivityRow", "SensitivityRecord"]


def _number(x: float) -> str:
    return f"{x:.3g}"


@record
class SensitivityRow(Record):
    """One assumption against one requirement: the margins at the study's value and at the range's ends, and where
    the verdict flips."""

    assumption: str = entry('The assumption, in words ("the screw\'s pretension").')
    key: str = entry('Its key: the study key it stands for ("thermal.pretension_K"), or the model\'s parameter.')
    unit: str = entry("The unit of ``low``, ``high``, ``nominal`` and ``flips_at``.")
    source: str = entry("Where the range comes from, in words.")
    requirement: str = entry("The requirement's key (``thermal.thermal_growth_max_um``).")
    requirement_name: str = entry("The requirement, in words.")
    nominal: float = entry("The study's value of the assumption.")
    low: float = entry("The range's low end.")
    high: float = entry("The range's high end.")
    margin_pct_nominal: float = entry("The requirement's margin at the study's value, in % of its limit.")
    margin_pct_low: float = entry("The margin at the low end, in % of the limit.")
    margin_pct_high: float = entry("The margin at the high end, in % of the limit.")
    domain: tuple[float, float] = entry("The assumption's admissible domain the flip is searched in.")
    flips_at: float | None = entry("The value at which the verdict flips (bisection within ``domain``); null: it "
                                   "does not flip there.", default=None, required=True)
    labels: tuple[str, ...] = entry("A two-valued assumption's values' names (low, high); empty: a number.",
                                    default=(), omit=True)

    def __post_init__(self) -> None:
        if not self.low <= self.high:
            raise ValueError(f"SensitivityRow '{self.key}': low must be <= high, got {self.low!r} > {self.high!r}")
        if self.labels and len(self.labels) != 2:
            raise ValueError(f"SensitivityRow '{self.key}': labels must name the low and the high value")

    @property
    def holds(self) -> bool:
        """Whether the verdict at the study's value is the verdict at both ends of the range (and no flip lies
        inside it)."""
        met = self.margin_pct_nominal >= 0
        inside = self.flips_at is not None and self.low < self.flips_at < self.high
        return (self.margin_pct_low >= 0) == met and (self.margin_pct_high >= 0) == met and not inside

    @property
    def swing_pct(self) -> float:
        """How far the range moves the margin: |high's - low's| (percentage points)."""
        return abs(self.margin_pct_high - self.margin_pct_low)

    def value_text(self, x: float) -> str:
        """``x`` in words: a two-valued assumption's name, else the number and its unit."""
        if self.labels:
            return self.labels[0] if x == self.low else self.labels[1]
        return f"{_number(x)} {self.unit}".rstrip()

    def flip_sentence(self) -> str:
        """Where the verdict flips, in words (for a row that does not hold): the assumption, the end of its range
        that flips it (its margin there) and the value it flips at."""
        met = self.margin_pct_nominal >= 0
        end = self.low if (self.margin_pct_low >= 0) != met else self.high
        pct = self.margin_pct_low if end == self.low else self.margin_pct_high
        at = "" if self.flips_at is None or self.labels else f", flips at {self.value_text(self.flips_at)}"
        return f"{self.assumption} {self.value_text(end)} ({'missed' if met else 'met'}, {pct:+.1f} %{at})"


@record
class SensitivityRecord(Record):
    """The sensitivity study of a system run: one row per assumption and requirement it moves, and the requirements
    no assumption moves."""

    rows: tuple[SensitivityRow, ...] = entry("One row per assumption and requirement it moves.")
    unmoved: tuple[str, ...] = entry("The requirements judged again that no assumption of the study moves (their "
                                     "names).", default=())
    not_judged: tuple[str, ...] = entry("The run's requirements the study does not judge again (their names): they "
                                        "rest on other runs (the Monte Carlo plants).", default=())

    @property
    def assumptions(self) -> tuple[str, ...]:
        """The assumptions' keys, in the study's order."""
        return tuple(dict.fromkeys(r.key for r in self.rows))

    @property
    def requirements(self) -> tuple[str, ...]:
        """The requirements' keys the rows judge, in order."""
        return tuple(dict.fromkeys(r.requirement for r in self.rows))

    @property
    def verdict_robust(self) -> bool:
        """Whether every verdict holds over every assumption's range."""
        return all(r.holds for r in self.rows)

    def flipping(self) -> tuple[SensitivityRow, ...]:
        """The rows whose verdict does not hold over the range, the largest swing first."""
        return tuple(sorted((r for r in self.rows if not r.holds), key=lambda r: -r.swing_pct))

    def least(self) -> SensitivityRow | None:
        """The row with the least margin at an end of its range (None: no rows)."""
        return min(self.rows, key=lambda r: min(r.margin_pct_low, r.margin_pct_high), default=None)

    def sentence(self) -> str:
        """The robustness in one line: robust over how many assumptions, or what flips which verdict."""
        n = len(self.assumptions)
        flips = self.flipping()
        if not flips:
            least = self.least()
            tail = "" if least is None else (
                f"; least margin at a range's end {min(least.margin_pct_low, least.margin_pct_high):.1f} % "
                f"({least.requirement_name}, {least.assumption})")
            return f"verdict robust over {n} assumptions' ranges{tail}"
        by: dict[str, list[SensitivityRow]] = {}
        for r in flips:
            by.setdefault(r.requirement_name, []).append(r)
        return f"verdict not robust over {n} assumptions' ranges: " + "; ".join(
            f"{name} flips with " + ", ".join(r.flip_sentence() for r in rows) for name, rows in by.items())

    def to_dict(self) -> dict[str, Any]:
        """The fields and the verdict they give (``verdict_robust``).

        Returns
        -------
        dict
            The record's object.
        """
        return {**super().to_dict(), "verdict_robust": self.verdict_robust}

    def _check_document(self, raw: Raw) -> None:
        if raw.get("verdict_robust") is not self.verdict_robust:
            raise raw.fail("verdict_robust", "does not agree with its 'rows'")
