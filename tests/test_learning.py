"""Preview and iterative learning control: the floors, the laws' theory on linear plants, the artifact."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.actuator import Rig, RigParams
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.tuning import learning as L
from piezopreload.tuning.pid import tracking_floor

TRAJECTORY = Reference.staircase(25.0, [60.0, 80.0, 100.0, 80.0, 60.0], 1.0, t_start_s=0.5)


def _linear_model(**kw) -> L.LearningModel:
    """A first-order lag read a sample late (y_k = C x_k, x+ = A x + B u): G(z) = 0.2 z^-1 / (1 - 0.8 z^-1)."""
    return L.LearningModel(np.array([[0.8]]), np.array([[1.0]]), np.array([[0.2]]), 1e-3, **kw)


def _simulate_linear(model: L.LearningModel, u: np.ndarray) -> np.ndarray:
    return model.lifted(u.size) @ u


def test_preview_floor_without_preview_is_the_causal_floor_and_falls_with_preview():
    params = RigParams(amp_current_limit_A=0.0142)  # the paper's slow amplifier: ramps of tens of samples
    causal = tracking_floor(params, TRAJECTORY)["rms_N"]
    plan0 = L.preview_plan(params, TRAJECTORY, 0.0)
    assert plan0.rms_N == pytest.approx(causal, rel=1e-12), "with no preview the plan's floor is not tracking_floor's"
    floors = [L.preview_plan(params, TRAJECTORY, p).rms_N for p in (0.0, 0.005, 0.01, 0.2)]
    assert all(a > b for a, b in zip(floors, floors[1:-1])), f"the floor does not fall with the preview: {floors}"
    # a ramp centred on each jump: the continuous bound sum dF^3 / (12 rate), to the sample grid's rounding
    rate = plan0.rate_N_per_s
    jumps = np.abs(np.diff(TRAJECTORY.levels_N))
    scored = TRAJECTORY.duration_s - TRAJECTORY.times_s[1]
    # (the score starts at the first change, so the first ramp's half before it costs nothing)
    centred = np.sqrt((np.sum(jumps**3) - 0.5 * jumps[0] ** 3) / (12 * rate) / scored)
    assert floors[-1] == pytest.approx(centred, rel=0.02), "the long-preview floor is not the centred ramps' error"


def test_preview_on_a_pure_delay_removes_it_exactly():
    # a rig that is a pure delay: amplifier and slew far faster than a sample, no creep, hysteresis negligible
    params = RigParams(amp_bandwidth_Hz=1e6, amp_current_limit_A=1e3, creep_per_decade=0.0, bw_alpha=1e-12,
                       bw_kappa=0.0, noise_N=0.0, adc_bits=32, delay_samples=2)
    rig = Rig(params)
    gain = float(params.effective_stiffness_N_per_um * params.stroke_um_per_V)  # N/V
    ref = Reference.staircase(25.0, [40.0, 55.0, 30.0], 0.05, t_start_s=0.02)
    c = Controller(PIDGains(Kc=0.0, Ti_s=np.inf, u_min=-1e3, u_max=1e3), rig.dt_s)  # the feedforward alone
    n = int(round(ref.duration_s / rig.dt_s)) + 1
    r = ref.at(np.arange(n) * rig.dt_s)
    ff = (r - params.bolt_preload_N) / gain
    lag = params.delay_samples + 1  # the delay line and the D/A's sample
    late = simulate(rig, c, ref, ff_extra_V=ff, engine="numpy")
    early = simulate(rig, c, ref, ff_extra_V=L.advance(ff, lag), engine="numpy")
    assert np.max(np.abs(late.force_N - r)) > 10.0, "without preview the delay should show"
    np.testing.assert_allclose(early.force_N[lag:], r[lag:], atol=1e-6,
                               err_msg="previewed by the delay, the pure delay's output is not the reference")


def test_p_type_ilc_converges_monotonically_as_its_contraction_says():
    model = L.tune_laws(_linear_model(sp_gain=1.0))
    model = replace(model, q_cutoff_Hz=100.0)
    n = 300
    G = model.lifted(n)
    Q = np.array([L.zero_phase_lowpass(col, model.q_cutoff_Hz, model.dt_s) for col in np.eye(n)]).T
    Lm = model.gamma * np.array([L.advance(col, model.delta, fill="zero") for col in np.eye(n)]).T
    M = Q @ (np.eye(n) - Lm @ G)
    rho = np.linalg.norm(M, 2)
    assert rho < 1.0, f"the lifted contraction ||Q(I - LG)|| is {rho}"
    t = np.arange(n) * model.dt_s
    r = np.where(t > 0.05, 1.0, 0.0) + 0.5 * np.sin(2 * np.pi * 8 * t)
    u_inf = np.linalg.solve(np.eye(n) - M, Q @ Lm @ r)
    u = np.zeros(n)
    dist = [np.linalg.norm(u - u_inf)]
    for _ in range(15):
        u = L.p_type_update(model, u, r - _simulate_linear(model, u))
        dist.append(np.linalg.norm(u - u_inf))
    ratios = np.array(dist[1:]) / np.array(dist[:-1])
    assert np.all(ratios <= rho + 1e-9), f"a step shrank the distance by less than the contraction {rho}: {ratios}"
    # without Q the error itself decays monotonically, by at most ||I - G L|| per trial
    model1 = replace(model, q_cutoff_Hz=np.inf)
    Lm1 = model1.gamma * np.array([L.advance(col, model1.delta, fill="zero") for col in np.eye(n)]).T
    bound = np.linalg.norm(np.eye(n) - G @ Lm1, 2)
    u, errs = np.zeros(n), []
    for _ in range(10):
        e = r - _simulate_linear(model1, u)
        errs.append(np.linalg.norm(e))
        u = L.p_type_update(model1, u, e)
    steps = np.array(errs[1:]) / np.array(errs[:-1])
    assert bound <= 1.0 + 1e-9 and np.all(steps <= bound + 1e-9), f"error ratios {steps} beyond ||I - GL|| = {bound}"


def test_the_model_contraction_bound_matches_the_lifted_norm_for_long_trials():
    model = replace(L.tune_laws(_linear_model(sp_gain=1.0)), q_cutoff_Hz=100.0)
    n = 600
    Q = np.array([L.zero_phase_lowpass(col, model.q_cutoff_Hz, model.dt_s) for col in np.eye(n)]).T
    Lm = model.gamma * np.array([L.advance(col, model.delta, fill="zero") for col in np.eye(n)]).T
    lifted = np.linalg.norm(Q @ (np.eye(n) - Lm @ model.lifted(n)), 2)
    assert lifted <= model.contraction() + 1e-6, "the lifted norm exceeds the frequency-domain contraction"
    assert lifted > model.contraction() - 0.02, "the frequency-domain contraction is far above the lifted norm"


def test_norm_optimal_ilc_respects_its_limits_and_reduces_the_error():
    model = _linear_model(u_range_V=(-2.0, 3.0), slew_V_per_sample=0.05, weight=1e-4)
    n = 200
    t = np.arange(n) * model.dt_s
    r = np.where((t > 0.05) & (t < 0.15), 4.0, 0.0)  # needs more than the range and the slew allow
    u = np.zeros(n)
    errs = []
    for _ in range(4):
        e = r - _simulate_linear(model, u)
        errs.append(np.linalg.norm(e))
        u = L.norm_optimal_update(model, u, e, command_V=u)
        assert u.min() >= -2.0 - 1e-6 and u.max() <= 3.0 + 1e-6, f"the command left its range: {u.min()}..{u.max()}"
        assert np.max(np.abs(np.diff(u))) <= 0.05 + 1e-6, f"the command slews {np.max(np.abs(np.diff(u)))} V/sample"
    errs.append(np.linalg.norm(r - _simulate_linear(model, u)))
    assert errs[-1] < 0.6 * errs[0] and all(b <= a + 1e-6 for a, b in zip(errs, errs[1:])), errs
    assert np.max(np.abs(np.diff(u))) > 0.05 - 1e-4, "the slew limit never bound: the test does not test it"


def test_learning_on_the_rig_converges_and_the_guard_keeps_the_best():
    params = RigParams(noise_N=0.05)
    rig = Rig(params)
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)
    ref = Reference.staircase(25.0, [60.0, 80.0], 0.6, t_start_s=0.2)
    # (at the plan's default 0.85 of the slew the error still falls by more than settle_tol at trial 6: 8 trials)
    res = L.learn(c, rig, ref, iterations=8, seed=1, settle_tol=0.2)
    rms = [h.tracking_rms_after_change_N for h in res.history]
    assert rms[-1] < 0.5 * rms[0], f"learning did not reduce the error: {rms}"
    assert bool(res.converged.all()) and not res.diverged.any()
    assert res.tracking_rms_N >= res.preview_floor_N - 1e-9, "a run beat the preview floor"
    # a gain far too high diverges: the guard stops and keeps the best iterate
    wild = replace(L.learning_model(params, c), gamma=40.0)
    bad = L.learn(c, rig, ref, iterations=6, seed=1, model=wild)
    assert bad.diverged.all() and len(bad.history) < 7, "the divergence guard did not stop"
    measured = [float(h.measured_rms_N) for h in bad.history]
    assert int(bad.best[()]) == int(np.argmin(measured)), "the kept iterate is not the best"


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


def test_learn_rig_playback_and_one_update_per_rig_run(tmp_path, capsys):
    """'learn --out' writes a signal the rig plays back as learned (its error as in the simulation); a run's log
    gives the next iteration; another reference is refused (exit 2)."""
    import json
    import sys

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from rigkit import write_gain_set

    from piezopreload.cli import main
    from piezopreload.study import load_study

    study = load_study("paper2021")
    gains = write_gain_set(tmp_path / "gains.json", study, study.identify_feedforward().model)
    assert main(["learn", "--gains", str(gains), "--iterations", "2", "--out", str(tmp_path / "L"), "--json"]) == 0
    learned = json.loads(capsys.readouterr().out)
    assert learned["iterations"] == 2 and learned["preview_floor_N"] < learned["causal_floor_N"]
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


def test_the_rigs_own_branch_is_never_faster_than_the_steepest_slope_and_ends_at_each_level():
    params = RigParams(amp_current_limit_A=0.0142)
    rate = tracking_floor(params, TRAJECTORY)["rate_N_per_s"] * params.sample_period_s
    ramps = L.branch_ramps(params, TRAJECTORY.levels_N)
    assert len(ramps) == TRAJECTORY.levels_N.size - 1
    for level, start, ramp in zip(TRAJECTORY.levels_N[1:], TRAJECTORY.levels_N[:-1], ramps):
        steps = np.abs(np.diff(ramp))  # (the first sample may carry the last one's overshoot of its level: < 2 steps)
        assert np.all(steps <= rate * (1 + 1e-9)), f"a branch step of {steps.max()} N beats the steepest {rate} N"
        assert abs(ramp[0] - start) <= 2 * rate, "the ramp does not start at its level"
        assert ramp[-1] == pytest.approx(level), f"the ramp to {level} N ends at {ramp[-1]} N"
    falling = ramps[3]  # 100 -> 80 N: right after a reversal the branch is flat (1 - alpha of the slope)
    assert np.abs(falling[1] - falling[0]) < 0.8 * rate, "no slow start after the reversal"
    plain = L.preview_plan(params, TRAJECTORY, 0.2).rms_N
    branch = L.preview_plan(params, TRAJECTORY, 0.2, ramps=ramps).rms_N
    assert branch > plain, "the rig's own branch cannot track better than the steepest-slope bound"


def test_a_slower_planned_ramp_follows_the_same_branch_in_proportionally_more_samples():
    params = RigParams(amp_current_limit_A=0.0142)
    full = L.branch_ramps(params, TRAJECTORY.levels_N)
    half = L.branch_ramps(params, TRAJECTORY.levels_N, slew_fraction=0.5)
    for a, b in zip(full, half):
        # quasi-static: the force is a function of the voltage along the branch, so half the voltage step per
        # sample takes twice the samples to the level, up to where the last level was reached (each ramp stops at
        # the first sample past its level: the next starts from a voltage up to one step apart, a few % of a ramp)
        assert abs(b.size - 2 * a.size) <= max(3, 0.1 * 2 * a.size), f"{a.size} samples at full slew but {b.size} at half"
        assert b[-1] == pytest.approx(a[-1]), "the slower ramp does not end where the full-slew one does"
    with pytest.raises(InputError, match="slew_fraction"):
        L.branch_ramps(params, TRAJECTORY.levels_N, slew_fraction=0.0)


def test_weighting_the_after_change_error_starts_the_ramps_later_and_trades_the_two_scores():
    params = RigParams(amp_current_limit_A=0.0142)
    ramps = L.branch_ramps(params, TRAJECTORY.levels_N)
    lead = L.feedforward_lead(params)

    def scores(w: float) -> tuple[L.PreviewPlan, float, float]:
        plan = L.preview_plan(params, TRAJECTORY, 0.2, lead_samples=lead, ramps=ramps, after_change_weight=w)
        t, r = plan.t_s, TRAJECTORY.at(plan.t_s)
        outside = t >= TRAJECTORY.times_s[1]
        for tj in TRAJECTORY.times_s[1:]:
            outside &= ~((t >= tj - 1e-12) & (t < tj + L.AFTER_CHANGE_S - 1e-12))
        return plan, plan.rms_N, float(np.sqrt(np.mean((r - plan.force_N)[outside] ** 2)))

    plan0, whole0, after0 = scores(0.0)
    default = L.preview_plan(params, TRAJECTORY, 0.2, lead_samples=lead, ramps=ramps)
    assert np.array_equal(default.force_N, plan0.force_N), "weight 0 is not the plain plan"
    plan1, whole1, after1 = scores(1e4)
    assert all(s1 >= s0 for s0, s1 in zip(plan0.starts, plan1.starts)), (plan0.starts, plan1.starts)
    # (a ramp may start a sample or two early where its first steps are tiny: just after a reversal)
    assert all(s >= -3 for s in plan1.starts), f"a heavy weight still previews a ramp far ahead: {plan1.starts}"
    assert min(plan0.starts) < -10, f"the plain plan previews nothing here: {plan0.starts}"
    assert after1 < after0 and whole1 > whole0, (f"no trade: whole {whole0:.3f} -> {whole1:.3f} N, "
                                                 f"after the jumps {after0:.3f} -> {after1:.3f} N")
    with pytest.raises(InputError, match="after_change_weight"):
        L.preview_plan(params, TRAJECTORY, 0.2, after_change_weight=-1.0)


# ---- ramped references and the designed plant ----------------------------------------------------
def _pure_delay() -> RigParams:
    """A rig that is a pure delay (amplifier and slew far faster than a sample, no creep, hysteresis negligible)."""
    return RigParams(amp_bandwidth_Hz=1e6, amp_current_limit_A=1e3, creep_per_decade=0.0, bw_alpha=1e-12,
                     bw_kappa=0.0, noise_N=0.0, adc_bits=32, delay_samples=2)


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
    plan = L.ramp_plan(params, ref, lag * dt, lead_samples=lag)
    np.testing.assert_allclose(plan.force_N, r, atol=1e-12, err_msg="with preview over the lead the plan is not the ramp")
    c = Controller(PIDGains(Kc=0.0, Ti_s=np.inf, u_min=-1e3, u_max=1e3), dt)  # the feedforward alone
    ff = (plan.force_N - params.bolt_preload_N) / gain
    late = simulate(rig, c, ref, ff_extra_V=ff, engine="numpy")
    early = simulate(rig, c, ref, ff_extra_V=L.advance(ff, lag), engine="numpy")
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
    assert L.causal_floor(params, ref) == pytest.approx(closed, rel=1e-9), "the ramp's causal floor is not the kinks' lag"
    assert L.preview_plan(params, ref, d * dt).rms_N == pytest.approx(0.0, abs=1e-12), "a preview of the delay leaves a floor"


@pytest.fixture(scope="module")
def designed_loop():
    """The designed plant of the machine axis' kind (the design optimum of the default spec, its hardware as
    studies/machine_axis.toml's [rig]) under a PID of the tuned gains' size, no feedforward."""
    from piezopreload.design.plant import plant_from_design
    from piezopreload.design.preload import DesignNLP, DesignSpec, optimise

    spec = DesignSpec()
    opt = optimise(spec, "stiffness", DesignNLP(spec))
    hardware = RigParams(amp_bandwidth_Hz=100.0, bw_alpha=0.3238, bw_kappa=0.0931, creep_per_decade=0.0385,
                         noise_N=1.0, adc_full_scale_N=10000.0, amp_v_min_V=-20.0, amp_v_max_V=120.0)
    plant = plant_from_design(spec, opt, hardware, design_sha256="0" * 64, sleeve_stiffness_N_per_um=4000.0)
    c = Controller(PIDGains(Kc=0.0108, Ti_s=0.0486, b=0.91, u_min=-20.0, u_max=115.0), plant.rig.sample_period_s)
    return plant, c


def test_the_learning_law_contracts_over_the_designed_plants_range(designed_loop):
    plant, c = designed_loop
    levels = np.linspace(0.0, 115.0, 5)
    model = L.learning_model_over(plant.rig, c, levels)
    loops = [L.learning_model(plant.rig, c, v0_V=v) for v in levels]
    gains = [float(np.max(lp.g)) for lp in loops]
    assert max(gains) > 1.3 * min(gains), f"the plant's force per volt should change with the level: peak responses {gains}"
    worst = max(model.contraction(loop=lp) for lp in loops)
    assert model.range_contraction == pytest.approx(worst) and worst < 1.0, \
        f"the law does not contract at every level: {[model.contraction(loop=lp) for lp in loops]}"
    # on each linearised loop the lifted error map of the law (Q is the identity: its cut-off is Nyquist) keeps the
    # error from growing, and it shrinks trial by trial on a ramped repeated reference as far as the theory allows
    assert model.q_cutoff_Hz >= 0.5 / model.dt_s - 1e-9
    n = 400
    t = np.arange(n) * model.dt_s
    r = np.interp(t, [0.0, 0.05, 0.15, 0.25, 0.35], [0.0, 0.0, 800.0, 800.0, 100.0])
    Lm = model.gamma * np.array([model.setpoint_path(L.advance(col, model.delta, fill="zero")) for col in np.eye(n)]).T
    for v, lp in zip(levels, loops):
        G = lp.lifted(n)
        errs = [np.linalg.norm(r)]
        u = np.zeros(n)
        for _ in range(8):
            u = L.p_type_update(model, u, r - G @ u)
            errs.append(np.linalg.norm(r - G @ u))
        ratios = np.array(errs[1:]) / np.array(errs[:-1])
        bound = np.linalg.norm(np.eye(n) - G @ Lm, 2)
        assert np.all(ratios <= bound + 1e-9), f"at {v} V the error ratios {ratios} exceed ||I - G L|| = {bound}"
        assert errs[-1] < 0.2 * errs[0], f"at {v} V eight trials left {errs[-1] / errs[0]:.2f} of the error"


def test_learning_on_a_ramped_repeated_reference_on_the_designed_plant_reduces_the_error(designed_loop):
    plant, c = designed_loop
    rig = Rig(plant.rig)
    ref = Reference.ramps([0.0, 0.1, 0.3, 0.5, 0.6, 0.8], [50.0, 50.0, 1500.0, 1500.0, 600.0, 50.0], 1.0).repeat(2)
    res = L.learn(c, rig, ref, iterations=6, seed=2)
    assert res.model.range_contraction is not None and res.model.range_contraction < 1.0
    measured = [float(h.measured_rms_N) for h in res.history]
    assert res.tracking_rms_N < 0.35 * float(res.history[0].tracking_rms_N), f"learning did not reduce the error: {measured}"
    assert bool(res.converged.all()) and not res.diverged.any(), f"the learning stopped: {measured}"
    # the measured error falls trial by trial down to what the sensor's noise (1 N per sample) and the hysteresis leave,
    # and stays there: no later trial more than the divergence guard's 5 % above the best
    near = next(k for k, m in enumerate(measured) if m <= 2.0 * min(measured))  # the first trial near the floor
    assert all(b < a for a, b in zip(measured[:near], measured[1:near + 1])), f"the error grew while falling: {measured}"
    assert max(measured[near + 1:]) <= 1.05 * min(measured), f"the error grew past the best: {measured}"
    assert res.preview_floor_N <= res.causal_floor_N, "preview raised the floor"


def test_a_schedules_passes_are_saved_and_each_signal_is_found_by_its_reference(tmp_path):
    from piezopreload.core.artifacts import read_artifact

    rig = Rig(RigParams(noise_N=0.05))
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)
    refs = [Reference.ramps([0.0, 0.1, 0.3, 0.5], [25.0, 25.0, 60.0 + m, 60.0 + m], 0.6).repeat(2) for m in (0.0, 5.0)]
    passes = [L.learn(c, rig, ref, iterations=2, seed=1) for ref in refs]
    paths = L.save_passes(passes, tmp_path / "learn", "a" * 64, {"study": "test"})
    record = read_artifact(paths["learning"], "learning")
    assert record["passes"] == 2 and paths["learned"] == paths["pass2"]
    assert record["tracking_rms_N"] == pytest.approx(passes[-1].tracking_rms_N)
    assert record["before_learning_rms_N"] == pytest.approx(float(passes[-1].history[0].tracking_rms_N))
    signal_for = L.learned_by_reference([paths["pass1"], paths["pass2"]], "a" * 64)
    for ref, result in zip(refs, passes):
        np.testing.assert_array_equal(signal_for(ref), result.ff_extra_V, err_msg="not the signal learned on this reference")
    with pytest.raises(InputError, match="no learned signal was learned on reference"):
        signal_for(TRAJECTORY)
    with pytest.raises(InputError, match="a{64}"):
        L.learned_by_reference([paths["pass1"]], "b" * 64)
