"""The inverses of the P-I models: one one-sample step for every model, and the whole-signal inverses.

* :class:`InverseStep`: one sample of the inverse of any model here (classical, the paper's
  asymmetric, Kuhnen's modified, each with or without creep), over the ops table of
  :mod:`piezopreload.models.ops`, so the numpy simulation, the compiled rig step, the exported C
  code and the LabVIEW and PLC exports all run the same algorithm;
* :func:`inverse_realtime`: that step's structure and parameter vector for a model, from the
  numbers the model gives (:class:`InverseSpec`, built by each model's ``inverse_spec()``);
* :class:`InverseClassicalPI`, :class:`InverseAsymmetricPI`, :class:`InverseModifiedPI`,
  :class:`InverseCreepPI`: what each model's ``inverse()`` returns (eqs. (19)-(20) of the paper
  on whole signals for the classical and modified models; the one-sample step for all).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.errors import InputError
from piezopreload.models.hysteresis.operators import DeadZone, inverse_weights, play
from piezopreload.models.ops import CASADI, NUMPY, Layout, Ops

if TYPE_CHECKING:
    from piezopreload.models.hysteresis.creep import CreepPI
    from piezopreload.models.hysteresis.pi import AsymmetricPI, ClassicalPI, ModifiedPI

__all__ = ["InverseSpec", "InverseStep", "inverse_realtime", "InverseClassicalPI", "InverseAsymmetricPI",
           "InverseModifiedPI", "InverseCreepPI", "InverseModel"]

_EMPTY = np.zeros(0)


@dataclass(frozen=True, eq=False)
class InverseSpec:
    """The numbers of a model's one-sample map that its inverse step needs (built by ``model.inverse_spec()``).

    ``weights`` maps a direction (``rising``, and ``falling`` for the paper's asymmetric model) to
    the one-sample weights: the model's, with the creep's one-sample gain added to the linear
    weight. ``shaper`` is the modified model's forward dead-zone superposition; ``creep_weights``,
    ``creep_decay`` and ``creep_input`` the creep bank's ``c``, ``a`` and ``e`` at the model's
    sample period (:class:`~piezopreload.models.hysteresis.creep.LagCoefficients`). ``what``
    names the model in an error.
    """

    thresholds: NDArray[np.float64]
    weights: Mapping[str, NDArray[np.float64]]
    offset: float
    what: str
    bias: float = 0.0
    shaper: DeadZone | None = None
    creep_weights: NDArray[np.float64] = field(default_factory=lambda: _EMPTY)
    creep_decay: NDArray[np.float64] = field(default_factory=lambda: _EMPTY)
    creep_input: NDArray[np.float64] = field(default_factory=lambda: _EMPTY)

    def __post_init__(self) -> None:
        if set(self.weights) not in ({"rising"}, {"rising", "falling"}):
            raise InputError(f"InverseSpec.weights must name 'rising' (and 'falling'), got {sorted(self.weights)}.")


# --------------------------------------------------------------------------------------
# the inverse's one-sample step: one definition for every model, over the ops table
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InverseStep:
    """One sample of the inverse of any P-I model here, over an ops table (:mod:`~piezopreload.models.ops`).

    The structure (sizes and whether the weights switch with the direction) is this object; the
    numbers are a parameter vector (:attr:`params`, built by :func:`inverse_realtime`), so one
    compiled step serves every model of one structure. It is the feedforward component of
    :class:`~piezopreload.models.controller.ControllerModel`, and the same code runs on numpy
    (the simulation, the rig's fall-back), on CasADi (the tuning graph, the compiled rig step,
    the exported C code).

    The state is the *forward* model's state (:attr:`state`): the play operator outputs ``y``
    (n), the creep carries ``s`` (m) and, for the paper's asymmetric model, the last input
    ``v_prev``. With ``x = target - offset``, one sample is:

    1. ``P = S^-1(x)``, the inverse dead-zone superposition of the modified model (``x`` for the
       others);
    2. ``g = P - bias - sum_j c_j s_j``: what the one-sample P-I map must give once the creep's
       part known from the last sample is taken off;
    3. for the one-sample weights ``w`` (``w_1`` plus the creep's gain ``beta`` of this sample's
       input, :class:`CreepPI`): the inverse operators' states ``z'_k = W_k y_k + sum_{i>k} w_i
       y_i`` (``W`` the partial sums), ``z' = max(g - r', min(g + r', z'))`` and
       ``v = sum w' z'``: eqs. (19)-(20);
    4. the asymmetric model does 3. with the rising and the falling weights and keeps an
       answer whose direction agrees with the weights used (``v_rise >= v_prev`` or
       ``v_fall < v_prev``), the one nearer ``v_prev`` where both do (the output of eq. (18)
       can jump up at a reversal, so a target may have two inputs); where neither does (the
       outputs next to a reversal that eq. (18) cannot reach) it holds ``v_prev``. Within
       ``1e-9 (1 + |v_prev|)`` of ``v_prev`` a candidate is moved to its own side of it, so a
       held target does not flip the direction by rounding;
    5. ``y = max(v - r, min(v + r, y))``, ``s = a s + e v``.

    Exact (to rounding) for the classical and the modified model with or without creep, and for
    the asymmetric model wherever its output is reachable.
    """

    n_operators: int
    n_lags: int = 0
    n_shaper: int = 0
    asymmetric: bool = False
    kind: str = field(default="inverse-pi", init=False)

    def __post_init__(self) -> None:
        for name, low in (("n_operators", 1), ("n_lags", 0), ("n_shaper", 0)):
            x = getattr(self, name)
            if not isinstance(x, int | np.integer) or isinstance(x, bool) or x < low:
                raise InputError(f"InverseStep.{name} must be an integer >= {low}, got {x!r}.")
        if not isinstance(self.asymmetric, bool):
            raise InputError(f"InverseStep.asymmetric must be True or False, got {self.asymmetric!r}.")

    @cached_property
    def params(self) -> Layout:
        n, m, d = self.n_operators, self.n_lags, self.n_shaper
        directions = ("rising", "falling") if self.asymmetric else ("rising",)
        fields: list[tuple[str, int | None]] = [("offset_N", None), ("shaper_thresholds", d), ("shaper_weights", d),
                                                ("bias", None), ("thresholds", n)]
        for name in directions:
            fields += [(f"weights_{name}", n), (f"partial_{name}", n), (f"inverse_thresholds_{name}", n),
                       (f"inverse_weights_{name}", n)]
        fields += [("creep_weights", m), ("creep_decay", m), ("creep_input", m)]
        return Layout("inverse P-I parameters", fields)

    @cached_property
    def state(self) -> Layout:
        return Layout("inverse P-I state", [("operators", self.n_operators), ("carries", self.n_lags),
                                            ("v_prev_V", 1 if self.asymmetric else 0)])

    @property
    def n_states(self) -> int:
        return int(self.state.size)

    def rest_state(self, ops: Ops, params: Any) -> Any:
        """At rest at 0 V: every operator, carry and the last input 0."""
        return ops.repeat(0.0, self.n_states)

    def _direction(self, ops: Ops, p: Any, name: str, g: Any, y: Any) -> Any:
        w, partial = getattr(p, f"weights_{name}"), getattr(p, f"partial_{name}")
        r_inv, w_inv = getattr(p, f"inverse_thresholds_{name}"), getattr(p, f"inverse_weights_{name}")
        wy = w * y
        z_prev = partial * y + ops.expand(ops.sum(wy)) - ops.cumsum(wy)
        ge = ops.expand(g)
        z = ops.maximum(ge - r_inv, ops.minimum(ge + r_inv, z_prev))
        return ops.dot(z, w_inv)

    def step(self, ops: Ops, params: Any, state: Any, target: Any) -> tuple[Any, Any]:
        """``(input, next state)`` that makes the forward model output ``target`` this sample."""
        p, s = self.params.unpack(params), self.state.unpack(state)
        x = target - p.offset_N
        if self.n_shaper:
            d = p.shaper_thresholds
            xd = ops.expand(x) - d
            shaped = ops.where(d > 0, ops.maximum(xd, 0.0), ops.where(d < 0, ops.minimum(xd, 0.0), xd + d))
            x = ops.dot(shaped, p.shaper_weights)
        g = x - p.bias
        if self.n_lags:
            g = g - ops.dot(s.carries, p.creep_weights)
        v = self._direction(ops, p, "rising", g, s.operators)
        last = ops.repeat(0.0, 0)
        if self.asymmetric:
            v_prev = ops.sum(s.v_prev_V)
            v_fall = self._direction(ops, p, "falling", g, s.operators)
            tol = 1e-9 * (1.0 + ops.fabs(v_prev))  # a held target: rounding must not flip the direction
            rise_ok, fall_ok = v >= v_prev - tol, v_fall < v_prev + tol
            v, v_fall = ops.maximum(v, v_prev), ops.minimum(v_fall, v_prev - tol)
            nearer = ops.where(v - v_prev <= v_prev - v_fall, v, v_fall)
            v = ops.where(ops.logical_and(rise_ok, fall_ok), nearer,
                          ops.where(rise_ok, v, ops.where(fall_ok, v_fall, v_prev)))
            last = ops.expand(v)
        ve = ops.expand(v)
        y = ops.maximum(ve - p.thresholds, ops.minimum(ve + p.thresholds, s.operators))
        carries = p.creep_decay * s.carries + p.creep_input * ve if self.n_lags else s.carries
        return v, self.state.pack(ops, operators=y, carries=carries, v_prev_V=last)



def inverse_realtime(model: Any) -> tuple[InverseStep, NDArray[np.float64]]:
    """The :class:`InverseStep` of ``model`` and its parameter vector.

    Any model of :mod:`piezopreload.models.hysteresis`: classical, modified, the paper's
    asymmetric, each with or without creep (each gives its numbers by ``inverse_spec()``). Raises
    :class:`~piezopreload.models.hysteresis.operators.NotInvertibleError` where a partial sum of
    the one-sample weights (or of the dead-zone weights) is not positive.
    """
    if not callable(getattr(model, "inverse_spec", None)):
        raise InputError(f"expected a P-I model of piezopreload.models.hysteresis, got {type(model).__name__}.")
    spec: InverseSpec = model.inverse_spec()
    asymmetric = "falling" in spec.weights
    parts: dict[str, Any] = {"offset_N": spec.offset, "thresholds": spec.thresholds, "bias": spec.bias,
                             "creep_weights": spec.creep_weights, "creep_decay": spec.creep_decay,
                             "creep_input": spec.creep_input}
    for name, w in spec.weights.items():
        r_inv, w_inv = inverse_weights(spec.thresholds, w, spec.what + (f" ({name} weights)" if asymmetric else ""))
        parts.update({f"weights_{name}": w, f"partial_{name}": np.cumsum(w), f"inverse_thresholds_{name}": r_inv,
                      f"inverse_weights_{name}": w_inv})
    shaper = None if spec.shaper is None else spec.shaper.inverse()
    parts.update(shaper_thresholds=_EMPTY if shaper is None else shaper.thresholds,
                 shaper_weights=_EMPTY if shaper is None else shaper.weights)
    structure = InverseStep(int(spec.thresholds.size), int(spec.creep_weights.size),
                            int(parts["shaper_thresholds"].size), asymmetric)
    return structure, structure.params.numbers(**parts)


class _RealTimeInverse:
    """What every inverse model shares: :class:`InverseStep` with the forward model's numbers.

    Its state is the forward model's (play operator outputs, creep carries, the last input of
    the asymmetric model): zeros at rest at 0 V, and any state the forward model left.
    """

    forward: Any

    @cached_property
    def _realtime(self) -> tuple[InverseStep, NDArray[np.float64]]:
        return inverse_realtime(self.forward)

    def realtime(self) -> tuple[InverseStep, NDArray[np.float64]]:
        """The controller's feedforward component: the step's structure and its parameter vector."""
        structure, params = self._realtime
        return structure, params.copy()

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """At rest at 0 V: zeros of shape ``batch + (n_states,)``."""
        return np.zeros(batch + (self._realtime[0].n_states,))

    def step(self, state: ArrayLike, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample (numpy, batched): the input that makes the forward model output ``target``, and the next state."""
        structure, params = self._realtime
        v, nxt = structure.step(NUMPY, params, np.asarray(state, float), np.asarray(target, float))
        return np.asarray(v, float), np.asarray(nxt, float)

    def casadi_step(self, state: Any, target: Any) -> tuple[Any, Any]:
        """:meth:`step` on CasADi expressions (one loop), the model's numbers as constants."""
        structure, params = self._realtime
        return structure.step(CASADI, ca.DM(params), state, target)

    def run(self, target: ArrayLike, state: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inputs for the targets of shape (..., N), sample by sample from ``state`` (at rest by
        default), and the final state."""
        target = np.asarray(target, dtype=float)
        x = self.initial_state(target.shape[:-1]) if state is None else np.asarray(state, float)
        out = np.empty(target.shape)
        for k in range(target.shape[-1]):
            out[..., k], x = self.step(x, target[..., k])
        return out, x



@dataclass(frozen=True, eq=False)
class InverseClassicalPI(_RealTimeInverse):
    """Inverse of a :class:`ClassicalPI`: ``v = sum_k w'_k F_{r'_k}[O - offset]``, eqs. (19)-(20).

    Built by :meth:`ClassicalPI.inverse`. Called on a whole signal it runs the inverse
    operators, whose states relate to the forward ones by ``z_k = W_k y_k + sum_{i>k} w_i y_i``
    (``W_k`` the partial sums of the forward weights; :meth:`state_from_forward`), so it can
    start from any forward state. One sample at a time (:meth:`step`, :meth:`realtime`: the
    controller's feedforward) it is :class:`InverseStep`, whose state is the forward
    operators' own.
    """

    forward: ClassicalPI
    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]

    def state_from_forward(self, y: ArrayLike) -> NDArray[np.float64]:
        """Inverse-operator states equivalent to forward operator states ``y`` (..., n)."""
        y = np.asarray(y, dtype=float)
        w = self.forward.weights
        partial = np.cumsum(w)
        weighted = y * w
        tail = np.cumsum(weighted[..., ::-1], axis=-1)[..., ::-1]  # sum_{i>=k} w_i y_i
        return np.asarray(partial * y + tail - weighted, np.float64)  # (..., n): an array

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return np.zeros(batch + (self.thresholds.size,))

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """Input that makes the forward model output ``target`` (shape (..., N))."""
        z = np.asarray(target, dtype=float) - self.forward.offset
        return play(z, self.thresholds, state) @ self.weights


@dataclass(frozen=True, eq=False)
class InverseAsymmetricPI(_RealTimeInverse):
    """The direction-switched inverse of the paper's asymmetric model, eq. (18) (:class:`InverseStep`, point 4).

    Exact wherever the target is an output the model reaches; in the gaps eq. (18) leaves at a
    reversal of the input it holds the last input. Built by :meth:`AsymmetricPI.inverse`.
    """

    forward: AsymmetricPI

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.run(target, state)[0]


@dataclass(frozen=True, eq=False)
class InverseCreepPI(_RealTimeInverse):
    """The inverse of a :class:`CreepPI` (classical, modified, asymmetric), one sample at a time.

    Built by :meth:`CreepPI.inverse`: :class:`InverseStep` with the model's numbers; its state is
    the forward model's (``[play operator outputs (n), creep carries (m)]``, and the last input
    for the asymmetric model), so it takes over from any history the forward model left.
    """

    forward: CreepPI

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.run(target, state)[0]


@dataclass(frozen=True, eq=False)
class InverseModifiedPI(_RealTimeInverse):
    """Inverse of a :class:`ModifiedPI`: ``v = Gamma^-1[S^-1(O - offset)]``."""

    forward: ModifiedPI
    play_inverse: InverseClassicalPI
    shaper_inverse: DeadZone

    def state_from_forward(self, y: ArrayLike) -> NDArray[np.float64]:
        return self.play_inverse.state_from_forward(y)

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return self.play_inverse.initial_state(batch)

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        z = self.shaper_inverse(np.asarray(target, dtype=float) - self.forward.offset)
        return self.play_inverse(z, state)


#: any P-I model's inverse: the feedforward a controller runs (each is a :class:`InverseStep` with its own numbers)
InverseModel = InverseClassicalPI | InverseAsymmetricPI | InverseModifiedPI | InverseCreepPI
