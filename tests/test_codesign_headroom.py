"""The preload schedule's shape in the co-design (piezopreload/codesign.py, design/schedule.py ``headroom_schedule``):
the headroom raises every level the stacks drive by its factor, the lead advances every rise; the loop is judged along
the schedule inside the problem (its tracking RMS the objective's term, the schedule's requirements on the achieved
preload its constraints), and the inner problem takes the least-friction shape that meets them. The inner tuning is
stood in for by fixed gains near the tuned ones, so the tests are fast."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from piezopreload.codesign import (
    HEADROOM_MAX,
    LEADS_S,
    TERMS,
    VARIABLES,
    Candidate,
    CodesignWeights,
    along_schedule,
    planned_schedule,
    shape_schedule,
    with_headroom,
)
from piezopreload.core.errors import InfeasibleError
from piezopreload.design.preload import optimise
from piezopreload.design.schedule import headroom_schedule
from piezopreload.design.study import plan_schedule
from piezopreload.design.system import track_schedule
from piezopreload.design.tables import ScheduleTable
from piezopreload.models.controller import Controller
from piezopreload.study import load_study

SMALL_AXIS = Path(__file__).parent / "data" / "small_axis.toml"


@pytest.fixture(scope="module")
def small():
    return load_study(SMALL_AXIS)


@pytest.fixture(scope="module")
def point(small):
    return optimise(small.design_spec, small.design_table.objective).point


@pytest.fixture(scope="module")
def least(small, point):
    """The least-friction schedule, as plan_schedule plans it for the study."""
    plan, _, _ = plan_schedule(small.design_spec, point, None, **(small.schedule or ScheduleTable()).limits())
    return plan


def test_a_headroom_raises_each_driven_level_by_the_factor(small, point, least):
    h = 1.25
    raised = planned_schedule(small, point, h)
    F, G = np.asarray(least.preload_N), np.asarray(raised.preload_N)
    bolts = least.spec.bolt_preload_N
    driven = bolts * (1 + 1e-9) < F
    assert driven.any() and (~driven).any()  # the cycle has cuts and traverses with the stacks off
    # every level the stacks drive is h times the least-friction one (its ramps within the slew: the envelope is
    # the raised levels themselves on this cycle), the others stay at the bolts' preload
    np.testing.assert_allclose(G[driven], h * F[driven], rtol=1e-12)
    assert G[~driven].min() >= bolts * (1 - 1e-12)
    assert G.max() == pytest.approx(h * F.max(), rel=1e-12)
    assert np.all(np.abs(np.diff(G)) <= least.spec.slew_N_per_s * np.diff(least.profile.time_s) * (1 + 1e-9))
    # the friction energy and the rigidity are the raised levels': more friction bought more rigidity
    screw = small.design_spec.screw(point)
    w = screw.drag_torque_Nm(1.0) * np.asarray(least.profile.speed_rpm) * 2 * np.pi / 60 * least.profile.dt_s
    assert raised.friction_energy_J == pytest.approx(float(np.dot(w, G)), rel=1e-9)
    assert raised.friction_energy_J > least.friction_energy_J
    assert np.min(raised.rigidity_N_per_um - raised.required_N_per_um) > \
        np.min(least.rigidity_N_per_um - least.required_N_per_um)
    # at 1 the schedule is plan_schedule's own
    np.testing.assert_array_equal(planned_schedule(small, point, 1.0).preload_N, F)


def test_a_headroom_past_the_stacks_reach_or_below_1_is_refused(small, point, least):
    screw = small.design_spec.screw(point)
    too_much = 1.01 * least.spec.max_preload_N / float(np.max(least.preload_N))
    with pytest.raises(ValueError, match="stacks' reach"):
        headroom_schedule(screw, least, too_much)
    with pytest.raises(InfeasibleError, match="stacks' reach"):
        planned_schedule(small, point, too_much)
    with pytest.raises(ValueError, match=">= 1"):
        headroom_schedule(screw, least, 0.9)


def test_a_lead_advances_every_rise_and_keeps_every_fall(small, point, least):
    # on uniform samples the lead is a forward running maximum: G[k] = max F[k .. k + m], m samples of the lead
    screw = small.design_spec.screw(point)
    dt = float(least.profile.time_s[1] - least.profile.time_s[0])
    m = 5
    led = headroom_schedule(screw, least, 1.0, m * dt)
    F, G = np.asarray(least.preload_N), np.asarray(led.preload_N)
    want = np.array([F[k:k + m + 1].max() for k in range(F.size)])
    np.testing.assert_allclose(G, want, rtol=1e-12, err_msg="the lead is not the running maximum ahead")
    rises = np.flatnonzero(np.diff(F) > 0) + 1  # a sample whose level rose: the lead reaches it m samples earlier
    assert rises.size and all(G[k - m] >= F[k] for k in rises if k >= m)
    falls = np.flatnonzero(np.diff(F) < 0)  # a sample before a fall: the led schedule falls where the plan does
    assert all(G[k + 1] == pytest.approx(F[k + 1: k + m + 2].max()) for k in falls if k + m + 2 <= F.size)
    assert np.all(G >= F) and G.max() == pytest.approx(F.max())
    assert np.all(np.abs(np.diff(G)) <= least.spec.slew_N_per_s * dt * (1 + 1e-9))
    w = screw.drag_torque_Nm(1.0) * np.asarray(least.profile.speed_rpm) * 2 * np.pi / 60 * least.profile.dt_s
    assert led.friction_energy_J == pytest.approx(float(np.dot(w, G)), rel=1e-9)
    with pytest.raises(ValueError, match="lead"):
        headroom_schedule(screw, least, 1.0, -0.01)
    assert headroom_schedule(screw, least, 1.0, 0.0) is least


def _tuned(small, point) -> Candidate:
    """The design's candidate with gains near the ones the study's tuning finds on it (Kc 0.0108 V/N, Ti 48.6 ms,
    b 0.91; the inner tuning stood in for), its feedforward identified, judged along its least-friction schedule."""
    gains = replace(small.controller, Kc=0.0108, Ti_s=0.0486, Td_s=0.0, b=0.91)
    return with_headroom(small, Candidate(point, gains, 1000.0, 1.5, float("nan"), 20.0, 50.0, 0.1, True), 1.0)


def test_the_tracking_is_judged_along_the_preload_schedule_inside_the_problem(small, point):
    c = _tuned(small, point)
    # the tracking RMS the objective weighs is the loop's along the schedule (its pre-cycle left out), recomputed here
    # from the raw run of the same schedule, the same passes and the same controller
    plan = planned_schedule(small, point)
    run = along_schedule(small, c, plan)
    r = run.run
    cycle = r.t_s >= run.pre_cycle.duration_s - 0.5 * (r.t_s[1] - r.t_s[0])
    rms = float(np.sqrt(np.mean((r.reference_N - r.force_N)[cycle] ** 2)))
    assert c.cycle_tracking_rms_N == pytest.approx(rms, rel=1e-9)
    assert c.cycle_tracking_rms_N != pytest.approx(c.tracking_rms_N)  # not the staircase's
    assert TERMS[2] == ("tracking", "cycle_tracking_rms_N", "N along the schedule")
    # the schedule's requirements on the achieved preload are constraints: the candidate is feasible only where each
    # is met, and its friction is the schedule the loop ended on (the least-friction plan with the margin passes)
    met = all(rq.met for rq in run.evaluation.requirements)
    assert c.feasible == met and c.cycle_passes == len(run.passes)
    assert c.friction_energy_J == pytest.approx(run.schedule.friction_energy_J, rel=1e-12)
    assert c.friction_energy_J >= least_friction(small, point) * (1 - 1e-12)
    # a loop that lags more (a tenth of the gain) misses a requirement along the same schedule: infeasible, and why
    slow = replace(c, gains=replace(c.gains, Kc=0.1 * c.gains.Kc), loop_feasible=None, feasible=True, why="")
    lagging = with_headroom(small, slow, 1.0)
    assert not lagging.feasible and "along the preload schedule" in lagging.why
    assert lagging.cycle_tracking_rms_N > c.cycle_tracking_rms_N


def least_friction(small, point) -> float:
    return planned_schedule(small, point).friction_energy_J


def test_the_schedule_s_shape_is_the_inner_problem_s_least_friction_that_meets_along_the_cycle(small, point):
    assert "schedule_headroom" not in [name for name, _, _ in VARIABLES]  # the outer search is the design's
    base = _tuned(small, point)
    c = shape_schedule(small, base)
    # with these gains the least-friction schedule with the study's two margin passes misses the lift-off bound along
    # the cycle (by under 1 %): a shaped schedule meets it, the coupling of the loop and the schedule
    assert not base.feasible and "lift-off bound" in base.why
    assert c.feasible, c.why
    assert 1.0 <= c.schedule_headroom <= HEADROOM_MAX and c.schedule_lead_s in (0.0, *LEADS_S)
    assert (c.schedule_headroom, c.schedule_lead_s) != (1.0, 0.0)
    # the chosen shape, run again in one pass by the system stage's own function on the same plant: met, and its
    # friction the shaped plan's
    plan = planned_schedule(small, point, c.schedule_headroom, c.schedule_lead_s)
    designed = small.plant_table.plant(small.design_spec, point, small.rig)
    ff = base.feedforward
    run = track_schedule(designed, Controller(base.gains, designed.rig.sample_period_s, ff.inverse()), plan,
                         cycles=small.plant_table.cycles, seed=small.seed, passes=1,
                         contact_N=small.plant_table.stack_contact_N, settle_s=small.validation.settling_max_s)
    assert run.evaluation.met
    assert c.friction_energy_J == pytest.approx(plan.friction_energy_J, rel=1e-12) and c.cycle_passes == 1
    # a loop that misses the study's step or staircase limits is not shaped (no schedule mends those)
    missed = with_headroom(small, replace(base, loop_feasible=None, feasible=False, why="tracking RMS 200 N > 100 N"),
                           1.0)
    assert missed.loop_feasible is False
    kept = shape_schedule(small, missed)
    assert len(kept.shapes) == 1 and (kept.schedule_headroom, kept.schedule_lead_s) == (1.0, 0.0)
    assert not kept.feasible and kept.why.startswith("tracking RMS 200 N")
    # by the study's objective instead of the friction alone (the tracking along the schedule, each over the
    # reference's): the shape among those tried that meets the requirements with the least objective; its shapes are
    # reused, no run again
    assert c.shapes[0].cycle_passes >= 1 and len(c.shapes) >= 2
    tracking = CodesignWeights(growth=0.0, friction=0.0, tracking=1.0)
    best = shape_schedule(small, c, tracking, base)
    met = [s for s in c.shapes if s.feasible]
    assert best.cycle_tracking_rms_N == pytest.approx(min(s.cycle_tracking_rms_N for s in met))
    assert c.friction_energy_J == pytest.approx(min(s.friction_energy_J for s in met))
