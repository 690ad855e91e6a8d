"""Norm-optimal iterative learning control at a trial's scale: the Riccati form, the sparse QP, the robust gain.

**The law** (Amann, Owens, Rogers 1996, "Iterative learning control for discrete-time systems
with exponential rate of convergence", IEE Proc. Control Theory Appl. 143(2)). The learned signal
changes by ``du = F dv`` per trial, ``dv`` minimising

    ``J(dv) = ||e_k - H dv||^2 + w ||dv||^2``

with ``H`` the lifted model of the loop seen through ``F``, the PID's setpoint path
(:class:`~piezopreload.tuning.lifted.LiftedLoop`: ``ff_extra = F dv`` moves the force as a
setpoint change ``dv`` would, so ``H`` is the loop's complementary sensitivity, 1 at low
frequency, and ``w`` weighs a change of setpoint against the force error, both in N). Its
unconstrained minimiser is the Riccati form, ``O(N n^3)``
(:func:`~piezopreload.tuning.lifted.norm_optimal_step`).

**The constrained law.** The command and the amplifier's voltage after the update are predicted
by the model's outputs; where the unconstrained step keeps the command inside its range and the
voltage inside the amplifier's slew it is the constrained optimum too (the problem is convex).
Otherwise :func:`constrained_step` solves the same problem as a sparse QP with the states as
variables (the dynamics as equality constraints: a banded KKT system; Clarabel), the limits as
inequalities, over windows around the samples where the step would break them: after a window
the Riccati law's own cost-to-go (exact), before it the unconstrained step (a window starts
:data:`WINDOW_PAD_S` before the first sample it guards); ``exact=True`` solves the whole trial
as one QP instead.

**Robustness.** The law applies ``u+ = base + Q (u - base + beta F dv)`` (:class:`NormOptimalLaw`;
``base`` the signal learning started from): the gain ``beta`` and the zero-phase Q-filter's
cut-off are chosen on the model's uncertainty set (the loop linearised at every level on the
nominal plant and on Monte Carlo plants drawn with the validation's spread,
:func:`robust_choice`): for long trials the learned signal of a plant ``G`` evolves per frequency
by ``Q (1 - beta G F L)``, ``L = conj(H) / (|H|^2 + w)`` the law's frequency response at that
level, so ``beta`` and ``Q`` are the largest that keep ``|Q| |1 - beta G F L| <= 1`` on every
member (monotone convergence of the linearised loops). The error a trial measures is passed to
the law at full bandwidth only around the plan's changes (:func:`learning_error`); between them
what stands above the sensor's noise: learned, high-frequency noise would dither the stacks,
which shifts their hysteresis from one trial to the next.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from piezopreload.core._typing import Array, BoolArray
from piezopreload.core.errors import InputError, InternalError
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller
from piezopreload.tuning.ilc import LoopLinearisation, linearise_loop, zero_phase_lowpass
from piezopreload.tuning.lifted import (
    DEFAULT_LEVELS,
    LiftedLoop,
    NormOptimalStep,
    RiccatiGains,
    composite,
    costate,
    level_linearisations,
    lifted_loop,
    norm_optimal_step,
    riccati_gains,
    setpoint_path,
)
from piezopreload.tuning.validate import DEFAULT_SPREAD

__all__ = ["Limits", "constrained_step", "uncertainty_set", "with_gain", "RobustChoice", "robust_choice",
           "learning_error", "NormOptimalLaw", "norm_optimal_law", "DEFAULT_WEIGHT"]


#: the weight on a change of setpoint (N) against the force error (N): where the loop passes less than
#: about 10 % of a setpoint change (``|H|^2 < w``) the law learns little (the noise's band)
DEFAULT_WEIGHT = 0.01
#: the error is learned at full bandwidth from this long before a change of the plan to this long after it
WINDOW_BEFORE_S = 0.05
WINDOW_AFTER_S = 0.1
#: between the plan's changes the error is low-passed here before it is learned (the sensor noise out)
HOLD_CUTOFF_HZ = 10.0
#: between the changes, what the error holds above the hold's cut-off is learned beyond this many times the
#: sensor's noise (a soft threshold: 3 sigma passes a Gaussian noise's sample 0.3 % of the time)
NOISE_THRESHOLD = 3.0
#: a constrained window starts this long before the first sample whose limit it guards
WINDOW_PAD_S = 0.1


# --------------------------------------------------------------------------------------
# the constrained law: a sparse QP with the states as variables
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Limits:
    """What the step must keep: the command inside ``u_range_V``, the amplifier's voltage moving at most
    ``slew_V_per_sample``; ``command_V`` and ``voltage_V`` the last trial's (a sample already outside a limit is
    held where it was, not made worse)."""

    u_range_V: tuple[float, float]
    slew_V_per_sample: float
    command_V: Array
    voltage_V: Array

    def broken(self, step: NormOptimalStep, tol: float = 1e-6) -> BoolArray:
        """Per sample: where the command or the voltage after ``step`` breaks a limit (one plant)."""
        lo, hi = self.u_range_V
        c, v = self.command_V, self.voltage_V
        cmd, volt = c + step.command_V, v + step.voltage_V
        out = (cmd > np.maximum(hi, c) + tol) | (cmd < np.minimum(lo, c) - tol)
        rate = np.abs(np.diff(volt)) > self.room() + tol
        out[:-1] |= rate
        out[1:] |= rate
        return out

    def room(self) -> Array:
        return np.maximum(self.slew_V_per_sample, np.abs(np.diff(self.voltage_V)))


@dataclass
class _Window:
    """The sparse rows of a window's QP in ``z = (x_{t0+1} .. x_{t1}, dv_{t0} .. dv_{t1-1})``: the dynamics
    (``dyn z = rhs``) and the force, command and voltage at ``t0 .. t1`` (``rows[name] z + const[name]``)."""

    dyn: Any
    rhs: Array
    rows: dict[str, Any]
    const: dict[str, Array]
    nx: int
    k: int
    ends: bool


def _window_rows(lifted: LiftedLoop, t0: int, t1: int, x0: Array) -> _Window:
    import scipy.sparse as sp

    m, k = lifted.states, t1 - t0
    nx = k * m
    ends = t1 < lifted.n  # the voltage at t1 (a sample of the trial) is constrained too
    eye = np.arange(m)
    dyn: list[tuple[Array, Array, Array]] = []
    out: dict[str, list[tuple[Array, Array, Array]]] = {"force": [], "command": [], "voltage": []}
    rhs, const = np.zeros(nx), {name: np.zeros(k + 1) for name in out}

    def put(into: list[tuple[Array, Array, Array]], rows: Any, cols: Any, vals: Any) -> None:
        into.append(tuple(np.ravel(a) for a in np.broadcast_arrays(rows, cols, vals)))  # type: ignore[arg-type]

    for i, t in enumerate(range(t0, t1)):
        A, B, C, Cu, Du, Cv = lifted.at(t)
        row = i * m + eye  # the rows of x_{t+1}; x_t's columns are (i - 1) m + eye
        if t == 0:  # the start: x_1 = B0 dv_0, the first sample's outputs direct in dv_0
            B, Du = lifted.B0, lifted.Du0
            put(out["force"], 0, nx, lifted.D0)
            put(out["voltage"], 0, nx, lifted.V0)
        elif i == 0:  # the state at t0 is held: its outputs are constants
            const["force"][0], const["command"][0], const["voltage"][0] = C @ x0, Cu @ x0, Cv @ x0
            rhs[row] = A @ x0
        else:
            cols = (i - 1) * m + eye
            put(dyn, row[:, None], cols[None, :], -A)
            for name, vec in (("force", C), ("command", Cu), ("voltage", Cv)):
                put(out[name], np.full(m, i), cols, vec)
        put(dyn, row, row, np.ones(m))
        put(dyn, row, np.full(m, nx + i), -B)
        put(out["command"], i, nx + i, Du)
    if ends:
        put(out["voltage"], np.full(m, k), (k - 1) * m + eye, lifted.at(t1)[5])

    def matrix(parts: list[tuple[Array, Array, Array]], rows: int) -> Any:
        r, c, v = (np.concatenate([p[j] for p in parts]) if parts else np.zeros(0) for j in range(3))
        return sp.csr_matrix((v, (r.astype(int), c.astype(int))), shape=(rows, nx + k))

    return _Window(matrix(dyn, nx), rhs, {name: matrix(parts, k + 1) for name, parts in out.items()}, const, nx, k,
                   ends)


def _window_limits(win: _Window, limits: Limits, t0: int, t1: int) -> tuple[list[Any], list[Array]]:
    """The inequality rows ``G z <= h`` that keep the limits over the window."""
    import scipy.sparse as sp

    rows, bounds = [], []
    lo, hi = limits.u_range_V
    last = limits.command_V[t0:t1]
    c, cmd = last + win.const["command"][: win.k], win.rows["command"][: win.k]
    if np.isfinite(hi):
        rows.append(cmd)
        bounds.append(np.maximum(hi, last) - c)
    if np.isfinite(lo):
        rows.append(-cmd)
        bounds.append(c - np.minimum(lo, last))
    if np.isfinite(limits.slew_V_per_sample):
        j = win.k if win.ends else win.k - 1  # the voltage's steps the window holds
        D = sp.eye(j, j + 1, k=1) - sp.eye(j, j + 1)
        volt = D @ win.rows["voltage"][: j + 1]
        step_last = np.diff(limits.voltage_V[t0:t0 + j + 1] + win.const["voltage"][: j + 1])
        room = limits.room()[t0:t0 + j]
        rows += [volt, -volt]
        bounds += [room - step_last, room + step_last]
    return rows, bounds


def _window_qp(gains: RiccatiGains, e: Array, limits: Limits, t0: int, t1: int, x0: Array, s_end: Array) -> Array:
    """``dv`` over samples ``t0 .. t1 - 1`` minimising the errors there and the Riccati cost to go from ``t1``
    (``x' P[t1] x - 2 s_end' x``), the state at ``t0`` held at ``x0`` (ignored for ``t0 = 0``, the start), the
    limits kept: a sparse QP with the states as variables (Clarabel)."""
    import clarabel
    import scipy.sparse as sp

    lifted, w = gains.lifted, gains.weight
    m = lifted.states
    win = _window_rows(lifted, t0, t1, x0)
    nx, k = win.nx, win.k
    force = win.rows["force"][:k]
    # the cost: the errors over the window, the weight on dv, and the cost to go after it (on x_{t1})
    P = 2.0 * (force.T @ force) + 2.0 * w * sp.diags(np.r_[np.zeros(nx), np.ones(k)])
    P = P + sp.bmat([[sp.csr_matrix((nx - m, nx - m)), None, None], [None, sp.csr_matrix(2.0 * gains.P[t1]), None],
                     [None, None, sp.csr_matrix((k, k))]])
    q = -2.0 * (force.T @ (e[t0:t1] - win.const["force"][:k]))
    q[nx - m:nx] -= 2.0 * s_end
    rows, bounds = _window_limits(win, limits, t0, t1)
    A_all = sp.vstack([win.dyn, *rows], format="csc")
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    cones = [clarabel.ZeroConeT(nx)] + ([clarabel.NonnegativeConeT(A_all.shape[0] - nx)] if rows else [])
    solution = clarabel.DefaultSolver(sp.triu(P, format="csc"), q, A_all, np.concatenate([win.rhs, *bounds]), cones,
                                      settings).solve()
    status = str(solution.status)
    if status not in ("Solved", "AlmostSolved"):
        lo, hi = limits.u_range_V
        raise InternalError(f"the constrained norm-optimal step ended '{status}' (Clarabel) over samples {t0}..{t1}: "
                            f"the command's range {lo:g}..{hi:g} V or the slew {limits.slew_V_per_sample:g} V per "
                            "sample cannot be kept there")
    return np.asarray(solution.x, float)[nx:]


def _windows(broken: Array, pad: int, after: int) -> list[tuple[int, int]]:
    """Merged sample windows ``[t0, t1)`` from ``pad`` before to ``after`` past each broken sample."""
    out: list[tuple[int, int]] = []
    n = broken.size
    for t in np.flatnonzero(broken):
        a, b = max(int(t) - pad, 0), min(int(t) + after + 1, n - 1)
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return [(a, b) for a, b in out if b > a]


@dataclass
class _Rollout:
    """One plant's step as the law rolls it out: ``dv``, the outputs' changes, and the state at every sample."""

    dv: Array
    du: Array
    force: Array
    command: Array
    voltage: Array
    X: Array

    @property
    def step(self) -> NormOptimalStep:
        return NormOptimalStep(self.dv, self.du, self.force, self.command, self.voltage)


def _rollout(gains: RiccatiGains, bs: Array, e0: float, fixed: Array, t_from: int = 0,
             base: _Rollout | None = None, t_to: int | None = None) -> _Rollout:
    """The forward pass for one plant over samples ``t_from .. t_to - 1`` (in ``base``, changed in place; its
    state at ``t_from`` the start): the feedback law's ``dv``, or ``fixed`` where that is finite."""
    lifted, K, den = gains.lifted, gains.K, gains.den
    n, m = lifted.n, lifted.states
    r = (_Rollout(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros((n, m))) if base is None
         else base)
    if t_from == 0:
        d = fixed[0] if np.isfinite(fixed[0]) else (lifted.D0 * e0 + bs[0]) / den[0]
        r.dv[0], r.du[0], r.force[0] = d, lifted.Fd * d, lifted.D0 * d
        r.command[0], r.voltage[0] = lifted.Du0 * d, lifted.V0 * d
        x, t_from = lifted.B0 * d, 1
    else:
        x = r.X[t_from]
    for t in range(t_from, n if t_to is None else min(t_to, n)):
        A, B, C, Cu, Du, Cv = lifted.at(t)
        r.X[t] = x
        d = fixed[t] if np.isfinite(fixed[t]) else -K[t] @ x + bs[t] / den[t]
        r.dv[t], r.du[t], r.force[t] = d, lifted.Fx @ x + lifted.Fd * d, C @ x
        r.command[t], r.voltage[t] = Cu @ x + Du * d, Cv @ x
        x = A @ x + B * d
    return r


def constrained_step(gains: RiccatiGains, e: Array, limits: Limits, *, exact: bool = False,
                     pad_s: float = WINDOW_PAD_S, rounds: int = 4) -> NormOptimalStep:
    """``min ||e - H dv||^2 + w ||dv||^2`` with ``limits`` kept after the step (one plant).

    Where the unconstrained step keeps the limits it is returned. Otherwise a sparse QP (the states
    as variables, Clarabel) over each window around the broken samples, from ``pad_s`` before to a
    few samples after: the state at the window's start the step's so far, the cost after its end the
    Riccati cost to go (exact), the samples after it the Riccati law's from the new state; new
    breaks (the step changed downstream) are windowed in the next round. ``exact`` solves the whole
    trial as one QP instead.
    """
    lifted = gains.lifted
    e = np.asarray(e, float)
    if e.shape != (lifted.n,):
        raise InputError(f"constrained_step: e needs {lifted.n} samples (one plant), got shape {e.shape}")
    bs, S = costate(gains, e[:, None], keep=True)
    bs, fixed = bs[:, 0], np.full(lifted.n, np.nan)
    if exact:
        fixed = _window_qp(gains, e, limits, 0, lifted.n, np.zeros(lifted.states), np.zeros(lifted.states))
        return _rollout(gains, bs, e[0], fixed).step
    r = _rollout(gains, bs, e[0], fixed)
    pad = int(round(pad_s / lifted.dt_s))
    for _ in range(rounds):
        broken = limits.broken(r.step) & np.isnan(fixed)
        if not broken.any():
            return r.step
        windows = _windows(broken, pad, 3)
        for i, (t0, t1) in enumerate(windows):
            fixed[t0:t1] = _window_qp(gains, e, limits, t0, t1, r.X[t0], S[t1][:, 0])
            # on to the next window's start (its state), after the last to the end
            _rollout(gains, bs, e[0], fixed, t0, r, windows[i + 1][0] + 1 if i + 1 < len(windows) else None)
    if limits.broken(r.step, tol=1e-4).any():
        raise InternalError("the constrained norm-optimal step still breaks the limits after "
                            f"{rounds} rounds of windows")
    return r.step


# --------------------------------------------------------------------------------------
# robustness: the gain and the Q-filter from the uncertainty set
# --------------------------------------------------------------------------------------
def _frequency_response(A: Array, B: Array, C: Array, z: Array) -> Array:
    """``C (zI - A)^-1 B`` at ``z`` (the force read before the command: a sample late, as the lifted model)."""
    m = A.shape[0]
    res = np.linalg.solve(z[:, None, None] * np.eye(m) - A, np.broadcast_to(B[:, None], (z.size, m, 1)))
    return (C @ res)[:, 0]


def _q_gain(f_Hz: Array, cutoff_Hz: float, dt_s: float, order: int = 2) -> Array:
    """The zero-phase Butterworth's magnitude (run forward and back: squared)."""
    if cutoff_Hz >= 0.5 / dt_s:
        return np.ones_like(f_Hz)
    ratio = np.tan(np.pi * f_Hz * dt_s) / np.tan(np.pi * cutoff_Hz * dt_s)
    return 1.0 / (1.0 + ratio ** (2 * order))


@dataclass(frozen=True)
class RobustChoice:
    """The law's gain ``beta`` and Q-filter cut-off chosen on an uncertainty set of ``members`` linearised loops;
    ``contraction`` is ``max |1 - beta Q G F L|`` over the set and the frequencies from 0.1 Hz to where the
    law stops learning (``|H|^2 = w`` of the nominal model); ``learning_band_Hz`` that upper frequency."""

    gain: float
    q_cutoff_Hz: float
    contraction: float
    members: int
    learning_band_Hz: float

    def to_dict(self) -> dict[str, Any]:
        return {"gain": self.gain, "q_cutoff_Hz": self.q_cutoff_Hz, "contraction": self.contraction,
                "uncertainty_members": self.members, "learning_band_Hz": self.learning_band_Hz}


def _ratios(nominal: LiftedLoop, members: list[list[LoopLinearisation]], controller: Controller, weight: float,
            z: Array) -> tuple[Array, Array]:
    """``G F L`` per member and level (rows) and frequency (columns), and ``|H|^2`` of the nominal per level."""
    kp, ki_dt = setpoint_path(controller)
    rows, power = [], []
    for j in range(nominal.force_levels_N.size):
        H = _frequency_response(nominal.A[j], nominal.B[j], nominal.C[j], z)
        L = np.conj(H) / (np.abs(H) ** 2 + weight)
        power.append(np.abs(H) ** 2)
        for plant in members:
            A, B, C = composite(plant[j], kp, ki_dt)[:3]
            rows.append(_frequency_response(A, B, C, z) * L)
    return np.array(rows), np.array(power)


def robust_choice(nominal: LiftedLoop, members: list[list[LoopLinearisation]], controller: Controller, weight: float,
                  *, gain_max: float = 1.0, margin: float = 0.9) -> RobustChoice:
    """The largest gain (at most ``gain_max``) and Q cut-off that keep ``|Q| |1 - beta G F L| <= 1`` on every member.

    ``members``: per plant of the set, its loop linearised at each of the nominal model's levels (the
    same voltages). With ``r = G F L`` per frequency, ``|1 - beta r| <= 1`` asks ``beta |r|^2 <= 2 Re r``:
    ``beta`` is ``margin`` of the least such bound below the first frequency where some member's phase
    turns past 90 degrees from the nominal's (``Re r <= 0``, where no gain keeps it); the Q-filter (a
    zero-phase Butterworth on the learned signal) has the highest cut-off, from Nyquist down, that
    brings ``|Q| |1 - beta r|`` to at most 1 everywhere else.
    """
    dt = nominal.dt_s
    f = np.geomspace(0.01, 0.5 / dt, 400)
    z = np.exp(1j * 2 * np.pi * f * dt)
    r, power = _ratios(nominal, members, controller, weight, z)
    turned = np.any(r.real <= 0.0, axis=0)
    below = np.arange(f.size) < (int(np.argmax(turned)) if turned.any() else f.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(r.real > 0, 2.0 * r.real / np.abs(r) ** 2, np.inf)
    if not below.any():
        raise InternalError("no gain keeps the norm-optimal law monotone on the uncertainty set: the members' phase "
                            f"turns beyond 90 degrees from the model's already at {f[0]:g} Hz")
    gain = float(min(gain_max, margin * float(np.min(bound[:, below]))))
    growth = np.max(np.abs(1.0 - gain * r), axis=0)  # per frequency, the worst member's
    cutoff = 0.5 / dt
    while np.any(_q_gain(f, cutoff, dt) * growth > 1.0 + 1e-12) and cutoff > f[0]:
        cutoff /= 1.05
    Q = _q_gain(f, cutoff, dt)
    learns = np.min(power, axis=0) >= weight
    band = float(f[np.flatnonzero(learns)[-1]]) if learns.any() else float(f[0])
    sel = (f >= 0.1) & (f <= band)
    contraction = float(np.max(Q[sel] * growth[sel])) if sel.any() else 1.0
    return RobustChoice(gain, cutoff, contraction, len(members), band)


def uncertainty_set(params: Plant, controller: Controller, nominal: list[LoopLinearisation], plants: int,
                    spread: dict[str, float] | None = None, seed: int = 0) -> list[list[LoopLinearisation]]:
    """The nominal plant and ``plants`` Monte Carlo plants (the validation's spread), each linearised at the
    voltages of ``nominal``."""
    volts = [lin.voltage_V for lin in nominal]
    members = [nominal]
    if plants:
        batch = params.vary(plants, spread or DEFAULT_SPREAD, seed)
        members += [linearise_loop(batch.take(i), controller, volts) for i in range(plants)]
    return members


# --------------------------------------------------------------------------------------
# the error the law learns from
# --------------------------------------------------------------------------------------
def learning_error(e: Array, target_N: Array, dt_s: float, noise_N: float = 0.0, *, before_s: float = WINDOW_BEFORE_S,
                   after_s: float = WINDOW_AFTER_S, hold_cutoff_Hz: float = HOLD_CUTOFF_HZ,
                   noise_threshold: float = NOISE_THRESHOLD) -> Array:
    """The error a trial measured as the law learns it: at full bandwidth from ``before_s`` before each change of the
    plan ``target_N`` to ``after_s`` after it; elsewhere low-passed at ``hold_cutoff_Hz`` (zero phase), plus what
    its rest holds beyond ``noise_threshold`` times the sensor's noise ``noise_N`` (soft-thresholded: that much
    less).

    Where the plan holds, what the error holds above a few hertz is mostly the sensor's noise, different
    in every trial; learned, it would come back as a dither of the stacks. A transient well above the
    noise (a loop settling after a long ramp) is learned all the same.
    """
    e = np.asarray(e, float)
    moving = np.abs(np.diff(np.asarray(target_N, float), prepend=float(target_N[0]))) > 1e-9
    before, after = int(round(before_s / dt_s)), int(round(after_s / dt_s))
    n = moving.size
    near = np.convolve(moving.astype(float), np.ones(after + 1))[:n] > 0  # a change in the last `after` samples
    near |= np.convolve(moving[::-1].astype(float), np.ones(before + 1))[:n][::-1] > 0  # or in the next `before`
    slow = zero_phase_lowpass(e, hold_cutoff_Hz, dt_s)
    rest = e - slow
    kept = np.sign(rest) * np.maximum(np.abs(rest) - noise_threshold * float(noise_N), 0.0)
    return np.where(near, e, slow + kept)


# --------------------------------------------------------------------------------------
# the law
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class NormOptimalLaw:
    """The norm-optimal law on one trial's lifted loop, its gain and Q-filter chosen robustly.

    :meth:`update` makes the next trial's signal from the last one's, its error, its command and its
    voltage: ``base + Q (u - base + gain du)``, ``du`` the norm-optimal step on :func:`learning_error`
    (unconstrained, or the sparse QP where the step would take the command outside its range or the
    voltage past the amplifier's slew: :func:`constrained_step`); ``base_V`` is the signal learning
    started from (the previewed feedforward) and ``Q`` the zero-phase low-pass of the robust choice
    (the identity where its cut-off is Nyquist).
    """

    lifted: LiftedLoop
    weight: float
    robust: RobustChoice
    u_range_V: tuple[float, float]
    slew_V_per_sample: float
    target_N: Array
    base_V: Array
    noise_N: float = 0.0
    constrained: bool = True
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def gains(self) -> RiccatiGains:
        cached = self.__dict__.get("_gains")
        if cached is None:
            cached = riccati_gains(self.lifted, self.weight)
            object.__setattr__(self, "_gains", cached)  # the recursion depends on the model alone: once per law
        return cached

    def update(self, u: Array, e: Array, command_V: Array, voltage_V: Array) -> Array:
        """The next trial's ``ff_extra`` for each plant (last axis the samples), from the last trial's signal ``u``,
        its error ``e`` and its command and amplifier voltage (the limits' starting point)."""
        dt, gain = self.lifted.dt_s, self.robust.gain
        e_l = learning_error(e, self.target_N, dt, self.noise_N)
        step = norm_optimal_step(self.gains, e_l)
        du = gain * step.du
        if self.constrained:
            du = self._constrained(step, e_l, command_V, voltage_V, du)
        learned = np.asarray(u, float) - self.base_V + du
        return self.base_V + zero_phase_lowpass(learned, self.robust.q_cutoff_Hz, dt)

    def _constrained(self, step: NormOptimalStep, e_l: Array, command_V: Array, voltage_V: Array, du: Array) -> Array:
        """``du`` with the sparse QP's step for each plant whose step at the gain would break a limit."""
        gain = self.robust.gain
        flat = [np.reshape(np.asarray(a, float), (-1, self.lifted.n)) for a in (e_l, command_V, voltage_V, du)]
        for i in range(flat[0].shape[0]):
            limits = Limits(self.u_range_V, self.slew_V_per_sample, flat[1][i], flat[2][i])
            scaled = NormOptimalStep(*(gain * np.reshape(getattr(step, k), (-1, self.lifted.n))[i]
                                       for k in ("dv", "du", "force_N", "command_V", "voltage_V")))
            if limits.broken(scaled).any():  # the step at the gain, with the limits: its error scaled by the gain
                self.stats["constrained_steps"] = self.stats.get("constrained_steps", 0) + 1
                flat[3][i] = constrained_step(self.gains, gain * flat[0][i], limits).du
        return flat[3].reshape(np.shape(du))

    def to_dict(self) -> dict[str, Any]:
        return {"law": "norm-optimal", "weight": self.weight, "levels": self.lifted.force_levels_N.size,
                "level_range_N": [float(self.lifted.force_levels_N[0]), float(self.lifted.force_levels_N[-1])],
                **self.robust.to_dict(), "contraction_over_range": self.robust.contraction,
                "constrained_steps": int(self.stats.get("constrained_steps", 0))}


def norm_optimal_law(params: Plant, controller: Controller, target_N: Array, base_V: Array | None = None, *,
                     weight: float = DEFAULT_WEIGHT, levels: int = DEFAULT_LEVELS, plants: int = 8,
                     spread: dict[str, float] | None = None, seed: int = 0, constrained: bool = True) -> NormOptimalLaw:
    """The norm-optimal law of ``controller`` on ``params`` along the plan ``target_N`` (learning from ``base_V``,
    zero by default): the lifted loop (:func:`lifted_loop`), its gain and Q-filter from the uncertainty set of
    the nominal plant and ``plants`` Monte Carlo plants drawn with ``spread`` (:func:`robust_choice`)."""
    if params.batch_shape:
        raise InputError("norm_optimal_law: give the nominal plant, not a batch")
    target = np.asarray(target_N, float)
    lins = level_linearisations(params, controller, target, levels)
    lifted = lifted_loop(params, controller, target, linearisations=lins)
    choice = robust_choice(lifted, uncertainty_set(params, controller, lins, plants, spread, seed), controller, weight)
    g = controller.gains
    base = np.zeros_like(target) if base_V is None else np.asarray(base_V, float)
    if base.shape != target.shape:
        raise InputError(f"base_V has shape {base.shape}; the plan {target.shape}")
    return NormOptimalLaw(lifted, float(weight), choice, (g.u_min_V, g.u_max_V),
                          float(params.slew_V_per_s) * params.sample_period_s, target, base, float(params.noise_N),
                          constrained)


def with_gain(law: NormOptimalLaw, gain: float) -> NormOptimalLaw:
    """The law with another learning gain (a test's divergent law, say)."""
    return replace(law, robust=replace(law.robust, gain=float(gain)), stats={})
