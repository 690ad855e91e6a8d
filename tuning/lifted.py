"""The loop over one trial as the norm-optimal law sees it, and the law's unconstrained step in its Riccati form.

The learned signal changes by ``du = F dv`` per trial, ``F`` the PI-shaped setpoint path of the
PID (``F = Kc b + Kc / Ti`` times the trapezoidal integral): ``ff_extra = F dv`` moves the force as
a setpoint change ``dv`` would. :class:`LiftedLoop` is the lifted (trial-domain) model ``H`` of
the loop seen through ``F``: the loop linearised at rest at a set of levels
(:func:`~piezopreload.tuning.ilc.linearise_loop`), each sample taking the model of the planned
force there, interpolated between levels (the designed plant's Hertzian nuts stiffen with the
preload), its first sample carrying the controller's bumpless start (the integral takes up the
first ``ff_extra``): a linear time-varying model.

**The Riccati form.** ``min ||e - H dv||^2 + w ||dv||^2`` is a finite-horizon linear-quadratic
tracking problem in the state space of ``H``: its minimiser is one backward Riccati recursion (the
gains, once per model and weight: :func:`riccati_gains`), one backward pass for the costate driven
by ``e`` and one forward pass (:func:`norm_optimal_step`): ``O(N n^3)`` for ``N`` samples and ``n``
states, where the dense normal equations ``(H^T H + w I) dv = H^T e`` are ``O(N^3)``. It is the
same computation as a Rauch-Tung-Striebel smoother estimating ``dv`` (prior variance ``1 / w``)
from ``e = H dv + `` unit white noise. The law around it is :mod:`piezopreload.tuning.norm_optimal`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np

from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller
from piezopreload.tuning.ilc import LoopLinearisation, linearise_loop

__all__ = ["LiftedLoop", "lifted_loop", "level_linearisations", "composite", "setpoint_path", "RiccatiGains",
           "riccati_gains", "NormOptimalStep", "costate", "norm_optimal_step", "DEFAULT_LEVELS"]


#: the levels the loop is linearised at between the plan's lowest and highest force
DEFAULT_LEVELS = 12


# --------------------------------------------------------------------------------------
# the lifted loop
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LiftedLoop:
    """The loop over one trial as the norm-optimal law sees it: ``dv -> F -> loop``, linear, time-varying.

    Per level ``l`` of ``force_levels_N`` the state space ``A[l], B[l]`` with the force ``C[l] x``,
    the command ``Cu[l] x + Du[l] dv`` and the amplifier's voltage ``Cv[l] x`` (the loop's state, then
    the integral of ``F``); sample ``t`` takes ``(1 - frac[t])`` of level ``level[t]`` and ``frac[t]``
    of the next. The first sample is the start: its state is ``E0 dv_0`` (the bumpless start), so
    its force is ``D0 dv_0``, its command ``Du0 dv_0``, its voltage ``V0 dv_0`` and the second
    sample's state ``B0 dv_0``. ``ff_extra`` is ``Fx x + Fd dv``. ``n`` samples long.
    """

    A: Array
    B: Array
    C: Array
    Cu: Array
    Du: Array
    Cv: Array
    B0: Array
    D0: float
    Du0: float
    V0: float
    Fx: Array
    Fd: float
    level: Array
    frac: Array
    force_levels_N: Array
    dt_s: float

    @property
    def n(self) -> int:
        return int(self.level.size)

    @property
    def states(self) -> int:
        return int(self.A.shape[-1])

    def at(self, t: int) -> tuple[Array, Array, Array, Array, float, Array]:
        """``A, B, C, Cu, Du, Cv`` of sample ``t`` (``t >= 1``; the start is :attr:`B0`, :attr:`D0`, ...)."""
        return self.samples[t]

    @property
    def samples(self) -> list[tuple[Array, Array, Array, Array, float, Array]]:
        """Every sample's model, interpolated between its two levels (made once, then kept)."""
        cached = self.__dict__.get("_samples")
        if cached is None:
            a = self.frac
            j, k = self.level, np.minimum(self.level + 1, self.force_levels_N.size - 1)

            def mix(x: Array) -> Array:
                w = a.reshape((-1,) + (1,) * (x.ndim - 1))
                return (1.0 - w) * x[j] + w * x[k]

            per = [mix(x) for x in (self.A, self.B, self.C, self.Cu, self.Du, self.Cv)]
            cached = [(per[0][t], per[1][t], per[2][t], per[3][t], float(per[4][t]), per[5][t]) for t in range(self.n)]
            object.__setattr__(self, "_samples", cached)  # a frozen model keeps what it derived, as a cache
        return cached

    def response(self, dv: Array) -> NormOptimalStep:
        """The force, the command, the voltage and ``ff_extra`` the loop's model gives for ``dv`` (one plant)."""
        dv = np.asarray(dv, float)
        if dv.shape != (self.n,):
            raise InputError(f"dv needs one value per sample ({self.n}), got shape {dv.shape}")
        force, command, voltage, ff = np.zeros(self.n), np.zeros(self.n), np.zeros(self.n), self.Fd * dv
        force[0], command[0], voltage[0] = self.D0 * dv[0], self.Du0 * dv[0], self.V0 * dv[0]
        x = self.B0 * dv[0]
        for t in range(1, self.n):
            A, B, C, Cu, Du, Cv = self.at(t)
            force[t], command[t], voltage[t] = C @ x, Cu @ x + Du * dv[t], Cv @ x
            ff[t] += self.Fx @ x
            x = A @ x + B * dv[t]
        return NormOptimalStep(dv, ff, force, command, voltage)


def level_linearisations(params: Plant, controller: Controller, target_N: Array, count: int) -> list[LoopLinearisation]:
    """Linearisations at rest at ``count`` levels spanning ``target_N`` (by force; at least two)."""
    g = controller.gains
    coarse = linearise_loop(params, controller, np.linspace(g.u_min_V, g.u_max_V, 9))
    volts, forces = np.array([c.voltage_V for c in coarse]), np.array([c.force_N for c in coarse])
    lo, hi = float(np.min(target_N)), float(np.max(target_N))
    wanted = np.linspace(lo, hi, max(count, 2)) if hi > lo else np.array([lo])
    v = np.unique(np.interp(wanted, forces, volts))  # the quasi-static force is monotone in the voltage
    lins = linearise_loop(params, controller, v)
    return sorted(lins, key=lambda lin: lin.force_N)


def composite(lin: LoopLinearisation, kp: float, ki_dt: float) -> tuple[Array, Array, Array, Array, float, Array]:
    """The loop behind the setpoint path ``F``: ``ff = (kp + ki_dt / 2) dv + z``, ``z+ = z + ki_dt dv`` (``z`` the
    integral part of ``F``, in volts: a state of the size of the others)."""
    n = lin.A.shape[0]
    f0 = kp + 0.5 * ki_dt
    A = np.zeros((n + 1, n + 1))
    A[:n, :n], A[:n, n], A[n, n] = lin.A, lin.B, 1.0
    B = np.concatenate([lin.B * f0, [ki_dt]])
    C = np.concatenate([lin.C, [0.0]])
    Cu = np.concatenate([lin.Cu, [lin.Du]])
    return A, B, C, Cu, lin.Du * f0, np.concatenate([lin.Cv, [0.0]])


def setpoint_path(controller: Controller) -> tuple[float, float]:
    """``F``'s proportional gain and its integral gain times the sample period."""
    g = controller.gains
    ki = 0.0 if not np.isfinite(g.Ti_s) else g.Kc / g.Ti_s
    return float(g.Kc * g.b), float(ki * controller.dt_s)


def lifted_loop(params: Plant, controller: Controller, target_N: Array, *, levels: int = DEFAULT_LEVELS,
                linearisations: list[LoopLinearisation] | None = None) -> LiftedLoop:
    """The lifted model of ``controller`` on ``params`` along the planned force ``target_N`` (one per sample).

    The loop is linearised at rest at ``levels`` forces spanning the plan (or at ``linearisations``,
    given), each sample interpolating the two levels about its planned force.
    """
    target = np.asarray(target_N, float)
    if target.ndim != 1 or target.size < 2 or not np.all(np.isfinite(target)):
        raise InputError(f"target_N: give the planned force per sample (finite, at least 2), got shape {target.shape}")
    lins = linearisations if linearisations is not None else level_linearisations(params, controller, target, levels)
    lins = sorted(lins, key=lambda lin: lin.force_N)
    kp, ki_dt = setpoint_path(controller)
    parts = [composite(lin, kp, ki_dt) for lin in lins]
    A, B, C, Cu = (np.stack([p[k] for p in parts]) for k in range(4))
    Du, Cv = np.array([p[4] for p in parts]), np.stack([p[5] for p in parts])
    forces = np.array([lin.force_N for lin in lins])
    if forces.size == 1:
        level, frac = np.zeros(target.size, int), np.zeros(target.size)
    else:
        level = np.clip(np.searchsorted(forces, target, side="right") - 1, 0, forces.size - 2)
        frac = np.clip((target - forces[level]) / np.maximum(forces[level + 1] - forces[level], 1e-12), 0.0, 1.0)
    m = A.shape[-1]
    j0, a0 = int(level[0]), float(frac[0])

    def first(x: Array) -> Array:  # the first sample's model, interpolated as every other sample's
        return x[j0] if a0 == 0.0 else (1.0 - a0) * x[j0] + a0 * x[j0 + 1]

    f0 = kp + 0.5 * ki_dt
    e0 = np.concatenate([lins[j0].E * f0, [0.0]])  # the start state per dv_0 (the integral of F starts at 0)
    Fx = np.zeros(m)
    Fx[-1] = 1.0
    return LiftedLoop(A, B, C, Cu, Du, Cv, first(A) @ e0 + first(B), float(first(C) @ e0),
                      float(first(Cu) @ e0 + first(Du)), float(first(Cv) @ e0), Fx, f0, level.astype(int), frac, forces,
                      float(controller.dt_s))


# --------------------------------------------------------------------------------------
# the Riccati form
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RiccatiGains:
    """The backward Riccati recursion of ``min ||e - H dv||^2 + w ||dv||^2`` on a :class:`LiftedLoop`.

    ``dv_t = -K[t] x_t + (B_t . s_{t+1}) / den[t]`` for ``t >= 1`` (``s`` the costate of the error);
    the first sample: ``dv_0 = (D0 e_0 + B0 . s_1) / den[0]``. ``P[t]`` is the cost to go from sample
    ``t`` on, ``x' P[t] x - 2 s_t' x`` (``P[n] = 0``).
    """

    lifted: LiftedLoop
    weight: float
    K: Array
    den: Array
    P: Array


def riccati_gains(lifted: LiftedLoop, weight: float) -> RiccatiGains:
    """The feedback gains of the norm-optimal step: one backward pass, ``O(N n^3)``."""
    if not (np.isfinite(weight) and weight > 0):
        raise InputError(f"weight must be a finite number > 0, got {weight!r}")
    n, m = lifted.n, lifted.states
    K, den, Ps = np.zeros((n, m)), np.zeros(n), np.zeros((n + 1, m, m))
    P = Ps[n]  # the cost to go after the last sample
    for t in range(n - 1, 0, -1):
        A, B, C = lifted.at(t)[:3]
        PB = P @ B
        d = weight + B @ PB
        BPA = PB @ A
        K[t], den[t] = BPA / d, d
        P = np.outer(C, C) + A.T @ P @ A - np.outer(BPA, BPA) / d
        Ps[t] = P
    den[0] = lifted.D0**2 + weight + lifted.B0 @ P @ lifted.B0
    return RiccatiGains(lifted, float(weight), K, den, Ps)


@dataclass(frozen=True, eq=False)
class NormOptimalStep:
    """One step of the law for one or more plants (leading axes): ``dv``, the ``ff_extra`` change ``du`` and the
    model's prediction of the change of the force, the command and the amplifier's voltage it makes."""

    dv: Array
    du: Array
    force_N: Array
    command_V: Array
    voltage_V: Array


@overload
def costate(gains: RiccatiGains, E: Array, keep: Literal[False] = False) -> tuple[Array, None]: ...


@overload
def costate(gains: RiccatiGains, E: Array, keep: Literal[True]) -> tuple[Array, Array]: ...


def costate(gains: RiccatiGains, E: Array, keep: bool = False) -> tuple[Array, Array | None]:
    """The backward pass for errors ``E`` (samples, plants): ``B_t . s_{t+1}`` per sample and plant, and ``s_t`` itself
    (samples + 1, states, plants) where ``keep``."""
    lifted, K = gains.lifted, gains.K
    n, m, p = lifted.n, lifted.states, E.shape[1]
    bs = np.zeros((n, p))
    S = np.zeros((n + 1, m, p)) if keep else None
    s = np.zeros((m, p))
    one = p == 1  # one plant: vectors (numpy's small-matrix calls cost more than the sums)
    if one:
        s, e = s[:, 0], E[:, 0]
    for t in range(n - 1, 0, -1):
        A, B, C = lifted.at(t)[:3]
        b = B @ s
        bs[t] = b
        if S is not None:
            S[t + 1] = s[:, None] if one else s
        s = (C * e[t] + A.T @ s - K[t] * b) if one else (np.outer(C, E[t]) + A.T @ s - np.outer(K[t], b))
    bs[0] = lifted.B0 @ s
    if S is not None:
        S[1] = s[:, None] if one else s
    return bs, S


def _forward(gains: RiccatiGains, bs: Array, E0: Array) -> tuple[Array, Array, Array, Array, Array]:
    """The forward pass of the law for every plant (``bs`` from :func:`_costate`, ``E0`` the first sample's error):
    ``dv`` and the ``ff_extra``, force, command and voltage changes it makes."""
    lifted, K, den = gains.lifted, gains.K, gains.den
    n, p = lifted.n, bs.shape[1]
    dv, force, command, voltage, ff = (np.zeros((n, p)) for _ in range(5))
    dv[0] = (lifted.D0 * E0 + bs[0]) / den[0]
    force[0], command[0], voltage[0] = lifted.D0 * dv[0], lifted.Du0 * dv[0], lifted.V0 * dv[0]
    ff[0] = lifted.Fd * dv[0]
    x = np.outer(lifted.B0, dv[0])
    for t in range(1, n):
        A, B, C, Cu, Du, Cv = lifted.at(t)
        dv[t] = -K[t] @ x + bs[t] / den[t]
        force[t], command[t], voltage[t] = C @ x, Cu @ x + Du * dv[t], Cv @ x
        ff[t] = lifted.Fx @ x + lifted.Fd * dv[t]
        x = A @ x + np.outer(B, dv[t])
    return dv, ff, force, command, voltage


def norm_optimal_step(gains: RiccatiGains, e: Array) -> NormOptimalStep:
    """The unconstrained minimiser of ``||e - H dv||^2 + w ||dv||^2`` (``e`` along the last axis; plants before it).

    Two passes over the trial: the costate backward, the state forward; every plant of a batch at once.
    """
    lifted = gains.lifted
    e = np.asarray(e, float)
    if e.shape[-1] != lifted.n:
        raise InputError(f"the error has {e.shape[-1]} samples; the model {lifted.n}")
    batch = e.shape[:-1]
    E = e.reshape(-1, lifted.n).T  # (samples, plants)
    bs, _ = costate(gains, E)
    out = _forward(gains, bs, E[0])
    return NormOptimalStep(*(a.T.reshape(batch + (lifted.n,)) for a in out))
