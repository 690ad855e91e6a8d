"""The co-design test problems TP1-TP3 of Herber and Allison, solved simultaneously and nested.

Reference: D. R. Herber and J. T. Allison, "Nested and simultaneous solution strategies for general
combined plant and control design problems", J. Mech. Des. 141(1):011402, 2019, doi:10.1115/1.4040705,
sections 5.1 (TP1), 5.2 (TP2) and 5.3 (TP3). The optima below are the paper's, and each is checked
against its closed form where one exists.
"""

import math

import numpy as np
import pytest

from piezopreload.design import codesign_problems as cp

STRATEGIES = ("simultaneous", "nested")


# --- closed forms against the published numbers ---------------------------------------------------
def test_tp1_closed_form_is_the_published_optimum():
    b, gain, psi = cp.tp1_closed_form()
    # section 5.1: Psi* = sqrt(5.1) at b* = 3.0996520994, K* = 1.3284223283
    assert psi == pytest.approx(math.sqrt(5.1), rel=1e-12)
    assert b == pytest.approx(3.0996520994, rel=1e-9)
    assert gain == pytest.approx(1.3284223283, rel=1e-9)
    # the sequential answer (b = 0, then the best gain sqrt(q/r)) is 40 % worse: a 1 % check tells them apart
    assert cp.TP1().cost(0.0, math.sqrt(10.0)) / psi > 1.39


def test_tp2_closed_form_is_the_published_optimum():
    # section 5.2: (tf, x0, v0) = (1, 1, 2): k* = 6.92448098034, Psi* = 23.6228148389, Psi(0) = 52
    k, psi = cp.tp2_optimum(cp.TP2(1.0, 1.0, 2.0))
    assert psi == pytest.approx(23.6228148389, rel=1e-9)
    assert k == pytest.approx(6.92448098034, rel=1e-5)
    assert cp.tp2_closed_form(0.0, cp.TP2(1.0, 1.0, 2.0)) == pytest.approx(52.0)
    # (2, 0, -1): k* = 3.55352112986, Psi* = 0.895634580
    k, psi = cp.tp2_optimum(cp.TP2(2.0, 0.0, -1.0))
    assert psi == pytest.approx(0.895634580, rel=1e-8)
    assert k == pytest.approx(3.55352112986, rel=1e-5)


def test_tp3_published_optimum_scales():
    k, xi = cp.TP3().published_optimum()
    assert k == pytest.approx(0.854322898474148, rel=1e-14)
    assert xi == pytest.approx(1.20313138462729, rel=1e-14)


# --- both strategies, within 1 % of the paper, agreeing with each other ---------------------------
@pytest.mark.parametrize("strategy", STRATEGIES)
def test_tp1_both_strategies_reach_sqrt_5_1(strategy):
    sol = cp.solve_tp1(strategy)
    assert sol.success, f"TP1 {strategy} did not converge"
    assert sol.objective == pytest.approx(math.sqrt(5.1), rel=1e-6), f"TP1 {strategy}: Psi = {sol.objective}"
    assert sol.plant == pytest.approx(3.0996520994, rel=1e-5)
    assert sol.control[0] == pytest.approx(1.3284223283, rel=1e-5)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_tp2_both_strategies_reach_the_published_optimum(strategy):
    sol = cp.solve_tp2(strategy, cp.TP2(1.0, 1.0, 2.0), N=100)
    assert sol.success
    # Hermite-Simpson with 100 intervals: within 1e-7 of the closed form (the paper's 23.6228148389)
    assert sol.objective == pytest.approx(23.6228148389, rel=1e-6)
    assert sol.plant == pytest.approx(6.92448098034, rel=1e-4)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_tp2_local_minimum_trap(strategy):
    problem = cp.TP2(2.0, 0.0, -1.0)
    # a start at 8 ends in the local minimum near k = 12.16 (Psi = 0.9374), 5 % above the optimum ...
    trapped = cp.solve_tp2(strategy, problem, start=8.0)
    assert trapped.plant == pytest.approx(12.16, abs=0.02)
    assert trapped.objective == pytest.approx(0.9374, abs=1e-4)
    # ... and the default start (a scan of the exact inner value) finds the global one
    sol = cp.solve_tp2(strategy, problem)
    assert sol.success
    assert sol.objective == pytest.approx(0.895634580, rel=1e-6)
    assert sol.plant == pytest.approx(3.55352112986, rel=1e-4)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_tp3_both_strategies_reach_the_published_optimum(strategy):
    sol = cp.solve_tp3(strategy, N=100)
    assert sol.success
    # the objective to 1 %, as the paper's; the stiffness more loosely (the objective is flat in k)
    assert sol.objective == pytest.approx(1.20313138462729, rel=1e-2)
    assert abs(sol.objective_ratio - 1.0) < 1e-4
    assert sol.plant == pytest.approx(0.854322898474148, rel=2e-2)
    # the control is bang-bang with one switch from +u_max to -u_max near t_s = 1.4573
    u = np.asarray(sol.control)
    t = np.linspace(0.0, 2.0, u.size)
    assert np.all(u[t < 1.40] > 0.99) and np.all(u[t > 1.52] < -0.99)


@pytest.mark.parametrize("solve", [cp.solve_tp1, cp.solve_tp2, cp.solve_tp3])
def test_simultaneous_and_nested_agree(solve):
    a, b = solve("simultaneous"), solve("nested")
    assert a.objective == pytest.approx(b.objective, rel=1e-6), f"{a.problem}: {a.objective} vs {b.objective}"
    assert a.plant == pytest.approx(b.plant, rel=1e-3)
    assert b.solves > 1 and a.solves == 1


def test_nested_gradient_is_the_inner_sensitivity():
    # the outer gradient of TP2's nested strategy is -lam_p of the inner NLP; against the closed form's slope
    problem = cp.TP2(1.0, 1.0, 2.0)
    _, inner, nw = cp._tp2_functions(problem, 100)
    k, h = 3.0, 1e-5
    sol = inner(x0=np.zeros(nw), p=k, lbg=0.0, ubg=0.0)
    slope = (cp.tp2_closed_form(k + h, problem) - cp.tp2_closed_form(k - h, problem)) / (2 * h)
    assert -float(sol["lam_p"]) == pytest.approx(slope, rel=1e-5)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="strategy"):
        cp.solve_tp1("sequential")
    with pytest.raises(ValueError, match="TP1.w_p"):
        cp.TP1(w_p=2.0)
    with pytest.raises(ValueError, match="TP3.J"):
        cp.TP3(J=0.0)
