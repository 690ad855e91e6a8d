"""tuning.schedule: the entries tuned per level on a Hertz-coupled plant, both sets validated per level, the choice."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopreload.artifacts.validation import Criteria
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import PIDGains
from piezopreload.tuning.linearised import small_signal_gains
from piezopreload.tuning.pid import TuningSpec
from piezopreload.tuning.schedule import (
    LevelFigures,
    choose,
    level_windows,
    rising_setpoint_weights,
    schedule_levels,
    setpoint_action_rises,
    tune_schedule,
    window_ms,
)
from piezopreload.tuning.validate import validate


def test_levels_and_windows_tile_the_range():
    lv = schedule_levels(0.0, 4000.0, 3)
    np.testing.assert_array_equal(lv, [0.0, 2000.0, 4000.0])
    assert level_windows(lv) == [(0.0, 1000.0), (1000.0, 3000.0), (3000.0, 4000.0)]
    with pytest.raises(ValueError, match="at least 2"):
        schedule_levels(0.0, 1.0, 1)


def _figures(passed, failures=()):
    """A set's figures at a level as the schedule's record writes them (the worst cases never reached)."""
    return {"settling_s": None, "overshoot_N": None, "tracking_rms_N": None, "peak_voltage_V": None, "passed": passed,
            "failures": list(failures)}


def _choose(levels, whole):
    """:func:`choose` on a schedule record's levels and whole range (as its JSON has them)."""
    return choose([LevelFigures.from_dict(r) for r in levels], LevelFigures.from_dict(whole))


@pytest.mark.parametrize(("robust", "scheduled", "whole", "expected"), [
    ((True, True), (True, True), (True, True), "robust"),      # both meet it: one set is simpler
    ((True, False), (True, True), (True, True), "schedule"),   # the robust set misses a level
    ((True, False), (False, True), (True, True), "robust"),    # neither everywhere: the whole range decides
    ((False, False), (False, False), (False, True), "schedule"),
    ((True, True), (True, True), (False, True), "schedule"),   # the robust set misses the whole range
])
def test_the_choice_follows_the_figures(robust, scheduled, whole, expected):
    levels = [{"level_N": float(i), "robust": _figures(r, () if r else ("overshoot_N",)),
               "scheduled": _figures(s, () if s else ("settling_s",))}
              for i, (r, s) in enumerate(zip(robust, scheduled))]
    w = {"robust": _figures(whole[0], () if whole[0] else ("tracking_rms_N",)), "scheduled": _figures(whole[1])}
    choice, reason = _choose(levels, w)
    assert choice == expected, reason
    if not all(robust) or not whole[0]:
        assert "worst overshoot" in reason or "worst tracking RMS" in reason, (
            "the reason does not say in words where the robust set failed")
        assert "_N" not in reason, f"a field name in the reason: {reason}"


def _hertz_rig(**kw):
    """The paper's rig with a Hertz coupling whose force per volt grows with the preload."""
    return Plant(noise_N=0.2, hertz_um_per_N23=0.5, hertz_preload_N=25.0, **kw)


def test_a_window_s_slopes_are_the_hertz_coupling_s_there():
    """TuningSpec.force_range_N: the linearised loop's slopes at the window's ends, from the coupling's own
    local stiffness (stroke per volt times it; Bouc-Wen's alpha and kappa as over the whole stroke)."""
    rig = _hertz_rig()
    whole = small_signal_gains(rig)
    lo, hi = small_signal_gains(rig, (40.0, 60.0))
    k = np.asarray(rig.local_stiffness_N_per_um(np.array([40.0, 60.0]) - rig.bolt_preload_N)) * rig.stroke_um_per_V
    assert lo == pytest.approx(k[0] * (1 - rig.bw_alpha), rel=1e-12)
    assert hi == pytest.approx(k[1] * (1 + 2 * rig.bw_kappa * 1.1), rel=1e-12)
    assert whole[0] < lo < hi < whole[1], "a window's slopes are not inside the whole stroke's"


def test_an_entry_s_maximum_sensitivity_is_read_over_its_own_window():
    """An entry's Ms is the peak of |1 / (1 + C G)| over the plant variants at both ends of its window's slope, not of
    the whole stroke's (whose stiffer end, on a Hertz coupling, gives a higher peak): checked against the loop's
    frequency response on a fine grid, computed here from the loop transfer."""
    from piezopreload.tuning.linearised import loop_frequency_response
    from piezopreload.tuning.pid import plant_variants

    rig = _hertz_rig()
    gains = PIDGains(Kc=3.0, Ti_s=0.01, Td_s=0.0, Tf_s=0.0)
    window = replace(TuningSpec(band_N=1.5), force_range_N=(30.0, 45.0))
    omega = np.linspace(1e-2, np.pi / rig.sample_period_s, 20001)
    ours = window_ms(gains, rig, window)
    peak = max(float(np.max(np.abs(1.0 / (1.0 + loop_frequency_response(gains, v, omega, slope)))))
               for v in plant_variants(rig, window.variants) for slope in small_signal_gains(v, window.force_range_N))
    assert ours == pytest.approx(peak, rel=2e-3), (ours, peak)
    whole = window_ms(gains, rig, replace(window, force_range_N=None))
    assert ours < whole - 0.05, f"the low window's Ms {ours:.3f} is not below the whole stroke's {whole:.3f}"


@pytest.mark.slow  # four tunings and eight Monte Carlo validations (about 8 s under load)
def test_tune_schedule_records_both_sets_per_level_and_chooses_by_them():
    rig = _hertz_rig()
    spec = TuningSpec(band_N=1.5)
    criteria = Criteria(band_N=1.5)
    robust = PIDGains(Kc=0.6, Ti_s=0.05, Td_s=0.0, Tf_s=0.001, b=0.5)
    step = Reference.step(25.0, 60.0, 0.3, 1.2)
    trajectory = Reference.staircase(25.0, [45.0, 65.0, 45.0], 0.6, t_start_s=0.3)
    res = tune_schedule(rig, None, spec, criteria, robust, levels_N=[30.0, 60.0], step=step, trajectory=trajectory,
                        n_plants=3, seed=1)  # no pool: here, one job after another
    assert res.table.levels_N == (30.0, 60.0)
    chosen = res.chosen(robust)
    assert chosen is robust if res.choice == "robust" else (chosen.schedule is res.table and chosen.Tf_s == robust.Tf_s)
    d = res.to_dict()
    assert d["choice"] in ("robust", "schedule") and type(res).from_dict(d) == res
    assert (d["choice"], d["reason"]) == _choose(d["levels"], d["whole_range"])
    # the figures are the validation's own: the first level's robust worst case again, independently
    r0 = d["levels"][0]
    lo, hi = r0["window_N"]
    again = validate(robust, None, rig, criteria, n_plants=3, seed=1, step=Reference.step(lo, hi, 0.3, 1.2),
                     trajectory=Reference.staircase(lo, [hi, lo], 0.6, t_start_s=0.3))
    for k in ("settling_s", "overshoot_N", "tracking_rms_N"):
        assert r0["robust"][k] == again.summary()[k]["worst"], f"level 30 N, robust, {k} is not the validation's"
    # each entry has its own b (the table's column, tuned with the entry) and the robust set's Tf; an entry whose
    # tuning was infeasible keeps the robust set's gains, and says so
    assert res.table.b is not None and d["table"]["b"] == list(res.table.b)
    for r, kc, b in zip(d["levels"], res.table.Kc, res.table.b):
        assert r["entry"]["Kc_V_per_N"] == kc and r["entry"]["b"] == b and r["entry"]["Tf_s"] == robust.Tf_s
        assert 0.0 <= b <= 1.0, f"the setpoint weight {b} is outside the tuning's box"
        if "infeasible" in r["tuning"]:
            assert kc == robust.Kc
        else:  # the tuning's Ms and the record's are the entry's over its own window
            entry = PIDGains(Kc=kc, Ti_s=r["entry"]["Ti_s"], Td_s=r["entry"]["Td_s"], Tf_s=r["entry"]["Tf_s"])
            own = window_ms(entry, rig, replace(spec, force_range_N=tuple(r["window_N"])))
            assert r["tuning"]["ms"] == pytest.approx(own, rel=1e-9) and r["ms"]["scheduled"] == pytest.approx(own)
        assert ("bound" in r) == (not r["scheduled"]["passed"]), (
            "a level the schedule misses does not say what stops it")
    assert setpoint_action_rises(res.table.levels_N, res.table.Kc, res.table.b)


def test_a_flat_schedule_validates_as_the_robust_set():
    """The scheduled controller with every entry the robust set's gains: the same Monte Carlo figures."""
    from piezopreload.models.controller import GainSchedule

    rig = _hertz_rig()
    robust = PIDGains(Kc=0.6, Ti_s=0.05, Td_s=0.0, Tf_s=0.001, b=0.5)
    flat = replace(robust, schedule=GainSchedule((30.0, 60.0), (0.6, 0.6), (0.05, 0.05), (0.0, 0.0)))
    ref = Reference.step(25.0, 60.0, 0.3, 1.0), Reference.staircase(25.0, [45.0, 65.0], 0.5, t_start_s=0.3)
    a = validate(robust, None, rig, Criteria(band_N=1.5), n_plants=3, seed=2, step=ref[0], trajectory=ref[1])
    b = validate(flat, None, rig, Criteria(band_N=1.5), n_plants=3, seed=2, step=ref[0], trajectory=ref[1])
    for k in a.metrics:
        np.testing.assert_allclose(b.metrics[k], a.metrics[k], rtol=0, atol=1e-9, err_msg=k)


def test_the_setpoint_action_must_rise_with_the_setpoint_and_the_weights_are_raised_to_the_least_that_does():
    """Kc constant, b linear between (L0, b0) and (L1, b1): d(b r)/dr = b(r) + r (b1 - b0) / (L1 - L0) is least at
    L1 when b falls, so the setpoint action rises iff b1 >= b0 L1 / (2 L1 - L0); the raised weight is that bound."""
    lv, kc = (2000.0, 4000.0), (0.011, 0.011)
    bound = 0.6 * 4000.0 / (2 * 4000.0 - 2000.0)
    assert setpoint_action_rises(lv, kc, (0.6, bound + 1e-4)) and not setpoint_action_rises(lv, kc, (0.6, bound - 1e-3))
    raised = rising_setpoint_weights(lv, kc, (0.6, 0.1))
    assert raised[0] == 0.6 and raised[1] == pytest.approx(bound, abs=2e-6), raised
    assert rising_setpoint_weights(lv, kc, (0.6, 0.7)) == (0.6, 0.7), "a rising table was changed"
    # three entries, from the bottom up: the middle one is raised first, and the top one against the raised middle
    three = rising_setpoint_weights((0.0, 2000.0, 4000.0), (0.01, 0.0115, 0.0112), (0.9, 0.05, 0.6))
    assert setpoint_action_rises((0.0, 2000.0, 4000.0), (0.01, 0.0115, 0.0112), three)
    assert three[1] > 0.05 and three[2] == 0.6
    # a falling setpoint action makes a step across the segment lower the command: the closed loop lags
    from piezopreload.models.controller import Controller, GainSchedule

    def command_after_step(b):
        g = PIDGains(Kc=0.011, Ti_s=0.05, b=0.6, u_min_V=-1e3, u_max_V=1e3, schedule=GainSchedule(lv, kc, (0.05, 0.05),
                                                                                               (0.0, 0.0), b))
        c = Controller(g, 1e-3)
        state = c.initial_state(3000.0, 3000.0, u0=0.0)
        u, _ = c.step(state, 3500.0, 3000.0)
        return float(u)

    assert command_after_step((0.6, 0.1)) < 0.0 < command_after_step(raised), \
        "the raised weights do not make a step up raise the command"


def test_a_level_the_schedule_misses_says_what_stops_a_pid_entry():
    from piezopreload.tuning.schedule import WorstFigures, _bound

    limits = {"settling_s": 0.6, "overshoot_N": 25.0, "tracking_rms_N": 40.0, "peak_voltage_V": 120.0}
    figures = WorstFigures(settling_s=0.5, overshoot_N=28.8, tracking_rms_N=None, peak_voltage_V=None, passed=False,
                        failures=("overshoot_N",))
    tuned = _bound({"binding": ["Ms <= 1.6, variant 2", "overshoot inside 15 N, step, variant 1"],
                    "overshoot_target_N": 15.0}, figures, limits)
    assert "Ms <= 1.6, variant 2" in tuned and "worst overshoot 28.8 N against 25" in tuned and "15 N" in tuned
    none = _bound({"infeasible": "not met: overshoot inside 15 N, step, variant 2 (by 18.5)"}, figures, limits)
    assert "no PID entry meets" in none and "by 18.5" in none
    levels = [{"level_N": 2000.0, "robust": _figures(False, ("overshoot_N",)),
               "scheduled": _figures(False, ("overshoot_N",)), "bound": tuned}]
    whole = {"robust": _figures(True), "scheduled": _figures(True)}
    choice, reason = _choose(levels, whole)
    assert choice == "robust" and "What stops a PID entry: at 2000 N" in reason and "Ms <= 1.6" in reason
    assert "misses it at 2,000 N (worst overshoot)" in reason, reason


def test_the_chosen_sets_verdict_at_each_level_is_a_requirement():
    """The tune stage's per-level verdicts: the chosen set's worst case at each level against every limit, a miss
    where it misses (the robust set kept at a level it misses is reported as missing it, not hidden)."""
    from piezopreload.tuning.schedule import level_requirements

    limits = {"settling_s": 0.6, "overshoot_N": 25.0, "tracking_rms_N": 40.0, "peak_voltage_V": 120.0}
    ok = {"settling_s": 0.3, "overshoot_N": 20.0, "tracking_rms_N": 30.0, "peak_voltage_V": 100.0}
    over = {**ok, "overshoot_N": 28.8}
    record = _record("robust", limits, [(0.0, ok, ok), (2000.0, over, ok)])
    reqs = level_requirements(record)
    assert len(reqs) == 8 and [r.met for r in reqs].count(False) == 1
    missed = next(r for r in reqs if not r.met)
    assert missed.name == "worst overshoot at the 2,000 N level over 50 Monte Carlo plants (robust)"
    assert missed.value == 28.8 and missed.limit == 25.0 and missed.source == "[validation] overshoot_max_N"
    assert all(r.met for r in level_requirements(replace(record, choice="schedule"))), "the schedule meets every level"
    never = _record("robust", limits, [(0.0, {**ok, "settling_s": None}, ok)])
    assert not level_requirements(never)[0].met, "a step that never settles misses the settling limit"


def _record(choice, limits, levels):
    """A gain schedule's record with these levels' figures ((level, robust, scheduled) each) and the rest filler."""
    from piezopreload.artifacts.tuning import GainScheduleRecord, ScheduleLevel, SetFigures, SetGains, WorstFigures
    from piezopreload.models.controller import GainSchedule

    def worst(f):
        return WorstFigures(**f, passed=True, failures=())

    gains = SetGains(0.01, 0.05, 0.0, 0.001, 0.5)
    table = GainSchedule((0.0, 2000.0), (0.01, 0.01), (0.05, 0.05), (0.0, 0.0))
    return GainScheduleRecord(choice, "", table.levels_N, table, 0.001, 0.5, gains,
                              tuple(ScheduleLevel(x, (x, x), gains, None, {}, worst(r), worst(s))
                                    for x, r, s in levels),
                              SetFigures(worst(levels[0][1]), worst(levels[0][2])), 50,
                              ("settling_s", "overshoot_N", "tracking_rms_N", "peak_voltage_V"), limits, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("draw", [3, 11])
def test_the_machine_axis_verdict_does_not_hang_on_the_last_digits(monkeypatch, draw):
    """Another machine's rounding, played here: the tuner's starting points moved by 1e-9 (in the unit box). Before
    the search kept its best point and its known ones, draw 3 ended the 4,000 N entry on IPOPT's iteration limit
    from its one start, the entry kept the robust set, the schedule missed the whole range and the robust set (28.9
    N overshoot at 2,000 N against 25 N) was kept: the default study exited 4. Now every draw tunes every entry and
    the schedule meets each level's Monte Carlo limits with at least 5 % to spare."""
    from piezopreload import steps
    from piezopreload.study import load_study
    from piezopreload.tuning import pid
    from piezopreload.tuning.schedule import level_requirements

    study = load_study("machine_axis")
    feedforward = study.identify_feedforward()
    seeds, rng = pid._seeds, np.random.default_rng(draw)

    def moved(*args, **kwargs):
        points = seeds(*args, **kwargs)
        return np.clip(points + 1e-9 * rng.standard_normal(points.shape), 0.0, 1.0)

    monkeypatch.setattr(pid, "_seeds", moved)
    schedule = steps.tune(study, study.solved, feedforward).solve.schedule
    assert schedule is not None and schedule.choice == "schedule", schedule and schedule.reason
    kept = [lv.level_N for lv in schedule.levels if "infeasible" in lv.tuning]
    assert not kept, f"the entries at {kept} N kept the robust set"
    least = min((r for r in level_requirements(schedule)), key=lambda r: r.margin_pct)
    assert least.margin_pct >= 5.0, least.sentence()
