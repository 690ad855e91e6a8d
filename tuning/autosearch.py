"""The autotuner's search on a plant's grid: analytic starts, a local solve by exchange, a refinement of the best.

:class:`Search` holds what every step shares, computed once: the design grid and the plant's response on it, the
check grid (ten times denser and a decade wider) and the response there, the grid the Nyquist count runs on (eight
decades below the design grid, where an integrating loop reaches its asymptote; a measured response's every
point). :meth:`Search.run`:

1. the starts: the best slices of the stabilising set in the ``(kp, ki)`` plane cut by the bounds
   (:func:`~piezopreload.tuning.stabset.stabilising_starts`), for the plant's sign (an unstable plant's: the
   sign whose slices stabilise);
2. from each of the first :data:`_STARTS`, the local solve by exchange (:meth:`Search.local`): the SQP with exact
   derivatives (:class:`~piezopreload.tuning.pidopt.PIDProblem`) on the rows (frequency, bound) near each bound's
   peaks, in a trust region; after each solve the peaks over a bound on the check grid (located by successive
   parabolas) join the rows and it is solved again, warm, until every bound holds there within
   :data:`REFINE_TO`; a step to an unstable loop (the Nyquist criterion on the count grid) shortens the region,
   one on its edge that holds every bound moves it and widens it. A start behind the best inside its region stops
   (more rows only lower its integral gain);
3. the best start's solution refined the same way until every bound holds within :data:`FINISH_TO`;
4. where no start ends on gains that meet the bounds with a stable loop: the other slices' starts, then the bounds
   relaxed until a slice stabilises and from there the least worst bound any gains reach
   (:meth:`~piezopreload.tuning.pidopt.PIDProblem.least_violation`): gains that meet every bound are a start, else
   an :class:`~piezopreload.core.errors.InfeasibleError` names the bound and that least value.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, NoReturn

import numpy as np

from piezopreload.core.errors import InfeasibleError, InternalError
from piezopreload.tuning.autotune_result import REFINED_TO, StartRecord, located
from piezopreload.tuning.loopshape import Bound
from piezopreload.tuning.lti import LinearPlant
from piezopreload.tuning.pidform import PIDController
from piezopreload.tuning.pidopt import IE, Form, Objective, PIDProblem, Scales, Solution
from piezopreload.tuning.stabset import RELAX, plane_of, stabilising_any, stabilising_starts, unstable_counts

__all__ = ["Search", "Found", "bound_reach", "TOLERANCE", "REFINE_TO", "FINISH_TO", "PER_DECADE"]

#: how far (relative) a bound may be exceeded on the check grid
TOLERANCE = 0.005
#: how far the refinement goes (the grid gains the check grid's peaks until they are within this)
REFINE_TO = 3e-3
#: how far the best start's solution is refined at the end (the result's ``over_by`` names a bound it misses)
FINISH_TO = REFINED_TO
#: the design grid's points a decade (the check grid has ten times as many)
PER_DECADE = 25
_ROUNDS = 16  # the exchange's solves from one start
_FEASIBLE = 1e-6  # |X| / M - 1 on the problem's frequencies
_LOW_DECADES = 8  # the Nyquist count's frequencies below the design grid
_SLICE_PER_DECADE = 10
_PEAKS = 4  # the peaks of each bound a round adds to the problem, largest first
#: the slices' optima the local solve starts from (a start far behind the best stops early: _BEHIND)
_STARTS = 2
_KEEP = 0.6  # a row whose |X| / M falls below this leaves the problem
_LOCATE = 2e-3  # a check-grid peak this close under its bound, or over it ...
_LOCATE_OVER = 3e-2  # ... by up to this, is located between the grid's points
#: a start whose ki is below this fraction of the best start's after three solves stops (an IAE: above its inverse)
_BEHIND = 0.75


@dataclass
class Found:
    """What the search found: the problem it ended on, its solution, the controller (of the plant of positive
    gain), the controller's sign, each start's record, the refinements and iterations."""

    problem: PIDProblem
    solution: Solution
    controller: PIDController
    sign: float
    records: list[StartRecord] = field(default_factory=list)
    refinements: int = 0
    iterations: int = 0
    seconds: float = 0.0
    ratio: float = np.inf  # the worst bound's |X| / M on the check grid (peaks located)
    rows: Any = None  # the problem's rows (_Rows)


def _far(plant: LinearPlant, omega: np.ndarray, decades: float, points: int) -> np.ndarray:
    """A continuous rational plant's grid continued ``decades`` beyond its end (``|KS|`` approaches its supremum
    ``|C(inf)|`` there); a discrete or measured plant's as it is."""
    if plant.discrete or not plant.rational:
        return omega
    return np.unique(np.append(omega, np.logspace(np.log10(omega[-1]), np.log10(omega[-1]) + decades, points)))


def design_grid(plant: LinearPlant, per_decade: int = PER_DECADE, upto: float | None = None) -> np.ndarray:
    """The plant's design grid (:meth:`~piezopreload.tuning.lti.LinearPlant.grid`, :data:`PER_DECADE` a decade,
    clusters at its resonances, reaching ten times beyond ``upto``: :func:`bound_reach`) and, continuous, two points
    three decades on."""
    return _far(plant, plant.grid(per_decade, upto=upto), 3.0, 2)


def bound_reach(plant: LinearPlant, bounds: dict[str, float | None]) -> float | None:
    """The highest frequency where ``Mks |G| >= 1``: the loop's gain crossover lies below it (there ``|KS|`` is about
    ``|C| >= 1/|G|``), however far above the plant's own poles and zeros (a near-integrating or double-integrating
    plant's PID crosses over where the bound on ``|KS|`` lets it, decades above its slow poles); None without an
    ``Mks``, for a measured or discrete plant (their grids end at their data or their Nyquist frequency), or where
    ``Mks |G|`` stays at least 1 (a biproper plant)."""
    mks = bounds.get(Bound.MKS)
    if mks is None or not plant.rational or plant.discrete:
        return None
    w = plant.grid(10, widen=4.0)
    above = np.flatnonzero(mks * np.abs(plant.response(w)) >= 1.0)
    if above.size == 0 or above[-1] == w.size - 1:
        return None
    return float(w[above[-1]])


def check_grid(plant: LinearPlant, omega: np.ndarray) -> np.ndarray:
    """Ten times denser than the design grid and a decade wider each side (resonances' clusters included), and
    three decades further where a continuous controller's gain levels off; a measured response: every frequency."""
    if not plant.rational:
        return plant.measured_response()[0]
    dense = plant.grid(10 * PER_DECADE, widen=1.0)
    lo, hi = np.log10(omega.min()) - 1.0, np.log10(omega.max()) + 1.0
    if plant.discrete:
        hi = min(hi, np.log10(0.999 * np.pi / plant.sample_period()))
    if lo < np.log10(dense[0]) - 1e-9 or hi > np.log10(dense[-1]) + 1e-9:  # a grid given wider than the plant's
        dense = np.union1d(dense, np.logspace(lo, hi, int(np.ceil((hi - lo) * 10 * PER_DECADE)) + 1))
    return _far(plant, np.union1d(dense, omega), 3.0, 31)


class Search:
    """The search for ``plant`` on the design grid ``omega`` (see the module docstring): ``bounds`` the problem's
    (the user's and the defaults), ``filter_order`` and ``dt`` the controller's form and period (None: continuous),
    ``Tf_min`` the filter's floor, ``method`` the local solver."""

    def __init__(self, plant: LinearPlant, omega: np.ndarray, bounds: dict[str, float | None], filter_order: int,
                 dt: float | None, Tf_min: float, method: str, given: Any = None) -> None:
        self.plant, self.omega, self.bounds = plant, omega, bounds
        self.filter_order, self.dt, self.Tf_min, self.method = filter_order, dt, Tf_min, method
        self.limits = {Bound(k): m for k, m in bounds.items() if m is not None}  # the bounds set, by name
        self.names = tuple(self.limits)
        self.G = plant.response(omega)
        self.check = check_grid(plant, omega)
        self.G_check = plant.response(self.check)
        self.low = np.logspace(np.log10(omega[0]) - _LOW_DECADES, np.log10(omega[0]), 5 * _LOW_DECADES + 1)[:-1]
        # a measured response: every data point
        grid = omega if plant.rational else np.union1d(omega, plant.measured_response()[0])
        self.count_w = np.concatenate([self.low, grid])
        self.G_count = plant.response(self.count_w)
        # the slices' grid: the design grid at SLICE_PER_DECADE (a given grid: as it is), their starts refined after
        self.reach = bound_reach(plant, bounds)
        self.slice_w = design_grid(plant, _SLICE_PER_DECADE, self.reach) if given is None else omega
        self.G_slice = plant.response(self.slice_w)
        f = np.sort(plant.characteristic_frequencies()) if plant.rational else np.zeros(0)
        self.hints = tuple(float(x) for x in np.concatenate([0.2 * f[:1], f]))  # the slices' reference frequencies
        self.w_mid = float(np.sqrt(omega[0] * omega[-1]) if not f.size else np.exp(np.mean(np.log(f))))
        self._stable: dict[tuple[PIDController, float], bool] = {}
        self._closest: tuple[float, PIDController, float] | None = None  # the stable start closest to the bounds

    # ---- the pieces ----------------------------------------------------------------------------------
    def stable(self, c: PIDController, sign: float) -> bool:
        """The Nyquist criterion on the count grid (a fast check; the result's is on a resolved grid), once per
        controller: the exchange, the start's record and the refinement ask it of the same gains."""
        key = (c, sign)
        if key not in self._stable:
            L = c.response(self.count_w) * sign * self.G_count
            self._stable[key] = bool(unstable_counts(L[None, :], self.plant.unstable_poles,
                                                     self.plant.integrators + c.integrators, self.dt)[0] == 0)
        return self._stable[key]

    def problem(self, omega: np.ndarray, G: np.ndarray, sign: float, scales: Scales, objective: Objective = IE,
                which: Any = None) -> PIDProblem:
        return PIDProblem(omega, sign * G, self.bounds, scales, objective, which=which)

    def scales(self, c: PIDController) -> Scales:
        """Scales from a start: its gains (``kp`` at least a tenth of the derivative's high-frequency gain, ``ki`` at
        least a thousandth of ``kp`` times the plant's middle frequency: a start without proportional or integral
        action still has room for it); a PI start's derivative scale ``kp Ti / 10``, its filter's a hundredth of
        ``Ti``; the filter's floor."""
        kp = max(c.kp, 0.1 * c.kd / c.Tf if c.Tf > 0 else 0.0)
        ki = max(c.ki, 1e-3 * kp * self.w_mid)  # a start with almost no integral action still has room for it
        Ti = kp / ki
        kd = c.kd if c.kd > 0 else 0.1 * kp * Ti
        Tf = c.Tf if c.Tf > 0 else max(0.01 * Ti, self.Tf_min)
        return Scales(kp=kp, ki=ki, kd=kd, Tf=Tf, filter_order=self.filter_order, dt=self.dt, Tf_min=self.Tf_min)

    def plane(self, sign: float, bounds: dict[str, float | None]) -> Any:
        """The stabilising set's plane on the slices' grid for the plant times ``sign``."""
        return plane_of(self.slice_w, sign * self.G_slice, self.count_w, sign * self.G_count, bounds,
                        self.plant.unstable_poles, self.plant.integrators, self.filter_order, self.dt)

    def starts(self) -> tuple[float, list[tuple[str, PIDController]]]:
        """The sign and the starts (see the module docstring); empty where no slice stabilises within the bounds."""
        plant = self.plant
        for sign in [plant.sign] + ([-plant.sign] if plant.unstable_poles else []):
            plane = self.plane(sign, self.bounds)
            found = stabilising_starts(plane, self.Tf_min, keep=_STARTS + 2, hints=self.hints)
            if found:
                return sign, [(name, c) for name, c, _ in found]
        return plant.sign, []

    # ---- the search ----------------------------------------------------------------------------------
    def run(self, objective: Objective = IE,
            seeds: list[tuple[str, PIDController]] | None = None, sign: float | None = None) -> Found:
        """The search (see the module docstring); ``seeds`` and ``sign``: starts given (the IAE's, from the IE
        optimum) instead of the slices. Where none of the first :data:`_STARTS` starts ends on gains that meet the
        bounds with a stable loop, the other slices' starts are tried, then those from relaxed bounds."""
        spare: list[tuple[str, PIDController]] = []
        sliced = seeds is None
        if seeds is None:
            sign, seeds = self.starts()
            seeds, spare = seeds[:_STARTS], seeds[_STARTS:]
            if not seeds:
                sliced = False
                sign, seeds = self.least()
        sign = self.plant.sign if sign is None else sign
        records: list[StartRecord] = []
        self._closest = None
        best = self._try(seeds, sign, objective, records)
        if best is None and spare:
            best = self._try(spare, sign, objective, records)
        if best is None and sliced:  # the slices' starts all failed: from relaxed bounds
            sign, more = self.least()
            best = self._try(more, sign, objective, records)
        if best is None:
            raise self._not_met(len(records))
        found = self.finish(best[1], objective)
        found.records, found.iterations = records, sum(r.iterations for r in records) + found.iterations - \
            best[1].iterations
        return found

    def _try(self, seeds: list[tuple[str, PIDController]], sign: float, objective: Objective,
             records: list[StartRecord]) -> tuple[float, Found] | None:
        """The local solve from each seed, each recorded; the best that meets the bounds with a stable loop."""
        best: tuple[float, Found] | None = None
        for name, c in seeds:
            found = self.local(c, sign, objective, None if best is None else best[0])
            ctrl, sol = found.controller, found.solution
            stable = self.stable(ctrl, sign)
            value = _value(sol, ctrl, objective)
            records.append(StartRecord(name, *ctrl.scaled(sign).parallel(), objective=value,
                                       violation=self.over(ctrl, sign), stable=stable, status=sol.status,
                                       iterations=found.iterations, seconds=found.seconds))
            if found.ratio <= 1.0 + TOLERANCE and stable and (best is None or value < best[0]):
                best = (value, found)
            if stable and (self._closest is None or records[-1].violation < self._closest[0]):
                self._closest = (records[-1].violation, ctrl, sign)
        return best

    def _not_met(self, starts: int) -> InfeasibleError:
        """No start ended on gains that meet every bound with a stable loop: the error that names the bound the
        closest stable one misses most, and by how much; none stable: says so."""
        if self._closest is None:
            return InfeasibleError(f"none of the {starts} starts of the search ended on a stable loop near the bounds "
                                  f"({self._bounds_text()}); this is no proof that no {_form(self.filter_order)} "
                                  "meets them: relax them, or give a grid (w) that resolves the plant")
        _, c, sign = self._closest
        peaks = self.worst(c, sign)
        name, (ratio, w) = max(((k, p[0]) for k, p in peaks.items()), key=lambda kv: kv[1][0])
        what = name.symbol
        return InfeasibleError(f"{name} <= {self.limits[name]:g} was not met: the least largest {what} the search's "
                              f"{starts} starts reached with a stable loop is {ratio * self.limits[name]:.4g} (over by "
                              f"{ratio - 1:.2%}, at {w:.4g} rad/s). Relax that bound, or tune the other form")

    def _bounds_text(self) -> str:
        return ", ".join(f"{k} <= {v:g}" for k, v in self.limits.items())

    def over(self, c: PIDController, sign: float) -> float:
        """The worst bound's ``|X| / M - 1`` on the check grid (its grid points)."""
        C = c.response(self.check)
        L = C * (sign * self.G_check)
        d = np.abs(1 + L)  # |S|, |T|, |KS| share it
        return max(float(np.max(k.numerator(C, L) / d)) / self.limits[k] for k in self.names) - 1.0

    def _near(self, c: PIDController, sign: float, above: float) -> dict[Bound, np.ndarray]:
        """Per bound, the design grid's frequencies at and beside each local maximum of its ``|X| / M`` above
        ``above`` (a plateau's first point; the :data:`_PEAKS` largest) and its largest value's."""
        C, G = c.response(self.omega), sign * self.G
        out = {}
        for k in self.names:
            r = k.magnitude(C, G) / self.limits[k]
            peak = np.zeros(r.size, bool)
            peak[1:-1] = (r[1:-1] > r[:-2]) & (r[1:-1] >= r[2:])
            peak[0], peak[-1] = r[0] >= r[1], r[-1] > r[-2]
            idx = np.flatnonzero(peak & (r > above))
            at = np.zeros(r.size, bool)
            at[idx[np.argsort(-r[idx])][:_PEAKS]] = True  # the largest (a delay's ripples of |KS| would add hundreds)
            at[int(np.argmax(r))] = True  # and the largest of all (|KS| at the grid's end, say)
            beside = at.copy()  # and their neighbours
            beside[1:] |= at[:-1]
            beside[:-1] |= at[1:]
            out[k] = self.omega[beside]
        return out

    def local(self, c: PIDController, sign: float, objective: Objective = IE,
              best: float | None = None) -> Found:
        """The local solve from ``c`` by exchange (see the module docstring): the problem holds, per bound, the
        design grid's frequencies about its peaks above 0.8 of it, in a trust region (:func:`_region`); after each
        solve the peaks over a bound on the check grid (located by successive parabolas) and the design grid's about
        the new peaks join it, and it is solved again, warm, until every bound holds on the check grid within
        :data:`REFINE_TO` inside the region (a solution on its edge that holds every bound moves it). ``best``: the
        value an earlier start reached; this one stops after three solves where it is far behind (:data:`_BEHIND`)."""
        scales = self.scales(c)
        rows = _Rows(self.names)
        rows.add(self._near(c, sign, 0.8))
        return self._exchange(scales, rows, scales.x(c), None, sign, objective, REFINE_TO, best)

    def finish(self, found: Found, objective: Objective = IE) -> Found:
        """The best start's solution refined further, until every bound holds within :data:`FINISH_TO`."""
        if found.ratio <= 1.0 + FINISH_TO:
            return found
        more = self._exchange(found.problem.scales, found.rows, found.solution.x, found.solution, found.sign,
                              objective, FINISH_TO, None, reach=0.5)
        worse = more.ratio > found.ratio or more.solution.violation > _FEASIBLE
        if worse or not self.stable(more.controller, found.sign):
            return found
        more.iterations += found.iterations
        more.refinements += found.refinements + 1
        return more

    def _exchange(self, scales: Scales, rows: _Rows, x0: np.ndarray, warm: Solution | None, sign: float,
                  objective: Objective, refine_to: float, best: float | None, reach: float = 1.0) -> Found:
        t0 = time.perf_counter()
        walk = _Walk(x0, x0, reach, warm)
        iterations = 0
        good: Found | None = None
        for k in range(_ROUNDS):
            problem = self.problem(rows.omega, self.plant.response(rows.omega), sign, scales, objective,
                                   rows.which)
            region = _region(walk.centre, scales.form, walk.reach)
            sol = problem.solve(walk.x0, self.method, box=region, warm=walk.warm)
            iterations += sol.iterations
            ctrl = scales.controller(sol.x)
            verdict = walk.judge(sol, self.stable(ctrl, sign) if sol.violation <= _FEASIBLE else False)
            if verdict is _Next.STOP:
                break
            if verdict is _Next.AGAIN:
                continue
            peaks = self.worst(ctrl, sign, fine=refine_to <= FINISH_TO)
            good = Found(problem, sol, ctrl, sign, refinements=k, ratio=max(p[0][0] for p in peaks.values()),
                         rows=rows)
            over = {name: [q for q in p if q[0] > 1.0 + refine_to] for name, p in peaks.items()}
            edge = _on_edge(sol.x, region, scales.box())
            if not any(over.values()) and not edge:
                break
            if best is not None and not edge and _value(sol, ctrl, objective) >= best:
                break  # behind the best start inside its region: more rows only lower its ki, it cannot win
            if best is not None and k >= 2 and _behind(_value(sol, ctrl, objective), best):
                break  # far behind the best start's optimum after three solves: another basin, not worth refining
            pruned = rows.prune(ctrl, sign, self)  # rows far from their bounds now: out (their multipliers too)
            rows.add({name: np.array([w * f for _, w in p for f in (0.995, 1.0, 1.005)]) for name, p in over.items()})
            rows.add(self._near(ctrl, sign, 0.9))
            walk.accepted(sol, moved=not any(over.values()), keep_multipliers=not pruned)
        if good is None:  # no stable solution from this start: its last, marked as failing
            good = Found(problem, sol, ctrl, sign, ratio=np.inf, rows=rows)
        good.iterations, good.seconds = iterations, time.perf_counter() - t0
        return good

    def worst(self, c: PIDController, sign: float, fine: bool = True) -> dict[Bound, list[tuple[float, float]]]:
        """Per bound, its largest ``|X| / M`` on the check grid and every other peak above 1 (at most
        :data:`_PEAKS`, largest first), ``(|X| / M, w)``; a peak from :data:`_LOCATE` under the bound to
        :data:`_LOCATE_OVER` over it located between its grid points (successive parabolas, every bound's at once),
        the rest as the grid has them (ten times the design grid's density: a peak's top is within a small fraction
        of it; one far over its bound joins the problem as it is). ``fine=False``: every other point of the check
        grid (five times the design grid's density: the starts' refinement to :data:`REFINE_TO`; the best's is on
        the whole)."""
        check, G_check = (self.check, self.G_check) if fine else (self.check[::2], self.G_check[::2])
        C = c.response(check)
        L = C * (sign * G_check)
        d = np.abs(1 + L)  # |S|, |T|, |KS| share it
        picked: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for name in self.names:
            r = name.numerator(C, L) / d / self.limits[name]
            top = np.zeros(r.size, bool)
            top[1:-1] = (r[1:-1] >= r[:-2]) & (r[1:-1] >= r[2:]) & (r[1:-1] > 1.0)
            top[int(np.argmax(r))] = True
            idx = np.flatnonzero(top)
            idx = idx[np.argsort(-r[idx])][:_PEAKS]  # the largest first; the rest in later rounds
            picked[name] = (idx, r[idx])
        near = {k: (r > 1.0 - _LOCATE) & (r < 1.0 + _LOCATE_OVER) for k, (_, r) in picked.items()}
        idx = np.concatenate([picked[k][0][near[k]] for k in self.names])
        names = np.concatenate([np.full(int(near[k].sum()), k, dtype=object) for k in self.names])
        values, where = located(self.plant, c, names, check, idx, sign, steps=3) if idx.size else (idx, idx)
        out = {}
        for name in self.names:
            mine = names == name
            found = [(float(v) / self.limits[name], float(w)) for v, w in zip(values[mine], where[mine])]
            i, r = picked[name]
            out[name] = sorted(found + [(float(x), float(check[j])) for j, x in zip(i[~near[name]],
                                                                                          r[~near[name]])],
                               reverse=True)
        return out

    # ---- no start ------------------------------------------------------------------------------------
    def least(self) -> tuple[float, list[tuple[str, PIDController]]]:
        """Where no slice stabilises within the bounds: the bounds relaxed until one does, and from there the gains
        with the least worst bound (the least-violation problem on the design grid). Gains that meet every bound
        there are the starts ``(sign, [("least violation", controller)])``; else the :class:`InfeasibleError` that
        names the bound no gains meet and the least value reached."""
        plant = self.plant
        seeds: list[tuple[str, PIDController]] = []
        sign = plant.sign
        for factor in RELAX:  # each relaxation for either sign before the next
            for s in [plant.sign] + ([-plant.sign] if plant.unstable_poles else []):
                seeds = [(name, c) for name, c, _ in stabilising_any(self.plane(s, self.bounds), self.bounds,
                                                                     self.Tf_min, self.hints, (factor,))]
                if seeds:
                    sign = s
                    break
            if seeds:
                break
        if not seeds:
            raise InfeasibleError(f"no stabilising {_form(self.filter_order)} was found: the slices searched of the "
                                  f"(kp, ki) plane hold none with the bounds ({self._bounds_text()}) relaxed up to "
                                  f"{RELAX[-1]:g} times. A search, no proof: check the plant and its sign")
        best = None
        for _, c in seeds:
            scales = self.scales(c)
            problem = self.problem(self.omega, self.G, sign, scales)
            least = problem.least_violation(scales.x(c), self.method)
            if self.stable(scales.controller(least.x), sign) and (best is None or least.violation < best[1].violation):
                best = (problem, least)
        if best is None:
            raise InfeasibleError(f"no {_form(self.filter_order)} was found that stabilises this plant and meets the "
                                  f"bounds ({self._bounds_text()}): with them relaxed {factor:g} times a slice "
                                  "stabilises, but the least violation from there is unstable. A search, no proof: "
                                  "relax the bounds, or check the plant")
        problem, least = best
        if least.violation <= 0.0:
            return sign, [("least violation", problem.scales.controller(least.x))]
        self._infeasible(problem, least)

    def _infeasible(self, problem: PIDProblem, least: Solution) -> NoReturn:
        worst = {Bound(k): v for k, v in problem.worst_by_bound(least.x).items()}
        name, (ratio, w) = max(worst.items(), key=lambda kv: kv[1][0])
        what = name.symbol
        others = "; ".join(f"{k} <= {self.limits[k]:g} at {v[0] * self.limits[k]:.4g}"
                           for k, v in worst.items() if k != name)
        raise InfeasibleError(
            f"{name} <= {self.limits[name]:g} cannot be met with a {_form(self.filter_order)} on this plant: the least "
            f"largest {what} the search reached is {ratio * self.limits[name]:.4g} (over by {ratio - 1:.1%}, at "
            f"{w:.4g} rad/s)" + (f"; there, {others}" if others else "") + ". Relax that bound, or tune the other form")


class _Next(Enum):
    """What the exchange does after a solve (:meth:`_Walk.judge`): go on with it, solve again in the changed region,
    or stop this start."""

    OK = "ok"
    AGAIN = "again"
    STOP = "stop"


@dataclass
class _Walk:
    """Where the exchange stands: its start point, the trust region's centre and reach, the warm start."""

    x0: np.ndarray
    centre: np.ndarray
    reach: float
    warm: Solution | None

    def judge(self, sol: Solution, stable: bool) -> _Next:
        """``OK``, or ``AGAIN`` with the region changed, or ``STOP``: a solution off its own rows (no gains in
        the region meet them) widens the region, up to eight times; one that left the stable loops between the rows
        shortens it, down to a sixteenth."""
        if sol.violation > _FEASIBLE:
            if self.reach >= 8.0:
                return _Next.STOP
            self.reach, self.warm = min(2.0 * self.reach, 8.0), None
            return _Next.AGAIN
        if not stable:
            self.reach /= 2.0
            self.warm = None
            return _Next.STOP if self.reach < 1.0 / 16.0 else _Next.AGAIN
        return _Next.OK

    def accepted(self, sol: Solution, moved: bool, keep_multipliers: bool) -> None:
        """The next solve starts from ``sol`` (warm where its rows stayed); ``moved``: it held every bound on the
        region's edge, so the region moves there, twice as wide (its multipliers on the edge would hold the solver
        where it was)."""
        self.x0, self.warm = sol.x, sol if keep_multipliers else None
        if moved:
            self.centre, self.warm, self.reach = sol.x, None, min(2.0 * self.reach, 8.0)


class _Rows:
    """The problem's rows: ``(frequency, bound)`` pairs, in the order they were added (a warm start's multipliers
    stay with their rows)."""

    def __init__(self, names: tuple[Bound, ...]) -> None:
        self.names = names
        self.omega = np.zeros(0)
        self.which = np.zeros(0, dtype=object)
        self._held: dict[Bound, set[float]] = {name: set() for name in names}  # each bound's frequencies, to add once

    def prune(self, c: PIDController, sign: float, search: Search) -> bool:
        """Drop the rows whose ``|X| / M`` is below :data:`_KEEP` at ``c``; whether any were."""
        C, G = c.response(self.omega), sign * search.plant.response(self.omega)
        ratio = np.zeros(self.omega.size)
        for name in self.names:
            mine = self.which == name
            ratio[mine] = Bound(name).magnitude(C[mine], G[mine]) / search.bounds[name]
        keep = ratio >= _KEEP
        if keep.all():
            return False
        self.omega, self.which = self.omega[keep], self.which[keep]
        self._held = {name: set(self.omega[self.which == name].tolist()) for name in self.names}
        return True

    def add(self, per_bound: dict[Bound, np.ndarray]) -> None:
        """Each bound's frequencies it does not hold yet, in increasing order."""
        for name, w in per_bound.items():
            held = self._held[name]
            new = np.array(sorted(set(np.asarray(w, float).ravel().tolist()) - held), float)
            held.update(new.tolist())
            self.omega = np.concatenate([self.omega, new])
            self.which = np.concatenate([self.which, np.full(new.size, name, dtype=object)])


def _region(x: np.ndarray, form: Form, reach: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The trust region about ``x`` (scaled gains, O(1) at the start): ``kp`` and ``ki`` within a factor
    ``1 + reach / 2`` (never to zero: an unstable plant's loop needs its proportional gain; from zero up by a quarter
    of ``reach``), the derivative within
    ``reach / 2`` of its scale (it may reach zero: a PI), the filter's log within ``reach / 2``. A problem holding a
    few frequencies may not move far before the check grid sees it; each move that holds every bound doubles
    ``reach``."""
    f = 1.0 + 0.5 * reach
    lo, hi = x / f, np.maximum(x * f, x + 0.25 * reach)  # a gain at zero may grow by a quarter of its scale
    if x.size != form.variables:
        raise InternalError(f"a {form}'s trust region needs {form.variables} variables, got {x.size}")
    if form is Form.PID:
        lo[2:], hi[2:] = x[2:] - 0.5 * reach * np.array([max(abs(x[2]), 0.1), 1.0]), \
            x[2:] + 0.5 * reach * np.array([max(abs(x[2]), 0.1), 1.0])
    return lo, hi


def _on_edge(x: np.ndarray, region: tuple[np.ndarray, np.ndarray], box: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether ``x`` ends on the trust region's edge where that is not the search box's."""
    tol = 1e-6 * (region[1] - region[0])
    lo = (x - region[0] < tol) & (region[0] > box[0] + tol)
    hi = (region[1] - x < tol) & (region[1] < box[1] - tol)
    return bool(np.any(lo | hi))


def _behind(value: float, best: float) -> bool:
    """Whether ``value`` (``-ki``, or an IAE) is far behind ``best`` (:data:`_BEHIND`)."""
    return value > best * (_BEHIND if best < 0 else 1.0 / _BEHIND)


def _form(filter_order: int) -> Form:
    return Form.of(filter_order)


def _value(sol: Solution, c: PIDController, objective: Objective) -> float:
    """What is minimised, unscaled: ``-ki`` (IE) or the scaled IAE."""
    return objective.value(sol.objective, c.ki)
