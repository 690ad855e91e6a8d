"""The calibrated rig against the paper's Section 4, and the calibration itself."""

from dataclasses import replace

import numpy as np
import pytest

from piezopreload.models.actuator import Rig, loop_width, reach_N
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.calibrate import PAPER_RESULTS, _mismatch, _worst_mismatch, calibrate, reproduce

# studies/paper2021.md: four of the six within +/-25 %; PID rise and FF settling outside, with
# the account of why. These tests hold the preset to what that document says.
WITHIN = {("pid", "peak_s"), ("pid", "settling_s"), ("ff+pid", "rise_s"), ("ff+pid", "peak_s")}


def test_the_preset_reproduces_the_paper_as_documented():
    s = load_study(paper_study()).reproduce()
    for key in WITHIN:
        assert s.row(*key).within_25pct, f"{key}: {s.row(*key)}"
    pid_rise, ff_settling = s.row("pid", "rise_s").ratio, s.row("ff+pid", "settling_s").ratio
    assert pid_rise is not None and 0.70 <= pid_rise < 1.0  # documented: 0.74, limited by the 100 N reach
    assert ff_settling is not None and 1.0 < ff_settling <= 1.40  # documented: 1.32, open work
    assert s.feedforward_fit["rms_pct"] < 2.0


def test_the_preset_is_physical():
    rig = Rig(load_study(paper_study()).plant)
    assert float(reach_N(rig, 110.0)) >= 100.0, "the trajectory's 100 N must be reachable within 0-110 V"
    assert 0.10 <= float(loop_width(rig)) <= 0.15


def test_mismatch_is_zero_at_the_papers_numbers_and_penalises_never():
    assert _mismatch(PAPER_RESULTS) == 0.0
    never = {c: dict(m) for c, m in PAPER_RESULTS.items()}
    never["pid"]["settling_s"] = float("nan")
    assert _mismatch(never) == 9.0


def test_calibrate_improves_on_its_start():
    study = load_study(paper_study())
    start = replace(study.plant, amp_current_limit_A=0.05)  # the feedforward step would rise far too fast
    res = calibrate(start, {"amp_current_limit_A": (0.005, 0.1)}, max_evaluations=6)
    assert res.evaluations >= 6 and len(res.history) == res.evaluations
    first = res.history[0]["objective"]
    assert min(h["objective"] for h in res.history) < first
    assert res.params.amp_current_limit_A < 0.05
    rep = reproduce(res.params)
    assert rep.metrics["ff+pid"]["rise_s"] > reproduce(start).metrics["ff+pid"]["rise_s"]


def test_calibrate_rejects_unknown_parameters():
    with pytest.raises(ValueError, match="cannot calibrate"):
        calibrate(load_study(paper_study()).plant, {"wheel_count": (1.0, 2.0)})


def test_repeats_report_the_median_and_range_of_independent_noise_realisations():
    rig = load_study(paper_study()).plant
    rep = reproduce(rig, repeats=3)
    runs = rep.runs["ff+pid"].step_metrics(1.5, signal="measured_N")
    assert len(runs) == 3
    settle = sorted(m.settling_s for m in runs)
    assert rep.metrics["ff+pid"]["settling_s"] == settle[1]
    assert rep.spread["ff+pid"]["settling_s"] == (settle[0], settle[2])
    assert settle[0] < settle[2], "three noise realisations must not all settle at the same sample"


def test_worst_case_objective_is_the_largest_log_ratio_outside_skip():
    metrics = {c: dict(m) for c, m in PAPER_RESULTS.items()}
    assert _worst_mismatch(metrics, ()) == 0.0
    metrics["pid"]["rise_s"] *= 2.0
    metrics["ff+pid"]["settling_s"] *= 1.1
    full = _worst_mismatch(metrics, ())
    assert full == pytest.approx(np.log(2.0) + 0.1 * (np.log(2.0) ** 2 + np.log(1.1) ** 2))
    skipped = _worst_mismatch(metrics, (("pid", "rise_s"),))
    assert skipped == pytest.approx(np.log(1.1) + 0.1 * np.log(1.1) ** 2)
