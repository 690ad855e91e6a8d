"""Lower bounds no controller beats on the rig: the minimum-time step and the tracking floor.

:func:`minimum_time` is an optimal control problem on the tuning model (the rig's one step with
its corners rounded, :func:`~piezopreload.tuning.horizon.tuning_loop`): the least settling time
any command sequence reaches. :func:`tracking_floor` is a closed-form floor on the RMS tracking
error of any causal controller without preview. The tuned loop is read against both.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from piezopreload.core.errors import InfeasibleError
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import PAPER_BAND_N, Reference
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V
from piezopreload.models.ops import CASADI, NUMPY
from piezopreload.tuning.horizon import tuning_loop
from piezopreload.tuning.linearised import small_signal_gains

__all__ = ["minimum_time", "tracking_floor", "MinimumTime", "CausalFloor"]


@dataclass(frozen=True, eq=False)
class MinimumTime:
    """The minimum-time bound (:func:`minimum_time`): the shortest settling time, in seconds and in samples, the
    command that reaches it, the hold it was judged with, the time the search took and the settling time it started
    from (the first feasible horizon)."""

    settling_s: float
    samples: int
    command_V: np.ndarray
    hold_s: float
    seconds: float
    start_settling_s: float


@dataclass(frozen=True)
class CausalFloor:
    """The floor on a causal controller's RMS tracking error (:func:`tracking_floor`) and the steepest rate the force
    can move at, on which it rests."""

    rms_N: float
    rate_N_per_s: float

#: IPOPT iterations a minimum-time candidate gets (from the previous feasible solution the feasible ones
#: converge in some twenty; one not solved in this many counts as infeasible)
_MIN_TIME_ITERATIONS = 60


class _RigSteps:
    """The tuning model's rig step (the plant of :func:`~piezopreload.tuning.horizon.tuning_loop`) on numpy
    (a batch of states) and in CasADi, with its rest state at 0 V."""

    def __init__(self, params: Plant) -> None:
        self.plant = tuning_loop(params).plant
        self.theta = np.asarray(self.plant.parameters(params), float)
        self.x0 = np.asarray(self.plant.rest_state(NUMPY, self.theta), float)
        x, u = ca.SX.sym("x", self.x0.size), ca.SX.sym("u")
        theta = ca.DM(self.theta)
        self.casadi = ca.Function("rig", [x, u], [self.plant.step(CASADI, theta, x, u),
                                                  self.plant.force(CASADI, theta, x)])

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.asarray(self.plant.step(NUMPY, self.theta, x, u), float)

    def force(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.plant.force(NUMPY, self.theta, x), float)


def _greedy_start(rig: _RigSteps, params: Plant, final_N: float, n: int, u_range: tuple[float, float]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A command sequence that takes the rig to ``final_N`` and holds it there: at each sample, the command
    whose force, held for the delay and three of the amplifier's time constants, is ``final_N`` (two grids
    of candidates, then linear interpolation; the creep is answered sample by sample). Returns the
    states ``(nx, n + 1)``, the commands ``(n,)`` and the forces ``(n,)``."""
    tau_samples = 1.0 / (2.0 * np.pi * float(params.amp_bandwidth_Hz) * params.sample_period_s)
    look = int(params.delay_samples) + 1 + int(np.ceil(3.0 * tau_samples))
    X, U, F = np.empty((rig.x0.size, n + 1)), np.empty(n), np.empty(n)
    X[:, 0] = rig.x0

    def ahead(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        xs = np.broadcast_to(x, (u.size, x.size)).copy()
        for _ in range(look):
            xs = rig.step(xs, u)
        return rig.force(xs)

    for k in range(n):
        lo, hi = u_range
        for _ in range(2):  # a grid of candidates, then a finer one in the bracket
            u = np.linspace(lo, hi, 21)
            err = ahead(X[:, k], u) - final_N
            i = int(np.clip(np.searchsorted(err, 0.0), 1, u.size - 1))
            lo, hi, e_lo, e_hi = u[i - 1], u[i], err[i - 1], err[i]
        U[k] = float(np.clip(lo - e_lo * (hi - lo) / (e_hi - e_lo) if e_hi != e_lo else lo, *u_range))
        F[k] = float(rig.force(X[:, k]))
        X[:, k + 1] = rig.step(X[:, k][None, :], np.array([U[k]]))[0]
    return X, U, F


class _MinimumTimeNLP:
    """The minimum-time feasibility problem over a fixed window: states and commands are variables (multiple
    shooting), the rig's step equality constraints, the command in its range, and the force (scaled by the
    band) inside the band from a candidate sample to the window's end, set through the constraints' bounds, so
    one solver serves every candidate."""

    def __init__(self, rig: _RigSteps, n: int, u_range: tuple[float, float], final_N: float, band_N: float) -> None:
        nx = rig.x0.size
        X, U = ca.MX.sym("X", nx, n + 1), ca.MX.sym("U", 1, n)
        x_next, force = rig.casadi.map(n)(X[:, :n], U)
        self.n, self.nx, self.final_N, self.band_N = n, nx, final_N, band_N
        g = ca.vertcat(ca.vec(X[:, 1:] - x_next), ca.vec((force - final_N) / band_N))
        self.solver = ca.nlpsol("minimum_time", "ipopt", {"x": ca.vertcat(ca.vec(X), ca.vec(U)), "g": g,
                                                          "f": 1e-6 * ca.sumsqr(ca.diff(U, 1, 1))},
                                {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                 "ipopt.max_iter": _MIN_TIME_ITERATIONS})
        lbx = np.concatenate([np.full((nx, n + 1), -np.inf), np.full((1, n), u_range[0])], axis=None)
        ubx = np.concatenate([np.full((nx, n + 1), np.inf), np.full((1, n), u_range[1])], axis=None)
        lbx[:nx], ubx[:nx] = rig.x0, rig.x0  # the first state: at rest
        self.lbx, self.ubx = lbx, ubx

    def solve(self, n_settle: int, X0: np.ndarray, U0: np.ndarray) -> tuple[bool, np.ndarray, np.ndarray]:
        """Whether the force can be in the band from sample ``n_settle`` on; the solution (or the start)."""
        n_dyn = self.nx * self.n
        lbg = np.concatenate([np.zeros(n_dyn), np.where(np.arange(self.n) >= n_settle, -1.0, -np.inf)])
        ubg = np.concatenate([np.zeros(n_dyn), np.where(np.arange(self.n) >= n_settle, 1.0, np.inf)])
        sol = self.solver(x0=np.concatenate([X0.ravel(order="F"), U0]), lbx=self.lbx, ubx=self.ubx, lbg=lbg, ubg=ubg)
        if not self.solver.stats()["success"]:
            return False, X0, U0
        x = np.asarray(sol["x"], float).ravel()
        return True, x[:self.nx * (self.n + 1)].reshape((self.nx, self.n + 1), order="F"), x[self.nx * (self.n + 1):]


def minimum_time(
    params: Plant,
    *,
    initial_N: float = 25.0,
    final_N: float = 60.0,
    band_N: float = PAPER_BAND_N,
    hold_s: float = 0.3,
    u_min_V: float = OUTPUT_MIN_V,
    u_max_V: float = OUTPUT_MAX_V,
    horizon_s: float | None = None,
) -> MinimumTime:
    """The shortest settling time any command sequence gives on this plant: an optimal control problem.

    The command sequence is free (no controller structure, perfect knowledge of the noise-free
    tuning model) within ``[u_min, u_max]``, through the same delay, amplifier bandwidth and slew
    limit, from rest at 0 V; the force must enter the band at sample ``N`` and stay in it to the end
    of a window at least ``hold_s`` longer. The start is a command sequence that gets there (at each
    sample, the command whose force, held a little while, is ``final_N``: :func:`_greedy_start`), which
    settles at some ``N_0``; the smallest feasible ``N`` is then searched down from ``N_0`` (steps of 1,
    1, 2, 2, 4, ... samples while feasible, then bisection), above a bound no command beats (the force
    does not move for ``delay + 1`` samples and then at most at the steepest slope times the slew, as
    :func:`tracking_floor` argues), each candidate one IPOPT solve of the same problem
    (:class:`_MinimumTimeNLP`, the band set through its bounds) started from the last feasible solution. IPOPT finds
    local solutions: the result is the least settling time it finds a command for. ``horizon_s`` (None: as long as the
    start needs) caps the settling time searched.

    Returns a :class:`MinimumTime`.
    """
    t0 = time.perf_counter()
    dt = params.sample_period_s
    rig = _RigSteps(params)
    n_hold = int(round(hold_s / dt))
    n_max = None if horizon_s is None else int(round(horizon_s / dt))
    # the start, over a window long enough for it to settle (twice over where it did not)
    n = n_hold + (n_max if n_max is not None else max(n_hold // 2, 1))
    for _ in range(4):
        X0, U0, F0 = _greedy_start(rig, params, final_N, n, (u_min_V, u_max_V))
        outside = np.flatnonzero(np.abs(F0 - final_N) > band_N)
        n_start = 0 if outside.size == 0 else int(outside[-1]) + 1
        if n - n_start >= n_hold or n_max is not None:
            break
        n *= 2
    if n - n_start < n_hold or (n_max is not None and n_start > n_max):
        raise InfeasibleError(f"no command found that reaches {final_N:g} +/- {band_N:g} N and holds it for "
                              f"{hold_s:g} s{'' if n_max is None else f' within {horizon_s:g} s'} on this plant")
    n = n_start + n_hold
    X0, U0 = X0[:, :n + 1], U0[:n]
    nlp = _MinimumTimeNLP(rig, n, (u_min_V, u_max_V), final_N, band_N)
    rate = small_signal_gains(params)[1] * float(params.slew_V_per_s) * dt  # N per sample, at most
    lo = max(0, int(params.delay_samples + (abs(final_N - initial_N) - band_N) / rate) - 1)  # no command settles here
    lo_found = False
    hi, X_best, U_best = n_start, X0, U0
    # down from the start, a sample, a sample, two, two, four, ... while feasible (each from the last solution,
    # so a few IPOPT iterations); the first infeasible candidate, then bisection below the last feasible one
    steps = iter(2 ** (i // 2) for i in range(64))
    while hi - lo > 1:
        mid = max(hi - next(steps), lo + 1) if lo_found is False else (lo + hi) // 2
        ok, X, U = nlp.solve(mid, X_best, U_best)
        if ok:
            hi, X_best, U_best = mid, X, U
        else:
            lo, lo_found = mid, True
    return MinimumTime(settling_s=hi * dt, samples=hi, command_V=U_best, hold_s=hold_s,
                       seconds=time.perf_counter() - t0, start_settling_s=n_start * dt)


def tracking_floor(params: Plant, reference: Reference) -> CausalFloor:
    """A lower bound on the RMS tracking error of any causal controller without preview.

    After a jump of ``dF`` the force cannot move for ``delay + 1`` samples (the commands that
    decide them were sent before the jump), and then at most ``rate * dt`` per sample, where
    ``rate`` is the amplifier's slew times the steepest local slope of force over voltage
    (:func:`small_signal_gains`; the amplifier's bandwidth, the creep lag and the hysteresis
    only slow it further). So sample ``m`` after the jump errs by at least
    ``max(dF - (m - delay) rate dt, 0)``. Summed over the reference's jumps and divided by the
    samples :meth:`ClosedLoopRun.tracking_error` scores (from the first change to the end),
    that is a floor for its RMS. Returns a :class:`CausalFloor`.
    """
    dt, delay = params.sample_period_s, params.delay_samples
    rate = small_signal_gains(params)[1] * float(params.slew_V_per_s)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n) * dt
    k_jumps = np.searchsorted(t, reference.times_s[1:] - 1e-12)
    ends = np.append(k_jumps[1:], n)
    total = 0.0
    for j, (k, end) in enumerate(zip(k_jumps, ends)):
        jump = abs(float(reference.levels_N[j + 1] - reference.levels_N[j]))
        m = np.arange(int(end - k))
        total += float(np.sum(np.maximum(jump - np.maximum(m - delay, 0) * rate * dt, 0.0) ** 2))
    scored = int(np.sum(t >= reference.times_s[1]))
    return CausalFloor(rms_N=float(np.sqrt(total / scored)), rate_N_per_s=rate)
