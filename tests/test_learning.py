"""Preview and iterative learning control: the floors, the laws' theory on linear plants, the norm-optimal law's
Riccati form against the dense lifted solution, its QP, its robust gain, the trials and the artifacts."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.tuning import ilc as I
from piezopreload.tuning import learning as L
from piezopreload.tuning import lifted as LI
from piezopreload.tuning import norm_optimal as NO
from piezopreload.tuning import preview as P
from piezopreload.tuning.bounds import tracking_floor

TRAJECTORY = Reference.staircase(25.0, [60.0, 80.0, 100.0, 80.0, 60.0], 1.0, t_start_s=0.5)


def _linear_model(**kw) -> I.LearningModel:
    """A first-order lag read a sample late (y_k = C x_k, x+ = A x + B u): G(z) = 0.2 z^-1 / (1 - 0.8 z^-1)."""
    return I.LearningModel(np.array([[0.8]]), np.array([[1.0]]), np.array([[0.2]]), 1e-3, **kw)


def _simulate_linear(model: I.LearningModel, u: np.ndarray) -> np.ndarray:
    return model.lifted(u.size) @ u


# ---- preview ---------------------------------------------------------------------------------
def test_preview_floor_without_preview_is_the_causal_floor_and_falls_with_preview():
    params = Plant(amp_current_limit_A=0.0142)  # the paper's slow amplifier: ramps of tens of samples
    causal = tracking_floor(params, TRAJECTORY).rms_N
    plan0 = P.preview_plan(params, TRAJECTORY, 0.0)
    assert plan0.rms_N == pytest.approx(causal, rel=1e-12), "with no preview the plan's floor is not tracking_floor's"
    floors = [P.preview_plan(params, TRAJECTORY, p).rms_N for p in (0.0, 0.005, 0.01, 0.2)]
    assert all(a > b for a, b in zip(floors, floors[1:-1])), f"the floor does not fall with the preview: {floors}"
    # a ramp centred on each jump: the continuous bound sum dF^3 / (12 rate), to the sample grid's rounding
    rate = plan0.rate_N_per_s
    jumps = np.abs(np.diff(TRAJECTORY.levels_N))
    scored = TRAJECTORY.duration_s - TRAJECTORY.times_s[1]
    # (the score starts at the first change, so the first ramp's half before it costs nothing)
    centred = np.sqrt((np.sum(jumps**3) - 0.5 * jumps[0] ** 3) / (12 * rate) / scored)
    assert floors[-1] == pytest.approx(centred, rel=0.02), "the long-preview floor is not the centred ramps' error"


def _pure_delay() -> Plant:
    """A rig that is a pure delay (amplifier and slew far faster than a sample, no creep, hysteresis negligible)."""
    return Plant(amp_bandwidth_Hz=1e6, amp_current_limit_A=1e3, creep_per_decade=0.0, bw_alpha=1e-12,
                     bw_kappa=0.0, noise_N=0.0, adc_bits=32, delay_samples=2)


def test_preview_on_a_pure_delay_removes_it_exactly():
    params = _pure_delay()
    rig = Rig(params)
    gain = float(params.effective_stiffness_N_per_um * params.stroke_um_per_V)  # N/V
    ref = Reference.staircase(25.0, [40.0, 55.0, 30.0], 0.05, t_start_s=0.02)
    c = Controller(PIDGains(Kc=0.0, Ti_s=np.inf, u_min_V=-1e3, u_max_V=1e3), rig.dt_s)  # the feedforward alone
    n = int(round(ref.duration_s / rig.dt_s)) + 1
    r = ref.at(np.arange(n) * rig.dt_s)
    ff = (r - params.bolt_preload_N) / gain
    lag = params.delay_samples + 1  # the delay line and the D/A's sample
    late = simulate(rig, c, ref, ff_extra_V=ff, engine="numpy")
    early = simulate(rig, c, ref, ff_extra_V=P.advance(ff, lag), engine="numpy")
    assert np.max(np.abs(late.force_N - r)) > 10.0, "without preview the delay should show"
    np.testing.assert_allclose(early.force_N[lag:], r[lag:], atol=1e-6,
                               err_msg="previewed by the delay, the pure delay's output is not the reference")


def test_the_rigs_own_branch_is_never_faster_than_the_steepest_slope_and_ends_at_each_level():
    params = Plant(amp_current_limit_A=0.0142)
    rate = tracking_floor(params, TRAJECTORY).rate_N_per_s * params.sample_period_s
    ramps = P.branch_ramps(params, TRAJECTORY.levels_N)
    assert len(ramps) == TRAJECTORY.levels_N.size - 1
    for level, start, ramp in zip(TRAJECTORY.levels_N[1:], TRAJECTORY.levels_N[:-1], ramps):
        steps = np.abs(np.diff(ramp))  # (the first sample may carry the last one's overshoot of its level: < 2 steps)
        assert np.all(steps <= rate * (1 + 1e-9)), f"a branch step of {steps.max()} N beats the steepest {rate} N"
        assert abs(ramp[0] - start) <= 2 * rate, "the ramp does not start at its level"
        assert ramp[-1] == pytest.approx(level), f"the ramp to {level} N ends at {ramp[-1]} N"
    falling = ramps[3]  # 100 -> 80 N: right after a reversal the branch is flat (1 - alpha of the slope)
    assert np.abs(falling[1] - falling[0]) < 0.8 * rate, "no slow start after the reversal"
    plain = P.preview_plan(params, TRAJECTORY, 0.2).rms_N
    branch = P.preview_plan(params, TRAJECTORY, 0.2, ramps=ramps).rms_N
    assert branch > plain, "the rig's own branch cannot track better than the steepest-slope bound"


def test_a_slower_planned_ramp_follows_the_same_branch_in_proportionally_more_samples():
    params = Plant(amp_current_limit_A=0.0142)
    full = P.branch_ramps(params, TRAJECTORY.levels_N)
    half = P.branch_ramps(params, TRAJECTORY.levels_N, slew_fraction=0.5)
    for a, b in zip(full, half):
        # quasi-static: the force is a function of the voltage along the branch, so half the voltage step per
        # sample takes twice the samples to the level, up to where the last level was reached (each ramp stops at
        # the first sample past its level: the next starts from a voltage up to one step apart, a few % of a ramp)
        assert abs(b.size - 2 * a.size) <= max(3, 0.1 * 2 * a.size), (
            f"{a.size} samples at full slew but {b.size} at half")
        assert b[-1] == pytest.approx(a[-1]), "the slower ramp does not end where the full-slew one does"
    with pytest.raises(InputError, match="slew_fraction"):
        P.branch_ramps(params, TRAJECTORY.levels_N, slew_fraction=0.0)


def test_weighting_the_after_change_error_starts_the_ramps_later_and_trades_the_two_scores():
    params = Plant(amp_current_limit_A=0.0142)
    ramps = P.branch_ramps(params, TRAJECTORY.levels_N)
    lead = P.feedforward_lead(params)

    def scores(w: float) -> tuple[P.PreviewPlan, float, float]:
        plan = P.preview_plan(params, TRAJECTORY, 0.2, lead_samples=lead, ramps=ramps, after_change_weight=w)
        t, r = plan.t_s, TRAJECTORY.at(plan.t_s)
        outside = t >= TRAJECTORY.times_s[1]
        for tj in TRAJECTORY.times_s[1:]:
            outside &= ~((t >= tj - 1e-12) & (t < tj + P.AFTER_CHANGE_S - 1e-12))
        return plan, plan.rms_N, float(np.sqrt(np.mean((r - plan.force_N)[outside] ** 2)))

    plan0, whole0, after0 = scores(0.0)
    default = P.preview_plan(params, TRAJECTORY, 0.2, lead_samples=lead, ramps=ramps)
    assert np.array_equal(default.force_N, plan0.force_N), "weight 0 is not the plain plan"
    plan1, whole1, after1 = scores(1e4)
    assert all(s1 >= s0 for s0, s1 in zip(plan0.starts, plan1.starts)), (plan0.starts, plan1.starts)
    # (a ramp may start a sample or two early where its first steps are tiny: just after a reversal)
    assert all(s >= -3 for s in plan1.starts), f"a heavy weight still previews a ramp far ahead: {plan1.starts}"
    assert min(plan0.starts) < -10, f"the plain plan previews nothing here: {plan0.starts}"
    assert after1 < after0 and whole1 > whole0, (f"no trade: whole {whole0:.3f} -> {whole1:.3f} N, "
                                                 f"after the jumps {after0:.3f} -> {after1:.3f} N")
    with pytest.raises(InputError, match="after_change_weight"):
        P.preview_plan(params, TRAJECTORY, 0.2, after_change_weight=-1.0)


def test_preview_on_a_ramp_with_a_pure_delay_removes_it_and_without_it_the_floor_is_the_kinks_lag():
    params = _pure_delay()
    rig = Rig(params)
    dt = rig.dt_s
    gain = float(params.effective_stiffness_N_per_um * params.stroke_um_per_V)  # N/V
    # from the bolts' preload (where the rig rests at 0 V) up 25 N and back, twice
    ref = Reference.ramps([0.0, 0.02, 0.07, 0.12, 0.17], [25.0, 25.0, 50.0, 50.0, 25.0], 0.2).repeat(2)
    n = int(round(ref.duration_s / dt)) + 1
    r = ref.at(np.arange(n) * dt)
    lag = params.delay_samples + 1  # the delay line and the D/A's sample
    plan = P.ramp_plan(params, ref, lag * dt, lead_samples=lag)
    np.testing.assert_allclose(plan.force_N, r, atol=1e-12,
                               err_msg="with preview over the lead the plan is not the ramp")
    c = Controller(PIDGains(Kc=0.0, Ti_s=np.inf, u_min_V=-1e3, u_max_V=1e3), dt)  # the feedforward alone
    ff = (plan.force_N - params.bolt_preload_N) / gain
    late = simulate(rig, c, ref, ff_extra_V=ff, engine="numpy")
    early = simulate(rig, c, ref, ff_extra_V=P.advance(ff, lag), engine="numpy")
    slope = 25.0 / 0.05 * dt  # N per sample on the ramps
    assert np.max(np.abs(late.force_N - r)[lag:]) == pytest.approx(lag * slope, rel=1e-6), \
        "without preview the lag is not lag x slope"
    np.testing.assert_allclose(early.force_N[lag:], r[lag:], atol=1e-6,
                               err_msg="previewed by the lead, the pure delay's output is not the ramp")
    # without preview the floor is the slope's extrapolation over the delay: at each of the 4 kinks
    # (4 per cycle, scored from the first at t = 0.02 s on) the error grows by a slope per sample for d samples; but
    # where a ramp ends at the bolts' level the extrapolation below it is held at the level the rig reaches at 0 V
    d = params.delay_samples
    kinks = 6
    scored = int(np.sum(np.arange(n) * dt >= ref.times_s[1] - 1e-12))
    closed = np.sqrt(kinks * slope**2 * d * (d + 1) * (2 * d + 1) / 6 / scored)
    assert P.causal_floor(params, ref) == pytest.approx(closed, rel=1e-9), (
        "the ramp's causal floor is not the kinks' lag")
    assert P.preview_plan(params, ref, d * dt).rms_N == pytest.approx(0.0, abs=1e-12), (
        "a preview of the delay leaves a floor")


# ---- the P-type law on linear plants -----------------------------------------------------------
def test_p_type_ilc_converges_monotonically_as_its_contraction_says():
    model = I.tune_laws(_linear_model(sp_gain=1.0))
    model = replace(model, q_cutoff_Hz=100.0)
    n = 300
    G = model.lifted(n)
    Q = np.array([I.zero_phase_lowpass(col, model.q_cutoff_Hz, model.dt_s) for col in np.eye(n)]).T
    Lm = model.gamma * np.array([P.advance(col, model.delta, fill="zero") for col in np.eye(n)]).T
    M = Q @ (np.eye(n) - Lm @ G)
    rho = np.linalg.norm(M, 2)
    assert rho < 1.0, f"the lifted contraction ||Q(I - LG)|| is {rho}"
    t = np.arange(n) * model.dt_s
    r = np.where(t > 0.05, 1.0, 0.0) + 0.5 * np.sin(2 * np.pi * 8 * t)
    u_inf = np.linalg.solve(np.eye(n) - M, Q @ Lm @ r)
    u = np.zeros(n)
    dist = [np.linalg.norm(u - u_inf)]
    for _ in range(15):
        u = I.p_type_update(model, u, r - _simulate_linear(model, u))
        dist.append(np.linalg.norm(u - u_inf))
    ratios = np.array(dist[1:]) / np.array(dist[:-1])
    assert np.all(ratios <= rho + 1e-9), f"a step shrank the distance by less than the contraction {rho}: {ratios}"
    # without Q the error itself decays monotonically, by at most ||I - G L|| per trial
    model1 = replace(model, q_cutoff_Hz=np.inf)
    Lm1 = model1.gamma * np.array([P.advance(col, model1.delta, fill="zero") for col in np.eye(n)]).T
    bound = np.linalg.norm(np.eye(n) - G @ Lm1, 2)
    u, errs = np.zeros(n), []
    for _ in range(10):
        e = r - _simulate_linear(model1, u)
        errs.append(np.linalg.norm(e))
        u = I.p_type_update(model1, u, e)
    steps = np.array(errs[1:]) / np.array(errs[:-1])
    assert bound <= 1.0 + 1e-9 and np.all(steps <= bound + 1e-9), f"error ratios {steps} beyond ||I - GL|| = {bound}"


def test_the_model_contraction_bound_matches_the_lifted_norm_for_long_trials():
    model = replace(I.tune_laws(_linear_model(sp_gain=1.0)), q_cutoff_Hz=100.0)
    n = 600
    Q = np.array([I.zero_phase_lowpass(col, model.q_cutoff_Hz, model.dt_s) for col in np.eye(n)]).T
    Lm = model.gamma * np.array([P.advance(col, model.delta, fill="zero") for col in np.eye(n)]).T
    lifted = np.linalg.norm(Q @ (np.eye(n) - Lm @ model.lifted(n)), 2)
    assert lifted <= model.contraction() + 1e-6, "the lifted norm exceeds the frequency-domain contraction"
    assert lifted > model.contraction() - 0.02, "the frequency-domain contraction is far above the lifted norm"


# ---- the norm-optimal law: the lifted loop, the Riccati form, the QP --------------------------------
@pytest.fixture(scope="module")
def paper_loop():
    """The paper's rig under its PID gains (no feedforward): the loop the laws linearise."""
    params = Plant(noise_N=0.0)
    return params, Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), params.sample_period_s)


def _lti(params, controller, v0=50.0, n=200) -> LI.LiftedLoop:
    """The lifted loop at one level (linear time-invariant after its start), ``n`` samples long."""
    lin = I.linearise_loop(params, controller, [v0])
    return LI.lifted_loop(params, controller, np.full(n, lin[0].force_N), linearisations=lin)


def _dense_lti(lifted: LI.LiftedLoop) -> np.ndarray:
    """The lifted matrix H from python-control's impulse response of the level's state space (an independent
    computation of the Markov parameters), its first column from the start's ``B0`` and ``D0``."""
    import control

    n = lifted.n
    # (on a sample-period time base: python-control scales a discrete impulse by 1 / dt)
    sys = control.ss(lifted.A[0], lifted.B[0][:, None], lifted.C[0][None, :], 0.0, True)
    markov = np.asarray(control.impulse_response(sys, T=np.arange(n)).outputs, float).ravel()
    idx = np.arange(n)[:, None] - np.arange(n)[None, :]
    H = np.where(idx >= 0, markov[np.clip(idx, 0, n - 1)], 0.0)
    first = np.zeros(n)
    first[0] = lifted.D0
    x = lifted.B0.copy()
    for t in range(1, n):
        first[t] = lifted.C[0] @ x
        x = lifted.A[0] @ x
    H[:, 0] = first
    return H


def test_the_riccati_form_is_the_dense_lifted_solution(paper_loop):
    """The O(N) Riccati step solves the same normal equations as the dense lifted matrix, to rounding: on one level
    (H from python-control's impulse response) and on a level-scheduled (time-varying) model against its own H."""
    params, controller = paper_loop
    lifted = _lti(params, controller)
    H = _dense_lti(lifted)
    rng = np.random.default_rng(3)
    e = np.cumsum(rng.normal(size=(2, lifted.n)), axis=-1)
    for w in (1e-3, 1e-2, 1.0):
        dense = np.linalg.solve(H.T @ H + w * np.eye(lifted.n), H.T @ e.T).T
        step = LI.norm_optimal_step(LI.riccati_gains(lifted, w), e)  # two plants at once
        np.testing.assert_allclose(step.dv, dense, rtol=0, atol=1e-9 * np.max(np.abs(dense)),
                                   err_msg=f"the Riccati step is not the dense solution at w = {w}")
        np.testing.assert_allclose(step.force_N, dense @ H.T, atol=1e-9 * np.max(np.abs(dense @ H.T)),
                                   err_msg="the step's predicted force is not H dv")
    # a model that changes along the plan: its own dense H, column by column from its response to unit steps
    target = np.r_[np.full(60, 30.0), np.linspace(30.0, 95.0, 80), np.full(60, 95.0)]
    tv = LI.lifted_loop(params, controller, target, levels=4)
    assert len(set(map(tuple, np.c_[tv.level, tv.frac]))) > 10, "the model does not change along the plan"
    Htv = np.array([tv.response(col).force_N for col in np.eye(tv.n)]).T
    dense = np.linalg.solve(Htv.T @ Htv + 1e-2 * np.eye(tv.n), Htv.T @ e[0])
    np.testing.assert_allclose(LI.norm_optimal_step(LI.riccati_gains(tv, 1e-2), e[0]).dv, dense,
                               atol=1e-9 * np.max(np.abs(dense)), err_msg="the time-varying Riccati step is not dense")


def test_the_lifted_model_predicts_the_rig_including_the_bumpless_start(paper_loop):
    """A small learned change of the first sample's setpoint path moves the noise-free rig's force as the lifted model
    predicts: the controller's bumpless start takes up ff_extra[0] in its integral (dropping that from the model,
    the prediction is off by far more than the linearisation's error)."""
    params, controller = paper_loop
    rig = Rig(params)
    ref = Reference.ramps([0.0, 0.2], [50.0, 50.0], 0.25)
    n = int(round(ref.duration_s / rig.dt_s)) + 1
    lifted = LI.lifted_loop(params, controller, np.full(n, 50.0), levels=2)
    dv = np.zeros(n)
    dv[0] = 0.5  # half a newton of setpoint, through F
    model = lifted.response(dv)
    base = simulate(rig, controller, ref, engine="numpy")
    moved = simulate(rig, controller, ref, ff_extra_V=model.du, engine="numpy")
    actual = moved.force_N - base.force_N
    assert np.max(np.abs(actual)) > 0.05, "the change did not move the force: the test tests nothing"
    assert np.max(np.abs(actual - model.force_N)) < 0.1 * np.max(np.abs(actual)), "the lifted model mispredicts"
    no_start = replace(lifted, B0=lifted.B[int(lifted.level[0])], D0=0.0)
    wrong = no_start.response(dv).force_N
    assert np.max(np.abs(actual - wrong)) > 0.5 * np.max(np.abs(actual)), "the bumpless start made no difference"


def test_the_constrained_law_is_the_riccati_step_where_no_limit_binds_and_keeps_the_limits_where_they_do(paper_loop):
    params, controller = paper_loop
    lifted = _lti(params, controller, n=300)
    gains = LI.riccati_gains(lifted, 1e-2)
    t = np.arange(lifted.n) * lifted.dt_s
    e = np.where((t > 0.05) & (t < 0.2), 3.0, 0.0)
    free = NO.Limits((-np.inf, np.inf), np.inf, np.zeros(lifted.n), np.zeros(lifted.n))
    riccati = LI.norm_optimal_step(gains, e)
    exact = NO.constrained_step(gains, e, free, exact=True)
    np.testing.assert_allclose(exact.dv, riccati.dv, atol=1e-6 * np.max(np.abs(riccati.dv)),
                               err_msg="the sparse QP without active limits is not the Riccati step")
    # limits that bind: the command's range and the voltage's slew, the last trial's command and voltage at rest
    lo, hi = -0.5 * np.max(np.abs(riccati.command_V)), 0.5 * np.max(np.abs(riccati.command_V))
    slew = 0.5 * np.max(np.abs(np.diff(riccati.voltage_V)))
    limits = NO.Limits((lo, hi), slew, np.zeros(lifted.n), np.zeros(lifted.n))
    assert limits.broken(riccati).any(), "the limits do not bind: the test tests nothing"
    cost = lambda s: np.sum((e - s.force_N) ** 2) + 1e-2 * np.sum(s.dv**2)  # noqa: E731
    full = NO.constrained_step(gains, e, limits, exact=True)
    windows = NO.constrained_step(gains, e, limits)
    for name, s in (("the whole-trial QP", full), ("the windowed QP", windows)):
        assert not limits.broken(s, tol=1e-5).any(), f"{name} breaks a limit"
        check = lifted.response(s.dv)  # the step's outputs are the model's response to its dv
        np.testing.assert_allclose(check.command_V, s.command_V, atol=1e-9, err_msg=f"{name}: command")
        assert cost(riccati) < cost(s), f"{name} beats the unconstrained optimum"
    assert cost(windows) == pytest.approx(cost(full), rel=1e-4), "the windowed QP is not the constrained optimum"


def test_the_robust_gain_and_q_filter_keep_every_member_of_the_uncertainty_set_monotone(paper_loop):
    params, controller = paper_loop
    lins = I.linearise_loop(params, controller, [20.0, 80.0])
    lifted = LI.lifted_loop(params, controller, np.linspace(lins[0].force_N, lins[1].force_N, 50), linearisations=lins)
    alone = NO.robust_choice(lifted, [lins], controller, 1e-2)
    assert alone.gain == pytest.approx(1.0) and alone.q_cutoff_Hz == pytest.approx(0.5 / lifted.dt_s), \
        "on the nominal model alone the law needs neither a lower gain nor a Q-filter"
    assert alone.contraction < 1.0
    # a member that responds three times as strongly, and one a few samples late (its phase turns past 90 degrees)
    strong = [replace(lin, C=3.0 * lin.C) for lin in lins]
    late = [_delayed(lin, 6) for lin in lins]
    choice = NO.robust_choice(lifted, [lins, strong, late], controller, 1e-2)
    assert choice.gain < 0.75, f"a member with three times the gain kept the gain at {choice.gain}"
    assert choice.q_cutoff_Hz < 0.5 / lifted.dt_s, "a late member's phase needs the Q-filter"
    # |Q| |1 - beta r| <= 1 on every member at every frequency (r = G F L: the member's loop under the nominal law),
    # u+ - u* = Q (1 - beta r)(u - u*) per frequency: the learned signal's distance to its limit never grows
    f = np.geomspace(0.01, 0.5 / lifted.dt_s, 400)
    z = np.exp(2j * np.pi * f * lifted.dt_s)
    Q = NO._q_gain(f, choice.q_cutoff_Hz, lifted.dt_s)
    kp, ki_dt = LI.setpoint_path(controller)
    for j in range(2):
        H = NO._frequency_response(lifted.A[j], lifted.B[j], lifted.C[j], z)
        L = np.conj(H) / (np.abs(H) ** 2 + 1e-2)
        for member in (lins, strong, late):
            A, B, C = LI.composite(member[j], kp, ki_dt)[:3]
            r = NO._frequency_response(A, B, C, z) * L
            assert np.max(Q * np.abs(1.0 - choice.gain * r)) <= 1.0 + 1e-9, "a member's learned signal can grow"


def _delayed(lin: I.LoopLinearisation, d: int) -> I.LoopLinearisation:
    """``lin`` with ``d`` more samples of delay on its input (a shift register before the loop)."""
    n = lin.A.shape[0]
    A = np.zeros((n + d, n + d))
    A[:n, :n], A[:n, n + d - 1] = lin.A, lin.B
    A[n + 1:, n:n + d - 1] = np.eye(d - 1)
    B = np.zeros(n + d)
    B[n] = 1.0
    pad = np.zeros(d)
    return replace(lin, A=A, B=B, C=np.r_[lin.C, pad], Cu=np.r_[lin.Cu, pad], Cv=np.r_[lin.Cv, pad],
                   E=np.r_[lin.E, pad])


def test_the_error_is_learned_at_full_bandwidth_only_around_the_plans_changes_and_elsewhere_above_the_noise():
    dt = 1e-3
    target = np.r_[np.full(500, 10.0), np.linspace(10.0, 20.0, 50), np.full(500, 20.0)]
    noise = np.random.default_rng(1).normal(size=target.size)
    k = np.arange(target.size)
    transient = np.where((k >= 800) & (k < 820), 8.0 * np.sin(np.pi * (k - 800) / 10.0), 0.0)  # 50 Hz, 8 sigma
    out = NO.learning_error(noise + transient, target, dt, noise_N=1.0)
    near = (k >= 501 - 50) & (k <= 549 + 100)  # the plan moves at samples 501..549 (50 before, 100 after: 0.05, 0.1 s)
    np.testing.assert_array_equal(out[near], (noise + transient)[near],
                                  err_msg="the error around a change was filtered")
    hold = k < 400
    assert np.std(out[hold]) < 0.3 * np.std(noise[hold]), "the noise between the changes was not filtered out"
    seen = out[800:820] - NO.learning_error(noise, target, dt, noise_N=1.0)[800:820]
    assert np.corrcoef(seen, transient[800:820])[0, 1] > 0.9 and np.max(np.abs(seen)) > 3.0, \
        "a transient far above the noise between the changes was filtered out with it"


def test_more_trials_pay_until_the_extrapolated_limit_is_within_the_stop_gain():
    limit, ratio = 2.0, 0.3
    errors = limit + 10.0 * ratio ** np.arange(6)
    pays = [bool(L.more_trials_pay(errors[: k + 1])[0]) for k in range(1, 6)]
    # Aitken's extrapolation of a geometric approach is exact: it stops at the first trial within 10 % of the limit
    first = int(np.argmax(errors <= 1.1 * limit))
    assert pays == [k < first for k in range(1, 6)], (pays, errors)
    assert not L.more_trials_pay(np.array([3.0, 2.0, 2.5]))[0], "a trial that made it worse pays"
    assert not L.more_trials_pay(np.array([5.0, 1.05]), floor_N=1.0)[0], "a trial within 10 % of the noise pays"
    assert L.more_trials_pay(np.array([[5.0, 5.0], [2.0, 1.0]]), floor_N=[1.5, 1.0]).tolist() == [True, False]


# ---- learning on the rig ---------------------------------------------------------------------------
def test_learning_on_the_rig_converges_and_the_guard_keeps_the_best():
    params = Plant(noise_N=0.05)
    rig = Rig(params)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)
    ref = Reference.staircase(25.0, [60.0, 80.0], 0.6, t_start_s=0.2)
    res = L.learn(c, rig, ref, iterations=8, seed=1, method="p-type")
    rms = [h.tracking_rms_after_change_N for h in res.history]
    assert rms[-1] < 0.5 * rms[0], f"learning did not reduce the error: {rms}"
    assert bool(res.converged.all()) and not res.diverged.any()
    assert res.tracking_rms_N >= res.preview_floor_N - 1e-9, "a run beat the preview floor"
    # a gain far too high diverges: the guard stops and keeps the best iterate
    wild = replace(I.learning_model(params, c), gamma=40.0)
    bad = L.learn(c, rig, ref, iterations=6, seed=1, law=wild, stop_gain=None)
    assert bad.diverged.all() and len(bad.history) < 7, "the divergence guard did not stop"
    measured = [float(h.measured_rms_N) for h in bad.history]
    assert int(bad.best[()]) == int(np.argmin(measured)), "the kept iterate is not the best"
    assert bad.stop_reason == ["diverged"] and not bad.converged.any()


def test_the_norm_optimal_law_learns_in_one_trial_what_p_type_learns_in_four_and_stops_when_more_no_longer_pay():
    params = Plant(noise_N=0.05)
    rig = Rig(params)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)  # no feedforward: the loop alone, 13.7 N RMS
    ref = Reference.staircase(25.0, [60.0, 80.0, 60.0], 0.5, t_start_s=0.2)
    full = L.learn(c, rig, ref, iterations=5, seed=1, stop_gain=None)
    whole = [float(h.tracking_rms_N) for h in full.history]
    p_type = L.learn(c, rig, ref, iterations=4, seed=1, method="p-type", stop_gain=None)
    slow = [float(h.tracking_rms_N) for h in p_type.history]
    assert full.method == "norm-optimal" and whole[1] < 0.1 * whole[0], f"one trial did not remove 90 %: {whole}"
    assert whole[1] < slow[4], f"the norm-optimal law's first trial {whole} is not better than P-type's fourth {slow}"
    assert bool(full.monotone.all()), f"the error rose by more than the noise floor {full.noise_floor_N}: {whole}"
    stopped = L.learn(c, rig, ref, iterations=5, seed=1)
    k = int(stopped.trials)
    assert stopped.stop_reason == ["no longer pays"] and 2 <= k < 5, (k, stopped.stop_reason)
    assert [float(h.tracking_rms_N) for h in stopped.history] == whole[: k + 1], "stopping changed the trials before it"
    measured = np.array([float(h.measured_rms_N) for h in stopped.history])
    assert L.more_trials_pay(measured[:k], params.noise_N)[0] and not L.more_trials_pay(measured, params.noise_N)[0]
    d = stopped.to_dict()
    assert d["trials"] == k == len(stopped.history) - 1 and d["learning"]["law"] == "norm-optimal"


@pytest.mark.slow
def test_on_the_papers_rig_with_its_feedforward_one_trial_comes_within_1p1_of_the_best():
    from piezopreload.study import load_study

    study = load_study("paper2021")
    rig = Rig(study.plant)
    c = Controller(study.controller, rig.dt_s, study.identify_feedforward().inverse())
    full = L.learn(c, rig, TRAJECTORY, iterations=6, seed=study.seed, stop_gain=None)
    whole = [float(h.tracking_rms_N) for h in full.history]
    assert full.trials_to_within_1p1 <= 2, f"more than two trials to within 1.1 x the best: {whole}"
    stopped = L.learn(c, rig, TRAJECTORY, iterations=6, seed=study.seed)
    assert int(stopped.trials) <= 3 and stopped.tracking_rms_N <= 1.1 * min(whole), (stopped.trials, whole)


def test_on_monte_carlo_plants_every_plant_converges_monotonically_and_a_divergent_law_is_caught():
    # the paper's rig's sensor noise (0.249 N); with a fifth of it a plant's error may stall by ~0.01 N at trial 2
    # (the stacks' hysteresis remembers trial 1's correction), beyond a noise floor of 0.006 N
    params = Plant(noise_N=0.249)
    rig = Rig(params)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001, u_max_V=200.0), rig.dt_s)
    ref = Reference.staircase(25.0, [45.0, 60.0], 0.4, t_start_s=0.1)
    res = L.learn(c, rig, ref, iterations=4, seed=2, plants=4, stop_gain=None)
    assert res.monotone.shape == (4,) and bool(res.monotone.all()), [h.tracking_rms_N for h in res.history]
    first, last = res.history[0].tracking_rms_N, res.history[-1].tracking_rms_N
    assert np.all(last < 0.6 * first), f"a plant did not learn: {first} -> {last}"
    preview = P.plan_preview(params, c, ref)
    law = NO.with_gain(L.law_for("norm-optimal", params, c, preview), 4.0)
    bad = L.learn(c, rig, ref, iterations=4, seed=2, plants=4, law=law, stop_gain=None)
    rose = [h.tracking_rms_N for h in bad.history]
    assert bad.diverged.all() and not bad.monotone.any() and not bad.converged.any(), \
        f"four times the robust gain went unnoticed: {rose}"


def test_a_warm_started_pass_starts_near_where_the_last_one_ended():
    params = Plant(noise_N=0.05)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), params.sample_period_s)
    refs = [Reference.ramps([0.0, 0.1, 0.3, 0.5], [25.0, 25.0, 60.0 + m, 60.0 + m], 0.6).repeat(2) for m in (0.0, 2.0)]
    learner, results = L.schedule_learner(params, c, iterations=3, preview_s=None, method="norm-optimal", seed=1)
    for ref in refs:
        learner(ref)
    first, second = results
    assert second.info["warm_start"] and not first.info["warm_start"]
    assert float(second.history[0].tracking_rms_N) < 0.5 * float(first.history[0].tracking_rms_N), \
        "the second pass's trial 0 did not carry the first pass's correction"
    assert second.info["before_learning_rms_N"] > 2.0 * float(second.history[0].tracking_rms_N), \
        "the second pass's 'before learning' is not the loop without a correction"


# ---- artifacts -------------------------------------------------------------------------------------
def test_the_learned_signal_artifact_is_tied_to_its_gain_set_and_reference(tmp_path):
    n = int(round(TRAJECTORY.duration_s / 1e-3)) + 1
    sig = LearnedSignal(np.zeros(n), TRAJECTORY.at(np.arange(n) * 1e-3), 1e-3, TRAJECTORY, "a" * 64, iteration=2)
    saved = sig.save(tmp_path / "learned.json")
    back = LearnedSignal.load(tmp_path / "learned.json")
    assert back.content_sha256 == saved.content_sha256 and back.iteration == 2
    back.check("a" * 64, TRAJECTORY)
    with pytest.raises(InputError, match="a{64}.*b{64}"):
        back.check("b" * 64, TRAJECTORY)
    other = Reference.step(25.0, 60.0)
    with pytest.raises(InputError, match="reference"):
        back.check("a" * 64, other)
    text = (tmp_path / "learned.json").read_text().replace('"iteration": 2', '"iteration": 3')
    (tmp_path / "changed.json").write_text(text)
    with pytest.raises(ArtifactError, match="changed after it was written"):
        LearnedSignal.load(tmp_path / "changed.json")


def test_a_schedules_passes_are_saved_as_one_typed_record_and_each_signal_is_found_by_its_reference(tmp_path):
    import json

    params = Plant(noise_N=0.05)
    rig = Rig(params)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)
    refs = [Reference.ramps([0.0, 0.1, 0.3, 0.5], [25.0, 25.0, 60.0 + m, 60.0 + m], 0.6).repeat(2) for m in (0.0, 5.0)]
    passes = [L.learn(c, rig, ref, iterations=2, seed=1, method="p-type", stop_gain=None) for ref in refs]
    paths, record = L.save_passes(passes, tmp_path / "learn", "a" * 64, {"study": "test"})
    back = LearningRecord.load(paths["learning"])
    assert back == record and len(back.passes) == 2 and paths["learned"] == paths["pass2"]
    assert back.last.tracking_rms_N == pytest.approx(passes[-1].tracking_rms_N)
    assert back.last.before_learning_rms_N == pytest.approx(float(passes[-1].history[0].tracking_rms_N))
    assert back.trials_per_pass == [2, 2] and back.trials == 4 and back.last.method == "p-type"
    signal_for = L.learned_by_reference(back.signal_paths(tmp_path / "learn"), "a" * 64)
    for ref, result in zip(refs, passes):
        np.testing.assert_array_equal(signal_for(ref), result.ff_extra_V,
                                      err_msg="not the signal learned on this reference")
    with pytest.raises(InputError, match="no learned signal was learned on reference"):
        signal_for(TRAJECTORY)
    with pytest.raises(InputError, match="a{64}"):
        L.learned_by_reference([paths["pass1"]], "b" * 64)
    # the reader names a missing, a non-finite and an inconsistent field
    doc = json.loads(paths["learning"].read_text())
    for change, field in ((lambda d: d["pass_records"][0].pop("trials"),
                           r"field 'pass_records\[0\]\.trials' is missing"),
                          (lambda d: d["pass_records"][1].__setitem__("tracking_rms_N", "NaN"), "tracking_rms_N"),
                          (lambda d: d.__setitem__("passes", 3), "passes")):
        bad = json.loads(json.dumps(doc))
        change(bad)
        with pytest.raises(ArtifactError, match=field):
            LearningRecord.from_dict(bad)


# ---- the designed plant ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def designed_loop():
    """The designed plant of the machine axis' kind (the design optimum of the default spec, its hardware as
    studies/machine_axis.toml's [rig]) under a PID of the tuned gains' size, no feedforward."""
    from piezopreload.design.plant import plant_from_design
    from piezopreload.design.preload import DesignNLP, DesignSpec, optimise

    spec = DesignSpec()
    opt = optimise(spec, "stiffness", DesignNLP(spec))
    hardware = Plant(amp_bandwidth_Hz=100.0, bw_alpha=0.3238, bw_kappa=0.0931, creep_per_decade=0.0385,
                         noise_N=1.0, adc_full_scale_N=10000.0, amp_v_min_V=-20.0, amp_v_max_V=120.0)
    plant = plant_from_design(spec, opt, hardware, design_sha256="0" * 64, sleeve_stiffness_N_per_um=4000.0)
    c = Controller(PIDGains(Kc=0.0108, Ti_s=0.0486, b=0.91, u_min_V=-20.0, u_max_V=115.0), plant.rig.sample_period_s)
    return plant, c


def test_the_p_type_law_contracts_over_the_designed_plants_range(designed_loop):
    plant, c = designed_loop
    levels = np.linspace(0.0, 115.0, 5)
    model = I.learning_model_over(plant.rig, c, levels)
    loops = [I.learning_model(plant.rig, c, v0_V=v) for v in levels]
    gains = [float(np.max(lp.g)) for lp in loops]
    assert max(gains) > 1.3 * min(gains), (
        f"the plant's force per volt should change with the level: peak responses {gains}")
    worst = max(model.contraction(loop=lp) for lp in loops)
    assert model.range_contraction == pytest.approx(worst) and worst < 1.0, \
        f"the law does not contract at every level: {[model.contraction(loop=lp) for lp in loops]}"
    # on each linearised loop the lifted error map of the law (Q is the identity: its cut-off is Nyquist) keeps the
    # error from growing, and it shrinks trial by trial on a ramped repeated reference as far as the theory allows
    assert model.q_cutoff_Hz >= 0.5 / model.dt_s - 1e-9
    n = 400
    t = np.arange(n) * model.dt_s
    r = np.interp(t, [0.0, 0.05, 0.15, 0.25, 0.35], [0.0, 0.0, 800.0, 800.0, 100.0])
    Lm = model.gamma * np.array([model.setpoint_path(P.advance(col, model.delta, fill="zero")) for col in np.eye(n)]).T
    for v, lp in zip(levels, loops):
        G = lp.lifted(n)
        errs = [np.linalg.norm(r)]
        u = np.zeros(n)
        for _ in range(8):
            u = I.p_type_update(model, u, r - G @ u)
            errs.append(np.linalg.norm(r - G @ u))
        ratios = np.array(errs[1:]) / np.array(errs[:-1])
        bound = np.linalg.norm(np.eye(n) - G @ Lm, 2)
        assert np.all(ratios <= bound + 1e-9), f"at {v} V the error ratios {ratios} exceed ||I - G L|| = {bound}"
        assert errs[-1] < 0.2 * errs[0], f"at {v} V eight trials left {errs[-1] / errs[0]:.2f} of the error"


@pytest.mark.slow
def test_learning_on_a_ramped_repeated_reference_on_the_designed_plant(designed_loop):
    """Both laws reduce the error on the designed plant (no feedforward: 395 N RMS before learning); the norm-optimal
    law in three trials to within 1.1 x its best, below what the P-type law reaches in six, its error never rising
    by more than the noise floor."""
    plant, c = designed_loop
    rig = Rig(plant.rig)
    ref = Reference.ramps([0.0, 0.1, 0.3, 0.5, 0.6, 0.8], [50.0, 50.0, 1500.0, 1500.0, 600.0, 50.0], 1.0).repeat(2)
    p_type = L.learn(c, rig, ref, iterations=6, seed=2, method="p-type", stop_gain=None)
    assert p_type.tracking_rms_N < 0.35 * float(p_type.history[0].tracking_rms_N)
    optimal = L.learn(c, rig, ref, iterations=6, seed=2, stop_gain=None)
    whole = [float(h.tracking_rms_N) for h in optimal.history]
    assert optimal.trials_to_within_1p1 <= 3 and bool(optimal.monotone.all()), (whole, optimal.noise_floor_N)
    assert optimal.tracking_rms_N < 0.5 * p_type.tracking_rms_N, (optimal.tracking_rms_N, p_type.tracking_rms_N)
    assert optimal.law.robust.contraction < 1.0 and optimal.law.robust.members == 9


# ---- the CLI ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_learn_rig_playback_and_one_update_per_rig_run(tmp_path, capsys):
    """'learn --out' writes a signal the rig plays back as learned (its error as in the simulation); a run's log
    gives the next iteration; another reference is refused (exit 2)."""
    import json

    from rigkit import write_gain_set

    from piezopreload.cli import main
    from piezopreload.study import load_study

    study = load_study("paper2021")
    gains = write_gain_set(tmp_path / "gains.json", study, study.identify_feedforward().model)
    assert main(["learn", "--study", "paper2021", "--gains", str(gains), "--iterations", "2",
                 "--out", str(tmp_path / "L"), "--json"]) == 0
    learned = json.loads(capsys.readouterr().out)
    assert learned["iterations"] <= 2 and learned["preview_floor_N"] < learned["causal_floor_N"]
    assert learned["trials"] == len(learned["history"]) - 1 and learned["method"] == "norm-optimal"
    assert main(["rig", "run", str(gains), "--learned", learned["out"], "--fast", "--log-dir", str(tmp_path / "runs"),
                 "--json"]) == 0
    run = json.loads(capsys.readouterr().out)
    best = learned["history"][learned["best_iteration"][0]]
    assert run["status"] == "completed" and run["learned"]["iteration"] == learned["best_iteration"][0]
    assert run["learned"]["plan_rms_measured_N"] == pytest.approx(best["measured_rms_N"], rel=0.1), \
        "the rig's playback does not track the plan as the simulation of the same signal did"
    assert main(["learn", "--gains", str(gains), "--from-run", run["log_csv"], "--learned", learned["out"],
                 "--out", str(tmp_path / "L2"), "--json"]) == 0
    update = json.loads(capsys.readouterr().out)
    assert update["iteration"] == learned["best_iteration"][0] + 1
    assert main(["rig", "run", str(gains), "--learned", learned["out"], "--reference", "step", "--fast",
                 "--log-dir", str(tmp_path / "runs")]) == 2
    assert "learned on reference" in capsys.readouterr().err


@pytest.mark.slow
def test_learn_cli_takes_the_after_change_weight_and_the_designs_schedule(tmp_path, capsys):
    import json
    from pathlib import Path

    from piezopreload.cli import main

    args = ["learn", "--study", "paper2021", "--iterations", "0", "--json"]
    assert main([*args, "--after-change-weight", "0"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main([*args, "--after-change-weight", "30"]) == 0
    weighted = json.loads(capsys.readouterr().out)
    assert weighted["after_change_weight"] == 30.0 and plain["after_change_weight"] == 0.0
    assert weighted["plan_rms_after_change_N"] < plain["plan_rms_after_change_N"], "the weight did not move the plan"
    assert main([*args, "--after-change-weight", "-1"]) == 2
    assert "error:" in capsys.readouterr().err
    # the paper's study's plant is its rig, not a design: 'schedule' is refused with what it needs
    assert main([*args, "--reference", "schedule"]) == 2
    assert "[plant] from_design = true" in capsys.readouterr().err
    small = Path(__file__).parent / "data" / "small_axis.toml"
    assert main(["learn", "--study", str(small), "--reference", "schedule", "--iterations", "1", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["reference"] == "schedule" and s["trials"] <= 1 and s["tracking_rms_N"] < s["history"][0]["tracking_rms_N"]
