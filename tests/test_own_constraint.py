"""The design's own constraint is whichever requirement binds the schedule the design solved, on any study.

The least-friction schedule sits on the rows that set each sample's least preload: on the machine axis the lift-off
bound ``lift_off_margin |F_a| / 2^(3/2)`` under every cut; with ``[schedule] stiffness_min_N_per_um = 1000`` (the
stiff edit) the rigidity instead, the plan holding the preload above the lift-off bound. The design's own constraint
(``basis="design"``, named apart from the least margin by the console and the report) is the one that binds, read
from the solved schedule, never a requirement by name; the other is judged as a margin. Each binding is checked here
against the closed forms: the lift-off bound itself, and the nut's rigidity by the numpy nut law
(``BallScrew.nut_loads``, not the CasADi function the schedule was solved with).
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from piezopreload.artifacts.requirements import least_margin, own_constraints
from piezopreload.artifacts.schedule import LIFT_OFF_KEY, RIGIDITY_KEY, PreloadSchedule
from piezopreload.cli.study import _print_verdict
from piezopreload.core.quantities import number
from piezopreload.design.system import (
    LIFT_OFF_BOUND_VERDICT,
    OWN_CONSTRAINT,
    RIGIDITY_VERDICT,
    _Frame,
    frame_under,
    requirements_of,
)
from piezopreload.reports.sections import _bound_words
from piezopreload.reports.summary import verdicts
from piezopreload.study import load_study

STUDY = Path(__file__).parents[1] / "studies" / "machine_axis.toml"


def _stiff(tmp_path: Path) -> Path:
    """The machine axis with the least rigidity while cutting raised from 300 to 1,000 N/um (its one edit)."""
    text = STUDY.read_text()
    old = "stiffness_min_N_per_um = 300.0"
    assert text.count(old) == 1, f"the machine axis' study no longer holds '{old}' once"
    path = tmp_path / "stiff.toml"
    path.write_text(text.replace(old, "stiffness_min_N_per_um = 1000.0"))
    return path


@pytest.fixture(scope="module")
def designs(tmp_path_factory):
    """The default study's and the stiff edit's solved schedules, with their screws."""
    out = {}
    for name, path in (("default", STUDY), ("stiff", _stiff(tmp_path_factory.mktemp("stiff")))):
        study = load_study(path)
        out[name] = (study.preload_schedule, study.designed_plant.screw)
    return out


def _rigidity(schedule: PreloadSchedule, screw, preload_N: np.ndarray) -> np.ndarray:
    """The nut's rigidity in the machine by the numpy nut law at ``preload_N`` under the profile's loads."""
    loads = screw.nut_loads(preload_N, schedule.profile.axial_load_N)
    return schedule.spec.rigidity_factor * np.asarray(loads.rigidity_N_per_um, float)


def test_the_default_schedule_sits_on_its_lift_off_bound_and_keeps_its_rigidity_with_room(designs):
    schedule, screw = designs["default"]
    assert schedule.binding == (LIFT_OFF_KEY,)
    where = schedule.binding_samples()[LIFT_OFF_KEY]
    load = schedule.profile.axial_load_N
    # the closed form: the plan is the lift-off bound itself where it binds, the heaviest cut (4,000 N) among them
    bound = 1.2 * np.abs(load) / 2.0 ** 1.5
    np.testing.assert_allclose(schedule.preload_N[where], bound[where], rtol=1e-9,
                               err_msg="the plan does not sit on the lift-off bound where it is said to bind")
    assert np.any(where & (load == 4000.0)), "the roughing cut's samples do not bind"
    cut = schedule.profile.cutting
    k = _rigidity(schedule, screw, schedule.preload_N)
    assert np.all(k[cut] > schedule.required_N_per_um[cut] * 1.05), "the rigidity binds somewhere under load"


def test_the_stiff_edit_sits_on_its_rigidity_and_holds_the_preload_above_the_lift_off_bound(designs):
    schedule, screw = designs["stiff"]
    assert schedule.binding == (RIGIDITY_KEY,)
    where = schedule.binding_samples()[RIGIDITY_KEY]
    cut = schedule.profile.cutting
    assert np.array_equal(where, cut), "the rigidity of 1,000 N/um does not bind under every cut"
    # the nut law's rigidity at the plan is the 1,000 N/um required, to the bisection's round-off
    np.testing.assert_allclose(_rigidity(schedule, screw, schedule.preload_N)[cut], 1000.0, rtol=1e-9,
                               err_msg="the rigidity at the plan is not the requirement where it binds")
    lift = 1.2 * np.abs(schedule.profile.axial_load_N) / 2.0 ** 1.5
    assert np.min(schedule.preload_N[cut] / lift[cut]) > 1.15, "the plan comes near the lift-off bound"


def _ideal(schedule: PreloadSchedule, screw) -> _Frame:
    """A run that follows the plan exactly over one cycle: the achieved preload is the planned one."""
    t, load = schedule.profile.time_s, schedule.profile.axial_load_N
    plan = np.asarray(schedule.preload_N, float)
    zero = np.zeros_like(plan)
    frame = _Frame(t_cycle=t, cycle=np.ones(t.size, bool), cutting=schedule.profile.cutting, load=load,
                   planned=plan, achieved=plan, required=zero, rigidity=zero, planned_rigidity=zero,
                   deflection=zero, lift_bound=zero, weight=zero)
    return frame_under(frame, screw, schedule.spec)


def test_the_verdicts_name_the_binding_requirement_as_the_designs_own(designs):
    """On a loop that follows the plan exactly the binding requirement is met with nothing to spare: it is named
    apart as the design's own; the other is a margin (the lift-off bound's 16 % on the stiff edit)."""
    default = requirements_of(_ideal(*designs["default"]), designs["default"][0])
    assert [(r.key, r.basis) for r in default] == [(RIGIDITY_KEY, None), ("schedule.deflection_max_um", None),
                                                   (LIFT_OFF_KEY, "design")]
    assert default[2].name == LIFT_OFF_BOUND_VERDICT + OWN_CONSTRAINT and default[2].margin == 0.0
    assert default[0].name == RIGIDITY_VERDICT and default[0].margin_pct > 5.0
    stiff = requirements_of(_ideal(*designs["stiff"]), designs["stiff"][0])
    assert [(r.key, r.basis) for r in stiff] == [(RIGIDITY_KEY, "design"), ("schedule.deflection_max_um", None),
                                                 (LIFT_OFF_KEY, None)]
    rigid, deflection, lift = stiff
    assert rigid.name == RIGIDITY_VERDICT + OWN_CONSTRAINT and lift.name == LIFT_OFF_BOUND_VERDICT
    assert rigid.margin_pct == pytest.approx(0.0, abs=1e-6)
    # the lift-off bound's margin is the plan's at the roughing cut over the closed-form bound 1.2 x 4,000 / 2^1.5
    schedule = designs["stiff"][0]
    plan_4000 = float(np.min(schedule.preload_N[schedule.profile.axial_load_N == 4000.0]))
    assert lift.margin_pct == pytest.approx(100.0 * (plan_4000 / (1.2 * 4000.0 / 2.0 ** 1.5) - 1.0), rel=1e-9)
    assert 15.0 < lift.margin_pct < 20.0
    assert own_constraints(stiff) == (rigid,) and least_margin(stiff) is min((deflection, lift),
                                                                             key=lambda r: r.margin_pct)


def _console(requirements) -> str:
    summary = SimpleNamespace(requirements_met=all(r.met for r in requirements), requirements=requirements,
                              least_margin=least_margin(requirements), missed=(),
                              headline=SimpleNamespace(sensitivity=None))
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        _print_verdict(summary)
    return buffer.getvalue()


def test_the_console_and_the_report_set_the_binding_requirement_apart_on_either_study(designs):
    default = requirements_of(_ideal(*designs["default"]), designs["default"][0])
    text = _console(default)
    assert ("apart from preload against the schedule's lift-off bound while cutting (the design's own constraint), "
            "0 %: a bound the design is built to sit on") in text, text
    (line,) = verdicts(SimpleNamespace(requirements=lambda: default, system=None))
    assert "apart from preload against the schedule's lift-off bound while cutting (the design's own constraint)" \
           in line and line.endswith(": a bound the design is built to sit on."), line
    assert _bound_words(designs["default"][0]) == ", the design's own constraint"

    stiff = requirements_of(_ideal(*designs["stiff"]), designs["stiff"][0])
    text = _console(stiff)
    assert ("apart from rigidity while cutting, where least against its requirement (the design's own constraint), "
            "0 %: a bound the design is built to sit on") in text, text
    assert "apart from preload against the schedule's lift-off bound" not in text, text
    least = least_margin(stiff)
    assert "the least margin: " in text and f"({least.name})" in text and least.basis is None, text
    (line,) = verdicts(SimpleNamespace(requirements=lambda: stiff, system=None))
    assert "apart from rigidity while cutting, where least against its requirement (the design's own constraint)" \
           in line, line
    assert "apart from preload against the schedule's lift-off bound" not in line, line
    words = _bound_words(designs["stiff"][0])
    assert "own constraint" in words and "rigidity required sets the preload" in words, words


def test_the_first_page_says_planned_to_sit_on_only_of_the_binding_requirement(designs):
    """The first page's requirements nearest their limits: the one the schedule binds on is 'a bound the least-friction
    schedule is planned to sit on', one the study's [schedule] table sets but the plan does not sit on is not (the
    stiff edit's lift-off bound, here brought within 5 % of its limit)."""
    from dataclasses import replace

    from piezopreload.reports.summary import _near_limits

    rigid, deflection, lift = requirements_of(_ideal(*designs["stiff"]), designs["stiff"][0])
    near_lift = replace(lift, value=1.05 * lift.limit)
    text = _near_limits((rigid, deflection, near_lift))
    assert text.count("(a bound the least-friction schedule is planned to sit on)") == 1, text
    assert f"{rigid.name}, met by 0 % (a bound the least-friction schedule is planned to sit on)" in text, text
    assert text.endswith(f"{near_lift.name}, met by 5 %."), text


def _lead_and_design_section(path: Path) -> tuple[str, str]:
    """The first page's design lead and the design section's paragraphs of a study's solved design."""
    from piezopreload.reports.inputs import ReportStudy
    from piezopreload.reports.sections import design_section
    from piezopreload.reports.summary import design_lead

    study = load_study(path)
    record = study.design(pareto=[]).record({"study": study.path})
    facts = ReportStudy(study.name, study.title, study.path, study.sha256, study.path)
    lead = " ".join(design_lead(facts, SimpleNamespace(design=record, system=None, requirements=lambda: ())))
    return lead, " ".join(design_section(facts, record).section.paragraphs)


def test_the_report_names_the_load_profile_the_schedule_was_planned_for(tmp_path):
    """The machine axis names no [schedule] profile: its schedule is planned over the built-in machining cycle, whose
    loads are not the [duty] table's, and the report says so rather than 'the study's load profile'; a study that
    names a profile file is planned over it, and the report names the file and its loads."""
    lead, section = _lead_and_design_section(STUDY)
    for text in (lead, section):
        assert "the built-in machining cycle (axial loads -1,500 to 4,000 N; the study names no [schedule] profile" \
               in text, text
        assert "the study's load profile" not in text, text
    t = np.arange(0.0, 4.0, 0.01)
    load = np.where(t < 2.0, 2500.0, -800.0)
    csv = tmp_path / "cycle.csv"
    csv.write_text("time_s,axial_load_N,speed_rpm\n" + "".join(f"{a:.2f},{b:.1f},500\n" for a, b in zip(t, load)))
    text = STUDY.read_text()
    assert text.count("[schedule]\n") == 1
    edited = tmp_path / "profiled.toml"
    edited.write_text(text.replace("[schedule]\n", f"[schedule]\nprofile = \"{csv.name}\"\n"))
    lead, section = _lead_and_design_section(edited)
    for text in (lead, section):
        assert "the study's load profile cycle.csv (axial loads -800 to 2,500 N)" in text, text
        assert "built-in" not in text, text


def _assert_rebuilt_from_the_design(before, out, amp_current_limit_A):
    """A changed design rebuilt the plant and every stage after it (each stage's content key changed), and the plant
    is the new design's, with its amplifier."""
    from piezopreload.artifacts.manifest import StudyRunManifest
    from piezopreload.artifacts.plant import DesignedPlant
    from piezopreload.pipeline import STAGES

    after = StudyRunManifest.load(out).stages
    assert STAGES[0].name == "design"
    rebuilt = [s.name for s in STAGES if after[s.name].status == "done" and after[s.name].key != before[s.name].key]
    assert rebuilt == [s.name for s in STAGES], f"a stage after the changed design was not run again: {rebuilt}"
    assert after["plant"].outputs["plant"].sha256 != before["plant"].outputs["plant"].sha256
    plant = DesignedPlant.load(out / "plant.json")
    assert plant.design_sha256 == after["design"].outputs["design"].sha256
    assert plant.rig.amp_current_limit_A == pytest.approx(amp_current_limit_A), "the plant lacks the new amplifier"


@pytest.mark.slow  # the small whole-system study runs end to end (about a minute)
def test_the_stiff_small_axis_run_names_its_rigidity_as_the_designs_own_and_judges_the_lift_off_bound(
        small_axis_run, tmp_path, capsys):
    """The small whole-system study with the least rigidity at 1,000 N/um, end to end: the system artifact, the
    console and the report call the rigidity the design's own constraint and the lift-off bound a margin, the least
    margin the console leads with being the least among the requirements the design does not sit on.

    It runs in a copy of the small study's own run (tests/conftest.py) with a smaller amplifier too, so that the same
    run shows a changed design rebuilding the plant and every stage after it (one run where two would ask the same of
    the pipeline)."""
    import shutil

    from piezopreload.artifacts.manifest import StudyRunManifest
    from piezopreload.artifacts.registry import read_artifact
    from piezopreload.artifacts.system import SystemRecord
    from piezopreload.cli import main

    text = (Path(__file__).parent / "data" / "small_axis.toml").read_text()
    assert text.count("stiffness_min_N_per_um = 300.0") == 1 and text.count("[design]\n") == 1
    assert "amp_current_limit_A" not in text  # the small study's amplifier is the default one
    study = tmp_path / "stiff_small.toml"
    # one robust gain set, no gain schedule's entries to tune (20 s of the run's 35): what binds the schedule, and
    # what the console and the report call it, is the design's and the wording's, not the loop's form
    assert text.count("schedule_levels = 2\n") == 1
    study.write_text(text.replace("stiffness_min_N_per_um = 300.0", "stiffness_min_N_per_um = 1000.0")
                     .replace("schedule_levels = 2\n", "schedule_levels = 0\n")
                     .replace("[design]\n", "[design]\namp_current_limit_A = 0.08\n"))
    out = tmp_path / "out"
    shutil.copytree(small_axis_run, out)
    (out / ".lock").unlink(missing_ok=True)
    before = StudyRunManifest.load(out).stages
    assert main(["run", str(study), "--out", str(out), "--quiet"]) == 0
    console = capsys.readouterr().out
    _assert_rebuilt_from_the_design(before, out, amp_current_limit_A=0.08)
    system = SystemRecord.load(out / "system" / "system.json")
    by_key = {r.key: r for r in system.requirements}
    rigid, lift = by_key[RIGIDITY_KEY], by_key[LIFT_OFF_KEY]
    assert (rigid.basis, lift.basis) == ("design", None) and rigid.name == RIGIDITY_VERDICT + OWN_CONSTRAINT
    assert 0.0 <= rigid.margin_pct < 1.0 and lift.margin_pct > 10.0, (rigid.margin_pct, lift.margin_pct)
    least = min((r for r in system.requirements if r.basis != "design" and r.margin_pct is not None),
                key=lambda r: r.margin_pct)
    assert f"every requirement met; the least margin: {number(least.margin_pct, '%')} % ({least.name})" in console
    assert (f"  apart from {rigid.name}, {number(rigid.margin_pct, '%')} %: a bound the design is built to sit on"
            in console), console
    assert "apart from preload against the schedule's lift-off bound" not in console, console
    report = str(read_artifact(out / "report" / "report.json", "report"))
    assert "the bound with its 1.2 margin: a margin, the schedule is not built to sit on it" in report
    assert "the rigidity required sets the preload there, the design's own constraint" in report
    assert "lift-off bound while cutting (the design's own constraint)" not in report
    assert "the design's own constraint, the schedule sits on it" in report  # the rigidity's row of the table
    # the system figure's caption names the deflection limit the study sets, and says so where it sets none
    from dataclasses import replace

    from piezopreload.artifacts.design import DesignRecord
    from piezopreload.reports.sections import system_section

    design = DesignRecord.load(out / "design" / "design.json")
    (_, _, caption), = system_section(system, design, None).figures
    assert caption.endswith("the nut's axial deflection under the load against its limit 5 um (dashed)."), caption
    unlimited = replace(system, numbers=replace(system.numbers, deflection_limit_um=None))
    (_, _, caption), = system_section(unlimited, design, None).figures
    assert caption.endswith("the nut's axial deflection under the load (the study sets no limit on it)."), caption


def test_with_a_lower_deflection_limit_both_rows_bind_each_at_its_own_loads(tmp_path):
    """``[schedule] deflection_max_um = 4``: the roughing cut (4,000 N) needs 1,000 N/um, more preload than its
    lift-off bound, while the lighter loads still sit on their lift-off bound: both requirements are the design's own,
    each where it sets the plan, and the schedule figure's caption says both."""
    text = STUDY.read_text()
    old = "deflection_max_um = 5.0 "
    assert text.count(old) == 1
    path = tmp_path / "defl4.toml"
    path.write_text(text.replace(old, "deflection_max_um = 4.0 "))
    study = load_study(path)
    schedule, screw = study.preload_schedule, study.designed_plant.screw
    assert schedule.binding == (RIGIDITY_KEY, LIFT_OFF_KEY)
    where, load = schedule.binding_samples(), schedule.profile.axial_load_N
    assert set(np.unique(load[where[RIGIDITY_KEY]])) == {4000.0}
    assert {-1500.0, 600.0} <= set(np.unique(load[where[LIFT_OFF_KEY]]))
    np.testing.assert_allclose(_rigidity(schedule, screw, schedule.preload_N)[where[RIGIDITY_KEY]], 4000.0 / 4.0,
                               rtol=1e-9, err_msg="the rigidity at the roughing cut is not |F_a| / deflection_max")
    np.testing.assert_allclose(schedule.preload_N[where[LIFT_OFF_KEY]],
                               1.2 * np.abs(load[where[LIFT_OFF_KEY]]) / 2.0 ** 1.5, rtol=1e-9)
    reqs = requirements_of(_ideal(schedule, screw), schedule)
    assert [r.key for r in own_constraints(reqs)] == [RIGIDITY_KEY, LIFT_OFF_KEY]
    text = _console(reqs)
    assert text.count("a bound the design is built to sit on") == 2, text
    words = _bound_words(schedule)
    assert words.count("the design's own constraint") == 2, words


@pytest.mark.parametrize("name", ["default", "stiff"])
def test_ipopts_schedule_binds_on_the_same_rows_at_the_same_samples(designs, name):
    """The schedule solved as an NLP by IPOPT (``method="nlp"``), an independent solver of the same problem, binds on
    the same rows at the same samples as the exact envelope: the tolerance BINDS_WITHIN (1e-6) is above IPOPT's
    optimum's distance from the need (about 1e-8) and below any margin a report states."""
    from piezopreload.design.schedule import schedule_preload

    envelope, screw = designs[name]
    nlp = schedule_preload(screw, envelope.profile, envelope.spec, method="nlp")
    assert nlp.binding == envelope.binding
    for key, where in envelope.binding_samples().items():
        assert np.array_equal(nlp.binding_samples()[key], where), f"{key}: IPOPT binds at other samples"
