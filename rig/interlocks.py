"""The interlocks, specified once: a table of tests on what a cycle measures, run by both rig loops.

A cycle of the rig's loop measures four quantities (:data:`QUANTITIES`): the force it read,
the age of that sample, how long the output has been held since the last write, and the
controller's command. Each row of :data:`INTERLOCKS` names a trip cause, the stage of the
cycle where it is tested (``reading``: after the read, before the controller runs;
``command``: after the controller, before the write), the quantity, the test
(:data:`TESTS`) and the :class:`Safety` limits it compares against. The rows are tested in
their order and the first that holds stops the run.

:func:`rows` turns the table and a :class:`Safety` into plain number rows. The Python loop
tests them with :func:`first_trip`; the native loop (``native_loop.c``) receives the same rows
and tests them with its own five-case switch; the codes of the stages, quantities, tests and
causes are written into the C source as ``#define`` lines from this module
(:func:`c_defines`), so neither loop names a limit, an order or a cause of its own. The words
of a trip (:func:`trip_detail`) come from the row too, for both loops.

Two causes are not tests on a quantity: ``signal`` (SIGINT, SIGTERM or :meth:`Executor.stop`)
and ``exception`` (anything the backend or the step raised). They follow the table's causes in
:data:`TRIP_CAUSES`.

The ``stall`` row is the missed-deadline interlock: it trips when the output has been held
longer than ``stall_limit_s``, which the session derives from the plant
(:mod:`piezopreload.rig.stall`). A shorter hold longer than :data:`STALL_REPORT_PERIODS`
periods (an update missed) is a *stall*: counted, logged and reported, not tripped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from piezopreload.artifacts.rigrun import Safety

__all__ = ["Safety", "Interlock", "INTERLOCKS", "TRIP_CAUSES", "QUANTITIES", "TESTS", "STAGES", "Trip", "Row", "rows",
           "first_trip", "trip_detail", "c_defines", "STALL_REPORT_PERIODS", "cause_code"]

#: what a cycle measures, in the order of the quantity vector both loops fill
QUANTITIES = ("force_N", "sample_age_s", "held_s", "command_V")
#: the tests a row may make: NaN; above its limit; below it; outside the open interval (lo, hi); not finite
TESTS = ("nan", "above", "below", "outside", "not_finite")
#: where in the cycle a row is tested
STAGES = ("reading", "command")
#: a hold longer than this many periods is a stall (an update missed): counted and logged
STALL_REPORT_PERIODS = 2.0


@dataclass(frozen=True)
class Interlock:
    """One row of the table: ``cause`` trips when ``test`` holds for ``quantity`` at ``stage``.

    ``limits`` names the :class:`Safety` attributes compared against (one for ``above`` and
    ``below``, two for ``outside``, none for ``nan`` and ``not_finite``); ``words`` is the
    trip's text, formatted with ``value`` (the quantity) and the limits by name.
    """

    cause: str
    stage: str
    quantity: str
    test: str
    limits: tuple[str, ...]
    words: str

    def __post_init__(self) -> None:
        need = {"nan": 0, "not_finite": 0, "above": 1, "below": 1, "outside": 2}
        if self.stage not in STAGES or self.quantity not in QUANTITIES or self.test not in TESTS:
            raise ValueError(f"interlock {self.cause}: unknown stage, quantity or test")
        if len(self.limits) != need[self.test]:
            raise ValueError(f"interlock {self.cause}: the test '{self.test}' takes {need[self.test]} limits")


#: the interlocks, in the order they are tested
INTERLOCKS: tuple[Interlock, ...] = (
    Interlock("sensor_nan", "reading", "force_N", "nan", (), "the force sensor reads NaN"),
    Interlock("sensor_stale", "reading", "sample_age_s", "above", ("stale_after_s",),
              "the force sample is {value:.4f} s old (limit {stale_after_s:g} s)"),
    Interlock("sensor_range", "reading", "force_N", "outside", ("sensor_min_N", "sensor_max_N"),
              "the force reads {value:.6g} N, at or beyond the sensor's range {sensor_min_N:g}..{sensor_max_N:g} N"),
    Interlock("force_high", "reading", "force_N", "above", ("force_max_N",),
              "the force reads {value:.6g} N, above the limit {force_max_N:g} N"),
    Interlock("force_low", "reading", "force_N", "below", ("force_low_N",),
              "the force reads {value:.6g} N, below the bolt preload less the margin ({force_low_N:g} N)"),
    Interlock("stall", "reading", "held_s", "above", ("stall_limit_s",),
              "the output was held {value:.4f} s without an update (limit {stall_limit_s:.4g} s)"),
    Interlock("command", "command", "command_V", "not_finite", (), "the controller's command is {value}"),
)

#: every cause a run may stop with: the table's, then a signal and an exception
TRIP_CAUSES: tuple[str, ...] = (*(i.cause for i in INTERLOCKS), "signal", "exception")


def cause_code(cause: str) -> int:
    """The number a loop reports for ``cause`` (1 + its index in :data:`TRIP_CAUSES`; 0 is none)."""
    return 1 + TRIP_CAUSES.index(cause)


#: one row as both loops test it: (stage, quantity, test, cause code, lo, hi)
Row = tuple[int, int, int, int, float, float]


def rows(safety: Safety) -> tuple[Row, ...]:
    """The table with ``safety``'s numbers in: what the Python loop tests and the native loop receives."""
    out = []
    for i in INTERLOCKS:
        limits = [float(getattr(safety, name)) for name in i.limits] + [math.nan, math.nan]
        out.append((STAGES.index(i.stage), QUANTITIES.index(i.quantity), TESTS.index(i.test), cause_code(i.cause),
                    limits[0], limits[1]))
    return tuple(out)


_NAN, _ABOVE, _BELOW, _OUTSIDE, _NOT_FINITE = range(len(TESTS))


def first_trip(table: tuple[Row, ...], stage: int, q: tuple[float, ...]) -> tuple[int, float] | None:
    """The first row of ``stage`` whose test holds for the quantities ``q``: ``(cause code, value)``, or None."""
    for row_stage, quantity, test, cause, lo, hi in table:
        if row_stage != stage:
            continue
        x = q[quantity]
        if test == _NAN:
            hit = x != x
        elif test == _ABOVE:
            hit = x > lo
        elif test == _BELOW:
            hit = x < lo
        elif test == _OUTSIDE:
            hit = not (lo < x < hi)
        else:
            hit = not math.isfinite(x)
        if hit:
            return cause, x
    return None


@dataclass(frozen=True)
class Trip:
    """Why and when a run stopped: the cause, its words, the time on the run's timeline and the voltage then."""

    cause: str
    detail: str
    t_s: float
    voltage_V: float = math.nan


def trip_detail(cause: str, value: float, safety: Safety) -> str:
    """The words of a table interlock's trip for the number that tripped it (one text for both loops)."""
    row = next((i for i in INTERLOCKS if i.cause == cause), None)
    if row is None:
        return str(value)
    limits = {name: getattr(safety, name) for name in row.limits}
    return row.words.format(value=value, **limits)


def c_defines() -> str:
    """The codes of the table as C ``#define`` lines, put before ``native_loop.c`` when it is built."""
    lines = ["/* generated from rig/interlocks.py: the codes of the interlock table */"]
    for prefix, names in (("PP_STAGE_", STAGES), ("PP_Q_", QUANTITIES), ("PP_TEST_", TESTS)):
        lines += [f"#define {prefix}{name.upper()} {j}" for j, name in enumerate(names)]
    lines.append(f"#define PP_N_QUANTITIES {len(QUANTITIES)}")
    lines += [f"#define PP_T_{cause.upper()} {cause_code(cause)}" for cause in TRIP_CAUSES]
    lines.append(f"#define PP_MAX_INTERLOCKS {max(16, len(INTERLOCKS))}")
    return "\n".join(lines) + "\n"
