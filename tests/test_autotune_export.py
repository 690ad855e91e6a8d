"""An autotuned PID with the second-order filter becomes a gain set, exports, and runs on the rig.

The plant is a linear model of the paper's rig as the simulated backend runs it (``models.actuator.Plant``'s
defaults): its small-signal gain (the geometric mean of the quasi-static loop's slopes,
``tuning.linearised.small_signal_gains``), the amplifier's first-order bandwidth and the delay of the sample's
read and write. The tuning holds its bounds on the sampled loop; the gain set it gives is the controller step with
the second-order filter on the measurement, whose response is python-control's Tustin map of the tuned controller
(the map the tuning checked), and the rig's compiled step in the native loop runs it sample for sample as the numpy
step does in the Python loop.
"""

import json

import numpy as np
import pytest

from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.rig.backends import SimBackend
from piezopreload.rig.executor import Executor, Safety
from piezopreload.rig.export import ExportError, export
from piezopreload.rig.runlog import RunLog, read_run_log
from piezopreload.tuning.autotune import autotune
from piezopreload.tuning.linearised import controller_frequency_response, small_signal_gains

control = pytest.importorskip("control", reason="python-control is the independent reference")


@pytest.fixture(scope="module")
def tuned():
    p = Plant()
    lo, hi = small_signal_gains(p)
    wa = 2 * np.pi * float(p.amp_bandwidth_Hz)
    G = control.tf([np.sqrt(lo * hi) * wa], [1.0, wa])
    dt = float(p.sample_period_s)
    r = autotune(G, Ms=1.4, Mks=5.0, delay_s=(p.delay_samples + 1) * dt, Ts=dt, loop="sampled", u_min=0.0,
                 u_max=110.0, filter_order=2)
    return p, r


def test_an_autotuned_second_order_pid_is_a_gain_set_whose_step_is_the_tuned_controller(tuned, tmp_path):
    """Its gain set is validated (the sampled loop's check), carries ``filter_order`` 2 and the ISA form of the
    tuned ``(kp + ki/s + kd s) F(s)``; the step's response from the measurement is ``-C`` at ``Ts`` as
    python-control maps it (``sample_system``, Tustin) to rounding (an impulse's response about the middle of the
    output range); the Structured Text and the C export it."""
    _, r = tuned
    assert r.filter_order == 2 and r.kd > 0
    gs = r.to_gain_set().save(tmp_path / "g.json")
    g = gs.gains
    assert gs.status == "validated" and g.filter_order == 2 and gs.sample_period_s == r.Ts
    assert "second-order filter" in repr(gs)
    assert (g.Kc, g.Kc / g.Ti_s, g.Kc * g.Td_s, g.Tf_s) == pytest.approx((r.kp, r.ki, r.kd, r.Tf), rel=1e-12)
    ctrl = gs.controller()
    n, dt = 20000, r.Ts
    pv = np.zeros(n)
    pv[0] = 1e-3  # a small impulse about the middle of the output range: the clamp never acts
    state, u = ctrl.initial_state(0.0, 0.0, u0=55.0), np.empty(n)
    for k in range(n):
        u[k], state = ctrl.step(state, 0.0, pv[k])
    assert u.min() > 0.0 and u.max() < 110.0
    u = (u - 55.0) / 1e-3
    w = np.geomspace(1.0, 0.9 * np.pi / dt, 40)
    zi = np.exp(-1j * np.outer(w, np.arange(n)) * dt)
    got = -(zi @ np.diff(u, prepend=0.0)) / (1 - np.exp(-1j * w * dt))
    want = np.asarray(control.sample_system(r.controller, dt, method="tustin")(np.exp(1j * w * dt))).ravel()
    np.testing.assert_allclose(got, want, rtol=1e-8, err_msg="the gain set's step is not the tuned controller")
    # the linearised loop's sensitivity (tuning.linearised) reads the same controller off the gains
    np.testing.assert_allclose(controller_frequency_response(g, dt, w), got, rtol=1e-8)
    plc, c = export(gs, "plc"), export(gs, "casadi-c")
    assert "pv_filtered_N" in plc and "PP_CONTROLLER_STATE_SIZE 6" in c
    assert "second-order filter" in plc and "second-order filter" in c
    assert json.loads(export(gs, "json"))["gains"]["filter_order"] == 2
    assert "#define PP_FILTER_ORDER 2" in export(gs, "c-header")
    with pytest.raises(ExportError, match="field 'gains.filter_order' is 2: LabVIEW's PID VIs"):
        export(gs, "labview")  # its PID VIs have no second-order filter: refused, not written as a first order


def test_the_rig_runs_an_autotuned_second_order_gain_set(tuned, tmp_path):
    """On the simulated rig, the native loop (the compiled step) and the Python loop (the numpy step) run it to the
    same voltages, and the loop settles on the step's new force (the rig's nonlinear plant, within 1 N)."""
    p, r = tuned
    gs = r.to_gain_set().save(tmp_path / "g.json")
    ref = Reference.step(40.0, 70.0, 0.3, 1.5)
    logs = {}
    for loop, step in (("native", "c"), ("python", "numpy")):
        log = RunLog(tmp_path, loop)
        result = Executor(gs.controller(), SimBackend(p, seed=3), ref, Safety(), realtime=False, log=log, loop=loop,
                          step=step).run()
        assert result.ok and result.status == "completed", (loop, result.status)
        logs[loop] = read_run_log(log.csv_path)
    a, b = logs["native"], logs["python"]
    np.testing.assert_allclose(a["voltage_V"], b["voltage_V"], rtol=0, atol=1e-9, err_msg="the two loops differ")
    t, f = a["time_s"], a["measured_N"]
    settled = (t > 1.0) & (t < 1.5)
    assert np.max(np.abs(f[settled] - 70.0)) < 1.0 and np.max(f[(t > 0.3) & (t < 1.5)]) > 69.0
