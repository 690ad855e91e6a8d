"""The whole-system study end to end (a small copy of studies/machine_axis.toml): the plant from the design, the
schedule tracked, the summary of ``run --json``, and a changed design rebuilding the plant and all after it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.manifest import StudyRunManifest
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.registry import read_artifact
from piezopreload.artifacts.summaries import DesignSummary, LearnSummary, RigSummary, SystemSummary
from piezopreload.artifacts.system import SystemRecord
from piezopreload.cli import main
from piezopreload.design.system import LIFT_OFF_BOUND_VERDICT, OWN_CONSTRAINT, RIGIDITY_VERDICT
from piezopreload.models.thermal import EXPANSION_PER_K
from piezopreload.pipeline import STAGES
from piezopreload.study import load_study

SMALL_AXIS = Path(__file__).parent / "data" / "small_axis.toml"
pytestmark = pytest.mark.slow  # the whole small study runs (tens of seconds)


@pytest.fixture
def axis_run(small_axis_run):
    """The small study's run, shared with tests/test_own_constraint.py (tests/conftest.py)."""
    return small_axis_run


def test_every_stage_runs_and_the_plant_is_the_designs(axis_run, capsys):
    out = axis_run
    manifest = StudyRunManifest.load(out)
    assert {n: r.status for n, r in manifest.stages.items()} == {s.name: "done" for s in STAGES}
    plant = DesignedPlant.load(out / "plant.json")
    assert plant.design_sha256 == manifest.stages["design"].outputs["design"].sha256
    assert plant.rig.hertz_um_per_N23 > 0 and plant.rig.bolt_preload_N == 0.0
    gains = read_artifact(out / "gains.json", "gain-set")
    assert gains["plant"]["rig"]["hertz_um_per_N23"] == plant.rig.hertz_um_per_N23, \
        "the gain set was not tuned and validated on the designed plant"
    system = SystemRecord.load(out / "system" / "system.json")
    assert system.inputs["gain_set_sha256"] == gains["content_sha256"]
    assert 0 < system.numbers.tracking_rms_pct_of_range < 100 and system.numbers.rigidity_required_at_min_N_per_um > 0
    # the requirements as verdicts, beside their sum
    names = [r.name for r in system.requirements]
    plants = load_study(SMALL_AXIS).validation.plants
    assert names == [RIGIDITY_VERDICT, "nut axial deflection while cutting", LIFT_OFF_BOUND_VERDICT + OWN_CONSTRAINT,
                     f"lift-off load by the nut law against the cutting load, the worst of {plants} Monte Carlo plants",
                     "thermal growth at the table over the shift",
                     "positioning error over the shift (deflection, growth, tracking)"], names
    # what the lift-off margins rest on: the schedule's bound is the design's own, the nut law's is physics
    assert [r.basis for r in system.requirements[2:4]] == ["design", "physics"]
    assert system.basis is not None and system.basis.lift_off_plants == plants
    assert system.requirements_met == all(r.met for r in system.requirements)
    rigidity = system.requirements[0]
    assert (rigidity.value, rigidity.limit) == (system.numbers.rigidity_at_worst_ratio_N_per_um,
                                                system.numbers.rigidity_required_at_worst_ratio_N_per_um)
    # the least rigidity while cutting is the least over the cutting samples of the series (every 10th sample)
    series = system.series
    assert system.numbers.rigidity_min_cutting_N_per_um <= float(series.rigidity_N_per_um[series.cutting].min())
    # the cycles start after the pre-cycle: from rest to the first level at the slew limit, then the settling time
    design = DesignRecord.load(out / "design" / "design.json")
    pre = system.pre_cycle
    assert pre.slew_N_per_s == design.schedule.spec.slew_N_per_s and pre.level_N >= 50.0
    assert pre.settle_s >= load_study(SMALL_AXIS).validation.settling_max_s


def test_run_json_summary_names_the_whole_systems_numbers(axis_run, capsys):
    code = main(["run", str(SMALL_AXIS), "--out", str(axis_run), "--json", "--quiet"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ran"] == [], "an unchanged study ran a stage again"
    assert [s["stage"] for s in result["stages"]] == [s.name for s in STAGES]
    summary = result["summary"]
    system = read_artifact(axis_run / "system" / "system.json", "system")
    for key in ("tracking_rms_pct_of_range", "rigidity_min_cutting_N_per_um", "rigidity_required_at_min_N_per_um",
                "friction_saved_fraction", "requirements_met"):
        assert summary[key] == system[key], f"summary.{key} is not the system stage's"


def test_the_best_constant_preload_is_computed_once_and_read_from_the_design(axis_run):
    """One number, one source: the design records the best constant preload and its friction energy; the system's
    saving is read against it, and the report's table prints the design's."""
    design = DesignRecord.load(axis_run / "design" / "design.json")
    system = SystemRecord.load(axis_run / "system" / "system.json")
    s = design.schedule
    assert system.numbers.friction_saved_fraction == pytest.approx(
        1.0 - system.numbers.friction_energy_per_cycle / s.constant_friction_energy_J, rel=1e-12)
    summary = StudyRunManifest.load(axis_run).summary(DesignSummary)
    assert summary is not None
    assert (summary.constant_preload_N, summary.constant_friction_energy) == (s.constant_preload_N,
                                                                              s.constant_friction_energy_J)
    report = read_artifact(axis_run / "report" / "report.json", "report")
    section = next(x for x in report["sections"] if x["title"] == "The designed system along its preload schedule")
    row = next(r for r in section["tables"][0]["rows"] if r[0].startswith("friction energy per cycle, best constant"))
    from piezopreload.reports.document import fmt

    assert (row[1].startswith(fmt(s.constant_friction_energy_J))
            and row[2].startswith(f"at {fmt(s.constant_preload_N)} N")), row


def test_the_learn_stage_learns_on_each_pass_and_the_system_and_the_rig_play_it(axis_run):
    from piezopreload.artifacts.learned import LearnedSignal

    out = axis_run
    learning = read_artifact(out / "learn" / "learning.json", "learning")
    gains = read_artifact(out / "gains.json", "gain-set")
    system = read_artifact(out / "system" / "system.json", "system")
    assert learning["passes"] == len(system["passes"]), "a margin pass of the schedule was not learned"
    for record in learning["pass_records"]:
        signal = LearnedSignal.load(out / "learn" / record["signal"])
        assert signal.gain_set_sha256 == gains["content_sha256"], (
            "a learned signal is not tied to the exported gain set")
        history = [h["tracking_rms_N"] for h in record["history"]]
        # at most [learning] iterations = 3 trials after trial 0, fewer where more no longer paid
        assert len(history) == record["trials"] + 1 <= 4, f"pass {record['pass']}: {record['trials']} trials, {history}"
        assert record["tracking_rms_N"] < 0.5 * record["before_learning_rms_N"], f"pass {record['pass']}: {history}"
    manifest = StudyRunManifest.load(out)
    learn = manifest.summary(LearnSummary)
    assert learn is not None and learn.trials == sum(learn.trials_per_pass) == learning["trials"], (
        "the learn stage does not count trials")
    # the system stage's last pass plays the last pass's signal on its reference: the learning's best iterate, scored
    # as the system scores it (from t = 0: the start, 0 N against the stacks' contact force, counts), but with the
    # run's own noise draw (the trials draw seed + k)
    summary = manifest.summary(SystemSummary)
    assert summary is not None and summary.before is not None
    assert system["tracking_rms_N"] < 0.5 * summary.before.tracking_rms_N_before_learning
    assert summary.before.tracking_rms_N_before_learning == pytest.approx(learning["before_learning_rms_N"])
    last = learning["pass_records"][-1]
    assert system["tracking_rms_N"] == pytest.approx(last["tracking_rms_from_start_N"], rel=0.15), \
        "the system stage's learned run is not the learning's best iterate"
    rig = manifest.summary(RigSummary)
    assert rig is not None and rig.learned_tracking_rms_measured_N is not None, (
        "the rig stage did not play the learned signal back")


def test_the_tune_stage_chooses_between_the_schedule_and_the_robust_set_and_the_report_shows_it(axis_run):
    """[tuning] schedule_levels: the tuning records both sets' worst cases per level, the gain set is the chosen
    one (a schedule's table in its gains and exports), and the report carries the gain schedule's table and figure."""
    from piezopreload.tuning.schedule import LevelFigures, choose

    tuning = read_artifact(axis_run / "tuning.json", "tuning")
    sched = tuning["tuning"]["schedule"]
    refs = load_study(SMALL_AXIS).references
    span = [min(float(refs[k].levels_N.min()) for k in ("step", "trajectory")),
            max(float(refs[k].levels_N.max()) for k in ("step", "trajectory"))]
    assert sched["levels_N"] == span, "the schedule's entries do not span the study's references"
    assert (sched["choice"], sched["reason"]) == choose([LevelFigures.from_dict(r) for r in sched["levels"]],
                                                        LevelFigures.from_dict(sched["whole_range"]))
    for r in sched["levels"]:
        for which in ("robust", "scheduled"):
            assert set(r[which]) >= {"settling_s", "overshoot_N", "tracking_rms_N", "passed"}, r
    gains = read_artifact(axis_run / "gains.json", "gain-set")["gains"]
    assert ("schedule" in gains) == (sched["choice"] == "schedule"), "the gain set is not the chosen set"
    if sched["choice"] == "schedule":
        assert gains["schedule"]["levels_N"] == sched["levels_N"]
        assert "PP_SCHEDULE_LEVELS_N" in (axis_run / "exports" / "pp_gains.h").read_text()
    else:
        assert gains["Kc_V_per_N"] == sched["robust"]["Kc_V_per_N"]
    report = read_artifact(axis_run / "report" / "report.json", "report")
    controller = next(s for s in report["sections"] if s["title"] == "The tuned controller")
    schedule = next(s for s in controller["subsections"] if s["title"] == "The gain schedule")
    chosen = {"robust": "the one robust set", "schedule": "the scheduled gains"}[sched["choice"]]
    assert f"Chosen: {chosen}, as " in schedule["paragraphs"][0]
    assert len(schedule["tables"][0]["rows"]) == len(sched["levels"]) + 1, "one row per level and the whole range"
    assert (axis_run / "report" / "figures" / "gain-schedule.pdf").stat().st_size > 1000


def test_the_tune_stage_s_key_covers_the_validation_limits_only_where_it_chooses_by_them():
    """With a gain schedule the tune stage judges by the [validation] limits, so they are in its key; without, a
    changed limit reruns validate alone, as it always did."""
    from piezopreload.pipeline import _stage_key

    tune = next(s for s in STAGES if s.name == "tune")
    small = Path(__file__).parent / "data" / "small_study.toml"
    for path, scheduled in ((SMALL_AXIS, True), (small, False)):
        study = load_study(path)
        stricter = study.replace(validation={"overshoot_max_N": 1.0})
        changed = _stage_key(tune, study, {}) != _stage_key(tune, stricter, {})
        assert changed == scheduled, f"{path.name}: the tune stage's key {'ignores' if scheduled else 'follows'} " \
                                     "the validation limits"


def _report_words(report: dict) -> str:
    def walk(section: dict) -> list[str]:
        words = [section["title"], *section["paragraphs"], *section["omitted"]]
        for table in section["tables"]:
            words += [table["caption"], *table["header"], *(c for row in table["rows"] for c in row)]
        return words + [w for sub in section["subsections"] for w in walk(sub)]

    return " ".join([report["title"], *report["verdicts"], *report["summary"],
                     *(w for s in report["sections"] for w in walk(s)),
                     *(f["caption"] for f in report["figures"].values())])


def test_the_report_speaks_of_its_own_study_and_leads_with_its_figures(axis_run):
    """A whole-system study without published numbers: no sentence of the report is the paper's (its equations are
    cited by number), no dash stands for a number, the summary opens with the schedule's tracking, and each of the
    summary's figures is the system artifact's own."""
    import re

    report = read_artifact(axis_run / "report" / "report.json", "report")
    words = _report_words(report)
    paper = [m.group(0) for m in re.finditer(r".{40}paper.{40}", words) if "paper's eq." not in m.group(0)]
    assert not paper, f"the report speaks of the paper on a study that declares no published numbers: {paper}"
    assert " – " not in words and " - " not in words.replace(" - force", ""), "a dash stands where a number should"
    system = read_artifact(axis_run / "system" / "system.json", "system")
    first = report["summary"][0]
    from piezopreload.reports.document import q

    # the measured figure first where the study learns, then the true force, named as the one no sensor reads
    assert first.startswith(("The force sensors read the preload within", "The designed axis: the true preload")), first
    assert f"which no sensor reads, follows the schedule over the machining cycles within " \
           f"{q(system['tracking_rms_N'], 'N')} RMS" in first, first
    design = read_artifact(axis_run / "design" / "design.json", "design")
    friction = [s for s in report["summary"] if "friction energy" in s][0]
    assert f"{100 * system['friction_saved_fraction']:.2g} %" in friction, "the saving is not the system artifact's"
    assert f"{design['schedule']['constant_preload_N']:,.0f} N" in friction, "the constant preload is not the design's"
    assert report["verdicts"], "the verdicts on the requirements come first"


def test_the_shifts_thermal_budget_is_in_the_system_artifact_the_summary_the_report_and_the_sweeps_columns(axis_run):
    """[thermal]: the system artifact records the shift for the schedule and the best constant preload; run --json's
    summary and a sweep's columns read the same numbers; the requirements carry their margins; the report has its
    section, its figures and its summary lines."""
    from piezopreload.artifacts.thermal import ThermalRecord
    from piezopreload.pipeline import run_summary
    from piezopreload.sweep import headline

    system = SystemRecord.load(axis_run / "system" / "system.json")
    thermal = system.thermal
    assert isinstance(thermal, ThermalRecord) and thermal.shift_h == 2.5 and thermal.mounting == "pretensioned"
    s, c = thermal.schedule, thermal.constant
    assert s.times_h.tolist()[-3:] == [1.0, 2.0, 2.5] and s.rise_along_K.shape == (s.times_h.size, 30)
    assert s.heat_mean_W < c.heat_mean_W and s.heat_mean_other_W < c.heat_mean_other_W
    assert s.growth_max_um < c.growth_max_um and s.positioning_error_max_um <= c.positioning_error_max_um
    assert s.positioning_error_max_um >= s.growth_max_um, "the budget holds the growth (a semi-closed loop)"
    summary = run_summary(axis_run).to_dict()["thermal"]  # run --json's summary, as a user's script parses it
    for key in ("heat_mean_W", "temperature_rise_max_K", "growth_max_um", "positioning_error_max_um"):
        assert summary[key] == {"schedule": getattr(s, key), "constant": getattr(c, key)}, key
    growth, budget = system.requirements[-2:]
    assert (growth.value, growth.limit, growth.margin) == (s.growth_max_um, 200.0, 200.0 - s.growth_max_um)
    assert (budget.value, budget.limit) == (s.positioning_error_max_um, 250.0) and budget.met
    figures = headline(axis_run).to_dict()  # a sweep's columns: each figure under the thermal case's own name
    for key in ("heat_mean_W", "temperature_rise_max_K", "growth_max_um", "positioning_error_max_um"):
        assert (figures[key], figures[f"constant_{key}"]) == (getattr(s, key), getattr(c, key)), key
    report = read_artifact(axis_run / "report" / "report.json", "report")
    section = next(x for x in report["sections"] if x["title"] == "Heat, temperature and growth over a shift")
    assert section["figures"] == ["thermal-temperature", "thermal-growth", "thermal-budget"]
    assert all((axis_run / "report" / report["figures"][f]["file"]).is_file() for f in section["figures"])
    lines = [line for line in report["summary"] if line.startswith("Over the 2.5 h shift the schedule makes")]
    assert len(lines) == 1, report["summary"]
    # the heat by source: the bearings' share shown beside the seals' and the preload's, in the record's figures
    assert (f"{s.bearing_heat_mean_W:.0f} W at the support bearings, {s.seal_heat_mean_W:.0f} W at the nut's seals, "
            f"{s.heat_mean_W - s.seal_heat_mean_W:.0f} W of the preload's friction") in lines[0], lines[0]
    assert c.seal_heat_mean_W > 0 and s.seal_heat_mean_W == pytest.approx(c.seal_heat_mean_W, rel=0.01), \
        "the seals' heat depends on the preload (the same cycle's speeds, the preloads apart)"
    assert f"{s.bearing_heat_mean_W:.0f} W at the support bearings" in thermal.sentence()
    assert summary["bearing_heat_mean_W"]["schedule"] == s.bearing_heat_mean_W
    # the largest rises named by their place, the nut against the screw said with its sign
    assert summary["rise_max_place"] == {k: thermal.place(thermal.case(k).rise_max_at_mm) for k in ("schedule",
                                                                                                     "constant")}
    word = "warmer" if s.nut_over_screw_end_K >= 0 else "colder"
    assert f"the nut runs {abs(s.nut_over_screw_end_K):.1f} K {word} than the screw" in " ".join(report["summary"])
    # a growth or a budget over its limit names what drives it: the heat by source and the mounting
    from dataclasses import replace

    from piezopreload.design.tables import ThermalTable
    from piezopreload.design.thermal import _requirements

    tight = _requirements(replace(ThermalTable(), thermal_growth_max_um=0.5 * s.growth_max_um,
                                  positioning_error_max_um=2.0 * s.positioning_error_max_um), thermal)
    assert not tight[0].met and tight[1].met
    assert thermal.heat_words(s) in tight[0].sentence() and "pretension relieved" in tight[0].sentence()
    assert tight[1].name == "positioning error over the shift (deflection, growth, tracking)", "a met one explains"
    # the passive drift along the nut law, not the tangent extrapolated
    d, plant = thermal.drift, DesignedPlant.load(axis_run / "plant.json")
    over = d.passive_linear_N / d.passive_N_per_K  # the nut over the screw (K) the tangent was applied to
    mismatch = EXPANSION_PER_K * d.span_mm * 1e3 * over
    left = float(plant.screw.spacer_preload_N(d.passive_preload_N, mismatch, plant.sleeve_stiffness_N_per_um))
    assert d.passive_left_N == pytest.approx(left, rel=1e-9) and d.passive_max_N == pytest.approx(
        left - d.passive_preload_N, rel=1e-9)


def test_the_report_names_each_figure_apart_and_rounds_it_once(axis_run):
    """The least rigidity while cutting is the system's least over its cutting samples, beside the requirement at
    that moment, and the ratio to the requirement is its own line; the design's least rigidity over its duty cases
    is named as the design's; the system's tracking and the learning runs' are named apart; the friction energies
    achieved, the loop's plan and the design's plan are named apart; each quantity is printed with one rounding; the
    gain set's hash is called its content hash."""
    from piezopreload.reports.document import fmt, ratio

    report = read_artifact(axis_run / "report" / "report.json", "report")
    words = _report_words(report)
    system = SystemRecord.load(axis_run / "system" / "system.json").numbers
    design = DesignRecord.load(axis_run / "design" / "design.json")
    rigidity = [s for s in report["summary"] if s.startswith("While cutting")][0]
    assert (f"least rigidity is {fmt(system.rigidity_min_cutting_N_per_um, 3, 'N/um')} N/um "
            f"({fmt(system.rigidity_required_at_min_N_per_um, 3, 'N/um')} N/um required at that moment)") in rigidity, \
        rigidity
    assert f"at least {ratio(system.rigidity_ratio_min)} times its requirement" in rigidity, rigidity
    assert "least rigidity over the duty cycle" not in words and \
        "least rigidity over the duty cases at their design preloads" in words
    assert "over the machining cycles" in report["summary"][0] and "learning runs" in report["summary"][0]
    for name in ("friction energy per cycle, achieved", "friction energy per cycle, the loop's plan",
                 "friction energy per cycle, the design's plan"):
        assert name in words, name
    sch = design.schedule
    for x in (sch.constant_friction_energy_J, sch.constant_preload_N, sch.friction_energy_J,
              design.optimum.point.bolt_preload_N):
        other = [f"{x:.4g}", f"{x:.5g}", f"{x:,.1f}"]
        assert fmt(x) in words and not [o for o in other if o != fmt(x) and f" {o} " in words], (x, fmt(x))
    assert "content hash" in words and "gain set SHA-256" not in words


def test_no_figure_of_the_report_has_a_legend_over_its_data(axis_run):
    from figkit import legends_over_ink, report_figures

    covered = {name: found for name, fig in report_figures(axis_run) if (found := legends_over_ink(fig))}
    assert not covered, covered


def test_run_json_carries_the_sensitivity_and_the_robustness_and_the_console_says_it(axis_run, capsys):
    """summary.sensitivity: one row per assumption and requirement it moves (at least 6 assumptions), each with its
    range, margins and flip; summary.verdict_robust agrees with the rows; the console prints the robustness."""
    code = main(["run", str(SMALL_AXIS), "--out", str(axis_run), "--json", "--quiet"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)["summary"]
    rows = summary["sensitivity"]
    assert isinstance(rows, list) and rows
    for row in rows:
        for key in ("assumption", "key", "unit", "source", "requirement", "low", "high", "margin_pct_low",
                    "margin_pct_high", "flips_at"):
            assert key in row, f"summary.sensitivity row without '{key}'"
        assert row["source"], f"{row['key']}: a range without its source"
    assert len({row["key"] for row in rows}) >= 6
    moved = {row["requirement"] for row in rows}
    assert moved <= {r["key"] for r in summary["requirements"]}

    def holds(row: dict) -> bool:  # the same verdict at the study's value and at both ends, no flip inside
        met = row["margin_pct_nominal"] >= 0
        inside = row["flips_at"] is not None and row["low"] < row["flips_at"] < row["high"]
        return (row["margin_pct_low"] >= 0) == met and (row["margin_pct_high"] >= 0) == met and not inside

    assert summary["verdict_robust"] is all(holds(row) for row in rows)
    system = SystemRecord.load(axis_run / "system" / "system.json")
    assert [r.to_dict() for r in system.sensitivity.rows] == rows, "summary.sensitivity is not the system stage's"
    main(["run", str(SMALL_AXIS), "--out", str(axis_run), "--quiet"])
    said = [line for line in capsys.readouterr().out.splitlines() if line.startswith("robustness: ")]
    assert said == [f"robustness: {system.sensitivity.sentence()}"], said
    report = read_artifact(axis_run / "report" / "report.json", "report")
    section = next(x for x in report["sections"] if x["title"].startswith("The verdicts under the assumptions"))
    assert section["figures"] == ["sensitivity-tornado"]
