"""The closed loop defined once: the plant step and the controller step composed, and run.

:class:`LoopModel` composes :class:`~piezopreload.models.actuator.PlantModel` and
:class:`~piezopreload.models.controller.ControllerModel` into one sample of the loop, written
over the ops table like its parts. Sample ``k``, as a LabVIEW loop with an A/D and a D/A card
runs it: the A/D reads the force (the standard normal draw ``noise`` scaled by the sensor's
noise, then quantisation), the controller computes the command from the reading, the
reference ``r`` and the external feedforward ``ff_extra``, the command goes to the D/A, and
the rig advances to ``k + 1``. :class:`OpenLoopModel` is the rig alone under a given command.

From these definitions come the numpy reference simulation (:func:`run` with
``engine="numpy"``, batches in the leading axes), the compiled simulation (CasADi's code
generator and the system C compiler through :mod:`piezopreload.core.native`: the step as C,
called by a C loop over time and plants) and, with ``smoothing > 0``, the CasADi graph the
tuning differentiates. Both engines take the noise as an input drawn in numpy, so they give
the same numbers (to rounding, 1e-9 and far below).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.core import native
from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import PlantModel
from piezopreload.models.controller import ControllerModel
from piezopreload.models.ops import CASADI, NUMPY, Layout, Ops

__all__ = ["LoopModel", "OpenLoopModel", "LOOP_OUTPUTS", "OPEN_LOOP_OUTPUTS", "run", "step_function", "ENGINES"]


#: what one sample of the closed loop records (in this order)
LOOP_OUTPUTS = Layout("loop outputs", [("force_N", None), ("measured_N", None), ("command_V", None),
                                       ("voltage_V", None), ("p_V", None), ("i_V", None), ("d_V", None),
                                       ("ff_V", None)])
#: what one sample of the open loop records
OPEN_LOOP_OUTPUTS = Layout("open-loop outputs", [("voltage_V", None), ("force_N", None), ("measured_N", None)])

ENGINES = ("auto", "c", "numpy")


@dataclass(frozen=True)
class LoopModel:
    """One sample of the closed loop: plant, sensor, controller (see the module docstring).

    ``step(ops, params, state, reference_N, noise, ff_extra_V) -> (state_next, outputs)``
    with :attr:`params` = plant parameters then controller parameters, :attr:`state` = plant
    state then controller state, and outputs as :data:`LOOP_OUTPUTS`. The plant's smoothing
    (0: the exact rig) is the loop's.
    """

    plant: PlantModel
    controller: ControllerModel
    inputs = ("reference_N", "noise", "ff_extra_V")

    @property
    def name(self) -> str:
        return "loop"

    @cached_property
    def state(self) -> Layout:
        return Layout("loop state", [("plant", self.plant.state.size), ("controller", self.controller.state.size)])

    @cached_property
    def params(self) -> Layout:
        return Layout("loop parameters", [("plant", self.plant.params.size),
                                          ("controller", self.controller.params.size)])

    @cached_property
    def outputs(self) -> Layout:
        return LOOP_OUTPUTS

    def parameters(self, plant: Array, controller: Array) -> Array:
        """The loop's parameter vector from the plant's (batch leading) and the controller's."""
        return self.params.numbers(plant=plant, controller=controller)

    def step(self, ops: Ops, params: Any, state: Any, reference_N: Any, noise: Any,
             ff_extra_V: Any = 0.0) -> tuple[Any, Any]:
        p, x = self.params.unpack(params), self.state.unpack(state)
        force = self.plant.force(ops, p.plant, x.plant)
        measured = self.plant.measure(ops, p.plant, force, noise)
        controller_next, t = self.controller.step(ops, p.controller, x.controller, reference_N, measured, ff_extra_V)
        plant_next = self.plant.step(ops, p.plant, x.plant, t.u)
        voltage = self.plant.state.get(x.plant, "v_amp")
        y = self.outputs.pack(ops, force_N=force, measured_N=measured, command_V=t.u, voltage_V=voltage, p_V=t.p,
                              i_V=t.i, d_V=t.d, ff_V=t.ff)
        return self.state.pack(ops, plant=plant_next, controller=controller_next), y

    def start(self, ops: Ops, params: Any, reference_N: Any, ff_extra_V: Any = 0.0, v0_V: Any = 0.0) -> Any:
        """The rig at rest at ``v0_V`` (creep settled), the controller bumplessly at ``v0_V`` with
        its setpoint at ``reference_N`` and its measurement the true force."""
        p = self.params.unpack(params)
        plant = self.plant.rest_state(ops, p.plant, v0_V)
        force = self.plant.force(ops, p.plant, plant)
        controller = self.controller.start(ops, p.controller, reference_N, force, v0_V, ff_extra_V)
        return self.state.pack(ops, plant=plant, controller=controller)


@dataclass(frozen=True)
class OpenLoopModel:
    """The rig alone under a command sequence: ``step(ops, params, state, command_V, noise)``
    with outputs :data:`OPEN_LOOP_OUTPUTS` (amplifier voltage, true and measured force, before
    the command is written)."""

    plant: PlantModel
    inputs = ("command_V", "noise")

    @property
    def name(self) -> str:
        return "open_loop"

    @cached_property
    def state(self) -> Layout:
        return self.plant.state

    @cached_property
    def params(self) -> Layout:
        return self.plant.params

    @cached_property
    def outputs(self) -> Layout:
        return OPEN_LOOP_OUTPUTS

    def step(self, ops: Ops, params: Any, state: Any, command_V: Any, noise: Any) -> tuple[Any, Any]:
        force = self.plant.force(ops, params, state)
        measured = self.plant.measure(ops, params, force, noise)
        y = self.outputs.pack(ops, voltage_V=self.plant.state.get(state, "v_amp"), force_N=force, measured_N=measured)
        return self.plant.step(ops, params, state, command_V), y

    def start(self, ops: Ops, params: Any, v0_V: Any = 0.0) -> Any:
        return self.plant.rest_state(ops, params, v0_V)


def step_function(model: LoopModel | OpenLoopModel, name: str | None = None) -> ca.Function:
    """The model's step as a CasADi function ``(x, p, inputs...) -> (x_next, y)`` (SX, one sample)."""
    x = ca.SX.sym("x", model.state.size)
    p = ca.SX.sym("p", model.params.size)
    inputs = [ca.SX.sym(n) for n in model.inputs]
    x_next, y = model.step(CASADI, p, x, *inputs)
    return ca.Function(name or f"pp_{model.name}_step", [x, p, *inputs], [x_next, y],
                       ["x", "p", *model.inputs], ["x_next", "y"])


def run(model: LoopModel | OpenLoopModel, params: Array, x0: Array, series: dict[str, Any], n_steps: int,
        *, engine: str = "auto") -> tuple[Array, Array, str]:
    """Run ``model`` over ``n_steps`` samples for a batch of plants.

    ``params`` and ``x0`` have shape ``batch + (n,)`` (``batch`` may be ``()``); each entry of
    ``series`` (named as ``model.inputs``; a missing one is 0) is a scalar, a ``(n_steps,)``
    array shared by the batch, or ``(n_steps,) + batch``. Returns the outputs, shape
    ``batch + (n_outputs, n_steps)``, the final states ``batch + (nx,)``, and the engine that
    ran: ``"c"`` (compiled) or ``"numpy"``. ``engine="auto"`` compiles where a C compiler
    works (:func:`piezopreload.core.native.enabled`) and falls back to numpy where the build
    fails; ``"c"`` insists; ``"numpy"`` forces the reference path.
    """
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {ENGINES}, got {engine!r}.")
    params, x0 = np.asarray(params, float), np.asarray(x0, float)
    batch = np.broadcast_shapes(params.shape[:-1], x0.shape[:-1])
    unknown = sorted(set(series) - set(model.inputs))
    if unknown:
        raise InputError(f"unknown input series {unknown}; {model.name} takes {list(model.inputs)}.")
    columns = []
    for name in model.inputs:
        s = np.asarray(series.get(name, 0.0), float)
        if s.ndim == 0:
            s = np.broadcast_to(s, (n_steps,))
        if s.shape[0] != n_steps:
            raise InputError(f"series {name!r} has {s.shape[0]} samples, expected {n_steps}.")
        columns.append(s)
    use_c = engine == "c" or (engine == "auto" and native.enabled() and native.engine() != "numpy")
    if use_c:
        try:
            return (*_run_compiled(model, params, x0, columns, n_steps, batch), "c")
        except native.NativeBuildError:
            if engine == "c" or native.engine() == "c":
                raise
    return (*_run_numpy(model, params, x0, columns, n_steps, batch), "numpy")


def _run_compiled(model: LoopModel | OpenLoopModel, params: Array, x0: Array, columns: list[Array], n_steps: int,
                  batch: tuple[int, ...]) -> tuple[Array, Array]:
    runner = native.step_runner(model, lambda: step_function(model), f"pp_{model.name}")
    n = int(np.prod(batch)) if batch else 1

    def per_plant(a: Array) -> Array:  # (n,) shared by every plant, or (plants, n)
        return a if a.ndim == 1 else np.broadcast_to(a, batch + a.shape[-1:]).reshape(n, a.shape[-1])

    flat = [s if s.ndim == 1 else np.broadcast_to(s, (n_steps,) + batch).reshape(n_steps, n) for s in columns]
    out, x_end = runner(per_plant(params), per_plant(x0), flat, n)
    return out.reshape(batch + out.shape[1:]), x_end.reshape(batch + x_end.shape[1:])


def _run_numpy(model: LoopModel | OpenLoopModel, params: Array, x0: Array, columns: list[Array], n_steps: int,
               batch: tuple[int, ...]) -> tuple[Array, Array]:
    out = np.empty(batch + (model.outputs.size, n_steps))
    x = np.broadcast_to(x0, batch + x0.shape[-1:]).copy()
    for k in range(n_steps):
        x, y = model.step(NUMPY, params, x, *(s[k] for s in columns))
        out[..., k] = y
    return out, x
