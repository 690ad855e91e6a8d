"""The rig tuner's time-domain part: the tuning model of the compensated loop and its derivatives by the gains.

The loop the tuning differentiates is the one closed loop of :mod:`piezopreload.models.loop`
(:func:`tuning_loop`: the rig's and the controller's one step, the same the simulation, the rig
executor and the generated C code run) with its corners rounded (``smoothing``
:data:`TUNING_SMOOTHING`): the slew clip's corners, and the Bouc-Wen rate's ``|.|`` in one
explicit step per sample (see :func:`~piezopreload.models.actuator.bouc_wen_step`); the output
clamp stays the controller's (a kink, active only when the command reaches its limits). No
noise, no quantisation. It runs over the step and then the trajectory on one horizon (single
shooting) on every plant variant.

The derivatives by the gains are carried along the simulation (forward sensitivities of the
one loop step, first and second order: :func:`sensitivity_step`), so one pass over the horizon
gives the objective, the overshoots and their gradients and Hessians (:class:`Horizon`, handed
to CasADi as a callback with its Jacobians, :class:`TimeDomain`). Where only the values are asked
for (IPOPT's line search trying a step, a start being scored) the loop runs without its
derivatives (:func:`value_step`, the same expressions: the same force to the last bit, in about a
tenth of the time); a point whose derivatives are then asked for runs again with them. Where a
C compiler works both steps run as C, compiled once and cached (:mod:`piezopreload.core.native`);
elsewhere (``engine="plain"``) CasADi's virtual machine evaluates them: the same numbers, so the
same iterates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.core import native
from piezopreload.models.actuator import Plant, PlantModel
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import ControllerModel
from piezopreload.models.hysteresis import InverseModel
from piezopreload.models.loop import LOOP_OUTPUTS, LoopModel
from piezopreload.models.ops import CASADI

__all__ = ["TUNING_SMOOTHING", "tuning_loop", "feedforward_sequence", "loop_rows", "ROWS", "N_GAINS",
           "sensitivity_step", "value_step", "Horizon", "TimeDomain"]

#: how round the tuning model's corners are (see :class:`~piezopreload.models.actuator.PlantModel`):
#: the slew limit's over 1/50 of the limit, the Bouc-Wen direction switch over 1 mV
TUNING_SMOOTHING = 0.02


def tuning_loop(params: Plant, smoothing: float = TUNING_SMOOTHING, schedule_size: int = 0) -> LoopModel:
    """The loop the tuning differentiates: the rig's one step with its corners rounded
    (``smoothing``; 0 is the exact rig), the PID alone (the feedforward enters as ``ff_extra``,
    computed once from the reference; ``schedule_size`` entries of a gain schedule), the sensor
    without quantisation (and no noise given)."""
    return LoopModel(PlantModel.of(params, smoothing), ControllerModel(None, schedule_size=schedule_size))


def feedforward_sequence(feedforward: InverseModel | None, r: np.ndarray) -> np.ndarray:
    """The feedforward's voltage for the reference ``r`` from its initial state (zeros without one)."""
    if feedforward is None:
        return np.zeros_like(r)
    return np.asarray(feedforward(r, feedforward.initial_state()), float)


def loop_rows(ref: Reference, dt: float, ramp_s: float) -> dict[str, np.ndarray]:
    """Per sample of ``ref``: the reference, the objective's weight (ramping up after each change)
    and the sign of the last change (0 before the first), which the overshoot is measured along."""
    n = int(round(ref.duration_s / dt)) + 1
    t = np.arange(n) * dt
    r = ref.at(t)
    k_change = np.searchsorted(ref.times_s, t, side="right") - 1
    t_since = t - ref.times_s[k_change]
    prev_level = np.where(k_change > 0, ref.levels_N[np.maximum(k_change - 1, 0)], ref.levels_N[0])
    return {"r": r, "weight": np.minimum(t_since / ramp_s, 1.0) * dt / ref.duration_s, "sign": np.sign(r - prev_level)}


_RHO_OVERSHOOT = 40.0  # 1/N: at most log(n)/40 ~ 0.16 N conservative, ~0.02 N in practice

#: the gains the time-domain part is differentiated by, in the controller's parameter order
N_GAINS = 5
PAIRS = [(i, j) for i in range(N_GAINS) for j in range(i, N_GAINS)]
#: the per-sample rows of the horizon, in order
ROWS = ("r", "ff", "weight", "sign", "restart")


def _sample(loop: LoopModel) -> tuple[Any, Any, Any, Any, Any, Any]:
    """One sample of the tuning loop over CasADi symbols: ``(x, p, r, ff, restart, out)``, ``out`` the next state
    and the force (the loop restarted first where ``restart`` is 1); the one expression both steps below run."""
    x, p = ca.SX.sym("x", loop.state.size), ca.SX.sym("p", loop.params.size)
    r, ff, restart = ca.SX.sym("r"), ca.SX.sym("ff"), ca.SX.sym("restart")
    x_from = ca.if_else(restart > 0.5, loop.start(CASADI, p, r, ff), x)
    x_next, y = loop.step(CASADI, p, x_from, r, 0.0, ff)
    return x, p, r, ff, restart, ca.vertcat(x_next, y[LOOP_OUTPUTS.index("force_N")])


def value_step(loop: LoopModel) -> ca.Function:
    """One sample of the tuning loop without derivatives: ``(x, p, r, ff, restart) -> (x_next, force)``.

    The same expression as :func:`sensitivity_step`'s state and force (:func:`_sample`), so the same
    numbers to the last bit, for the evaluations that need no derivatives: a trial point of IPOPT's
    line search, a start being scored.
    """
    nx = loop.state.size
    x, p, r, ff, restart, out = _sample(loop)
    return ca.Function("pp_tuning_value_step", [x, p, r, ff, restart], [out[:nx], out[nx]],
                       ["x", "p", "r", "ff", "restart"], ["x_next", "force_N"])


def _pairs(free: Sequence[int]) -> list[tuple[int, int]]:
    """The pairs ``i <= j`` of the gains ``free`` (indices into the gains), in :data:`PAIRS`' order."""
    return [(i, j) for i, j in PAIRS if i in free and j in free]


def sensitivity_step(loop: LoopModel, free: Sequence[int] = tuple(range(N_GAINS))) -> ca.Function:
    """One sample of the tuning loop with its derivatives by the gains carried along.

    ``(xa, p, r, ff, restart) -> (xa_next, out)``: ``xa`` holds the loop's state ``x``, its
    first derivatives ``S = dx/dg`` (by the gains ``g = (Kc, Ti, Td, Tf, b)``, the first five
    controller parameters; by those of them ``free`` names, by index, where the tuning holds the
    others) and its second derivatives ``T`` (one column per pair ``i <= j`` of them);
    ``p`` the loop's parameters; ``out`` the force, its gradient and its second derivatives.
    Where ``restart`` is 1 the loop first starts afresh (the rig at rest at 0 V, the controller
    bumpless at 0 V with the reference and feedforward of this sample: :meth:`LoopModel.start`),
    so the references run one after another on one horizon.

    Forward sensitivities, by CasADi's directional derivatives of the one loop step: with
    ``w = (x, g)`` and directions ``d_i = (S_i, e_i)``, ``S_i+ = F' d_i`` and
    ``T_ij+ = d_j' F'' d_i + F_x T_ij``. Five gains make this one small function that a C loop
    runs over the horizon: the whole NLP's derivatives in one pass, exact. Each direction is its
    own expression, so a held gain left out changes none of the others' numbers; four gains carry
    15 columns instead of 21, three 10.
    """
    free = tuple(int(i) for i in free)
    if not free or list(free) != sorted(set(free)) or not set(free) <= set(range(N_GAINS)):
        raise ValueError(f"free must name gains by increasing index in 0..{N_GAINS - 1}, got {free!r}")
    pairs = _pairs(free)
    nx, n_plant = loop.state.size, loop.plant.params.size
    x, p, r, ff, restart, out = _sample(loop)
    gains = p[n_plant:n_plant + N_GAINS]
    S, T = ca.SX.sym("S", nx, len(free)), ca.SX.sym("T", nx, len(pairs))
    w = ca.vertcat(x, gains)
    directions = ca.vertcat(S, ca.DM.eye(N_GAINS)[:, list(free)])
    first = ca.jtimes(out, w, directions)
    along = [ca.jtimes(out, w, directions[:, a]) for a in range(len(free))]
    second = ca.horzcat(*[ca.jtimes(along[free.index(i)], w, directions[:, free.index(j)]) + ca.jtimes(out, x, T[:, k])
                          for k, (i, j) in enumerate(pairs)])
    xa = ca.vertcat(x, ca.vec(S), ca.vec(T))
    xa_next = ca.vertcat(out[:nx], ca.vec(first[:nx, :]), ca.vec(second[:nx, :]))
    result = ca.vertcat(out[nx], first[nx, :].T, second[nx, :].T)
    return ca.Function("pp_tuningsensitivity_step", [xa, p, r, ff, restart], [xa_next, result],
                       ["xa", "p", "r", "ff", "restart"], ["xa_next", "out"])


class Horizon:
    """The tuning references on one horizon, run on every plant variant with the force's first and
    second derivatives by the gains, and what the NLP takes from them: the objective and the
    step's overshoot (a smooth maximum) per variant, with their gradients and Hessians.

    ``engine`` ``"compiled"`` runs :func:`sensitivity_step` and :func:`value_step` as C (each a
    :class:`~piezopreload.core.native.StepRunner`, built once and cached); ``"plain"`` evaluates the same functions in
    CasADi's virtual machine. :meth:`values` runs the loop without its derivatives, :meth:`evaluate` with them; the
    last evaluation of each is kept: IPOPT asks for values, Jacobians and Hessians at one point. ``free`` names (by
    index into the gains) those the tuning varies (None: all five); the derivatives by the others are not run.
    """

    def __init__(self, loop: LoopModel, variants: list[Plant], rows: np.ndarray, tail: np.ndarray,
                 engine: str, free: Sequence[int] | None = None) -> None:
        self.loop, self.rows, self.tail = loop, rows, tail  # tail: the controller's parameters after the gains
        self.plants = np.array([loop.plant.parameters(v) for v in variants])
        self.n_variants, self.n = len(variants), rows.shape[1]
        self.free = tuple(range(N_GAINS)) if free is None else tuple(int(i) for i in free)
        self.fn = sensitivity_step(loop, self.free)
        self.fn_value = value_step(loop)
        self.size_x = int(self.fn.numel_in(0))
        self.engine = engine
        self.runner: native.StepRunner | None = None
        self.value_runner: native.StepRunner | None = None
        if engine == "compiled":
            suffix = "" if len(self.free) == N_GAINS else "_" + "".join(str(i) for i in self.free)
            self.runner = native.step_runner(("tuning", loop, self.free), lambda: self.fn,
                                             "pp_tuning_sensitivity" + suffix, native.FLAGS_LARGE)
            self.value_runner = native.step_runner(("tuning value", loop), lambda: self.fn_value, "pp_tuning_value")
        self._key: bytes | None = None
        self._value: dict[str, np.ndarray] = {}
        self._values_key: bytes | None = None
        self._values: dict[str, np.ndarray] = {}
        self._rolls: dict[str, ca.Function] = {}  # the plain engine's steps over the horizon

    def _params(self, gains: np.ndarray) -> np.ndarray:
        return np.hstack([self.plants, np.tile(np.concatenate([gains, self.tail]), (self.n_variants, 1))])

    def _run(self, fn: ca.Function, runner: native.StepRunner | None, gains: np.ndarray) -> np.ndarray:
        """``fn``'s outputs ``(variants, outputs, samples)`` over the horizon, each variant from rest."""
        params = self._params(gains)
        r, ff, restart = (self.rows[ROWS.index(k)] for k in ("r", "ff", "restart"))
        x0 = np.zeros(int(fn.numel_in(0)))
        if runner is not None:
            out, _ = runner(params, x0, [r, ff, restart], self.n_variants)
            return out
        if fn.name() not in self._rolls:  # built once: building the derivative step's takes a third of a run
            self._rolls[fn.name()] = fn.mapaccum(self.n)
        roll = self._rolls[fn.name()]
        return np.array([np.asarray(roll(x0, params[v], r[None, :], ff[None, :], restart[None, :])[1], float)
                         .reshape(-1, self.n) for v in range(self.n_variants)])

    def forces(self, gains: np.ndarray) -> np.ndarray:
        """``(variants, 1 + 5 + 15, samples)``: the force, its gradient and its second derivatives (in :data:`PAIRS`'
        order); those by a gain the tuning holds (not in ``free``) are not run and hold 0."""
        ran = self._run(self.fn, self.runner, np.asarray(gains, float))
        if len(self.free) == N_GAINS:
            return ran
        out = np.zeros((self.n_variants, 1 + N_GAINS + len(PAIRS), self.n))
        rows = [0] + [1 + i for i in self.free] + [1 + N_GAINS + PAIRS.index(pair) for pair in _pairs(self.free)]
        out[:, rows, :] = ran
        return out

    def force(self, gains: np.ndarray) -> np.ndarray:
        """``(variants, samples)``: the force alone (:func:`value_step`; the same numbers as :meth:`forces`'s first
        row)."""
        return self._run(self.fn_value, self.value_runner, np.asarray(gains, float))[:, 0, :]

    def _reduced(self, y: np.ndarray) -> dict[str, np.ndarray]:
        """What the NLP reads from the force ``y`` ``(variants, samples)``: the objective and the step's overshoot per
        variant, and the weights their derivatives are made of."""
        r, weight, sign = (self.rows[ROWS.index(k)] for k in ("r", "weight", "sign"))
        # the objective: sum_k w_k phi(r_k - y_k), phi(e) = sqrt(e^2 + 1e-4)
        e = r - y
        phi = np.sqrt(e * e + 1e-4)
        # the step's overshoot: a Kreisselmeier-Steinhauser maximum of sign (y - r); samples before
        # the first change (sign 0) drop out
        o = sign * (y - r) + (np.abs(sign) - 1.0) * 1e3
        m = np.max(o, axis=-1, keepdims=True)
        ex = np.exp(_RHO_OVERSHOOT * (o - m))
        total = np.sum(ex, axis=-1, keepdims=True)
        return {"objective": np.sum(weight * phi, axis=-1), "overshoot": m[:, 0] + np.log(total[:, 0]) / _RHO_OVERSHOOT,
                "e": e, "phi": phi, "pi": ex / total}

    def values(self, gains: Any) -> dict[str, np.ndarray]:
        """The objective and the step's overshoot per variant at ``gains``, without their derivatives (from the last
        :meth:`evaluate` where that was at the same gains): the same numbers as :meth:`evaluate`'s."""
        gains = np.asarray(gains, float).ravel()
        key = gains.tobytes()
        if key == self._key:
            return self._value
        if key != self._values_key:
            reduced = self._reduced(self.force(gains))
            self._values_key = key
            self._values = {"objective": reduced["objective"], "overshoot": reduced["overshoot"]}
        return self._values

    def evaluate(self, gains: Any) -> dict[str, np.ndarray]:
        """The objective and the step's overshoot per variant at ``gains`` with their gradients and Hessians."""
        gains = np.asarray(gains, float).ravel()
        key = gains.tobytes()
        if key == self._key:
            return self._value
        y_all = self.forces(gains)
        y, dy = y_all[:, 0, :], y_all[:, 1:1 + N_GAINS, :]
        d2 = np.zeros((self.n_variants, N_GAINS, N_GAINS, self.n))
        for k, (i, j) in enumerate(PAIRS):
            d2[:, i, j] = d2[:, j, i] = y_all[:, 1 + N_GAINS + k, :]
        weight, sign = (self.rows[ROWS.index(k)] for k in ("weight", "sign"))
        reduced = self._reduced(y)
        e, phi, pi = reduced["e"], reduced["phi"], reduced["pi"]
        d1, dd = e / phi, 1e-4 / phi**3  # phi' and phi''
        w1, w2 = weight * d1, weight * dd  # (variants, samples)
        obj_g = -np.matmul(dy, w1[:, :, None])[..., 0]
        obj_h = np.matmul(dy * w2[:, None, :], dy.transpose(0, 2, 1)) - np.matmul(d2, w1[:, None, :, None])[..., 0]
        s_dy = sign[None, None, :] * dy
        ks_g = np.matmul(s_dy, pi[:, :, None])[..., 0]
        ks_h = (np.matmul(d2, (pi * sign)[:, None, :, None])[..., 0]
                + _RHO_OVERSHOOT * (np.matmul(s_dy * pi[:, None, :], s_dy.transpose(0, 2, 1))
                                    - ks_g[:, :, None] * ks_g[:, None, :]))
        self._key = key
        self._value = {"objective": reduced["objective"], "objective_g": obj_g, "objective_h": obj_h,
                       "overshoot": reduced["overshoot"], "overshoot_g": ks_g, "overshoot_h": ks_h}
        return self._value


class TimeDomain(ca.Callback):
    """The time-domain part of the NLP for CasADi: ``gains -> (objective summed over the
    variants, overshoot per variant)``, with its Jacobian (``order=1``) and the Jacobian of
    that (``order=2``), all from one :class:`Horizon` evaluation."""

    def __init__(self, horizon: Horizon, order: int = 0) -> None:
        ca.Callback.__init__(self)
        self.h, self.order, self.nv = horizon, order, horizon.n_variants
        self._shapes_in = [(N_GAINS, 1), (1, 1), (self.nv, 1), (1, N_GAINS), (self.nv, N_GAINS)][:[1, 3, 5][order]]
        self._children: list[TimeDomain] = []
        self.construct(f"pp_tuning_time_domain_{order}", {})

    def get_n_in(self) -> int:
        return len(self._shapes_in)

    def get_n_out(self) -> int:
        return [2, 2, 6][self.order]

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(*self._shapes_in[i])

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        if self.order == 0:
            return ca.Sparsity.dense(1 if i == 0 else self.nv, 1)
        if self.order == 1:
            return ca.Sparsity.dense(1 if i == 0 else self.nv, N_GAINS)
        # the Jacobian of output i // 3 of order 1 (vectorised, column-major) by its input i % 3:
        # only the gains enter; the nominal outputs it also takes do not
        rows = N_GAINS if i < 3 else self.nv * N_GAINS
        shape = self._shapes_in[i % 3]
        return ca.Sparsity.dense(rows, N_GAINS) if i % 3 == 0 else ca.Sparsity(rows, shape[0] * shape[1])

    def eval(self, arg: Sequence[Any]) -> list[Any]:
        if self.order == 0:  # values only: no derivatives run unless asked for (:meth:`Horizon.values`)
            v = self.h.values(arg[0])
            return [np.sum(v["objective"]), v["overshoot"]]
        v = self.h.evaluate(arg[0])
        if self.order == 1:
            return [np.sum(v["objective_g"], axis=0)[None, :], v["overshoot_g"]]
        # d vec(jac)/d gains: row i the objective's; row v + nv i the overshoot of variant v's
        hess_os = np.transpose(v["overshoot_h"], (1, 0, 2)).reshape(self.nv * N_GAINS, N_GAINS)
        empty = [ca.DM(self.get_sparsity_out(i).size1(), self.get_sparsity_out(i).size2()) for i in range(6)]
        return [np.sum(v["objective_h"], axis=0), empty[1], empty[2], hess_os, empty[4], empty[5]]

    def has_jacobian(self) -> bool:
        return self.order < 2

    def get_jacobian(self, name: str, inames: Sequence[str], onames: Sequence[str],
                     opts: Mapping[str, Any]) -> ca.Function:
        child = TimeDomain(self.h, self.order + 1)
        self._children.append(child)  # CasADi keeps a reference to the Function, not to the Python object
        return child
