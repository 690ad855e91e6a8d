"""The P-I models: the classical model, the paper's asymmetric model and Kuhnen's modified model.

* the classical P-I model, eq. (15) of Zhang, Jin, Lin (2021), with a linear term (threshold 0)
  and an output offset (:class:`ClassicalPI`);
* the paper's direction-switched asymmetric model, eq. (18) (:class:`AsymmetricPI`);
* Kuhnen's modified P-I model (play operators followed by a superposition of one-sided
  dead-zone operators, K. Kuhnen, Eur. J. Control 9(4), 2003), which describes asymmetric
  loops and keeps an exact analytic inverse (:class:`ModifiedPI`).

Each model is a frozen dataclass that validates itself, runs on whole signals from an explicit
state, and gives its inverse (:mod:`piezopreload.models.hysteresis.inverse`) and the numbers of
its one-sample map (``inverse_spec()``) that the real-time inverse step runs on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.models.hysteresis.inverse import (
    InverseAsymmetricPI,
    InverseClassicalPI,
    InverseModifiedPI,
    InverseSpec,
)
from piezopreload.models.hysteresis.operators import (
    DeadZone,
    check_thresholds,
    inverse_weights,
    play,
    play_step,
    rising,
    scalar,
    vector,
)

__all__ = ["ClassicalPI", "AsymmetricPI", "ModifiedPI", "HysteresisModel"]


# --------------------------------------------------------------------------------------
# the classical P-I model, eq. (15)
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ClassicalPI:
    """Classical Prandtl-Ishlinskii model, eq. (15): ``O = sum_k w_k F_{r_k}[v] + offset``.

    Parameters
    ----------
    thresholds : array_like, shape (n,)
        ``0 = r_1 < r_2 < ... < r_n`` in input units; ``r_1 = 0`` is the linear term.
    weights : array_like, shape (n,)
        ``w_k`` in output units per input unit.
    offset : float
        Output when every operator is at rest (state 0).
    """

    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]
    offset: float = 0.0
    kind: str = field(default="classical", init=False)

    def __post_init__(self) -> None:
        r = vector("thresholds", self.thresholds)
        w = vector("weights", self.weights)
        check_thresholds("thresholds", r)
        if w.shape != r.shape:
            raise ValueError(f"weights must have {r.size} entries like thresholds, got {w.size}.")
        object.__setattr__(self, "thresholds", r)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "offset", scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    @property
    def invertible(self) -> bool:
        return bool(np.all(np.cumsum(self.weights) > 0))

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """Operators at rest: zeros of shape ``batch + (n,)``."""
        return np.zeros(batch + (self.n_operators,))

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """Output for input ``v`` of shape (..., N), from ``state`` (at rest by default)."""
        return play(v, self.thresholds, state) @ self.weights + self.offset

    def step(self, state: NDArray[np.float64], v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample: returns ``(output, new_state)``; state shape (..., n)."""
        y = play_step(state, v, self.thresholds)
        return y @ self.weights + self.offset, y

    def inverse_spec(self, beta: float = 0.0) -> InverseSpec:
        """The one-sample map's numbers for :class:`~piezopreload.models.hysteresis.inverse.InverseStep`;
        ``beta`` (a creep bank's one-sample gain) joins the linear weight."""
        w = self.weights.copy()
        w[0] += beta
        return InverseSpec(self.thresholds, {"rising": w}, self.offset, "this P-I model")

    def inverse(self) -> InverseClassicalPI:
        """The analytic inverse, eqs. (19)-(20): a P-I model from output to input."""
        r_inv, w_inv = inverse_weights(self.thresholds, self.weights, "this P-I model")
        return InverseClassicalPI(forward=self, thresholds=r_inv, weights=w_inv)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights": self.weights.tolist(),
            "offset": self.offset,
        }


# --------------------------------------------------------------------------------------
# the paper's direction-switched asymmetric model, eq. (18)
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class AsymmetricPI:
    """The paper's asymmetric P-I model, eq. (18).

    ``O(t_i) = sum_k (p w_rise_k + q w_fall_k) F_{r_k}[v](t_i) + offset`` with ``(p, q) = (1, 0)``
    while the input rises (``v_i >= v_{i-1}``) and ``(0, 1)`` while it falls.

    The output jumps by ``sum_k (w_rise_k - w_fall_k) F_{r_k}`` at every reversal of the input,
    so some outputs next to a reversal cannot be reached by any input: the model has no exact
    inverse everywhere (:attr:`invertible` is False); :meth:`inverse` is exact where the output is
    reachable and holds the input in the gaps. :class:`ModifiedPI` is the asymmetric model with
    an exact inverse. The state holds the operator outputs and the previous input
    (``v_{-1} = 0`` at rest).
    """

    thresholds: NDArray[np.float64]
    weights_rising: NDArray[np.float64]
    weights_falling: NDArray[np.float64]
    offset: float = 0.0
    kind: str = field(default="paper-asymmetric", init=False)

    def __post_init__(self) -> None:
        r = vector("thresholds", self.thresholds)
        check_thresholds("thresholds", r)
        for name in ("weights_rising", "weights_falling"):
            w = vector(name, getattr(self, name))
            if w.shape != r.shape:
                raise ValueError(f"{name} must have {r.size} entries like thresholds, got {w.size}.")
            object.__setattr__(self, name, w)
        object.__setattr__(self, "thresholds", r)
        object.__setattr__(self, "offset", scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    invertible = False

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None, v_prev: float = 0.0) -> NDArray[np.float64]:
        y = play(v, self.thresholds, state)
        p = rising(v, v_prev)
        return np.where(p, y @ self.weights_rising, y @ self.weights_falling) + self.offset

    def inverse_spec(self, beta: float = 0.0) -> InverseSpec:
        """The rising and the falling one-sample maps' numbers (``beta`` joins each linear weight)."""
        rise, fall = self.weights_rising.copy(), self.weights_falling.copy()
        rise[0] += beta
        fall[0] += beta
        return InverseSpec(self.thresholds, {"rising": rise, "falling": fall}, self.offset, "this P-I model")

    def inverse(self) -> InverseAsymmetricPI:
        """The direction-switched inverse (:class:`InverseStep`): exact where the output is reachable.

        The output jumps by ``sum_k (w_rise_k - w_fall_k) F_{r_k}`` at every reversal of the
        input, so next to a reversal some outputs no input reaches; there the inverse holds the
        last input. Raises :class:`NotInvertibleError` if a partial sum of either weight set is
        not positive.
        """
        inverse = InverseAsymmetricPI(forward=self)
        inverse.realtime()  # checks both weight sets
        return inverse

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights_rising": self.weights_rising.tolist(),
            "weights_falling": self.weights_falling.tolist(),
            "offset": self.offset,
        }



@dataclass(frozen=True, eq=False)
class ModifiedPI:
    """Kuhnen's modified P-I model for asymmetric loops, with an exact analytic inverse.

    ``O = S(sum_k w_k F_{r_k}[v] + bias) + offset`` where ``S`` is a :class:`DeadZone`
    superposition (memoryless, piecewise linear) that bends the symmetric loops of the
    play operators into asymmetric ones (K. Kuhnen, "Modeling, identification and compensation
    of complex hysteretic nonlinearities: a modified Prandtl-Ishlinskii approach",
    Eur. J. Control 9(4):407-418, 2003). Its inverse is the inverse P-I model after the inverse
    dead-zone superposition, both analytic.
    """

    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]
    deadzone_thresholds: NDArray[np.float64]
    deadzone_weights: NDArray[np.float64]
    bias: float = 0.0
    offset: float = 0.0
    kind: str = field(default="modified", init=False)

    def __post_init__(self) -> None:
        pi = ClassicalPI(self.thresholds, self.weights, 0.0)
        dz = DeadZone(self.deadzone_thresholds, self.deadzone_weights)
        object.__setattr__(self, "thresholds", pi.thresholds)
        object.__setattr__(self, "weights", pi.weights)
        object.__setattr__(self, "deadzone_thresholds", dz.thresholds)
        object.__setattr__(self, "deadzone_weights", dz.weights)
        object.__setattr__(self, "bias", scalar("bias", self.bias))
        object.__setattr__(self, "offset", scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    @property
    def play_model(self) -> ClassicalPI:
        return ClassicalPI(self.thresholds, self.weights, self.bias)

    @property
    def shaper(self) -> DeadZone:
        return DeadZone(self.deadzone_thresholds, self.deadzone_weights)

    @property
    def invertible(self) -> bool:
        return self.play_model.invertible and self.shaper.invertible

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return np.zeros(batch + (self.n_operators,))

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.shaper(self.play_model(v, state)) + self.offset

    def step(self, state: NDArray[np.float64], v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        z, y = self.play_model.step(state, v)
        return self.shaper(z) + self.offset, y

    def inverse_spec(self, beta: float = 0.0) -> InverseSpec:
        """The play part's one-sample map (``beta`` joins its linear weight), its bias and the dead-zone shaper."""
        w = self.weights.copy()
        w[0] += beta
        return InverseSpec(self.thresholds, {"rising": w}, self.offset, "this P-I model", bias=self.bias,
                           shaper=self.shaper)

    def inverse(self) -> InverseModifiedPI:
        return InverseModifiedPI(
            forward=self, play_inverse=self.play_model.inverse(), shaper_inverse=self.shaper.inverse()
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights": self.weights.tolist(),
            "deadzone_thresholds": self.deadzone_thresholds.tolist(),
            "deadzone_weights": self.deadzone_weights.tolist(),
            "bias": self.bias,
            "offset": self.offset,
        }



HysteresisModel = ClassicalPI | AsymmetricPI | ModifiedPI
