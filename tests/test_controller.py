"""The controller step: hand-computed samples, python-control's discrete transfer functions,
anti-windup, bumpless gain change, batches, LabVIEW units and the feedforward."""

import numpy as np
import pytest

from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.hysteresis import ClassicalPI, uniform_thresholds

control = pytest.importorskip("control", reason="python-control is the independent reference")

WIDE = dict(u_min_V=-1e9, u_max_V=1e9)


def run(ctrl, sp, pv, state=None):
    state = state or ctrl.initial_state(sp[0], pv[0])
    out = []
    for s, y in zip(sp, pv):
        u, state = ctrl.step(state, s, y)
        out.append(u)
    return np.array(out), state


def test_hand_computed_steps():
    ctrl = Controller(PIDGains(Kc=2.0, Ti_s=0.5, Td_s=0.1, **WIDE), dt_s=0.01)
    state = ctrl.initial_state(10.0, 4.0)  # e_prev = 6, pv_prev = 4, integral 0
    u1, state = ctrl.step(state, 10.0, 4.0)
    # P = 2*6 = 12; I = 2/0.5 * (6+6)/2 * 0.01 = 0.24; D = 0
    assert u1 == pytest.approx(12.24, abs=1e-12)
    u2, state = ctrl.step(state, 10.0, 5.0)
    # P = 10; I = 0.24 + 4 * (5+6)/2 * 0.01 = 0.46; D = -2 * 0.1 * (5-4)/0.01 = -20
    assert u2 == pytest.approx(10 + 0.46 - 20, abs=1e-12)


def test_matches_discrete_transfer_functions():
    """Unsaturated, unfiltered: u = Kc b r - Kc y + Kc dt/(2Ti) (z+1)/(z-1) e - Kc Td/dt (1 - 1/z) y."""
    kc, ti, td, dt, b = 1.5, 0.2, 0.02, 1e-3, 0.7
    ctrl = Controller(PIDGains(Kc=kc, Ti_s=ti, Td_s=td, b=b, **WIDE), dt_s=dt)
    rng = np.random.default_rng(1)
    n = 400
    sp = np.r_[0.0, np.repeat(rng.uniform(-5, 5, 8), n // 8)][:n]
    pv = np.r_[0.0, rng.normal(0, 1, n - 1).cumsum() * 0.1]
    ours, _ = run(ctrl, sp, pv, ctrl.initial_state(0.0, 0.0))
    t = np.arange(n) * dt
    integ = control.tf([kc * dt / (2 * ti), kc * dt / (2 * ti)], [1, -1], dt)
    deriv = control.tf([-kc * td / dt, kc * td / dt], [1, 0], dt)
    e = sp - pv
    ref = (kc * b * sp - kc * pv
           + control.forced_response(integ, t, e).outputs
           + control.forced_response(deriv, t, pv).outputs)
    np.testing.assert_allclose(ours, ref, atol=1e-9, err_msg="PID vs python-control transfer functions")


def test_anti_windup_leaves_saturation_at_once():
    gains = PIDGains(Kc=1.0, Ti_s=0.05, u_min_V=0.0, u_max_V=10.0)
    ctrl = Controller(gains, dt_s=1e-3)
    sp = np.r_[np.full(2000, 100.0), np.full(50, 0.0)]  # unreachable setpoint, then back to 0
    pv = np.full(sp.size, 5.0)
    u, state = run(ctrl, sp, pv)
    assert np.all(u[:2000] == 10.0)
    assert state.integral <= 10.0, "the integral must not wind up while the output is clamped"
    assert u[2000] < 10.0 and u[2001] == 0.0, "the output must leave the limit when the error turns"


def test_bumpless_gain_change():
    """A loop resting with a 1 N error: switching gains moves the output by the new integral
    increment only, where swapping the gains without retune() jumps by (Kc_new - Kc_old) e."""
    dt = 1e-3
    ctrl = Controller(PIDGains(Kc=0.5, Ti_s=0.3, Td_s=0.01, **WIDE), dt_s=dt)
    sp, pv = np.full(300, 60.0), np.full(300, 59.0)
    u, state = run(ctrl, sp, pv)
    new_gains = PIDGains(Kc=2.0, Ti_s=0.1, Td_s=0.05, **WIDE)
    new, state2 = ctrl.retune(state, new_gains)
    u_next, _ = new.step(state2, 60.0, 59.0)
    increment = new_gains.Kc / new_gains.Ti_s * 1.0 * dt
    assert u_next - u[-1] == pytest.approx(increment, abs=1e-12)
    naive, _ = Controller(new_gains, dt_s=dt).step(state, 60.0, 59.0)
    assert naive - u[-1] == pytest.approx((2.0 - 0.5) * 1.0 + increment, abs=1e-12)


def test_batch_equals_one_loop_at_a_time():
    ctrl = Controller(PIDGains(Kc=0.3, Ti_s=4.8, Td_s=0.06, Tf_s=0.01), dt_s=1e-3)
    rng = np.random.default_rng(2)
    pv = 25 + rng.normal(0, 5, (6, 200)).cumsum(axis=1) * 0.1
    sp = np.full((6, 200), 60.0)
    state = ctrl.initial_state(sp[:, 0], pv[:, 0])
    batch = []
    for k in range(200):
        u, state = ctrl.step(state, sp[:, k], pv[:, k])
        batch.append(u)
    batch = np.array(batch).T
    for j in range(6):
        single, _ = run(ctrl, sp[j], pv[j])
        np.testing.assert_allclose(batch[j], single, atol=1e-12, err_msg=f"loop {j}")


def test_labview_minutes():
    g = PIDGains.from_labview(0.3, 0.08, 0.001)  # the paper's gains as entered in LabVIEW
    assert g.Ti_s == pytest.approx(4.8) and g.Td_s == pytest.approx(0.06)
    assert g.labview() == pytest.approx({"Kc": 0.3, "Ti_min": 0.08, "Td_min": 0.001})
    with pytest.raises(ValueError, match=r"'PIDGains.Ti_s' must be a number > 0, or inf for no integral action, "
                                         r"got 0.0"):
        PIDGains(Kc=1.0, Ti_s=0.0)
    with pytest.raises(ValueError, match=r"'PIDGains.u_max_V' must be above u_min_V \(5 V\), got 5"):
        PIDGains(Kc=1.0, Ti_s=1.0, u_min_V=5.0, u_max_V=5.0)


def test_feedforward_inverts_the_hysteresis_and_start_is_bumpless():
    model = ClassicalPI(uniform_thresholds(10, 100.0), np.r_[0.5, np.full(9, 0.03)], offset=25.0)
    ctrl = Controller(PIDGains(Kc=0.0, Ti_s=np.inf, u_min_V=-1e9, u_max_V=1e9), dt_s=1e-3,
                      feedforward=model.inverse())
    target = 40 + 20 * np.sin(np.linspace(0, 6, 500))
    u, _ = run(ctrl, target, target)  # Kc = 0: pure feedforward
    np.testing.assert_allclose(model(u), target, rtol=1e-9)
    pid = Controller(PIDGains(Kc=0.3, Ti_s=4.8), dt_s=1e-3)
    state = pid.initial_state(60.0, 58.0, u0=42.0)
    u0, _ = pid.step(state, 60.0, 58.0)
    assert u0 == pytest.approx(42.0 + 0.3 / 4.8 * 2.0 * 1e-3, abs=1e-12)


# ---- the second-order filter on the measurement (filter_order 2, as the autotuner tunes it) --------------------
SECOND = dict(Kc=2.0, Ti_s=0.05, Td_s=0.004, Tf_s=0.002, filter_order=2)


def _impulse_response(ctrl, n):
    """The step's output to a unit impulse of the measurement (setpoint 0, b 0): ``-C`` sampled."""
    pv = np.zeros(n)
    pv[0] = 1.0
    u, _ = run(ctrl, np.zeros(n), pv, ctrl.initial_state(0.0, 0.0))
    return u


def _dtft(h, w, dt):
    """``sum_k h_k z^-k`` at ``z = e^{j w dt}`` of a response whose tail is a constant (the integrator's): its
    first difference summed and divided by ``1 - z^-1``."""
    zi = np.exp(-1j * np.outer(w, np.arange(h.size)) * dt)
    return (zi @ np.diff(h, prepend=0.0)) / (1 - np.exp(-1j * w * dt))


def test_the_second_order_step_is_the_tustin_map_of_the_continuous_controller():
    """From the measurement to the output the step is ``-(Kc + Kc/(Ti s) + Kc Td s) F(s)``, ``F = 1/(1 + Tf s +
    (Tf s)^2/2)``, mapped by Tustin's rule: against scipy's bilinear discretisation of that transfer function to
    rounding, and against the continuous controller within Tustin's error (the frequency warped to
    ``2/dt tan(w dt/2)``: a relative error below ``(w dt)^2/12`` times the response's log-slope, bounded here by
    the slope's largest value over the grid)."""
    from scipy import signal

    dt = 1e-3
    g = PIDGains(**SECOND, b=0.0, **WIDE)
    kc, ti, td, tf = g.Kc, g.Ti_s, g.Td_s, g.Tf_s
    n = 6000  # the filter's and the integrator's transient long over (Tf = 2 samples)
    w = np.geomspace(1.0, 0.9 * np.pi / dt, 60)
    got = _dtft(_impulse_response(Controller(g, dt), n), w, dt)
    num, den = -kc * np.array([td, 1.0, 1.0 / ti]), np.polymul([tf**2 / 2, tf, 1.0], [1.0, 0.0])
    bz, az, _ = signal.cont2discrete((num, den), dt, method="bilinear")
    _, want = signal.freqz(bz.ravel(), az, worN=w * dt)
    np.testing.assert_allclose(got, want, rtol=1e-9, err_msg="the step is not scipy's bilinear map of C F")
    # against the continuous controller: within Tustin's warping; the same gains with the first-order filter on the
    # derivative are far from it (the check tells the two filters apart)
    cont = signal.freqs(num, den, worN=w)[1]
    low = w * dt <= 0.3
    slope = np.max(np.abs(np.gradient(np.log(cont), np.log(w))))
    bound = slope * (w * dt) ** 2 / 12 * 1.1
    assert np.all(np.abs(got / cont - 1)[low] <= bound[low]), "beyond Tustin's warping error"
    first = Controller(PIDGains(**{**SECOND, "filter_order": 1}, b=0.0, **WIDE), dt)
    other = _dtft(_impulse_response(first, n), w, dt)
    assert np.max(np.abs(other / cont - 1)[low]) > 10 * np.max(np.abs(got / cont - 1)[low])


def test_the_second_order_step_starts_and_changes_gains_bumplessly():
    """A start at rest gives ``u0`` plus the integral's first increment; resting with a 1 N error, a change of gains
    (within the second order, and from and to the first) moves the output by the new integral increment only, as
    for the first order (test_bumpless_gain_change)."""
    dt = 1e-3
    a = Controller(PIDGains(**SECOND, **WIDE), dt)
    state = a.initial_state(50.0, 48.0, u0=30.0)
    assert state.pv_filtered == 48.0
    u, _ = a.step(state, 50.0, 48.0)
    assert u == pytest.approx(30.0 + 2.0 / 0.05 * 2.0 * dt, abs=1e-12)
    new_gains = dict(Kc=0.7, Ti_s=0.1, Td_s=0.01, Tf_s=0.003, **WIDE)
    for old_order, new_order in ((2, 2), (1, 2), (2, 1)):
        old = Controller(PIDGains(**{**SECOND, "filter_order": old_order}, **WIDE), dt)
        u, state = run(old, np.full(3000, 60.0), np.full(3000, 59.0))
        new, state2 = old.retune(state, PIDGains(**new_gains, filter_order=new_order))
        assert (state2.pv_filtered is None) == (new_order == 1)
        u_next, _ = new.step(state2, 60.0, 59.0)
        assert u_next - u[-1] == pytest.approx(0.7 / 0.1 * 1.0 * dt, abs=1e-9), (old_order, new_order)


def test_the_second_order_filter_needs_its_time_constant():
    with pytest.raises(ValueError, match=r"'PIDGains.Tf_s' must be > 0 for filter_order 2 \(the second-order "
                                         r"filter\), got 0.0"):
        PIDGains(Kc=1.0, Ti_s=1.0, Tf_s=0.0, filter_order=2)
    with pytest.raises(ValueError, match="filter_order"):
        PIDGains(Kc=1.0, Ti_s=1.0, Tf_s=0.1, filter_order=3)
