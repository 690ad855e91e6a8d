"""The verdicts under the modelling assumptions (design/sensitivity.py): the flip by bisection against closed forms,
a verdict robust over a narrow range and flipped by a wide one, the study's rows reusing the system stage's own
requirements, the record's round trip, the report's tornado."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from piezopreload.artifacts.sensitivity import SensitivityRecord
from piezopreload.artifacts.system import SystemRecord
from piezopreload.core.errors import ArtifactError
from piezopreload.design.plant import plant_from_design
from piezopreload.design.preload import DesignSpec
from piezopreload.design.sensitivity import ASSUMPTIONS, FLIP_TOLERANCE, flip_value, sensitivity
from piezopreload.design.study import design_study
from piezopreload.design.system import track_schedule
from piezopreload.design.tables import ThermalTable
from piezopreload.design.thermal import thermal_budget
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller, PIDGains

_BY_KEY = {a.key: a for a in ASSUMPTIONS}


def test_flip_value_finds_a_linear_margins_root_by_bisection():
    # margin 3 x - 1: met from x = 1/3 up; the bisection's last bracket's middle lies within the tolerance of it
    x = flip_value(lambda v: 3.0 * v - 1.0, 0.0, 1.0, tolerance=1e-3)
    assert x is not None and abs(x - 1.0 / 3.0) <= 1e-3, x
    # from the other side, a falling margin: 2 - 5 x is met below 0.4
    x = flip_value(lambda v: 2.0 - 5.0 * v, 1.0, 0.0, tolerance=1e-4)
    assert x is not None and abs(x - 0.4) <= 1e-4, x
    assert flip_value(lambda v: v + 1.0, 0.0, 1.0, tolerance=1e-3) is None, "no flip where both ends are met"


@pytest.fixture(scope="module")
def axis():
    spec = DesignSpec()
    result = design_study(spec, "stiffness", [], 3, stiffness_min_N_per_um=300.0, deflection_max_um=5.0)
    hardware = Plant(amp_bandwidth_Hz=100.0, bw_alpha=0.3238, bw_kappa=0.0931, creep_per_decade=0.0385,
                     noise_N=1.0, adc_full_scale_N=10000.0)
    plant = plant_from_design(spec, result.optimum, hardware, design_sha256="a" * 64, sleeve_stiffness_N_per_um=4000.0)
    loop = Controller(PIDGains(0.0108, 0.0486, u_min_V=-20.0, u_max_V=115.0), 1e-3)
    run = track_schedule(plant, loop, result.schedule, cycles=1, passes=2, settle_s=0.3)
    table = ThermalTable(mounting="pretensioned", pretension_K=3.0, thermal_growth_max_um=60.0,
                         positioning_error_max_um=80.0)
    budget = thermal_budget(run, spec.feed_drive, table, command_range_V=(-20.0, 115.0))
    from dataclasses import replace

    return spec, replace(run, thermal=budget), table


@pytest.fixture(scope="module")
def every_assumption(axis):
    """The sensitivity over every assumption at its default range, on the fixture's run: computed once, read by the
    tests of the study's rows, its record and its report (a frozen record: no test can change it for another)."""
    spec, run, table = axis
    return sensitivity(run, spec.feed_drive, table)


def test_the_in_machine_factors_flip_is_the_requirement_over_the_table_rigidity(axis):
    spec, run, table = axis
    factor = _BY_KEY["ballscrew.rigidity_in_machine_factor"]
    study = sensitivity(run, spec.feed_drive, table, assumptions=[factor])
    row = next(r for r in study.rows if r.requirement == "schedule.rigidity_while_cutting")
    # by hand: the nut's table rigidity at the achieved preload under each cutting sample's load, against the
    # requirement there; the margin is linear in the factor, so the verdict flips at required / table rigidity at
    # the sample where their ratio is least
    f = run.evaluation.frame
    cut = f.cutting
    table_k = run.plant.screw.nut_loads(np.maximum(f.achieved[cut], 1e-3), f.load[cut]).rigidity_N_per_um
    ratio = np.min(np.asarray(table_k) / f.required[cut])
    expected = 1.0 / ratio
    assert row.flips_at is not None
    assert abs(row.flips_at - expected) <= FLIP_TOLERANCE * (row.high - row.low), (row.flips_at, expected)
    # the ends' margins are the same line: 100 (factor * ratio - 1) %
    np.testing.assert_allclose([row.margin_pct_low, row.margin_pct_high],
                               [100.0 * (0.8 * ratio - 1.0), 100.0 * (1.0 * ratio - 1.0)], rtol=1e-9,
                               err_msg="the margins at the range's ends are not the factor's line")
    assert row.nominal == spec.rigidity_in_machine_factor and row.domain == factor.domain


def test_a_narrow_range_keeps_the_verdict_and_a_wide_one_flips_it(axis):
    spec, run, table = axis
    factor = _BY_KEY["ballscrew.rigidity_in_machine_factor"]
    narrow = sensitivity(run, spec.feed_drive, table, assumptions=[factor.with_range(0.78, 0.82)])
    assert run.evaluation.requirements[0].met, "the fixture's run must meet its rigidity requirement"
    assert narrow.verdict_robust, narrow.sentence()
    assert narrow.sentence().startswith("verdict robust over 1 assumptions' ranges")
    wide = sensitivity(run, spec.feed_drive, table, assumptions=[factor.with_range(0.3, 1.0)])
    assert not wide.verdict_robust
    flipped = wide.flipping()
    assert {r.requirement for r in flipped} >= {"schedule.rigidity_while_cutting"}
    assert all(0.3 < r.flips_at < 1.0 for r in flipped), [r.flips_at for r in flipped]
    said = wide.sentence()
    assert said.startswith("verdict not robust") and "the in-machine rigidity factor 0.3 (missed" in said, said
    # a verdict missed at the study's value and missed over the whole range is robust too (the verdict holds)
    shifted = sensitivity(run, spec.feed_drive, table, assumptions=[factor.with_range(0.1, 0.2)])
    rows = [r for r in shifted.rows if r.requirement == "schedule.rigidity_while_cutting"]
    assert rows and all(r.margin_pct_low < 0 and r.margin_pct_high < 0 for r in rows)


def test_the_study_reuses_the_systems_own_requirements_and_names_every_assumption(axis, every_assumption):
    spec, run, table = axis
    study = every_assumption
    by_key = {r.key: r for r in run.requirements}
    for row in study.rows:  # at the study's values each row's margin is the run's own
        assert row.margin_pct_nominal == pytest.approx(by_key[row.requirement].margin_pct, rel=1e-9, abs=1e-9), row.key
    assert set(study.assumptions) == {a.key for a in ASSUMPTIONS}, "an assumption that applies gave no row"
    assert len(study.assumptions) >= 6
    # the lift-off bound is the design's own construction: no assumption moves it, and the record says so
    from piezopreload.design.system import LIFT_OFF_BOUND_VERDICT, OWN_CONSTRAINT

    assert study.unmoved == (LIFT_OFF_BOUND_VERDICT + OWN_CONSTRAINT,), study.unmoved
    # the pretension's growth row is the thermal budget's at those pretensions
    row = next(r for r in study.rows if r.key == "thermal.pretension_K" and r.requirement.endswith("growth_max_um"))
    from dataclasses import replace

    low = thermal_budget(run, spec.feed_drive, replace(table, pretension_K=row.low), command_range_V=(-20.0, 115.0))
    growth = next(r for r in low.requirements if "growth" in r.name)
    assert row.margin_pct_low == pytest.approx(growth.margin_pct, rel=1e-9)
    for r in study.rows:
        if r.flips_at is not None and not r.labels:
            assert r.domain[0] <= r.flips_at <= r.domain[1]


def test_the_sensitivity_round_trips_in_the_system_record_and_a_wrong_verdict_is_refused(axis, every_assumption,
                                                                                         tmp_path):
    spec, run, table = axis
    from dataclasses import replace

    study = every_assumption
    run = replace(run, sensitivity=study)
    paths = run.save(tmp_path / "system", {"gain_set_sha256": "c" * 64})
    record = SystemRecord.load(paths["system"])
    assert record.sensitivity == study
    doc = json.loads(paths["system"].read_text())["sensitivity"]
    assert doc["verdict_robust"] is study.verdict_robust
    for key in ("assumption", "low", "high", "margin_pct_low", "margin_pct_high", "flips_at", "key", "unit",
                "source", "requirement"):
        assert key in doc["rows"][0], key
    doc["verdict_robust"] = not study.verdict_robust
    with pytest.raises(ArtifactError, match=re.escape("verdict_robust")):
        SensitivityRecord.from_dict(doc)


def test_the_tornado_draws_each_rows_swing_around_the_nominal_margin(axis, every_assumption):
    from figkit import legends_over_ink

    from piezopreload.reports.sensitivity import sensitivity_section, tornado

    spec, run, table = axis
    study = every_assumption
    fig = tornado(study)
    groups = {r.requirement_name for r in study.rows}
    assert [ax.get_title() for ax in fig.axes] == list(dict.fromkeys(r.requirement_name for r in study.rows))
    for ax in fig.axes:
        rows = [r for r in study.rows if r.requirement_name == ax.get_title()]
        ends = sorted((round(p.get_x() + p.get_width(), 6)) for p in ax.patches)
        assert ends == sorted(round(m, 6) for r in rows for m in (r.margin_pct_low, r.margin_pct_high)), ax.get_title()
        assert any(line.get_xdata()[0] == 0.0 for line in ax.get_lines()), "no zero line"
        # sorted by swing: the largest on top
        labels = [t.get_text() for t in ax.get_yticklabels()]
        swings = [next(r.swing_pct for r in rows if t.startswith(r.assumption + " (")) for t in labels]
        assert swings == sorted(swings), labels
    assert len(groups) == len(fig.axes)
    assert legends_over_ink(fig) == []
    part = sensitivity_section(study)
    text = " ".join(part.section.paragraphs)
    for r in study.flipping():
        assert r.assumption in text
    assert ("not robust" in part.section.title) == (not study.verdict_robust)


def test_a_robust_design_holds_at_the_worst_case_and_its_cost_is_the_nominal_designs_figure_less_its_own():
    import math
    from dataclasses import replace

    from piezopreload.design.preload import misses, objective_figure, optimise, robust_cost
    from piezopreload.design.sensitivity import worst_case
    from piezopreload.models.ballscrew import BallScrew

    spec = DesignSpec()
    worst = worst_case()
    assert (worst.contact_angle_deg, worst.conformity, worst.drag_coefficient) == ((-5.0, 5.0), (-0.01, 0.01), 0.3)
    robust_spec = replace(spec, worst=worst)
    nominal, robust = optimise(spec, "stiffness"), optimise(robust_spec, "stiffness")
    cost = robust_cost(robust_spec, nominal, robust)
    # the robust design keeps every constraint at the worst case; the nominal one misses its drag torque there, by
    # K_p F_hi l / (2000 pi) - the limit with K_p at 0.3 (the formula's is 0.16 for 32 x 10)
    assert misses(robust_spec, robust.point) == ()
    drag = 0.3 * nominal.point.max_preload_N * spec.lead_mm / (2000.0 * math.pi) - spec.drag_torque_max_Nm
    assert dict(cost.nominal_misses) == pytest.approx({"drag_torque": drag}, rel=1e-9)
    # the worst case's rigidity, by the numpy model of the as-built nut at each corner of the tolerance box
    p = robust.point
    corners = [BallScrew(nominal_diameter_mm=spec.nominal_diameter_mm, lead_mm=spec.lead_mm, ball_mm=p.ball_mm,
                         turns=p.turns, contact_angle_deg=p.contact_angle_deg + da, conformity_screw=p.conformity + df,
                         conformity_nut=p.conformity + df, balls_per_turn=int(p.balls_per_turn),
                         load_sharing=spec.load_sharing, accuracy_factor=spec.accuracy_factor)
               for da in (-5.0, 5.0) for df in (-0.01, 0.01)]
    by_hand = min(float(s.rigidity_N_per_um(f, c.axial_load_N)) for s in corners
                  for f, c in zip(p.case_preload_N, spec.duty))
    assert cost.robust_at_worst == pytest.approx(by_hand, rel=1e-6)
    assert cost.robust_at_worst == pytest.approx(objective_figure(robust_spec, p, "stiffness"))
    assert cost.robust_at_worst < cost.robust_at_nominal, "the worst case must cost rigidity"
    # the robust design's feasible set lies inside the nominal one's: it cannot do better at the study's values
    assert cost.nominal_at_nominal == pytest.approx(nominal.point.stiffness_N_per_um, rel=1e-9)
    assert cost.cost == pytest.approx(cost.nominal_at_nominal - cost.robust_at_nominal) and cost.cost >= -1e-6
    assert "gives up" in cost.sentence() and "misses drag_torque" in cost.sentence()


def test_a_verdict_flipped_at_the_high_end_alone_is_not_robust(axis):
    spec, run, table = axis
    seals = _BY_KEY["thermal.seal_torque_Nm"]
    growth = next(r for r in run.requirements if r.key == "thermal.thermal_growth_max_um")
    assert growth.met, "the fixture's growth must be met at the study's seal torque"
    narrow = sensitivity(run, spec.feed_drive, table, assumptions=[seals.with_range(0.0, 0.3)])
    assert narrow.verdict_robust, narrow.sentence()
    wide = sensitivity(run, spec.feed_drive, table, assumptions=[seals.with_range(0.0, 5.0)])
    row = next(r for r in wide.rows if r.requirement == "thermal.thermal_growth_max_um")
    assert row.margin_pct_low >= 0 > row.margin_pct_high, (row.margin_pct_low, row.margin_pct_high)
    assert not row.holds and not wide.verdict_robust
    assert row.flips_at is not None and 0.0 < row.flips_at < 5.0
    # the thermal budget itself (the whole one, both preloads) meets the growth just below the flip and misses it
    # just above (the growth is not linear in the seals' torque: the pretension and the bearing pairs hold the ends)
    from dataclasses import replace

    step = FLIP_TOLERANCE * 5.0
    for torque, met in ((row.flips_at - step, True), (row.flips_at + step, False)):
        budget = thermal_budget(run, spec.feed_drive, replace(table, seal_torque_Nm=torque),
                                command_range_V=(-20.0, 115.0))
        judged = next(r for r in budget.requirements if r.key == "thermal.thermal_growth_max_um")
        assert judged.met is met, (torque, judged.sentence())


@pytest.mark.slow  # the design and its three fronts, robust (tens of seconds)
def test_a_robust_design_keeps_the_json_on_stdout_one_object(tmp_path, capsys):
    from pathlib import Path

    from piezopreload.cli import main

    text = (Path(__file__).parents[1] / "studies" / "machine_axis.toml").read_text()
    study = tmp_path / "robust.toml"
    study.write_text(text.replace("[design]\n", "[design]\nrobust = true\n", 1))
    code = main(["design", "--study", str(study), "--out", str(tmp_path / "design.json"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)  # the solvers' messages (qpOASES on the robust corners' infeasible QPs) stay off stdout
    assert doc["objective"] == "stiffness" and doc["optimum"]["max_preload_N"] < 3200.0, "not the robust design"
