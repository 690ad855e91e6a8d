"""A controller as code: the one controller step's CasADi functions and its numbers and state, by name; and a
feedforward's inverse step alone the same way.

Every generated controller (the C of ``export --format casadi-c``, the PLC's function block
``PP_CONTROLLER`` of ``--format plc``) is written from :func:`controller_code`: the start and the
step of :class:`~piezopreload.models.controller.ControllerModel` as CasADi functions whose
parameter vector is an *input* (:func:`~piezopreload.models.controller.controller_functions`),
one expression tree per structure, and the gain set's numbers beside it. The C code passes the
numbers as a constant array, the PLC block holds them in variables (which ``rig push --to``
writes on a PLC's OPC UA server, by the same names).

The names (:class:`Parameter`, :func:`state_fields`) are the layouts' own
(:attr:`ControllerModel.params`, :attr:`ControllerModel.state`), the feedforward's parameters and
state prefixed ``ff_`` (the inverse step's, :class:`~piezopreload.models.hysteresis.InverseStep`);
a field of no numbers (no creep, no dead zones) has no name.

A hysteresis model exported alone is its inverse step (:func:`feedforward_code`): the CasADi
function of :class:`~piezopreload.models.hysteresis.InverseStep` with its parameter vector an
input, from which both its C (``pp_feedforward.c``) and its PLC block (``PP_FEEDFORWARD``) are
written, its numbers and state named as ``PP_CONTROLLER`` names a gain set's feedforward (``ff_``).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.models.controller import Controller, ControllerModel, controller_functions
from piezopreload.models.hysteresis import InverseStep
from piezopreload.models.ops import CASADI, Layout

__all__ = ["Parameter", "ControllerCode", "controller_code", "FeedforwardCode", "feedforward_code", "parameters",
           "state_fields", "read_elements", "DESCRIPTIONS", "GAIN_NAMES"]

#: what each parameter is, with its unit (a feedforward's: the inverse step's table, docs/exports.md)
DESCRIPTIONS = {
    "Kc": "controller gain Kc, V/N", "Ti_s": "integral time Ti, s", "Td_s": "derivative time Td, s",
    "Tf_s": "filter time constant Tf, s (first order on the derivative, 0: unfiltered; or second order on the "
            "measurement)",
    "b": "setpoint weight b of the proportional action",
    "u_min_V": "output range, low, V", "u_max_V": "output range, high, V",
    "dt_s": "sample period, s (the task's cycle time)",
    "ff_offset_N": "feedforward: the model's output at rest, N", "ff_bias": "feedforward: the modified model's bias, N",
    "ff_thresholds": "feedforward: play operator thresholds r, V",
    "ff_shaper_thresholds": "feedforward: inverse dead-zone thresholds, N",
    "ff_shaper_weights": "feedforward: inverse dead-zone weights",
    "ff_creep_weights": "feedforward: creep weights c, N/V", "ff_creep_decay": "feedforward: creep decay a per sample",
    "ff_creep_input": "feedforward: creep input gain e per sample",
    "schedule_levels_N": "gain schedule: the setpoints of its entries, N", "schedule_Kc": "gain schedule: Kc, V/N",
    "schedule_Ti_s": "gain schedule: Ti, s", "schedule_Td_s": "gain schedule: Td, s",
    "schedule_b": "gain schedule: setpoint weight b",
    "integral_V": "the integral action, V", "e_prev_N": "the previous error, N",
    "pv_prev_N": "the previous measurement, N", "sp_prev_N": "the previous setpoint, N",
    "dpv_N_per_s": "the filtered derivative of the measurement, N/s",
    "pv_filtered_N": "the measurement through the second-order filter, N",
    "ff_operators": "feedforward: the play operators' outputs, V", "ff_carries": "feedforward: the creep carries, V",
    "ff_v_prev_V": "feedforward: the last command, V",
}
for _d in ("rising", "falling"):
    DESCRIPTIONS.update({f"ff_weights_{_d}": f"feedforward: one-sample weights w, {_d}, N/V",
                         f"ff_partial_{_d}": f"feedforward: partial sums W of the weights, {_d}, N/V",
                         f"ff_inverse_thresholds_{_d}": f"feedforward: inverse thresholds, {_d}, N",
                         f"ff_inverse_weights_{_d}": f"feedforward: inverse weights, {_d}, V/N"})


#: the parameters a user tunes, by name: the single set's gains and the schedule's arrays (what a PLC block's header
#: says to change); the others are the output range, the task's period and the feedforward's table
GAIN_NAMES = ("Kc", "Ti_s", "Td_s", "Tf_s", "b", "schedule_levels_N", "schedule_Kc", "schedule_Ti_s", "schedule_Td_s",
              "schedule_b")


@dataclass(frozen=True)
class Parameter:
    """One named part of the parameter vector: ``values`` (one for a scalar), ``array`` whether it is a table."""

    name: str
    start: int
    values: tuple[float, ...]
    array: bool

    @property
    def size(self) -> int:
        return len(self.values)

    @property
    def description(self) -> str:
        return DESCRIPTIONS.get(self.name, self.name)


def _fields(layout: Layout, nested: Layout | None, nested_name: str) -> list[tuple[str, int, int | None]]:
    """``(name, start, size)`` of every field of ``layout`` with numbers, ``nested_name``'s own fields prefixed."""
    out: list[tuple[str, int, int | None]] = []
    for name in layout.names:
        start, size = layout.slice(name).start, layout.field_size(name)
        if name == nested_name and nested is not None:
            out += [(f"{nested_name}_{sub}", start + s, n) for sub, s, n in _fields(nested, None, "")]
        elif size != 0:
            out.append((name, start, size))
    return out


def parameters(model: ControllerModel, vector: np.ndarray) -> tuple[Parameter, ...]:
    """The parameter vector of ``model`` by name (see the module docstring)."""
    ff = None if model.feedforward is None else model.feedforward.params
    vector = np.asarray(vector, float)
    return tuple(Parameter(name, start, tuple(float(x) for x in vector[start:start + (size or 1)]), size is not None)
                 for name, start, size in _fields(model.params, ff, "ff"))


def state_fields(model: ControllerModel) -> tuple[tuple[str, int, int | None], ...]:
    """``(name, start, size)`` of the state vector's fields (size None: a scalar), the feedforward's prefixed."""
    ff = None if model.feedforward is None else model.feedforward.state
    return tuple(_fields(model.state, ff, "ff"))


def read_elements(fn: ca.Function, name: str) -> frozenset[int]:
    """The elements of ``fn``'s input ``name`` that its algorithm reads (an input element no instruction reads is dead
    in the code generated from it)."""
    index = fn.index_in(name)
    return frozenset(int(fn.instruction_input(k)[1]) for k in range(fn.n_instructions())
                     if fn.instruction_id(k) == ca.OP_INPUT and int(fn.instruction_input(k)[0]) == index)


@dataclass(frozen=True, eq=False)
class ControllerCode:
    """A controller's step as code: ``start(setpoint, pv, u0, params) -> state`` and ``step(state, setpoint, pv,
    params) -> (u, p, i, d, ff, state_next)``, its :class:`Parameter` list and its numbers."""

    controller: Controller
    start: ca.Function
    step: ca.Function
    parameters: tuple[Parameter, ...]

    @property
    def model(self) -> ControllerModel:
        return self.controller.model

    @property
    def vector(self) -> np.ndarray:
        return self.controller.parameter_vector()

    @property
    def read(self) -> tuple[Parameter, ...]:
        """The parameters the start or the step reads: a scheduled set's step runs on the schedule's arrays, so its
        single ``Kc``, ``Ti_s``, ``Td_s`` and ``b`` are not among them (the vector keeps their places)."""
        used = read_elements(self.start, "params") | read_elements(self.step, "params")
        return tuple(p for p in self.parameters if any(p.start + j in used for j in range(p.size)))


def controller_code(controller: Controller, prefix: str = "pp_controller") -> ControllerCode:
    """:class:`ControllerCode` of ``controller``; refuses a parameter that is not finite (no code can hold it)."""
    model = controller.model
    params = parameters(model, controller.parameter_vector())
    bad = next((p for p in params if not all(np.isfinite(p.values))), None)
    if bad is not None:
        raise InputError(f"the controller's parameter {bad.name} is {list(bad.values)!r}: generated code holds finite "
                         "numbers only")
    start, step = controller_functions(model, prefix=prefix)
    return ControllerCode(controller, start, step, params)


@dataclass(frozen=True, eq=False)
class FeedforwardCode:
    """A feedforward's inverse step alone as code: ``rest(params) -> state`` (at rest at 0 V) and ``step(state,
    target, params) -> (command, state_next)``, its :class:`Parameter` list and state fields, named ``ff_...`` as
    :func:`parameters` and :func:`state_fields` name a controller's feedforward."""

    structure: InverseStep
    rest: ca.Function
    step: ca.Function
    parameters: tuple[Parameter, ...]
    state: tuple[tuple[str, int, int | None], ...]

    @property
    def vector(self) -> np.ndarray:
        return np.array([x for p in self.parameters for x in p.values], float)

    @property
    def read(self) -> tuple[Parameter, ...]:
        """The parameters the step reads."""
        used = read_elements(self.step, "params")
        return tuple(p for p in self.parameters if any(p.start + j in used for j in range(p.size)))


def feedforward_code(structure: InverseStep, vector: np.ndarray, prefix: str = "pp_feedforward") -> FeedforwardCode:
    """:class:`FeedforwardCode` of the inverse step ``structure`` with the numbers ``vector`` (its
    :attr:`~piezopreload.models.hysteresis.InverseStep.params`); refuses a number that is not finite."""
    vector = np.asarray(vector, float)
    if vector.shape != (structure.params.size,):
        raise InputError(f"the inverse step's parameter vector must be {structure.params.size} numbers, got shape "
                         f"{vector.shape}")
    params = tuple(Parameter(f"ff_{name}", start, tuple(float(x) for x in vector[start:start + (size or 1)]),
                             size is not None) for name, start, size in _fields(structure.params, None, ""))
    bad = next((p for p in params if not all(np.isfinite(p.values))), None)
    if bad is not None:
        raise InputError(f"the feedforward's parameter {bad.name} is {list(bad.values)!r}: generated code holds finite "
                         "numbers only")
    x, target = ca.SX.sym("state", structure.n_states), ca.SX.sym("target")
    p = ca.SX.sym("params", structure.params.size)
    command, nxt = structure.step(CASADI, p, x, target)
    step = ca.Function(f"{prefix}_step_fn", [x, target, p], [command, nxt], ["state", "target", "params"],
                       ["command", "state_next"])
    rest = ca.Function(f"{prefix}_rest_fn", [p], [ca.SX(structure.rest_state(CASADI, p))], ["params"], ["state"])
    state = tuple((f"ff_{name}", start, size) for name, start, size in _fields(structure.state, None, ""))
    return FeedforwardCode(structure, rest, step, params, state)
