"""A gain schedule on the preload level, or the one robust set where it meets the same specification.

A designed preload system's force per volt changes with the preload (the nuts' Hertz contacts
stiffen as they are loaded: about 38 N/V at the bolts' preload, 57 N/V at the stacks' full
force for the machine axis). One robust set (:func:`~piezopreload.tuning.pid.tune_pid` on plant
variants over the whole range) has to be cautious where the plant is stiff and is slow where it
is soft. :func:`tune_schedule`:

1. places ``n`` entries evenly over the force range the study's references span and gives each
   the window half-way to its neighbours;
2. tunes each entry with CasADi (:func:`~piezopreload.tuning.pid.tune_pid`, warm-started from the
   robust set) on a step across its window and a staircase inside it, the Ms constraints on the
   force per volt of that window (``TuningSpec.force_range_N``) and the usual plant variants
   around it. ``Kc``, ``Ti``, ``Td`` and the setpoint weight ``b`` are each entry's decision
   variables (``b`` takes the step's kick off the command: the feedforward already follows the
   setpoint); the derivative filter ``Tf`` is held at the robust set's (where the tuned ``Td`` sits
   at its lower bound, as on the machine axis, the filter does not act, and a filter per entry
   would add a decision variable that changes nothing). Each entry's maximum sensitivity is read over its own window
   (:func:`window_ms`, the robust set's beside it: the level's ``ms``). An entry whose
   window's specification no gains meet keeps the robust set's gains (its record says so).
   Between two entries the controller interpolates ``Kc`` and ``b``: where the proportional
   action's setpoint part ``Kc(r) b(r) r`` would fall as the setpoint rises (a high ``b`` below a
   low one), a step up lowers the command and the integral carries the difference, so the loop
   lags every step there; the upper entry's ``b`` is raised to the least value that keeps it
   rising (:func:`rising_setpoint_weights`);
3. validates the schedule and the robust set alike by Monte Carlo
   (:func:`~piezopreload.tuning.validate.validate`, the study's criteria) at every entry's window
   and over the whole range (the study's own step and trajectory);
4. tunes again, once, each entry whose window the schedule still misses on the overshoot: with
   the overshoot margin widened by the Monte Carlo excess (the nominal variants' overshoot must
   come down by what the drawn plants add), and validates the schedule again;
5. chooses: the robust set if it meets the specification at every level and over the whole
   range (one set is simpler to commission and to certify), else the schedule if it does; where
   neither does, the one that meets it over the whole range (the robust set first), and the
   reason says which failed where. Where the schedule misses a level, the level's ``bound`` says
   what stops a PID entry there: the tuning's constraints that bind (Ms, the noise gain, the
   overshoot on the variants), or the specification no entry meets, and the Monte Carlo figure
   against its limit.

The per-level figures (gains, each entry's Ms over its window, worst-case settling, overshoot and
tracking error over the plants, both sets) are the report's "gain schedule" table.

**The lowest entry is tuned on a different problem.** Each entry's step and staircase start at its
window's bottom, and the loop starts from rest (0 V), so every entry's objective but the lowest's also
counts the rise from rest up to its window (the lowest window starts at rest). On the machine axis
that rise is almost all of the upper entries' objective (237 and 690 against the lowest entry's 2.6),
and it keeps their integral action slow (Ti 45 and 46 ms); the lowest entry, judged on its window
alone, goes to an integral-dominated PI (Ti 3.4 ms, its PI zero above the loop's crossover) with the
setpoint weight on its lower bound (b = 0: no proportional kick from the setpoint, the feedforward
follows it). It is robust where it acts: its Ms over its window is at the 1.6 bound, the
interpolated gains' local Ms stays at or below 1.6 from 0 to 4,000 N, and it passes the Monte Carlo
validation at its level (overshoot 6.8 N, settling 0.20 s). Leaving the rise out of every entry's
objective was tried and refused: the upper entries then go as aggressive and miss the Monte Carlo
overshoot at 2,000 N by an order of magnitude (237 N against 25), so the rise stays counted.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from piezopreload.artifacts.requirements import Requirement, Sense
from piezopreload.artifacts.tuning import (
    CHOICES,
    LEVEL_FIGURES,
    GainScheduleRecord,
    ScheduleChoice,
    ScheduleLevel,
    SetFigures,
    SetGains,
    WorstFigures,
)
from piezopreload.artifacts.validation import Criteria, ValidationResult
from piezopreload.core.errors import InternalError
from piezopreload.core.parallel import Pool
from piezopreload.core.progress import ProgressLike, say_of
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import GainSchedule, PIDGains
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, inverse_at
from piezopreload.tuning.linearised import max_sensitivity
from piezopreload.tuning.pid import TuningInfeasible, TuningSpec, plant_variants, tune_pid
from piezopreload.tuning.validate import executor, validate

__all__ = ["LevelFigures", "WorstFigures", "tune_schedule", "tune_entries", "window_ms",
           "level_requirements", "schedule_levels", "level_windows", "choose", "CHOICES", "CHOICE_WORDS",
           "setpoint_action_rises", "rising_setpoint_weights"]

#: the worst-case figures the table shows per level (the validation's metric names)
FIGURES = LEVEL_FIGURES


def schedule_levels(low_N: float, high_N: float, n: int) -> np.ndarray:
    """``n`` entries evenly over ``[low_N, high_N]`` (the ends included)."""
    if n < 2:
        raise ValueError(f"a gain schedule needs at least 2 levels, got {n}.")
    if not (np.isfinite(low_N) and np.isfinite(high_N) and high_N > low_N):
        raise ValueError(f"the schedule's range must be finite with high > low, got {low_N!r}..{high_N!r}.")
    return np.linspace(float(low_N), float(high_N), int(n))


def level_windows(levels_N: Any) -> list[tuple[float, float]]:
    """Each entry's window: from half-way to the entry below to half-way to the entry above (the ends: the entry)."""
    lv = np.asarray(levels_N, float)
    mids = 0.5 * (lv[1:] + lv[:-1])
    lows, highs = np.concatenate([[lv[0]], mids]), np.concatenate([mids, [lv[-1]]])
    return [(float(a), float(b)) for a, b in zip(lows, highs)]


def _path(a: float, level: float, b: float) -> list[float]:
    """The staircase inside a window from rest at ``a``: the level, the top, the level, the bottom (no repeats)."""
    out: list[float] = []
    for x in (level, b, level, a):
        if x != (out[-1] if out else a):
            out.append(x)
    return out or [b]


#: what :func:`choose` returns, in words ("schedule: schedule: ..." read as a stutter)
CHOICE_WORDS = {c: c.words for c in ScheduleChoice}


def choose(levels: Sequence[LevelFigures], whole: LevelFigures) -> tuple[ScheduleChoice, str]:
    """The robust set if it meets the specification at every level and over the whole range, else the schedule if it
    does; where neither does, the one that meets it over the whole range (the robust set first). With the reason."""
    def passes(which: str) -> bool:
        return whole.of(which).passed and all(r.of(which).passed for r in levels)

    def where(which: str) -> str:
        bad = [f"{r.level_N:,.0f} N ({_failed_words(r.of(which))})" for r in levels if not r.of(which).passed]
        if not whole.of(which).passed:
            bad.append(f"the whole range ({_failed_words(whole.of(which))})")
        return bad[0] if len(bad) == 1 else ", ".join(bad[:-1]) + " and " + bad[-1]

    if passes("robust"):
        return ScheduleChoice.ROBUST, ("the one robust set meets the specification at every level and over the whole "
                                       "range: it is used (one set, nothing to switch)")
    if passes("scheduled"):
        return ScheduleChoice.SCHEDULE, (f"the robust set misses the specification at {where('robust')}; the schedule "
                                         "meets it")
    # the validation stage judges the whole range as always: keep the set that meets it there
    choice = ScheduleChoice.SCHEDULE if whole.scheduled.passed and not whole.robust.passed else ScheduleChoice.ROBUST
    kept = whole.of(choice.set_key).passed
    bounds = "; ".join(f"at {r.level_N:g} N {r.bound}" for r in levels if r.bound)
    return choice, (f"neither meets the specification at every level (the robust set misses it at {where('robust')}, "
                    f"the schedule at {where('scheduled')}); the {choice} set is kept"
                    + (", as it meets it over the whole range" if kept else "")
                    + (f". What stops a PID entry: {bounds}" if bounds else ""))


#: each limit of the per-level validation: its words, its unit and the [validation] key that sets it
_LEVEL_LIMITS = {"settling_s": ("worst settling time", "s", "settling_max_s"),
                 "overshoot_N": ("worst overshoot", "N", "overshoot_max_N"),
                 "tracking_rms_N": ("worst tracking RMS after the changes", "N", "tracking_rms_max_N"),
                 "peak_voltage_V": ("highest command", "V", "peak_voltage_max_V")}


def _failed_words(figures: WorstFigures) -> str:
    """The metrics a set failed at a level, in words."""
    return ", ".join(_LEVEL_LIMITS[m][0] if m in _LEVEL_LIMITS else m for m in figures.failures)


def level_requirements(schedule: GainScheduleRecord) -> tuple[Requirement, ...]:
    """The chosen set's verdict at each preload level of a gain schedule's record: its worst case over the level's
    Monte Carlo plants against each limit of the study's ``[validation]``."""
    out = []
    for level in schedule.levels:
        figures = level.of(schedule.chosen_set)
        for metric, (words, unit, key) in _LEVEL_LIMITS.items():
            if schedule.limits.get(metric) is None:  # not a requirement of this study (the peak command's)
                continue
            value = figures.figure(metric)
            limit = schedule.limits[metric]
            value = 1e9 * max(abs(limit), 1.0) if value is None else float(value)  # never settled: missed by far
            out.append(Requirement(f"{words} at the {level.level_N:,.0f} N level over {schedule.plants} "
                                   f"Monte Carlo plants ({schedule.choice})", value, float(limit), unit,
                                   Sense.AT_MOST, f"[validation] {key}", f"validation.{key}@{level.level_N:g}N"))
    return tuple(out)


@dataclass(frozen=True)
class LevelFigures:
    """What the choice between the robust set and the schedule reads at one preload level (``level_N``; None: over
    the whole range): each set's worst cases and verdict there, and what stops the schedule's entry where it misses
    (``bound``)."""

    level_N: float | None
    robust: WorstFigures
    scheduled: WorstFigures
    bound: str | None = None

    def of(self, which: str) -> WorstFigures:
        """The figures of the set ``which`` (``"robust"`` or ``"scheduled"``, the record's keys)."""
        if which not in ("robust", "scheduled"):
            raise ValueError(f"LevelFigures.of: which must be 'robust' or 'scheduled', got {which!r}")
        return self.robust if which == "robust" else self.scheduled

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LevelFigures:
        """One entry of a schedule record's ``levels`` (or its ``whole_range``, which has no ``level_N``)."""
        return cls(None if d.get("level_N") is None else float(d["level_N"]), WorstFigures.from_dict(d["robust"]),
                   WorstFigures.from_dict(d["scheduled"]), d.get("bound"))


def _worst(result: ValidationResult) -> WorstFigures:
    s = result.summary()
    worst = {k: s[k]["worst"] for k in FIGURES}
    return WorstFigures(settling_s=worst["settling_s"], overshoot_N=worst["overshoot_N"],
                     tracking_rms_N=worst["tracking_rms_N"], peak_voltage_V=worst["peak_voltage_V"],
                     passed=result.passed, failures=tuple(sorted({f.metric for f in result.failures})))


_REST_S = 0.25  # the rest at a window's bottom before the tuning's step and staircase


def _judge(args: tuple[Any, ...]) -> WorstFigures:
    """One Monte Carlo validation (:func:`~piezopreload.tuning.validate.validate`, inline), its worst cases."""
    gains, feedforward, params, criteria, n_plants, seed, step, trajectory = args
    return _worst(validate(gains, feedforward, params, criteria, n_plants=n_plants, seed=seed, step=step,
                           trajectory=trajectory))


def _tune_entry(args: tuple[Plant, Any, TuningSpec, PIDGains, PIDGains | None]) -> tuple[PIDGains, dict[str, Any]]:
    """One entry tuned on its window from the robust set, which it keeps unless it finds better (and the warm
    start's entry at this level, where given)."""
    params, inverse, spec, start, warm = args
    known = {"the robust set": start, **({} if warm is None else {"the warm start's entry": warm})}
    try:
        tuned = tune_pid(params, inverse, spec, start=start, known=known)
    except TuningInfeasible as exc:  # no gains meet the window's specification: the entry keeps the robust set's
        return start, {"infeasible": str(exc), "kept": "the robust set",
                       "overshoot_target_N": spec.band_N - spec.overshoot_margin_N}
    return tuned.found(), {"iterations": tuned.iterations, "seconds": tuned.seconds, "ms": tuned.ms,
                           "objective": tuned.objective, "binding": list(tuned.binding), "engine": tuned.engine,
                           "status": tuned.status, "search": tuned.search,
                           "overshoot_target_N": spec.band_N - spec.overshoot_margin_N}


def window_ms(gains: PIDGains, params: Plant, spec: TuningSpec) -> float:
    """The largest maximum sensitivity of ``gains`` over ``spec``'s plant variants, each at both ends of the local
    slope over ``spec.force_range_N`` (an entry's own window; None: the whole stroke), as the tuning bounds it."""
    return float(max(max_sensitivity(gains, v, spec.force_range_N) for v in plant_variants(params, spec.variants)))


def _entry_spec(spec: TuningSpec, robust: PIDGains, lo: float, level: float, hi: float,
                overshoot_margin_N: float | None = None) -> TuningSpec:
    """An entry's tuning: a step across its window after a rest at its bottom (the loop starts at 0 V: the rest lets
    the step start from the window, as the validation's does) and a short staircase inside it, the Ms constraints on
    the window's force per volt, ``b`` tuned, the robust set's derivative filter held."""
    step = Reference.step(lo, hi, _REST_S, _REST_S + 0.6)
    trajectory = Reference.staircase(lo, _path(lo, float(level), hi), 0.4, t_start_s=_REST_S)
    margin = spec.overshoot_margin_N if overshoot_margin_N is None else overshoot_margin_N
    return replace(spec, step=step, trajectory=trajectory, force_range_N=(lo, hi), tune_setpoint_weight=True,
                   filter_s=robust.Tf_s, overshoot_margin_N=margin)


def _schedule_of(levels_N: np.ndarray, entries: list[PIDGains]) -> GainSchedule:
    return GainSchedule(tuple(levels_N), tuple(g.Kc for g in entries), tuple(g.Ti_s for g in entries),
                        tuple(g.Td_s for g in entries), tuple(g.b for g in entries))


def setpoint_action_rises(levels_N: Any, Kc: Any, b: Any) -> bool:
    """Whether the proportional action's setpoint part ``w(r) = Kc(r) b(r) r`` never falls as the setpoint ``r`` rises
    (``Kc`` and ``b`` linear between the entries, as the controller interpolates them). On each segment ``w`` is a
    cubic; its derivative, a quadratic, is checked at the segment's ends and at its vertex where that lies inside.
    Where ``w`` falls, a rising setpoint lowers the command and the integral has to carry the difference: the loop
    lags every step across that segment."""
    lv, kc, bb = (np.asarray(x, float) for x in (levels_N, Kc, b))
    for i in range(lv.size - 1):
        lo, hi = lv[i], lv[i + 1]
        k = np.polyfit([lo, hi], kc[i:i + 2], 1)
        c = np.polyfit([lo, hi], bb[i:i + 2], 1)
        dw = np.polyder(np.polymul(np.polymul(k, c), [1.0, 0.0]))
        r = [lo, hi] + ([-dw[1] / (2 * dw[0])] if dw[0] != 0 and lo < -dw[1] / (2 * dw[0]) < hi else [])
        scale = max(abs(float(np.polyval(dw, x))) for x in (lo, hi)) or 1.0
        if min(float(np.polyval(dw, x)) for x in r) < -1e-12 * scale:
            return False
    return True


def rising_setpoint_weights(levels_N: Any, Kc: Any, b: Any) -> tuple[float, ...]:
    """The entries' setpoint weights, each raised (from the lowest entry up) to the least value in ``[b_i, 1]`` for
    which the setpoint action rises over the segment below it (:func:`setpoint_action_rises`), by bisection to
    1e-6; an entry already rising keeps its ``b``."""
    lv, kc, out = np.asarray(levels_N, float), np.asarray(Kc, float), [float(x) for x in b]
    for i in range(1, lv.size):
        def ok(x: float, i: int = i) -> bool:
            return setpoint_action_rises(lv[i - 1:i + 1], kc[i - 1:i + 1], [out[i - 1], x])

        if ok(out[i]):
            continue
        lo, hi = out[i], max(1.0, out[i])
        while hi - lo > 1e-6:
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        out[i] = hi
    return tuple(out)


def _rising(levels_N: np.ndarray,
            tuned: list[tuple[PIDGains, dict[str, Any]]]) -> list[tuple[PIDGains, dict[str, Any]]]:
    """The tuned entries with their setpoint weights raised where the setpoint action would fall between entries
    (:func:`rising_setpoint_weights`); a raised entry's record says from what to what."""
    entries = [g for g, _ in tuned]
    b = rising_setpoint_weights(levels_N, [g.Kc for g in entries], [g.b for g in entries])
    return [(g, r) if nb == g.b else (replace(g, b=nb), {**r, "b_raised": {"from": g.b, "to": nb, "why": (
                "so that the setpoint action Kc b r rises with the setpoint between this entry and the one below")}})
            for (g, r), nb in zip(tuned, b)]


def _tighter(spec: TuningSpec, figures: WorstFigures, criteria: Criteria) -> float | None:
    """The overshoot margin an entry is tuned again with where the Monte Carlo overshoot exceeds its limit: widened by
    the excess (the drawn plants add it to the variants' nominal overshoot); None where it does not exceed it."""
    if figures.overshoot_N is None:
        raise InternalError("a Monte Carlo validation gave no worst overshoot")
    excess = figures.overshoot_N - criteria.overshoot_max_N
    return None if excess <= 0 else spec.overshoot_margin_N + excess


def _bound(record: dict[str, Any], figures: WorstFigures, limits: dict[str, float]) -> str:
    """What stops the schedule's entry at a level it misses: the tuning's binding constraints (or the specification no
    entry met) beside the Monte Carlo worst case of each failed metric against its limit."""
    missed = ", ".join(f"{_LEVEL_LIMITS[m][0]} {figures.figure(m):.3g} {_LEVEL_LIMITS[m][1]} against {limits[m]:.3g}"
                       for m in figures.failures if m in limits)
    if "infeasible" in record:
        return f"no PID entry meets the window's tuning specification ({record['infeasible']}); Monte Carlo: {missed}"
    binding = "; ".join(record.get("binding", [])) or "none"
    return (f"the entry's tuning (nominal overshoot inside {record.get('overshoot_target_N', float('nan')):.3g} N on "
            f"its plant variants) binds on: {binding}; Monte Carlo: {missed}")


def _warm_entries(known: GainSchedule | None, levels_N: np.ndarray, robust: PIDGains) -> list[PIDGains | None]:
    """Each level's entry of a known schedule (the robust set's filter and range), None where it has none at that
    level."""
    if known is None:
        return [None] * levels_N.size
    at = {round(float(x), 6): i for i, x in enumerate(known.levels_N)}
    b = known.b if known.b is not None else (robust.b,) * known.size
    out: list[PIDGains | None] = []
    for x in levels_N:
        i = at.get(round(float(x), 6))
        out.append(None if i is None else replace(robust, Kc=known.Kc[i], Ti_s=known.Ti_s[i], Td_s=known.Td_s[i],
                                                  b=b[i], schedule=None))
    return out


@dataclass(frozen=True)
class _Plan:
    """What a schedule is tuned and judged on: the levels, their windows, each entry's tuning, the validations."""

    levels_N: np.ndarray
    windows: list[tuple[float, float]]
    specs: list[TuningSpec]
    checks: list[tuple[Reference, Reference]]


def _plan(spec: TuningSpec, robust: PIDGains, levels_N: Any, step: Reference, trajectory: Reference) -> _Plan:
    lv = np.asarray(levels_N, float)
    windows = level_windows(lv)
    t_step = float(step.times_s[1]) if step.times_s.size > 1 else 0.5
    hold = float(np.min(np.diff(trajectory.times_s[1:]))) if trajectory.times_s.size > 2 else 1.0  # its levels' hold
    # each window validated on a step across it and a staircase inside it, with the study's timing; then the whole range
    checks = [(Reference.step(lo, hi, t_step, float(step.duration_s)),
               Reference.staircase(lo, _path(lo, float(level), hi), hold, t_start_s=float(trajectory.times_s[1])))
              for level, (lo, hi) in zip(lv, windows)] + [(step, trajectory)]
    return _Plan(lv, windows, [_entry_spec(spec, robust, lo, float(x), hi) for x, (lo, hi) in zip(lv, windows)], checks)


def tune_entries(params: Plant, feedforward: HysteresisModel | CreepPI | None, spec: TuningSpec, robust: PIDGains, *,
                 levels_N: Any, step: Reference, trajectory: Reference, starts: int = 3,
                 max_iterations: int = 150) -> tuple[GainSchedule, list[dict[str, Any]]]:
    """Each entry of a gain schedule at ``levels_N`` tuned on its window, as :func:`tune_schedule`'s step 2 tunes it
    (the Ms constraints on the window's force per volt, warm-started from ``robust``, the setpoint weights kept
    rising), without its Monte Carlo: the inner problem of a co-design that takes the entries as its decisions.

    Parameters
    ----------
    params : Plant
        The nominal plant.
    feedforward : HysteresisModel or CreepPI or None
        The forward P-I model the controller inverts.
    spec : TuningSpec
        The tuning's specification (its references and Ms range are replaced per entry).
    robust : PIDGains
        The robust set each entry starts from (and keeps where no gains meet its window's specification).
    levels_N : array_like
        The entries' levels (measured force, N).
    step, trajectory : Reference
        The study's references (each window is tuned on a step and a staircase with their timing).
    starts, max_iterations : int
        Each entry's tuning's starts and IPOPT iteration limit (:func:`~piezopreload.tuning.pid.tune_pid`'s).

    Returns
    -------
    (GainSchedule, list of dict)
        The schedule, and per entry its level, window, Ms over its window and tuning record (``infeasible`` and
        ``kept`` where it kept the robust set's gains).
    """
    plan = _plan(spec, robust, levels_N, step, trajectory)
    inverse = None if feedforward is None else inverse_at(feedforward, params.sample_period_s)
    tuned = []
    for sp in plan.specs:
        try:
            t = tune_pid(params, inverse, sp, start=robust, known={"the robust set": robust}, starts=starts,
                         max_iterations=max_iterations)
            tuned.append((t.found(), {"ms": t.ms, "binding": t.binding, "objective": t.objective}))
        except TuningInfeasible as exc:  # no gains meet the window's specification: the entry keeps the robust set's
            tuned.append((robust, {"infeasible": str(exc), "kept": "the robust set"}))
    tuned = _rising(plan.levels_N, tuned)
    records = [{"level_N": float(level), "window_N": list(window), "ms": window_ms(g, params, sp), "tuning": record}
               for level, window, sp, (g, record) in zip(plan.levels_N, plan.windows, plan.specs, tuned)]
    return _schedule_of(plan.levels_N, [g for g, _ in tuned]), records


def tune_schedule(
    params: Plant,
    feedforward: HysteresisModel | CreepPI | None,
    spec: TuningSpec,
    criteria: Criteria,
    robust: PIDGains,
    *,
    levels_N: Any,
    step: Reference,
    trajectory: Reference,
    n_plants: int = 50,
    seed: int = 0,
    pool: Pool | None = None,
    progress: ProgressLike | None = None,
    known: GainSchedule | None = None,
) -> GainScheduleRecord:
    """Tune a gain schedule at ``levels_N`` (measured force, N) around the robust set; validate both; choose.

    ``params`` is the nominal plant, ``feedforward`` the forward P-I model the controller inverts,
    ``spec`` the tuning's specification (its references are replaced per entry by a step across
    the entry's window and a staircase inside it, its Ms range by the window's force per volt),
    ``criteria`` the limits every Monte Carlo plant must meet, ``robust`` the one set tuned over
    the whole range. ``step`` and ``trajectory`` are the study's references (the whole range);
    each window is validated on a step and a staircase with their timing. ``n_plants`` Monte
    Carlo plants per validation (noise and draws from ``seed``); ``pool``: the run's worker processes the
    entries' tunings and the validations are submitted to (default: none, one after another here).
    ``known``: a schedule whose entries at the same levels each entry's tuning is given as a known point
    (a warm start's). See the module docstring.
    """
    say = say_of(progress) or (lambda _m: None)
    t0 = time.perf_counter()
    plan = _plan(spec, robust, levels_N, step, trajectory)
    lv, inverse = plan.levels_N, None if feedforward is None else inverse_at(feedforward, params.sample_period_s)
    limits = criteria.limits()  # the peak command's only where the study sets a headroom

    def judging(gains: PIDGains) -> list[tuple[Any, ...]]:
        return [(gains, feedforward, params, criteria, n_plants, seed, s, t) for s, t in plan.checks]

    with executor(1, pool=pool) as (run, pool_name):
        say(f"tuning {lv.size} entries of the gain schedule at {', '.join(f'{x:g}' for x in lv)} N (Kc, Ti, Td and b "
            f"each), validating the robust set at each level and over the whole range beside them ({n_plants} plants "
            f"each; {pool_name}) ...")
        warm = _warm_entries(known, lv, robust)
        tuning_futures = [run.submit(_tune_entry, (params, inverse, sp, robust, w)) for sp, w in zip(plan.specs, warm)]
        robust_futures = [run.submit(_judge, j) for j in judging(robust)]  # needs nothing the tuning gives
        tuned = _rising(lv, [f.result() for f in tuning_futures])
        say("validating the schedule at each level and over the whole range ...")
        scheduled_set = replace(robust, schedule=_schedule_of(lv, [g for g, _ in tuned]))
        scheduled_figures = [f.result() for f in [run.submit(_judge, j) for j in judging(scheduled_set)]]
        again = {i: m for i, (fig, sp) in enumerate(zip(scheduled_figures, plan.specs))
                 if (m := _tighter(sp, fig, criteria)) is not None and m < sp.band_N}
        if again:
            say(f"tuning again the entries at {', '.join(f'{lv[i]:g}' for i in again)} N with their overshoot margin "
                "widened by the Monte Carlo excess, and validating the schedule again ...")
            retuned = {i: run.submit(_tune_entry, (params, inverse, replace(plan.specs[i], overshoot_margin_N=m),
                                                    robust, warm[i]))
                       for i, m in again.items()}
            tuned = _rising(lv, [retuned[i].result() if i in retuned else t for i, t in enumerate(tuned)])
            scheduled_set = replace(robust, schedule=_schedule_of(lv, [g for g, _ in tuned]))
            scheduled_figures = [f.result() for f in [run.submit(_judge, j) for j in judging(scheduled_set)]]
        robust_figures = [f.result() for f in robust_futures]
    schedule = _schedule_of(lv, [g for g, _ in tuned])
    at = [LevelFigures(float(level), rb, sc, None if sc.passed else _bound(record, sc, limits))
          for level, (_, record), rb, sc in zip(lv, tuned, robust_figures, scheduled_figures)]
    over_all = LevelFigures(None, robust_figures[-1], scheduled_figures[-1])
    levels = tuple(ScheduleLevel(float(level), (float(window[0]), float(window[1])), SetGains.of(g),
                                 {"scheduled": window_ms(g, params, sp), "robust": window_ms(robust, params, sp)},
                                 record, f.robust, f.scheduled, f.bound)
                   for level, f, window, sp, (g, record) in zip(lv, at, plan.windows, plan.specs, tuned))

    choice, reason = choose(at, over_all)
    say(f"gain schedule: {choice.words} chosen: {reason}")
    return GainScheduleRecord(choice, reason, tuple(float(x) for x in schedule.levels_N), schedule, robust.Tf_s,
                              robust.b, SetGains.of(robust), levels, SetFigures(over_all.robust, over_all.scheduled),
                              n_plants, FIGURES, dict(limits), time.perf_counter() - t0)
