"""The preload schedule's headroom as a decision of the co-design's outer search (piezopreload/codesign.py,
design/schedule.py ``headroom_schedule``): it is one of the search's variables, the sequential start has it at 1 (the
least-friction schedule itself), and a candidate with headroom ``h > 1`` runs a schedule whose levels above the
bolts' preload are ``h`` times the least-friction schedule's, as :func:`plan_schedule` plans it. The inner tuning is
replaced by a stand-in here (it does not see the schedule: it is judged over the study's references), so the
test is fast."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import piezopreload.codesign as cd
from piezopreload.codesign import HEADROOM_MAX, VARIABLES, Candidate, CodesignWeights, planned_schedule, with_headroom
from piezopreload.core.errors import InfeasibleError
from piezopreload.design.preload import optimise
from piezopreload.design.schedule import headroom_schedule
from piezopreload.design.study import plan_schedule
from piezopreload.design.tables import ScheduleTable
from piezopreload.models.controller import PIDGains
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


def _stand_in(point, tracking_N: float = 20.0) -> Candidate:
    """A design's candidate with fixed controller figures (the inner tuning stood in for)."""
    return Candidate(point, PIDGains(Kc=0.004, Ti_s=0.05), 1000.0, 1.5, float("nan"), tracking_N, 50.0, 0.1, True)


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


def test_the_headroom_is_an_outer_variable_that_starts_at_1(small, point, least, monkeypatch):
    assert "schedule_headroom" in [name for name, _, _ in VARIABLES]
    seq = with_headroom(small, _stand_in(point), 1.0)
    assert seq.variables()["schedule_headroom"] == 1.0
    assert seq.friction_energy_J == pytest.approx(least.friction_energy_J, rel=1e-12)
    inner = []

    def stand_in(study, p, **kw):  # the inner problem without its tuning
        inner.append(p)
        return with_headroom(study, _stand_in(p), kw.get("headroom", 1.0))

    monkeypatch.setattr(cd, "evaluate_design", stand_in)
    search = cd._Search(small, small.design_spec, "heat", CodesignWeights(friction=1.0, tracking=1.0), seq, 1.0, 60,
                        None, lambda _m: None, least_heat=point.stiffness_N_per_um * 0.9)
    z0 = search.start()
    i = [name for name, _, _ in VARIABLES].index("schedule_headroom")
    assert search.ranges[i] == (1.0, HEADROOM_MAX)
    assert z0[i] == 0.0 and search.values(z0)["schedule_headroom"] == 1.0
    # a point with headroom > 1: the same design, its schedule raised by the factor, no new tuning for it
    z = z0.copy()
    z[i] = 0.5
    h = 1.0 + 0.5 * (HEADROOM_MAX - 1.0)
    cand, f = search.score(z, seq.gains)
    assert cand is not None and cand.schedule_headroom == pytest.approx(h)
    assert cand.point is seq.point and not inner  # the sequential design itself, its schedule raised
    assert cand.variables()["schedule_headroom"] == pytest.approx(h)
    assert cand.schedule_top_N == pytest.approx(h * float(np.max(least.preload_N)), rel=1e-12)
    assert cand.friction_energy_J == pytest.approx(planned_schedule(small, point, h).friction_energy_J, rel=1e-12)
    assert f > 1.0  # the same tracking at more friction
    n = search.evaluations
    search.score(np.where(np.arange(z.size) == i, 1.0, z), seq.gains)
    assert search.evaluations == n  # another headroom of the same design: no inner solve
    # the search polls it and, where it only costs friction, keeps the start's 1
    best, best_f = search.run(budget=8, step=0.5, min_step=0.5)
    assert any(c.schedule_headroom > 1.0 for c in search.scored)
    assert best.schedule_headroom == 1.0 and best_f <= 1.0 + 1e-12
