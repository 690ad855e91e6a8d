"""The study's co-design (piezopreload/codesign.py): never worse than its sequential start, a design no controller
makes meet the study refused by its binding pair, the objective's normalisation, the command line, and a study whose
design step is the co-design (``[design] method = "codesign"``) run end to end."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from piezopreload.cli import main
from piezopreload.codesign import Candidate, CodesignWeights, codesign, evaluate_design
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.design.preload import optimise
from piezopreload.models.controller import PIDGains
from piezopreload.study import load_study

SMALL_AXIS = Path(__file__).parent / "data" / "small_axis.toml"


def _candidate(friction: float, tracking: float, voltage: float) -> Candidate:
    # the objective's tracking term is the RMS along the preload schedule; the staircase's (a constraint) differs
    return Candidate(point=None, gains=PIDGains(Kc=0.01, Ti_s=0.05), coupling_stiffness_N_per_um=1000.0,  # type: ignore[arg-type]
                     ms=1.5, friction_energy_J=friction, tracking_rms_N=3.0 * tracking, peak_voltage_V=voltage,
                     settling_s=0.2, feasible=True, cycle_tracking_rms_N=tracking)


def test_the_objective_is_the_weighted_sum_over_the_sequential_values():
    seq = _candidate(200.0, 30.0, 100.0)
    half_tracking = _candidate(200.0, 15.0, 100.0)
    w = CodesignWeights(friction=1.0, tracking=1.0, voltage=0.0)
    assert seq.objective(w, seq) == pytest.approx(1.0)
    # (1 * 200/200 + 1 * 15/30 + 0) / 2 = 0.75
    assert half_tracking.objective(w, seq) == pytest.approx(0.75)
    w3 = CodesignWeights(friction=2.0, tracking=1.0, voltage=1.0)
    # (2 * 1 + 1 * 0.5 + 1 * 1) / 4 = 0.875
    assert half_tracking.objective(w3, seq) == pytest.approx(0.875)


def test_bad_weights_are_refused_by_name():
    with pytest.raises(InputError, match="'tracking'"):
        CodesignWeights(tracking=-1.0)
    with pytest.raises(InputError, match="at least one"):
        CodesignWeights(0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def small():
    return load_study(SMALL_AXIS)


@pytest.fixture(scope="module")
def small_codesign(small):
    # the one robust set asked for: what these tests hold (never worse, the same Monte Carlo, the words, the entries
    # tuned apart below) does not need the small study's 2 schedule entries, which would tune two more PIDs in every
    # inner problem; test_the_default_controller_follows_the_study holds the default
    return codesign(small, budget=3, validate_plants=3, time_factor=None, schedule=False)


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_codesign_is_never_worse_than_its_sequential_start(small, small_codesign):
    r = small_codesign
    assert r.strategy == "nested"
    assert r.objective_codesigned <= r.objective_sequential + 1e-12
    assert r.objective_sequential == pytest.approx(1.0)
    # the sequential answer is the design NLP's optimum for the study's objective, then the tuning on its plant
    seq = optimise(small.design_spec, small.design_table.objective).point
    assert r.sequential.point.contact_angle_deg == pytest.approx(seq.contact_angle_deg)
    assert r.sequential.point.conformity == pytest.approx(seq.conformity)
    # every inner solve but the start is counted, and the answer meets the co-design's constraints
    assert 1 <= r.evaluations <= 4
    assert r.codesigned.feasible
    assert r.codesigned.ms <= small.tuning.ms_max + 1e-3
    assert r.codesigned.tracking_rms_N <= small.validation.tracking_rms_max_N
    # the objective reported is the candidate's, recomputed
    w = r.weights
    assert r.objective_codesigned == pytest.approx(r.codesigned.objective(w, r.sequential))


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_both_answers_are_validated_by_the_same_monte_carlo(small_codesign):
    r = small_codesign
    assert r.validation_sequential is not None and r.validation_codesigned is not None
    assert r.validation_sequential.n_plants == r.validation_codesigned.n_plants == 3
    assert r.validation_sequential.seed == r.validation_codesigned.seed
    rows = {row["requirement"]: row for row in r.requirements()}
    assert rows["Ms over the tuning's variants"]["limit"] == pytest.approx(1.6)
    # the lift-off requirement: the design NLP keeps 2^(3/2) F_bolt above lift_off_margin x failsafe_load_N
    lift = rows["lift-off load at the bolts' preload"]
    assert lift["limit"] == pytest.approx(1.2 * 600.0)
    assert lift["sequential"] == pytest.approx(2 ** 1.5 * r.sequential.point.bolt_preload_N)
    assert lift["sequential"] >= lift["limit"] * (1 - 1e-6)
    d = r.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["strategy"] == "nested" and d["objective_ratio"] <= 1.0
    # which strategy, and why: the study's tuning exposes no sensitivity of its optimum to the plant
    assert "sensitivity" in d["strategy_why"] and "nested" in d["strategy_why"]
    assert d["schedule_inside"] is False and d["controller"].startswith("one robust PID set")
    # the small study's tune stage makes a 2-entry gain schedule: the words say the robust set was asked for and is
    # not what the study runs
    assert d["controller_follows_study"] is False
    assert "asked for: the study's tune stage makes a 2-entry gain schedule, not tuned here" in d["controller"], \
        d["controller"]


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_a_design_no_controller_makes_meet_the_study_is_refused_naming_the_binding_pair(small):
    # at Ms <= 1.6 the best PI the tuning finds tracks the staircase to about 28 N RMS on this plant: a limit of 5 N
    # is out of reach, and the refusal names the pair: the Ms limit (binding) and the tracking limit
    tight = small.replace(validation={"tracking_rms_max_N": 5.0})
    with pytest.raises(InfeasibleError) as err:  # the robust set: the refusal's words do not need the entries
        codesign(tight, budget=0, validate_plants=0, schedule=False)
    message = str(err.value)
    assert "Ms <= 1.6" in message and "binding" in message
    assert "tracking RMS" in message and "> 5 N" in message and "tracking_rms_max_N" in message
    assert "contact angle" in message


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_evaluate_design_starts_from_given_gains_and_keeps_them_where_they_are_best(small, small_codesign):
    seq = small_codesign.sequential
    again = evaluate_design(small, seq.point, start=seq.gains, ff_lead=False)  # as the sequential: no lead
    assert again.tracking_rms_N <= seq.tracking_rms_N * 1.05
    assert math.isfinite(again.friction_energy_J) and again.friction_energy_J == pytest.approx(seq.friction_energy_J)


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_codesign_command_prints_one_json_object(tmp_path, capsys):
    # the robust set asked for (the point is the one JSON object, not the entries)
    code = main(["codesign", str(SMALL_AXIS), "--budget", "0", "--plants", "2", "--robust-set", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    doc = json.loads(out)
    # no inner solve after the start: the co-design keeps the sequential design; the inner problem may still shape its
    # preload schedule for its loop (headroom and lead), never worse than the sequential schedule
    assert doc["strategy"] == "nested" and doc["objective_ratio"] <= 1.0 + 1e-12 and doc["evaluations"] == 1
    assert doc["codesigned"]["design"] == doc["sequential"]["design"]
    assert doc["codesigned"]["gains"] == doc["sequential"]["gains"]
    assert doc["validated"]["sequential"] is not None
    assert doc["schedule_inside"] is False and doc["controller_follows_study"] is False
    # the feedforward's lead: none on the sequential answer (the study's controller); the co-designed one's chosen in
    # its bounds, each lead tried with its tracking RMS, the chosen one the least of them
    assert doc["sequential"]["feedforward"]["lead_s"] == 0.0 and doc["sequential"]["feedforward"]["leads_tried"] == []
    ff = doc["codesigned"]["feedforward"]
    if ff["leads_tried"]:
        lo, hi = ff["lead_bounds_s"]
        assert all(lo <= t["lead_s"] <= hi for t in ff["leads_tried"])
        assert ff["tracking_rms_with_lead_N"] == min(t["tracking_rms_N"] for t in ff["leads_tried"])
        assert ff["tracking_rms_with_lead_N"] <= ff["tracking_rms_without_lead_N"]
    assert isinstance(doc["feedforward"], str) and doc["feedforward_lead_inside"] is True


def test_codesign_command_refuses_bad_input(capsys):
    assert main(["codesign", str(SMALL_AXIS), "--budget", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: --budget")
    # the controller is the study's, the schedule's entries or the robust set: not two of them
    assert main(["codesign", str(SMALL_AXIS), "--schedule", "--robust-set"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--robust-set" in err[0] and "--schedule" in err[0]


def test_the_schedule_s_entries_asked_of_a_study_without_a_schedule_are_refused_by_key(tmp_path, capsys):
    text = SMALL_AXIS.read_text().replace("schedule_levels = 2\n", "schedule_levels = 0\n", 1)
    path = tmp_path / "one_set.toml"
    path.write_text(text)
    assert main(["codesign", str(path), "--schedule", "--budget", "0", "--plants", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and "[tuning] schedule_levels >= 2" in err[-1] and "--robust-set" in err[-1]


@pytest.mark.slow  # a sequential design and tuning at least (tens of seconds)
def test_codesign_command_exits_2_on_a_design_no_controller_meets(tmp_path, capsys):
    text = SMALL_AXIS.read_text().replace("tracking_rms_max_N = 100.0", "tracking_rms_max_N = 5.0")
    study = tmp_path / "tight.toml"
    study.write_text(text)
    # the robust set asked for: the exit code does not need the entries
    assert main(["codesign", str(study), "--budget", "0", "--plants", "0", "--robust-set"]) == 2
    assert "error:" in capsys.readouterr().err


@pytest.mark.slow
def test_a_study_with_method_codesign_runs_end_to_end(tmp_path, monkeypatch):
    # the smaller study the claim allows: one inner solve after the sequential start (and for each front weight), and
    # one robust gain set (no gain schedule's entries to tune in the tune stage); the co-design still moves the design
    text = SMALL_AXIS.read_text().replace("[design]\n", '[design]\nmethod = "codesign"\ncodesign_budget = 1\n', 1)
    text = text.replace("schedule_levels = 2\n", "schedule_levels = 0\n", 1)
    assert "codesign_budget = 1" in text and "schedule_levels = 0" in text
    path = tmp_path / "small_codesign.toml"
    path.write_text(text)
    study = load_study(path)
    assert study.design_table.method == "codesign"
    import piezopreload.codesign as codesign_module

    answers = []  # the co-design the design stage ran (not solved a second time here: it is the test's cost)
    solve = codesign_module.codesign
    monkeypatch.setattr(codesign_module, "codesign", lambda *a, **k: answers.append(solve(*a, **k)) or answers[-1])
    out = tmp_path / "out"
    code = main(["run", str(path), "--out", str(out), "--json", "--quiet"])
    assert code == 0, "the co-designed small study failed"
    from piezopreload.artifacts.design import DesignRecord

    record = DesignRecord.load(out / "design" / "design.json")
    assert answers[0].evaluations == 2  # the start and the one inner solve the study's budget allows
    assert answers[0].codesigned is not answers[0].sequential  # the co-design moved the design
    chosen = answers[0].codesigned.variables()  # the co-design's own answer, as the design stage got it
    assert record.optimum.objective == "codesign"
    assert record.optimum.point.contact_angle_deg == pytest.approx(chosen["contact_angle_deg"], rel=1e-6)
    assert record.optimum.point.conformity == pytest.approx(chosen["conformity"], rel=1e-6)
    plant = json.loads((out / "plant.json").read_text())
    assert plant  # the plant stage ran on the co-designed design
    # the design stage wrote the co-design beside the design, both fronts swept; the report has its section
    from piezopreload.artifacts.codesign import CodesignRecord

    co = CodesignRecord.load(out / "design" / "codesign.json")
    assert co.strategy == "nested" and "sensitivit" in co.strategy_why
    # the study's stages run the learned feedforward: the design step chose no feedforward lead, and says so
    assert answers[0].ff_lead is False and answers[0].codesigned.ff_lead_s == 0.0
    assert "feedforward: no feedforward lead" in co.controller, co.controller
    assert len(co.sequential_front) >= 3 and len(co.codesigned_front) == 3
    assert {p.label for p in co.codesigned_front} == {"growth weight 1, tracking 0", "growth weight 0.5, tracking 0.5",
                                                      "growth weight 0, tracking 1"}
    assert all(p.ms <= co.ms_max * 1.001 for p in co.codesigned_front if p.feasible)
    report = json.loads((out / "report" / "report.json").read_text())
    section = next(s for s in report["sections"] if s["title"].startswith("Co-design"))
    assert "codesign-fronts" in section["figures"]
    assert ("nowhere worse" in " ".join(section["paragraphs"])) == co.front_dominates()


def test_the_method_key_is_declared_once_and_checked(tmp_path):
    text = SMALL_AXIS.read_text().replace("[design]\n", '[design]\nmethod = "both"\n', 1)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match="method"):
        load_study(path)
    assert replace(load_study(SMALL_AXIS).design_table).method == "sequential"


def test_a_growth_weight_needs_the_thermal_table(small):
    without = small.replace(thermal=None)
    assert without.thermal is None
    with pytest.raises(InputError, match=r"growth weight needs a \[thermal\] table"):
        codesign(without, CodesignWeights(growth=1.0, tracking=1.0), budget=0, validate_plants=0)
    # what the study states: growth and tracking where it has [thermal], friction and tracking where not
    assert CodesignWeights.of_study(small) == CodesignWeights(growth=1.0, friction=0.0, tracking=1.0)
    assert CodesignWeights.of_study(without) == CodesignWeights(growth=0.0, friction=1.0, tracking=1.0)


def test_a_codesign_study_s_plant_is_never_the_sequential_design_in_its_place(tmp_path):
    text = SMALL_AXIS.read_text().replace("[design]\n", '[design]\nmethod = "codesign"\n', 1)
    path = tmp_path / "small_codesign.toml"
    path.write_text(text)
    study = load_study(path)
    with pytest.raises(InputError, match='method = "codesign"'):
        study.plant  # noqa: B018 - the property solves the design
    seq = optimise(study.design_spec, study.design_table.objective)
    assert study.with_design(seq).plant is not None  # a design given is taken as it is


def test_a_worse_candidate_never_replaces_the_sequential_answer(small, monkeypatch):
    # every candidate after the sequential start is made 20 % worse on the tracking: the search must keep the start
    import piezopreload.codesign as cd

    real, made = cd.evaluate_design, []

    def evaluate(study, point, **kwargs):
        if not made:
            made.append(real(study, point, **kwargs))
            return made[0]
        return replace(made[0], point=point, cycle_tracking_rms_N=made[0].cycle_tracking_rms_N * 1.2)

    monkeypatch.setattr(cd, "evaluate_design", evaluate)
    # the schedule's shape held at the least-friction one: every candidate but the start is the worse one
    # the robust set and no feedforward lead: the point is the outer search's acceptance, with nothing but the design
    # moving (a lead chosen on the start's loop would be a better start)
    r = cd.codesign(small, CodesignWeights(growth=0.0, friction=0.0, tracking=1.0), budget=3, validate_plants=0,
                    time_factor=None, shape=False, schedule=False, ff_lead=False)
    assert r.evaluations == 4  # the start and three candidates scored
    assert r.codesigned is r.sequential
    assert r.objective_codesigned == pytest.approx(1.0)


@pytest.mark.slow  # one design's tuning and its schedule's entries (a minute or more)
def test_the_schedule_s_entries_are_inner_decisions_each_at_its_window_s_ms(small, small_codesign):
    from piezopreload.codesign import _plant
    from piezopreload.tuning.linearised import max_sensitivity
    from piezopreload.tuning.pid import plant_variants
    from piezopreload.tuning.schedule import level_windows

    seq = small_codesign.sequential
    assert seq.controller == "robust" and seq.gains.schedule is None and not small_codesign.schedule
    c = evaluate_design(small, seq.point, start=seq.gains, schedule=True, ff_lead=False)  # the entries alone
    s = c.gains.schedule
    assert c.controller == "schedule" and s is not None and len(s.levels_N) == small.tuning.schedule_levels
    # each entry's Ms over its own window, recomputed from the linearised loop at both ends of the window's slope on
    # every variant the tuning bounds: at most the study's limit (the tuner's constraint), as the candidate says
    plant, spec = _plant(small, seq.point), small.tuning
    for i, (lo, hi) in enumerate(level_windows(s.levels_N)):
        entry = replace(c.gains, Kc=s.Kc[i], Ti_s=s.Ti_s[i], Td_s=s.Td_s[i], b=s.b[i] if s.b else c.gains.b,
                        schedule=None)
        ms = max(max_sensitivity(entry, v, (lo, hi)) for v in plant_variants(plant, spec.variants))
        assert ms == pytest.approx(c.entry_ms[i], rel=1e-6)
        assert ms <= spec.ms_max * (1 + 1e-3), f"entry {i} at {s.levels_N[i]} N: Ms {ms}"
    assert c.ms == pytest.approx(max(c.entry_ms))
    # the inner problem keeps the schedule only where it tracks better than the robust set on the nominal plant
    assert c.tracking_rms_N < seq.tracking_rms_N
    assert c.feasible and c.to_dict()["schedule"]["levels_N"] == list(s.levels_N)


def test_a_design_no_controller_makes_meet_ms_is_refused_naming_the_design_and_the_binding_pair(small, monkeypatch):
    # the tuning finds no gains that meet Ms with its other constraints (its own message names the violated ones):
    # the co-design's inner problem refuses the design by its variables, the Ms limit and its key, and the pair
    import piezopreload.codesign as cd
    from piezopreload.tuning.pid import TuningInfeasible

    def infeasible(*args, **kwargs):
        raise TuningInfeasible("PID tuning found no gains that meet the specification (1 start); not met: Ms <= 1.6, "
                               "variant 2, slope 71.993 N/V (by 0.04); overshoot on variant 1 (by 2.1)")

    class Feedforward:
        def inverse(self):
            return None

    monkeypatch.setattr(cd, "tune_pid", infeasible)
    point = optimise(small.design_spec, small.design_table.objective).point
    with pytest.raises(InfeasibleError) as err:
        cd.evaluate_design(small, point, feedforward=Feedforward())
    message = str(err.value)
    assert f"contact angle {point.contact_angle_deg:.2f} deg" in message
    assert f"rigidity {point.stiffness_N_per_um:.0f} N/um" in message
    assert "has no controller that meets Ms <= 1.6 ([tuning] ms_max)" in message
    assert "Ms <= 1.6, variant 2, slope 71.993 N/V (by 0.04)" in message and "overshoot on variant 1" in message


def test_each_design_s_schedule_friction_is_its_own_and_equal_where_the_lift_off_bound_sets_every_level(small):
    # Three designs of one co-design run (balls and rigidity differ) read the same friction energy per cycle on the
    # study's machining cycle: every level of their least-friction schedules sits on the lift-off bound
    # lift_off_margin |F_a| / 2^(3/2) or on the bolts' preload (itself on that bound for the failsafe load), and the
    # drag per newton is the screw's helix' (its lead and diameter, the same for all). The friction is each design's
    # own: where the rigidity requirement binds the levels ([schedule] stiffness_min_N_per_um = 1000), they differ.
    from piezopreload.codesign import _optimum_at, planned_schedule
    from piezopreload.models.ballscrew import LIFT_OFF_RATIO

    spec = small.design_spec
    seq = optimise(spec, small.design_table.objective).point
    at = {"contact_angle_deg": seq.contact_angle_deg, "conformity": seq.conformity}
    points = [seq] + [_optimum_at(spec, {"stiffness_floor_N_per_um": f * seq.stiffness_N_per_um, **at}).point
                      for f in (0.85, 0.6)]
    assert len({(p.ball_mm, p.balls_per_turn) for p in points}) == 3
    assert len({round(p.stiffness_N_per_um) for p in points}) == 3
    energies = []
    for p in points:
        plan = planned_schedule(small, p)
        screw = spec.screw(p)
        Fa = np.abs(np.asarray(plan.profile.axial_load_N))
        bound = np.maximum(plan.spec.bolt_preload_N, plan.spec.lift_off_margin * Fa / LIFT_OFF_RATIO)
        np.testing.assert_allclose(plan.preload_N, bound, rtol=1e-9, err_msg="a level off the lift-off bound")
        w = screw.drag_torque_Nm(1.0) * np.asarray(plan.profile.speed_rpm) * 2 * np.pi / 60 * plan.profile.dt_s
        assert plan.friction_energy_J == pytest.approx(float(np.dot(w, bound)), rel=1e-9)
        energies.append(plan.friction_energy_J)
    assert max(energies) == pytest.approx(min(energies), rel=1e-9)
    stiff = small.replace(schedule={"stiffness_min_N_per_um": 1000.0})
    bound_by_rigidity = [planned_schedule(stiff, p).friction_energy_J for p in points]
    assert min(bound_by_rigidity) > max(energies)
    assert len({round(e, 3) for e in bound_by_rigidity}) == 3, bound_by_rigidity


# ---- the controller compared follows the study's own; the feedforward's lead an inner decision -------------------
def test_the_default_controller_follows_the_study(small, monkeypatch):
    # the study's tune stage makes a gain schedule where [tuning] schedule_levels >= 2 (the small axis: 2): by default
    # the co-design compares both answers with the schedule's entries inside; with fewer, the one robust set; either
    # when asked. The sequential answer's inner problem is stopped at once: what it was asked is the point.
    import piezopreload.codesign as cd

    asked: list[bool] = []

    class Stop(Exception):
        pass

    def evaluate(study, point, **kwargs):
        asked.append(kwargs["schedule"])
        raise Stop

    monkeypatch.setattr(cd, "evaluate_design", evaluate)
    monkeypatch.setattr(cd, "optimise", lambda spec, objective: type("Optimum", (), {"point": None})())
    one_set = small.replace(tuning={"schedule_levels": 0})
    assert small.tuning.schedule_levels == 2 and one_set.tuning.schedule_levels == 0
    for study, kwargs, want in ((small, {}, True), (small, {"schedule": False}, False),
                                (small, {"schedule": True}, True), (one_set, {}, False),
                                (one_set, {"schedule": False}, False)):
        with pytest.raises(Stop):
            cd.codesign(study, budget=0, validate_plants=0, **kwargs)
        assert asked[-1] is want, f"{study.tuning.schedule_levels} levels, {kwargs}: schedule {asked[-1]}"
    with pytest.raises(Stop):  # the Study's own method passes the choice on, following the study by default
        small.codesign(budget=0, plants=0)
    assert asked[-1] is True
    with pytest.raises(Stop):
        small.codesign(budget=0, plants=0, schedule=False)
    assert asked[-1] is False
    # the entries asked of a study that tunes none are refused by key before any solve
    n = len(asked)
    with pytest.raises(InputError, match=r"\[tuning\] schedule_levels >= 2"):
        cd.codesign(one_set, budget=0, validate_plants=0, schedule=True)
    assert len(asked) == n


@pytest.fixture(scope="module")
def small_point(small):
    return optimise(small.design_spec, small.design_table.objective).point


def _fixed(small, point) -> Candidate:
    """The design's candidate with gains near the ones the study's tuning finds on it (Kc 0.0108 V/N, Ti 48.6 ms,
    b 0.91; the inner tuning stood in for), its feedforward identified and its least-friction schedule planned."""
    import piezopreload.codesign as cd

    gains = replace(small.controller, Kc=0.0108, Ti_s=0.0486, Td_s=0.0, b=0.91)
    return cd.with_headroom(small, Candidate(point, gains, 1000.0, 1.5, math.nan, 20.0, 50.0, 0.1, True), 1.0)


def test_the_feedforward_reads_the_schedule_s_reference_ahead_by_its_lead(small, small_point):
    # the loop's feedforward along the schedule is the inverse P-I of the reference read the lead ahead (the last
    # level held past the end), recomputed here from the run's own reference by the identified inverse: to round-off
    import piezopreload.codesign as cd

    c = _fixed(small, small_point)
    inverse = c.feedforward.inverse()
    for lead in (0, 3, 12):
        run = cd.along_schedule(small, replace(c, ff_lead_s=lead * 1e-3), c.least_plan, 1).run
        r = run.reference_N
        ahead = np.concatenate([r[lead:], np.full(lead, r[-1])])
        want = np.asarray(inverse(ahead, inverse.initial_state()), float)
        np.testing.assert_allclose(run.ff_V, want, rtol=0, atol=1e-9 * np.max(np.abs(want)),
                                   err_msg=f"the feedforward at a {lead} ms lead is not the inverse read ahead")
    # the lead given to the run overrides the candidate's
    a = cd.along_schedule(small, c, c.least_plan, 1, 0.003).run.ff_V
    np.testing.assert_array_equal(a, cd.along_schedule(small, replace(c, ff_lead_s=0.003), c.least_plan, 1).run.ff_V)


def test_the_feedforward_lead_is_a_bounded_search_for_the_least_tracking_rms(small, small_point, monkeypatch):
    # the run along the schedule stood in for by a closed form of the lead: a valley at 7 ms, a valley at the upper
    # bound, and a rise from 0 (no lead kept); the search must land on each exactly, inside its bounds, in few runs
    from types import SimpleNamespace

    import piezopreload.codesign as cd

    c = _fixed(small, small_point)
    top = round(cd.FF_LEAD_MAX_S / 1e-3)
    for name, rms, want in (("7 ms", lambda k: 10.0 + 0.01 * (k - 7) ** 2, 7),
                            ("the bound", lambda k: 10.0 + 0.01 * (k - top) ** 2, top),
                            ("none", lambda k: 10.0 + 0.1 * k, 0)):
        calls: list[int] = []

        def run(study, cand, plan, passes=None, lead_s=None, rms=rms, calls=calls):
            k = round(lead_s / 1e-3)
            calls.append(k)
            return SimpleNamespace(evaluation=SimpleNamespace(numbers=SimpleNamespace(tracking_rms_N=rms(k))))

        monkeypatch.setattr(cd, "along_schedule", run)
        out = cd.choose_ff_lead(small, c)
        assert out.ff_lead_s == pytest.approx(want * 1e-3, abs=1e-12), f"{name}: chose {out.ff_lead_s} s"
        assert calls[0] == 0 and all(0 <= k <= top for k in calls) and len(calls) == len(set(calls)) <= 12, calls
        assert dict(out.ff_leads_tried) == {k * 1e-3: rms(k) for k in calls}
        assert out.ff_lead_bought() == (rms(0), rms(want))


def test_a_feedforward_lead_the_study_s_stages_cannot_run_is_not_handed_to_them(small, small_point):
    # a study with [design] method = "codesign" runs the learned feedforward along the schedule: a co-design that
    # chose a lead is refused as its design step rather than handed on as if the study ran it
    import piezopreload.codesign as cd

    seq = replace(_candidate(200.0, 30.0, 100.0), point=small_point)
    led = replace(seq, ff_lead_s=0.002, ff_leads_tried=((0.0, 30.0), (0.002, 29.0)))
    result = cd.CodesignResult(small.name, "nested", CodesignWeights(), seq, led, 1.0, 0.98, 2, (), 1.0, 1.0)
    with pytest.raises(InfeasibleError, match="feedforward lead of 0.002 s"):
        cd._chosen(small, result)
    assert "reads the schedule's reference 2 ms ahead" in result.feedforward_words()
    assert "30.00 N without a lead, 29.00 N with it" in result.feedforward_words()
    assert any(line.startswith("feedforward_lead_s 0 -> 0.002 s") for line in result.changed())
    kept = replace(result, codesigned=replace(led, ff_lead_s=0.0, ff_leads_tried=((0.0, 30.0), (0.002, 31.0))))
    assert "none tracked the least-friction schedule (one pass) better than none (30.00 N; the best lead, 2 ms, " \
           "31.00 N)" in kept.feedforward_words(), kept.feedforward_words()
    none = replace(result, ff_lead=False, codesigned=seq)
    assert none.feedforward_words().startswith("no feedforward lead: the inverse P-I feedforward reads the reference")
