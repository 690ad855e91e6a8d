"""The closed-loop simulation: against python-control on a linear rig, determinism, batches."""

from dataclasses import replace

import numpy as np
import pytest

from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate, simulate_open_loop, triangle
from piezopreload.models.controller import Controller, PIDGains

control = pytest.importorskip("control", reason="python-control is the independent reference (extra 'test')")

# a rig without hysteresis, creep, noise or quantisation: linear, so python-control can check it
LINEAR = Plant(bw_alpha=1e-12, bw_beta_per_V=1e-3, creep_per_decade=0.0, noise_N=0.0, adc_bits=32,
                   amp_current_limit_A=100.0, amp_bandwidth_Hz=15.0)


def test_closed_loop_matches_python_control_on_a_linear_rig():
    """y = T r with T = CP / (1 + CP): the PID (trapezoidal I) and the discrete rig in z."""
    rig = Rig(LINEAR)
    dt = rig.dt_s
    gains = PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.0, u_min_V=-1e6, u_max_V=1e6)
    ref = Reference.step(25.0, 60.0, 0.05, 1.5)
    run = simulate(rig, Controller(gains, dt), ref, seed=0)

    k = float(LINEAR.effective_stiffness_N_per_um * LINEAR.stroke_um_per_V)  # N per V
    a = np.exp(-dt * 2 * np.pi * 15.0)
    plant = control.tf([k * (1 - a)], [1, -a, 0], dt)  # amplifier (exact first order) and one-sample delay
    c = gains.Kc * (1 + dt / (2 * gains.Ti_s) * control.tf([1, 1], [1, -1], dt))
    loop = control.feedback(c * plant, 1)
    r = run.reference_N - 25.0
    resp = control.forced_response(loop, T=run.t_s, U=r)
    # the only difference left is the 32-bit A/D: LSB/2 = 2.3e-7 N per reading, through the loop
    np.testing.assert_allclose(run.force_N - 25.0, resp.outputs, atol=2 * LINEAR.adc_lsb_N, err_msg="closed-loop force")
    assert np.max(np.abs(run.force_N - 25.0 - resp.outputs)) < 1e-6


def test_pid_alone_reaches_the_setpoint_and_holds_it():
    rig = Rig(Plant())
    run = simulate(rig, Controller(PIDGains(0.3, 0.08, 0.001), rig.dt_s), Reference.step(25.0, 60.0, 0.5, 8.0))
    late = run.t_s > 6.0
    # creep keeps pushing the force up and the PI lowers the voltage along a descending branch
    # that starts flat, so it lags by about 0.1 N here; it never leaves the band
    assert abs(np.mean(run.force_N[late]) - 60.0) < 0.25
    assert np.all(np.abs(run.force_N[late] - 60.0) < 1.5)
    assert np.all((run.command_V >= 0.0) & (run.command_V <= 110.0))


def test_simulation_is_deterministic_for_a_seed():
    rig = Rig(Plant(noise_N=0.3))
    c = Controller(PIDGains(0.3, 0.08, 0.001), rig.dt_s)
    ref = Reference.step(25.0, 60.0, 0.1, 1.0)
    a, b = simulate(rig, c, ref, seed=7), simulate(rig, c, ref, seed=7)
    np.testing.assert_array_equal(a.measured_N, b.measured_N)
    np.testing.assert_array_equal(a.command_V, b.command_V)
    other = simulate(rig, c, ref, seed=8)
    assert not np.array_equal(a.measured_N, other.measured_N)


def test_a_batch_simulates_each_plant_as_alone():
    base = replace(Plant(), noise_N=0.0)
    batch = base.vary(5, {"amp_bandwidth_Hz": 0.3, "coupling_stiffness_N_per_um": 0.15, "creep_per_decade": 0.3},
                      seed=2)
    c = Controller(PIDGains(0.3, 0.08, 0.001), base.sample_period_s)
    ref = Reference.step(25.0, 60.0, 0.1, 4.0)
    runs = simulate(Rig(batch), c, ref)
    assert runs.force_N.shape == (5, runs.t_s.size)
    for i in (0, 3):
        one = simulate(Rig(batch.take(i)), c, ref)
        np.testing.assert_allclose(runs.force_N[i], one.force_N, rtol=1e-12, err_msg=f"plant {i}")
    metrics = runs.step_metrics(1.5)
    assert len(metrics) == 5 and all(np.isfinite(m.settling_s) for m in metrics)


def test_step_metrics_of_a_run_use_the_step_window():
    rig = Rig(replace(Plant(), noise_N=0.0))
    ref = Reference.staircase(25.0, [60.0, 80.0], hold_s=3.0, t_start_s=0.5)
    run = simulate(rig, Controller(PIDGains(0.3, 0.08, 0.001), rig.dt_s), ref)
    first, second = run.step_metrics(1.5, which=1), run.step_metrics(1.5, which=2)
    assert first.initial == 25.0 and first.final == 60.0
    assert second.initial == 60.0 and second.final == 80.0
    assert 0 < first.rise_s < 3.0 and 0 < second.rise_s < 3.0
    te = run.tracking_error()
    assert te.max_N == pytest.approx(35.0, abs=0.5)  # the first jump, before the force moves
    assert 0 < te.rms_N < te.max_N


def test_references_and_the_open_loop_measurement():
    with pytest.raises(ValueError, match="start at 0"):
        Reference(np.array([1.0, 2.0]), np.array([25.0, 60.0]), 3.0)
    ref = Reference.staircase(25.0, [60, 80, 100, 80, 60], hold_s=5.0, t_start_s=0.5)
    assert ref.at([0.0, 0.5, 5.49, 5.5, 25.4]).tolist() == [25.0, 60.0, 60.0, 80.0, 60.0]
    assert ref.duration_s == pytest.approx(25.5)
    t, v = triangle(100.0, 0.5, 2, 1e-3)
    assert v.max() == pytest.approx(100.0) and v[0] == 0.0 and t[-1] == pytest.approx(4.0)
    rec = simulate_open_loop(Rig(Plant()), v, seed=1)
    assert rec["measured_N"].shape == v.shape
    assert rec["force_N"].max() > 90.0  # about 1 N/V over the 0-100 V loop
