"""The design NLP, its fronts and the preload schedule, checked against scipy and the numpy model."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

import piezopreload.design.schedule as schedule_module
from piezopreload.artifacts.schedule import LoadProfile, ScheduleSpec
from piezopreload.cli import main
from piezopreload.design.preload import (
    OBJECTIVES,
    PARETO_PAIRS,
    WEIGHTS,
    DesignInfeasible,
    DesignNLP,
    DesignSpec,
    _integer_candidates,
    optimise,
    pareto_front,
)
from piezopreload.design.schedule import example_profile, schedule_preload
from piezopreload.models.ballscrew import LIFT_OFF_RATIO, BallScrew


@pytest.fixture(scope="module")
def spec():
    return DesignSpec()


@pytest.fixture(scope="module")
def nlp(spec):
    return DesignNLP(spec)


@pytest.mark.parametrize("objective", ["stiffness", "drag", "life"])
def test_optimum_meets_every_constraint_in_the_numpy_model(spec, nlp, objective):
    result = optimise(spec, objective, nlp)
    p = result.point
    assert p.integer and p.turns == int(p.turns) and p.balls_per_turn == int(p.balls_per_turn)
    screw = spec.screw(p)  # the numpy model, evaluated apart from the NLP's CasADi graph
    assert p.max_preload_N <= spec.preload_fraction_max * p.c_dyn_N * (1 + 1e-6)
    np.testing.assert_allclose(p.c_dyn_N, screw.dynamic_rating_N, rtol=1e-9)
    for case, fp in zip(spec.duty, p.case_preload_N):
        loads = screw.nut_loads(fp, case.axial_load_N)
        assert not loads.lifted_off
        assert spec.lift_off_margin * abs(case.axial_load_N) <= LIFT_OFF_RATIO * fp * (1 + 1e-6)
        assert loads.rigidity_N_per_um >= p.stiffness_N_per_um * (1 - 1e-6)
        f = spec.feed_drive.natural_frequency_Hz(screw, fp, spec.feed_drive.weakest_position_mm())
        assert f >= spec.frequency_min_Hz * (1 - 1e-6)
        assert p.bolt_preload_N * (1 - 1e-6) <= fp <= p.max_preload_N * (1 + 1e-6)
    # the least rigidity over the cases is what the NLP reports
    least = min(float(screw.rigidity_N_per_um(fp, c.axial_load_N)) for c, fp in zip(spec.duty, p.case_preload_N))
    np.testing.assert_allclose(p.stiffness_N_per_um, least, rtol=1e-6)
    assert p.life_h >= spec.life_min_h * (1 - 1e-6)
    assert p.drag_torque_at_max_preload_Nm <= spec.drag_torque_max_Nm * (1 + 1e-6)
    assert p.peak_pressure_MPa <= spec.contact_pressure_max_MPa * (1 + 1e-6)
    assert p.ball_mm * p.balls_per_turn <= math.pi * spec.nominal_diameter_mm / math.cos(spec.helix_rad) * (1 + 1e-9)
    assert spec.lift_off_margin * spec.failsafe_load_N <= LIFT_OFF_RATIO * p.bolt_preload_N * (1 + 1e-6)
    reach = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    assert p.max_preload_N <= reach * (1 + 1e-6), "the stacks must reach the highest preload"


def test_life_of_a_constant_preload_design_matches_the_numpy_life(spec, nlp):
    # with every case at one preload, the NLP's life expression must equal BallScrew.life
    p = optimise(spec, "stiffness", nlp).point
    y = nlp.initial_guess()
    x = nlp.to_physical(y)
    x[:5] = [math.radians(p.contact_angle_deg), p.ball_mm, p.conformity, p.turns, p.balls_per_turn]
    x[8:] = p.max_preload_N
    life_h = nlp.point((x - nlp.offset) / nlp.scale, "life", integer=False).life_h
    expected = spec.screw(p).life(p.max_preload_N, list(spec.duty), load_factor=spec.load_factor).hours
    np.testing.assert_allclose(life_h, expected, rtol=1e-6)


def test_casadi_and_scipy_slsqp_reach_the_same_optimum(spec, nlp):
    # the same continuous problem (integers fixed at the optimum's), the same start
    r = optimise(spec, "stiffness", nlp)
    ints = (int(r.point.turns), int(r.point.balls_per_turn))
    lbx, ubx = nlp.bounds(ints)
    y0 = np.clip(nlp.initial_guess(), lbx, ubx)
    ours = nlp.solve(WEIGHTS["stiffness"], y0, integers=ints)
    f, g = nlp.numpy_functions(WEIGHTS["stiffness"])
    np.testing.assert_allclose(f(ours.y), ours.f, rtol=1e-10, err_msg="numpy and CasADi objectives differ")
    peer = minimize(f, y0, method="SLSQP", bounds=list(zip(lbx, np.where(np.isinf(ubx), None, ubx))),
                    constraints=[{"type": "ineq", "fun": lambda y: -g(y)}], options={"maxiter": 500, "ftol": 1e-10})
    assert ours.success and peer.success, peer.message
    assert np.max(g(peer.x)) < 1e-6
    # neither finds a better point than the other (to the solvers' tolerances)
    assert abs(ours.f - peer.fun) < 1e-6 * abs(ours.f), (ours.f, peer.fun)


def test_infeasible_request_names_the_constraint_and_the_shortfall(spec):
    bad = replace(spec, life_min_h=1e12)
    with pytest.raises(DesignInfeasible) as info:
        optimise(bad, "stiffness")
    names = [v.constraint for v in info.value.violations]
    assert "life" in names, names
    assert "[design] life_min_h" in str(info.value) and "short" in str(info.value)
    # a request that is fine except for an impossible frequency
    with pytest.raises(DesignInfeasible, match=r"natural frequency in duty case \d .*\[design\] frequency_min_Hz"):
        optimise(replace(spec, frequency_min_Hz=2000.0), "drag")


def _only_miss(spec, objective="stiffness"):
    with pytest.raises(DesignInfeasible) as info:
        optimise(spec, objective)
    assert len(info.value.violations) == 1, str(info.value)
    return info.value.violations[0], str(info.value)


def test_a_least_rigidity_above_the_optimum_names_it_with_the_rigidity_reached(spec):
    """[design] stiffness_min_N_per_um above what any design reaches: the message names that key, the value the
    stiffest design meeting every other requirement reaches (the stiffness optimum of the same spec without the
    requirement: an independent solve) and the shortfall, in N/um."""
    best = optimise(spec, "stiffness").point.stiffness_N_per_um
    required = round(1.3 * best, -1)
    miss, text = _only_miss(replace(spec, stiffness_min_N_per_um=required))
    assert miss.constraint == "stiffness_min" and miss.units == "N/um", miss
    assert miss.reached == pytest.approx(best, rel=1e-3) and miss.required == required, miss
    assert miss.short_by == pytest.approx(required - best, rel=1e-2), miss
    assert "[design] stiffness_min_N_per_um" in text and f"reaches {miss.reached:,.0f} N/um" in text, text
    assert f"{required - miss.reached:,.0f} N/um short" in text and "nan" not in text, text


def test_a_life_beyond_reach_names_it_in_hours_with_the_longest_life(spec):
    longest = optimise(spec, "life").point.life_h
    miss, text = _only_miss(replace(spec, life_min_h=100 * longest))
    assert miss.constraint == "life" and miss.units == "h", miss
    assert miss.reached == pytest.approx(longest, rel=1e-3), (miss, longest)
    assert "[design] life_min_h" in text and f"reaches {miss.reached:,.0f} h" in text, text


def test_a_failsafe_load_beyond_the_bolts_names_the_lift_off(spec):
    miss, text = _only_miss(replace(spec, failsafe_load_N=40000.0))
    assert miss.constraint == "lift_off_failsafe" and miss.units == "N", miss
    assert miss.short_by == pytest.approx(40000.0 - miss.reached) and miss.short_by > 0, miss
    assert f"without lift-off at most {miss.reached:,.0f} N against at least 40,000 N" in text, text
    assert "[design] failsafe_load_N" in text, text


# the growth front's y is a shift's growth, which the optimum's record does not carry: the report draws no star on it
@pytest.mark.parametrize("pair", [p for p in PARETO_PAIRS if not p.endswith(":growth")])
def test_a_front_ends_at_the_stiffness_optimum_so_the_optimum_lies_on_it(spec, nlp, pair):
    """The report draws the optimum (objective stiffness) on each front: the front's last point is that optimum's
    rigidity with the other quantity the optimum's own (its tie-break leaves the least drag and preload at that
    rigidity; the life there is the one design's), so the star sits on the front's end, not beyond it."""
    best = optimise(spec, "stiffness", nlp).point
    front = pareto_front(spec, pair, 6, nlp)
    other = {"preload": best.max_preload_N, "drag": best.mean_drag_torque_Nm, "life": best.life_h}[front.y_name]
    assert front.x[-1] == pytest.approx(best.stiffness_N_per_um, rel=1e-5), (front.x[-1], best.stiffness_N_per_um)
    assert front.y[-1] == pytest.approx(other, rel=1e-4), (front.y[-1], other)


def test_pareto_fronts_are_monotone(spec, nlp):
    drag = pareto_front(spec, "stiffness:drag", 12, nlp)
    assert len(drag.points) == 12
    assert np.all(np.diff(drag.x) > 0)
    assert np.all(np.diff(drag.y) >= -1e-6 * drag.y.max()), "more stiffness cannot cost less drag"
    life = pareto_front(spec, "stiffness:life", 8, nlp)
    assert np.all(np.diff(life.y) <= 1e-6 * life.y.max()), "more stiffness cannot give more life"
    # each point's drag is no more than that of the stiffness optimum, which meets every epsilon
    stiff = optimise(spec, "stiffness", nlp).point
    assert drag.y.max() <= stiff.mean_drag_torque_Nm * (1 + 1e-6)


@pytest.fixture(scope="module")
def reference_nlp(spec):
    """Every warm solve left to IPOPT: the reference for the SQP warm starts."""
    return DesignNLP(spec, warm="ipopt")


@pytest.mark.parametrize("objective", OBJECTIVES)
def test_sqp_warm_starts_reach_the_ipopt_optimum(spec, nlp, reference_nlp, objective):
    ours, ref = optimise(spec, objective, nlp).point, optimise(spec, objective, reference_nlp).point
    assert (ours.turns, ours.balls_per_turn) == (ref.turns, ref.balls_per_turn)
    # both stop at a KKT tolerance of 1e-8 on the O(1)-scaled problem; what the objective
    # weighs only through the 1e-3 tie-break (the drag optimum's stiffness and life) is
    # known to about 1e-5
    np.testing.assert_allclose(ours.stiffness_N_per_um, ref.stiffness_N_per_um, rtol=1e-4)
    np.testing.assert_allclose(ours.mean_drag_torque_Nm, ref.mean_drag_torque_Nm, rtol=1e-6)
    np.testing.assert_allclose(ours.life_h, ref.life_h, rtol=1e-4)


@pytest.mark.parametrize("pair", PARETO_PAIRS)
def test_fronts_with_sqp_warm_starts_match_the_ipopt_fronts(spec, nlp, reference_nlp, pair):
    from piezopreload.design.tables import ThermalTable
    from piezopreload.design.thermal import duty_growth_um

    table = ThermalTable(volumes=20, shift_h=1.0)  # the growth front's y: the shift's growth of each point
    growth = (lambda p: duty_growth_um(spec, p, table)) if pair == "stiffness:growth" else None
    ours, ref = pareto_front(spec, pair, 20, nlp, growth=growth), pareto_front(spec, pair, 20, reference_nlp,
                                                                                growth=growth)
    assert len(ours.points) == len(ref.points) == 20
    assert [(p.turns, p.balls_per_turn) for p in ours.points] == [(p.turns, p.balls_per_turn) for p in ref.points]
    # where the epsilon binds, x is the epsilon; where it is slack, x is set by the tie-break alone (weight 1e-3, a
    # gradient of 1e-6 per N/um against the solvers' 1e-8 tolerance): the two solvers stop within 0.1 % of each other
    np.testing.assert_allclose(ours.x, ref.x, rtol=2e-3)
    np.testing.assert_allclose(ours.y, ref.y, rtol=1e-5)


def test_sqp_infeasibility_verdicts_agree_with_ipopt(spec, reference_nlp):
    nlp = DesignNLP(spec)
    calls = []
    solve = nlp.solve

    def recording(*args, **kwargs):
        out = solve(*args, **kwargs)
        calls.append((args, kwargs, out))
        return out

    nlp.solve = recording
    pareto_front(spec, "stiffness:drag", 20, nlp)
    verdicts = [(a, k) for a, k, out in calls if out.status.startswith("Infeasible: least")]
    assert verdicts, "the front should meet integer neighbours that cannot be made feasible"
    for args, kwargs in verdicts:
        check = reference_nlp.solve(*args, **kwargs)
        assert check.status == "Infeasible_Problem_Detected", (kwargs["integers"], check.status)


def test_integer_neighbours_the_bounds_rule_out_are_not_tried(spec, reference_nlp):
    # balls per turn beyond what fits with the smallest ball allowed cannot be feasible
    fit = math.pi * spec.nominal_diameter_mm / (math.cos(spec.helix_rad) * spec.ball_mm[0])
    z = math.floor(fit)
    kept = _integer_candidates(6.0, z + 0.5, spec)
    assert kept == [(6, z)]
    y0 = reference_nlp.initial_guess()
    assert reference_nlp.solve(WEIGHTS["drag"], y0, integers=(6, z)).feasible
    assert reference_nlp.solve(WEIGHTS["drag"], y0, integers=(6, z + 1)).status == "Infeasible_Problem_Detected"
    # and turns beyond the nut length (45 mm holds 4.5 turns of a 10 mm lead)
    short = replace(spec, nut_length_max_mm=45.0)
    assert _integer_candidates(4.5, 20.0, short) == [(4, 20)]
    short_nlp = DesignNLP(short, warm="ipopt")
    y0 = short_nlp.initial_guess()
    assert short_nlp.solve(WEIGHTS["drag"], y0, integers=(4, 20)).feasible
    assert short_nlp.solve(WEIGHTS["drag"], y0, integers=(5, 20)).status == "Infeasible_Problem_Detected"


def test_building_the_design_nlp_prints_nothing(spec, capsys):
    DesignNLP(spec)  # qpOASES prints a licence banner on every solver built
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


def test_schedule_meets_its_constraints_and_beats_the_best_constant(spec):
    p = optimise(spec, "drag").point
    screw = spec.screw(p)
    f_max = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    sspec = ScheduleSpec(p.bolt_preload_N, f_max, slew_N_per_s=20000.0, stiffness_min_N_per_um=300.0,
                         deflection_max_um=5.0)
    profile = example_profile(0.02)
    s = schedule_preload(screw, profile, sspec)
    assert s.status.startswith("Solve_Succeeded")
    tol = 1e-6 * f_max  # the bisection's 2^-60 of the range; IPOPT (below) relaxes bounds by 1e-8 of the variable
    assert np.all(s.rigidity_N_per_um >= s.required_N_per_um - tol)
    assert np.all(np.abs(np.diff(s.preload_N)) <= sspec.slew_N_per_s * np.diff(profile.time_s) * (1 + 1e-6) + tol)
    assert np.all(s.preload_N >= p.bolt_preload_N - tol) and np.all(s.preload_N <= f_max + tol)
    assert np.all(LIFT_OFF_RATIO * s.preload_N >= sspec.lift_off_margin * np.abs(profile.axial_load_N) - tol)
    # the best constant meets the same requirement and no lower constant does
    assert np.all(s.constant_rigidity_N_per_um >= s.required_N_per_um - tol)
    lower = screw.rigidity_N_per_um(s.constant_preload_N * (1 - 1e-4), profile.axial_load_N)
    lifts = sspec.lift_off_margin * np.abs(profile.axial_load_N) > LIFT_OFF_RATIO * s.constant_preload_N * (1 - 1e-4)
    assert np.any(lower < s.required_N_per_um) or np.any(lifts)
    assert s.friction_energy_J < s.constant_friction_energy_J and 0 < s.saving_fraction < 1
    # at standstill (the last second) the friction energy does not see the preload: the
    # schedule still takes the least one there
    rest = (profile.speed_rpm == 0) & (profile.axial_load_N == 0)
    assert rest.sum() >= 40
    np.testing.assert_allclose(s.preload_N[rest], p.bolt_preload_N, rtol=1e-6)
    # the schedule ramps up before the roughing pass (t = 1.5 s), as fast as the slew allows
    k = np.searchsorted(profile.time_s, 1.5)
    assert s.preload_N[k] > p.bolt_preload_N + 100


@pytest.mark.parametrize("margin_N", [0.0, 150.0])
def test_the_envelope_schedule_is_the_nlps_optimum(spec, margin_N):
    # the closed form against CasADi/IPOPT on the problem as stated (stiffness rows on the rigidity
    # function, lift-off and reach as bounds, slew rows, the friction energy): the same schedule
    p = optimise(spec, "drag").point
    screw = spec.screw(p)
    f_max = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    sspec = ScheduleSpec(p.bolt_preload_N, f_max, slew_N_per_s=20000.0, stiffness_min_N_per_um=300.0,
                         deflection_max_um=5.0, preload_margin_N=margin_N)
    profile = example_profile(0.02)
    exact = schedule_preload(screw, profile, sspec)
    nlp = schedule_preload(screw, profile, sspec, method="nlp")
    assert nlp.status == "Solve_Succeeded"
    # IPOPT stops at tol 1e-9 on the scaled problem with its bounds relaxed by 1e-8 of the variable (kN)
    np.testing.assert_allclose(exact.preload_N, nlp.preload_N, atol=1e-4 * f_max,
                               err_msg="the envelope is not the NLP's optimum")
    assert exact.friction_energy_J <= nlp.friction_energy_J * (1 + 1e-7), "the NLP found a cheaper schedule"
    assert exact.constant_preload_N == nlp.constant_preload_N


@pytest.mark.parametrize("model", ["catalogue", "contact"])
def test_the_least_friction_schedule_is_the_least_heat_one_under_either_model(spec, model):
    """The heat grows with the preload at every sample (linearly in the catalogue's model, as F_p^0.484 in the
    rolling-contact one): the NLP that minimises the cycle's heat instead of its friction energy lands on the
    envelope, and no schedule it finds makes less heat."""
    p = optimise(spec, "drag").point
    screw = spec.screw(p)
    f_max = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    sspec = ScheduleSpec(p.bolt_preload_N, f_max, slew_N_per_s=20000.0, stiffness_min_N_per_um=300.0,
                         deflection_max_um=5.0)
    profile = example_profile(0.05)
    heat = {"model": model, "lubricant_vg": 68, "seal_torque_Nm": 0.25, "temperature_C": 40.0}
    exact = schedule_preload(screw, profile, sspec)
    nlp = schedule_preload(screw, profile, sspec, method="nlp", heat=heat)
    assert nlp.status == "Solve_Succeeded"
    np.testing.assert_allclose(exact.preload_N, nlp.preload_N, atol=1e-4 * f_max,
                               err_msg="the least-heat schedule is not the envelope")

    def joules(preload):
        return float(np.dot(screw.friction_heat_W(preload, profile.speed_rpm, **heat), profile.dt_s))

    assert joules(exact.preload_N) <= joules(nlp.preload_N) * (1 + 1e-7), "the NLP found a schedule with less heat"
    assert joules(exact.preload_N) < joules(np.full(profile.time_s.size, exact.constant_preload_N))
    # the NLP's objective is that heat: the CasADi function against the numpy model on another schedule
    other = np.linspace(p.bolt_preload_N, f_max, profile.time_s.size)
    assert float(schedule_module._heat_objective(screw, profile, heat)(other)) == pytest.approx(joules(other), rel=1e-9)
    with pytest.raises(ValueError, match="needs the load profile's speed_rpm"):
        schedule_preload(screw, LoadProfile(profile.time_s, profile.axial_load_N), sspec, heat=heat)


def test_the_heat_objective_is_what_the_schedule_nlp_minimises(spec, monkeypatch):
    """The NLP takes its objective from the heat (no silent fall-back to the friction energy): an objective that
    rewards preload instead takes the plan to the stacks' reach wherever the screw turns."""
    p = optimise(spec, "drag").point
    screw = spec.screw(p)
    f_max = spec.actuator.max_preload_N(screw, p.bolt_preload_N)
    sspec = ScheduleSpec(p.bolt_preload_N, f_max, slew_N_per_s=20000.0, stiffness_min_N_per_um=300.0)
    profile = example_profile(0.1)
    real = schedule_module._heat_objective
    monkeypatch.setattr(schedule_module, "_heat_objective", lambda *a: _negated(real(*a)))
    upside_down = schedule_preload(screw, profile, sspec, method="nlp", heat={"model": "catalogue"})
    turning = np.asarray(profile.speed_rpm) > 0
    assert np.all(upside_down.preload_N[turning] > 0.99 * f_max), "the NLP did not minimise the objective it was given"


def _negated(f):
    import casadi as ca

    x = ca.MX.sym("F", f.size1_in(0))
    return ca.Function("negated", [x], [-f(x)])


def test_a_constant_load_gives_a_constant_schedule(spec):
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    t = np.linspace(0, 1, 51)
    profile = LoadProfile(t, np.full_like(t, 3000.0), np.full_like(t, 500.0))
    s = schedule_preload(screw, profile, ScheduleSpec(300.0, 5000.0, 1e4, stiffness_min_N_per_um=500.0))
    np.testing.assert_allclose(s.preload_N, s.constant_preload_N, rtol=1e-6)
    np.testing.assert_allclose(s.saving_fraction, 0.0, atol=1e-6)


def test_schedule_refuses_a_load_beyond_the_stacks_reach():
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    t = np.linspace(0, 1, 11)
    with pytest.raises(ValueError, match="stacks' reach"):
        schedule_preload(screw, LoadProfile(t, np.full_like(t, 20000.0)), ScheduleSpec(300.0, 2000.0, 1e4))


# ---- CLI -----------------------------------------------------------------------------------


def test_ballscrew_cli_json(capsys):
    code = main(["ballscrew", "--nominal-diameter-mm", "40", "--lead-mm", "10", "--ball-mm", "6.35", "--turns", "4",
                 "--c-dyn-N", "37890", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert abs(out["rigidity_N_per_um"] / 1010.0 - 1) < 0.2
    assert out["preload_N"] == pytest.approx(3789.0)
    assert out["lift_off_load_N"] == pytest.approx(2 ** 1.5 * 3789.0)


@pytest.mark.parametrize("argv, fragment", [
    (["--preload-N", "3000", "--preload-fraction", "0.1"], "not both"),
    (["--conformity", "0.49"], "conformity"),
    (["--preload-N", "-5"], "--preload-N"),
])
def test_ballscrew_cli_bad_input(capsys, argv, fragment):
    code = main(["ballscrew", "--nominal-diameter-mm", "32", "--lead-mm", "10", "--ball-mm", "6.35", "--turns", "4"]
                + argv)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error:") and fragment in err and err.count("\n") == 1


def test_design_cli_writes_the_artifact_and_fronts(tmp_path, capsys):
    out = tmp_path / "design.json"
    code = main(["design", "--study", "paper2021", "--pareto", "stiffness:drag", "--points", "6", "--out", str(out),
                 "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["schema"] == "piezopreload/design/1"
    assert len(doc["fronts"]) == 1 and len(doc["fronts"][0]["points"]) == 6
    csv = tmp_path / "design.pareto-stiffness-drag.csv"
    assert csv.exists() and len(csv.read_text().splitlines()) == 2 + 6
    assert result["schedule"]["saving_fraction"] > 0
    assert result["written"] == [str(out), str(csv)]


def test_design_cli_infeasible_study_exits_2_naming_the_constraint(tmp_path, capsys):
    from piezopreload.study import paper_study

    text = paper_study().read_text().replace("life_min_h = 20000.0", "life_min_h = 1.0e12")
    study = tmp_path / "study.toml"
    study.write_text(text)
    code = main(["design", "--study", str(study), "--pareto", "stiffness:drag", "--points", "3",
                 "--out", str(tmp_path / "d.json")])
    err = capsys.readouterr().err
    assert code == 2 and "[design] life_min_h" in err and " h short" in err, err
    assert not (tmp_path / "d.json").exists()


def test_design_study_errors_name_the_line(tmp_path, capsys):
    from piezopreload.study import paper_study

    text = paper_study().read_text().replace("turns = [2, 6]", "turns = [2.5, 6]")
    study = tmp_path / "study.toml"
    study.write_text(text)
    code = main(["design", "--study", str(study)])
    err = capsys.readouterr().err
    line = next(i for i, l in enumerate(text.splitlines(), 1) if l.startswith("turns = [2.5"))
    assert code == 2 and f"study.toml:{line}: 'ballscrew.turns'" in err


def test_load_profile_csv_errors_name_the_line(tmp_path, capsys):
    csv = tmp_path / "loads.csv"
    csv.write_text("time_s,axial_load_N,speed_rpm\n0,100,300\n0.1,nan,300\n")
    code = main(["design", "--study", "paper2021", "--schedule", str(csv), "--pareto", "stiffness:drag",
                 "--points", "2", "--out", str(tmp_path / "d.json")])
    err = capsys.readouterr().err
    assert code == 2 and "loads.csv:3" in err and "axial_load_N" in err


def test_results_draw_themselves(spec, nlp):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result = optimise(spec, "drag", nlp)
    (ax,) = result.plot().axes
    assert len(ax.lines) == 1 + len(spec.duty) + 2 and ax.get_xlabel() == "preload F_p (N)"
    front = pareto_front(spec, "stiffness:life", 4, nlp)
    (ax,) = front.plot().axes
    np.testing.assert_allclose(ax.lines[0].get_ydata(), front.y)
    screw = spec.screw(result.point)
    s = schedule_preload(screw, example_profile(0.05),
                         ScheduleSpec(result.point.bolt_preload_N, 4000.0, 2e4, stiffness_min_N_per_um=300.0))
    axes = s.plot().axes
    np.testing.assert_allclose(axes[1].lines[0].get_ydata(), s.preload_N)
    assert plt.get_fignums() == []  # drawn without pyplot: no figure left in its state
