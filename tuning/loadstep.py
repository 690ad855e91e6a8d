"""The load step at the plant input, simulated as the controller step runs it: the autotuner's IAE and its plot.

The loop is sampled at ``Ts``: the plant is its zero-order-hold equivalent (a discrete rational plant:
:meth:`~piezopreload.tuning.lti.LinearPlant.sampled`, the delay exact), the controller is the one
controller step (:func:`~piezopreload.models.controller.pid_update`, ideal/ISA gains from the parallel
``kp, ki, kd, Tf``, no output limit), and a unit step enters at the plant's input at ``t = 0`` with the
setpoint at 0. Each sample: the A/D reads ``y_k``, the controller writes ``u_k``, the plant takes
``u_k + 1``. :func:`load_step_function` is that loop as one CasADi function of the gains (the IAE
the NLP differentiates), :func:`load_response` its numbers. A second-order filter on the whole
controller (not a form the controller step runs) is simulated through Tustin's map of ``C(s)``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.models.controller import pid_update
from piezopreload.models.ops import CASADI
from piezopreload.tuning.lti import LinearPlant
from piezopreload.tuning.pidform import PIDController

__all__ = ["load_step_function", "load_response", "iae_function"]

_OPEN = 1e12  # the output range of the simulated controller: none


def _plant_matrices(plant: LinearPlant) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The plant's rational part ``(A, B, C)`` and its whole samples of delay ``N`` (its input shifted by them, a
    line of ``N`` values, never an ``N``-by-``N`` matrix); a direct term goes into the line's last value."""
    A, B, C, D = plant.rational_state_space()
    N = plant.delay_samples
    if N and np.any(np.abs(D) > 0):
        A, B, C, D = plant.state_space()
        N = 0
    if np.any(np.abs(D) > 0):
        raise InputError("the sampled plant passes its input straight to its output (a biproper plant without "
                         "delay): the A/D reading would depend on this sample's command; give the plant its "
                         "computation delay (delay_s) or a strictly proper model")
    return A, B, C, N


def load_step_function(plant: LinearPlant, sign: float = 1.0) -> ca.Function:
    """One sample of the loop under the load step: ``(x, gains) -> (x_next, y)`` with ``gains = (kp, ki, kd, Tf)``
    of form 0 or 1 (:class:`~piezopreload.tuning.pidform.PIDController`) and ``x`` the plant's state then the
    controller's (integral action, previous error, previous measurement, filtered derivative). ``sign`` multiplies
    the plant (the controller is tuned on the plant of positive gain)."""
    A, B, C, N = _plant_matrices(plant)
    n = A.shape[0]
    x, g = ca.SX.sym("x", n + 4 + N), ca.SX.sym("g", 4)
    kp, ki, kd, Tf = g[0], g[1], g[2], g[3]
    xp, integral, e_prev, pv_prev, dpv = x[:n], x[n], x[n + 1], x[n + 2], x[n + 3]
    line = x[n + 4:]  # u[k-1] .. u[k-N] with the load
    y = sign * ca.mtimes(ca.DM(C), xp)
    gains = (kp, kp / ki, kd / kp, Tf, 1.0)
    u, _, integral, _, e, dpv = pid_update(CASADI, gains, (-_OPEN, _OPEN), plant.sample_period(), integral, e_prev,
                                           pv_prev, dpv, 0.0, y, 0.0)
    into = u + 1.0 if N == 0 else line[N - 1]
    shifted = ca.vertcat(u + 1.0, *ca.vertsplit(line)[:N - 1]) if N else ca.SX(0, 1)
    x_next = ca.vertcat(ca.mtimes(ca.DM(A), xp) + ca.DM(B) * into, integral, e, y, dpv, shifted)
    return ca.Function("load_step", [x, g], [x_next, y], ["x", "gains"], ["x_next", "y"])


def iae_function(plant: LinearPlant, n_steps: int, sign: float = 1.0, smooth: float = 1e-4) -> ca.Function:
    """``gains -> IAE`` of the load step over ``n_steps`` samples: ``sum_k sqrt(y_k^2 + smooth^2) Ts`` (``|y|`` with
    its corner rounded over ``smooth``, in the output's unit per unit load)."""
    step = load_step_function(plant, sign)
    g = ca.MX.sym("g", 4)
    x0 = ca.DM.zeros(step.size1_in(0))
    _, y = step.mapaccum(n_steps)(x0, ca.repmat(g, 1, n_steps))
    return ca.Function("iae", [g], [ca.sum2(ca.sqrt(y**2 + smooth**2)) * plant.sample_period()])


def load_response(plant: LinearPlant, controller: PIDController, n_steps: int, sign: float = 1.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``(t_s, y)``: the loop's output under a unit load step at the plant input, ``n_steps`` samples at the
    plant's period (``controller`` at that period, or continuous and sampled there)."""
    if controller.filter_order < 2:
        step = load_step_function(plant, sign)
        x0 = np.zeros(step.size1_in(0))
        _, y = step.mapaccum(n_steps)(x0, np.tile(np.array([[controller.kp], [controller.ki], [controller.kd],
                                                             [controller.Tf]]), (1, n_steps)))
        y = np.asarray(y, float).ravel()
    else:
        y = _linear_response(plant, controller, n_steps, sign)
    return np.arange(n_steps) * plant.sample_period(), y


def _linear_response(plant: LinearPlant, controller: PIDController, n_steps: int, sign: float) -> np.ndarray:
    """The load response with a linear discrete controller (Tustin's map of ``C(s)``)."""
    import control

    A, B, C, N = _plant_matrices(plant)
    line = np.zeros(N + 1)  # u[k] .. u[k-N] with the load, as a ring
    c = PIDController(controller.kp, controller.ki, controller.kd, controller.Tf, controller.filter_order, plant.dt)
    ss = control.tf2ss(*c.num_den(), plant.dt)
    Ac, Bc, Cc, Dc = (np.atleast_2d(np.asarray(m, float)) for m in (ss.A, ss.B, ss.C, ss.D))
    x, xc, y = np.zeros((A.shape[0], 1)), np.zeros((Ac.shape[0], 1)), np.empty(n_steps)
    for k in range(n_steps):
        y[k] = sign * (C @ x).item()
        e = -y[k]
        u = (Cc @ xc).item() + float(Dc[0, 0]) * e
        xc = Ac @ xc + Bc * e
        line[k % (N + 1)] = u + 1.0
        x = A @ x + B * line[(k - N) % (N + 1)]
    return y
