"""The simulated rig against closed forms: Bouc-Wen, amplifier, creep, stiffness chain, sensor."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from piezopreload.models.actuator import P888_91, Plant, Rig, bouc_wen_increment, loop_width, reach_N
from piezopreload.tuning.identify import PIIdentifier

QUIET = dict(noise_N=0.0, creep_per_decade=0.0)


def _bw_ode(h0, dv, alpha, beta, gamma):
    """dh/dv = alpha - beta sgn(dv) h - gamma |h|, integrated numerically along v."""
    s = np.sign(dv)
    sol = solve_ivp(lambda v, h: alpha - beta * s * h - gamma * np.abs(h), (0.0, dv), [h0],
                    rtol=1e-12, atol=1e-13, method="DOP853")
    return sol.y[0, -1]


@pytest.mark.parametrize("h0", [-6.0, -0.5, 0.0, 0.7, 9.0])
@pytest.mark.parametrize("dv", [-40.0, -3.0, 2.5, 60.0])
@pytest.mark.parametrize("gamma", [-0.008, 0.0, 0.01])
def test_bouc_wen_increment_is_the_exact_solution(h0, dv, gamma):
    alpha, beta = 0.3, 0.02
    exact = bouc_wen_increment(h0, dv, alpha, beta, gamma)
    np.testing.assert_allclose(exact, _bw_ode(h0, dv, alpha, beta, gamma), rtol=1e-9, atol=1e-9,
                               err_msg=f"h0={h0}, dv={dv}, gamma={gamma}")


def test_bouc_wen_increment_composes():
    """Exact over any monotone increment: one step equals many smaller ones (rate independence)."""
    rng = np.random.default_rng(3)
    h0 = rng.uniform(-8, 8, 50)
    dv = rng.uniform(-50, 50, 50)
    one = bouc_wen_increment(h0, dv, 0.3, 0.02, 0.005)
    h = h0
    for _ in range(37):
        h = bouc_wen_increment(h, dv / 37, 0.3, 0.02, 0.005)
    np.testing.assert_allclose(one, h, rtol=1e-11, atol=1e-11)


def test_stacks_match_the_data_sheet_and_the_stiffness_chain():
    p = Plant()
    # the data sheet's blocked force is stiffness x travel, for each stack
    assert P888_91.stiffness_N_per_um * P888_91.max_travel_um == pytest.approx(P888_91.blocked_force_N, rel=0.06)
    assert p.stack_stiffness_N_per_um == 300.0
    ks, ke = 300.0, float(p.coupling_stiffness_N_per_um)
    assert p.effective_stiffness_N_per_um == pytest.approx(ks * ke / (ks + ke))
    stiff = replace(p, coupling_stiffness_N_per_um=1e9)
    assert stiff.effective_stiffness_N_per_um == pytest.approx(300.0, rel=1e-6)  # a rigid coupling sees the stacks
    assert p.slew_V_per_s == pytest.approx(float(p.amp_current_limit_A) / (3 * 6.0e-6))


def test_force_at_rest_is_the_bolt_preload():
    rig = Rig(Plant(bolt_preload_N=25.0))
    assert rig.force(rig.initial_state()) == pytest.approx(25.0)


def test_amplifier_small_step_is_first_order_and_large_step_is_slew_limited():
    p = Plant(**QUIET, amp_bandwidth_Hz=20.0, amp_current_limit_A=0.01, delay_samples=0)
    rig = Rig(p)
    dt, tau = p.sample_period_s, 1 / (2 * np.pi * 20.0)
    # small step: below the slew limit the output follows 1 - exp(-t/tau) exactly at the samples
    st, v = rig.initial_state(), []
    for _ in range(50):
        st = rig.step(st, 1.0)
        v.append(float(st.v_amp))
    k = np.arange(1, 51)
    np.testing.assert_allclose(v, 1 - np.exp(-k * dt / tau), rtol=1e-12)
    # large step: a ramp at the slew rate I / C while (u - v)(1 - e^{-dt/tau}) exceeds it
    st = rig.initial_state()
    for _ in range(5):
        st = rig.step(st, 100.0)
    assert float(st.v_amp) == pytest.approx(5 * p.slew_V_per_s * dt, rel=1e-12)


def test_one_sample_delay():
    p = Plant(**QUIET)
    rig0, rig1 = Rig(replace(p, delay_samples=0)), Rig(p)
    s0, s1 = rig0.step(rig0.initial_state(), 10.0), rig1.step(rig1.initial_state(), 10.0)
    assert float(s0.v_amp) > 0 and float(s1.v_amp) == 0.0
    s1 = rig1.step(s1, 10.0)
    assert float(s1.v_amp) == pytest.approx(float(s0.v_amp), rel=1e-15)


def test_creep_after_a_step_follows_its_closed_form():
    """x_total(t) = x - sum_i c (x - x0) exp(-t / tau_i) at constant voltage: exact at the samples."""
    p = Plant(noise_N=0.0, creep_per_decade=0.02, amp_bandwidth_Hz=1e4, amp_current_limit_A=10.0, delay_samples=0)
    rig = Rig(p)
    st = rig.step(rig.initial_state(), 50.0)  # the amplifier reaches 50 V within this sample
    assert float(st.v_amp) == pytest.approx(50.0, abs=1e-9)
    f = [float(rig.force(st))]
    for _ in range(3000):
        st = rig.step(st, 50.0)
        f.append(float(rig.force(st)))
    t = np.arange(len(f)) * p.sample_period_s
    f_final = float(rig.force(replace(st, creep=np.full(4, rig._stroke(st.v_amp, st.h)))))
    dx_force = f_final - 25.0
    expected = f_final - 0.02 * dx_force * sum(np.exp(-(t + p.sample_period_s) / tau) for tau in p.creep_tau_s)
    np.testing.assert_allclose(f, expected, rtol=1e-10)
    # about creep_per_decade of the step per decade of time between 0.1 s and 1 s
    rise_per_decade = (f[1000] - f[100]) / dx_force
    assert 0.01 < rise_per_decade < 0.03


def test_sensor_quantises_and_adds_noise_of_the_stated_level():
    p = Plant(noise_N=0.3)
    rig = Rig(p)
    st = rig.initial_state((20000,))
    y = rig.measure(st, np.random.default_rng(0))
    lsb = p.adc_lsb_N
    assert lsb == pytest.approx(2000.0 / 65536)
    np.testing.assert_allclose(y / lsb, np.round(y / lsb), atol=1e-9)
    assert abs(np.mean(y) - 25.0) < 5 * 0.3 / np.sqrt(y.size) + lsb
    assert np.std(y) == pytest.approx(np.sqrt(0.3**2 + lsb**2 / 12), rel=0.03)


def test_width_and_reach_are_those_of_real_stacks():
    rig = Rig(Plant(bw_alpha=0.3, bw_beta_per_V=0.02, coupling_stiffness_N_per_um=3.0))
    assert 0.10 <= float(loop_width(rig)) <= 0.15
    assert float(reach_N(rig, 110.0)) > 100.0


def test_truth_model_is_not_a_prandtl_ishlinskii_model():
    """A P-I model with many operators still leaves a residual on the noise-free truth loop."""
    rig = Rig(Plant(**QUIET, bw_kappa=0.2))
    v = np.concatenate([np.linspace(0, 100, 401), np.linspace(100, 20, 321)[1:], np.linspace(20, 80, 241)[1:],
                        np.linspace(80, 0, 321)[1:]])
    f, _ = rig.quasi_static_loop(v)
    est = PIIdentifier(model="classical", n_operators=100, thresholds="paper").fit(v, f)
    rms_pct = 100 * np.sqrt(np.mean((est.model_(v) - f) ** 2)) / np.ptp(f)
    assert rms_pct > 0.1, "the truth loop should not be reproducible by a P-I model"


def test_batches_vary_deterministically_and_simulate_like_single_plants():
    base = Plant(**QUIET)
    a = base.vary(8, {"amp_bandwidth_Hz": 0.2, "coupling_stiffness_N_per_um": 0.1}, seed=4)
    b = base.vary(8, {"amp_bandwidth_Hz": 0.2, "coupling_stiffness_N_per_um": 0.1}, seed=4)
    np.testing.assert_array_equal(a.amp_bandwidth_Hz, b.amp_bandwidth_Hz)
    assert a.batch_shape == (8,)
    assert np.all(np.abs(a.coupling_stiffness_N_per_um / 3.0 - 1) <= 0.2 + 1e-12)  # truncated at 2 sigma
    batch, single = Rig(a), Rig(a.take(5))
    sb, ss = batch.initial_state(), single.initial_state()
    u = 60 * np.sin(np.linspace(0, 6, 300)) ** 2
    for uk in u:
        sb, ss = batch.step(sb, uk), single.step(ss, uk)
    assert float(batch.force(sb)[5]) == pytest.approx(float(single.force(ss)), rel=1e-13)
    # a slice stays a batch of the varied fields only; the fixed ones stay scalars
    part = a.take(slice(2, 5))
    assert part.batch_shape == (3,) and np.ndim(part.sample_period_s) == 0 and np.ndim(part.noise_N) == 0
    np.testing.assert_array_equal(part.amp_bandwidth_Hz, a.amp_bandwidth_Hz[2:5])


@pytest.mark.parametrize("field,value", [("amp_bandwidth_Hz", 0.0), ("noise_N", -1.0), ("bw_beta_per_V", 0.001),
                                         ("delay_samples", -1), ("creep_tau_s", (1.0, -2.0))])
def test_bad_parameters_are_named(field, value):
    kwargs = {field: value}
    if field == "bw_beta_per_V":
        kwargs["bw_gamma_per_V"] = 0.01
    with pytest.raises(ValueError, match=field):
        Plant(**kwargs)


def test_parameters_round_trip_through_a_dict():
    p = Plant(bw_kappa=0.1).vary(3, {"noise_N": 0.2}, seed=1)
    q = Plant.from_dict(p.to_dict())
    np.testing.assert_array_equal(q.noise_N, p.noise_N)
    assert q.stack == p.stack and q.creep_tau_s == p.creep_tau_s and q.bw_kappa == 0.1
    with pytest.raises(ValueError, match="unknown rig parameter"):
        Plant.from_dict({"noise": 0.1})
