"""The report's first page leads with the design, numbers follow one rule per kind of quantity, and a run prints
its requirements.

The first page is typeset by the shipped template from the lead :func:`~piezopreload.reports.summary.design_lead`
builds out of a design record, for the machine axis, the paper's study and an edit of the machine axis (another
screw and a lower bound on the contact angle): every figure it names is read back from the PDF and checked
against the design record the study's own design solved.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from piezopreload.artifacts.manifest import StudyRef
from piezopreload.artifacts.requirements import Requirement, least_margin, own_constraints
from piezopreload.artifacts.sensitivity import SensitivityRecord, SensitivityRow
from piezopreload.core.quantities import RESOLUTION, number, quantity
from piezopreload.core.stages import StageOutcome
from piezopreload.models.thermal import ThermalMounting
from piezopreload.outcome import Headline, StudyResult
from piezopreload.reports.document import Report, fmt, q
from piezopreload.reports.inputs import ReportStudy
from piezopreload.reports.summary import design_lead, verdicts
from piezopreload.reports.typeset import compile_pdf, template_text
from piezopreload.study import load_study

pypdf = pytest.importorskip("pypdf", reason="pypdf (the test extra) reads the report back")

STUDIES = Path(__file__).parents[1] / "studies"


def _edited(tmp_path: Path) -> Path:
    """The machine axis with a 40 x 12 mm screw, the contact angle at most 50 degrees and no Pareto fronts."""
    text = (STUDIES / "machine_axis.toml").read_text()
    for old, new in (("nominal_diameter_mm = 32.0", "nominal_diameter_mm = 40.0"), ("lead_mm = 10.0", "lead_mm = 12.0"),
                     ("contact_angle_deg = [35.0, 55.0]", "contact_angle_deg = [35.0, 50.0]")):
        assert old in text, f"the machine axis' study no longer holds '{old}'"
        text = text.replace(old, new)
    lines = ["pareto = []" if line.startswith("pareto =") else line for line in text.splitlines()]
    path = tmp_path / "edited.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _first_page(study_path: str | Path, tmp_path: Path) -> tuple[str, object, object]:
    """Page 1 of the shipped template with the study's design lead, as pypdf reads it; the design's point."""
    study = load_study(study_path)
    record = study.design().record({"study": study.path})
    plant = study.designed_plant.rig if study.plant_from_design else study.plant
    spec = study.design_spec
    facts = ReportStudy(study.name, study.title, study.path, study.sha256, study.path,
                        screw_mm=(spec.nominal_diameter_mm, spec.lead_mm), stacks=(plant.n_stacks, plant.stack.name))
    artifacts = SimpleNamespace(design=record, system=None, requirements=lambda: ())
    report = Report(study.title, f"Study {study.name}", (), (), (), (), lead=design_lead(facts, artifacts))
    folder = tmp_path / "report"
    folder.mkdir()
    (folder / "report.json").write_text(json.dumps({**report.to_dict(), "study_name": study.name,
                                                    "package_version": "test"}))
    (folder / "report.typ").write_text(template_text())
    (tmp_path / "report.pdf").write_bytes(compile_pdf(folder / "report.typ"))
    text = " ".join((pypdf.PdfReader(tmp_path / "report.pdf").pages[0].extract_text() or "").split())
    return text, record.optimum.point, spec


@pytest.mark.parametrize("which", ["machine_axis", "paper2021", "edited"])
def test_the_first_page_names_the_designed_screw_nuts_and_contact_angle(which, tmp_path):
    path = _edited(tmp_path) if which == "edited" else STUDIES / f"{which}.toml"
    text, p, spec = _first_page(path, tmp_path)
    screw = f"{number(spec.nominal_diameter_mm, 'mm')} x {number(spec.lead_mm, 'mm')} mm"
    assert screw in text, f"page 1 does not name the screw '{screw}': {text[:400]}"
    assert f"contact angle {number(p.contact_angle_deg, 'deg')}°" in text, text[:400]
    assert f"{p.turns:.0f} loaded turns x {p.balls_per_turn:.0f} balls of {number(p.ball_mm, 'mm', 4)} mm" in text
    assert f"groove conformity {number(p.conformity)}" in text
    assert "stacks" in text and "preload schedule" in text
    if which == "edited":  # the edit's own screw and bound, not the default's
        assert "40 x 12 mm" in text and "32 x 10 mm" not in text and p.contact_angle_deg <= 50.0 + 1e-9
    # what limits it: the variables the optimum holds at their bounds, in words
    assert "at its upper bound" in text or "at its lower bound" in text


def test_the_first_page_says_which_requirement_is_nearest_without_config_key_text(tmp_path):
    lift = Requirement("preload against the lift-off bound while cutting", 1706.1, 1697.06, "N", "min",
                       "[schedule] lift_off_margin (lift_off_margin |F_a| / 2^(3/2))")
    rigid = Requirement("rigidity while cutting", 1126.2, 800.0, "N/um", "min", "[schedule] deflection_max_um")
    artifacts = SimpleNamespace(requirements=lambda: (lift, rigid), system=None)
    (line,) = verdicts(artifacts)
    assert "lift_off_margin" not in line and "[schedule]" not in line and "2^(3/2)" not in line
    assert "preload against the lift-off bound while cutting: 1,706 N against at least 1,697 N" in line
    assert "met with 9 N to spare (0.53 %)" in line


# --------------------------------------------------------------------------------------
# one formatting rule per kind of quantity
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(("x", "unit", "text"), [
    (0.00211, "um", "< 0.1"),  # a length below the Hertz and thermal models' tolerance
    (3.1489, "um", "3.1"),
    (0.0284, "N", "< 0.1"),  # a force below what the sensors resolve
    (0.416, "N", "0.4"),
    (1706.09, "N", "1,706"),
    (13236.4, "N", "13,236"),  # whole numbers stay whole, never 1.32e+04
    (0.0296, "%", "0.03"),
    (40.83, "%", "40.8"),
    (0.3218, "s", "0.322"),  # a time to the loop's millisecond
    (0.0145, "s", "0.015"),
    (1126.2, "N/um", "1,126"),
    (999.96, "N", "1,000"),
    (0.0107712, "", "0.0108"),  # a unit without a resolution keeps its significant digits
    (1e-05, "", "0.00001"),  # and no scientific notation
])
def test_a_number_carries_the_precision_its_unit_justifies(x, unit, text):
    assert number(x, unit) == text, f"{x} {unit}"
    assert quantity(x, unit) == f"{text} {unit}".rstrip()


def test_the_report_the_verdicts_and_the_console_print_a_quantity_alike():
    r = Requirement("axial deflection while cutting", 3.1489, 5.0, "um", "max", "[schedule] deflection_max_um")
    shown = q(3.1489, "um")
    assert shown == "3.1 um" == f"{fmt(3.1489, 3, 'um')} um"
    assert f"{shown} against at most 5 um" in r.sentence()
    assert r.line().split()[3:5] == ["3.1", "um"]  # met, the margin and its %, then the figures
    assert f"{number(r.margin_pct, '%')} %" in r.sentence() and f"+{number(r.margin_pct, '%')} %" in r.line()
    assert set(RESOLUTION) >= {"N", "um", "N/um", "s", "V", "W", "K", "%"}


def test_a_missing_number_is_refused_not_printed():
    for bad in (None, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="cannot be printed"):
            number(bad, "N")


# --------------------------------------------------------------------------------------
# print(result)
# --------------------------------------------------------------------------------------
def _result(requirements: tuple[Requirement, ...]) -> StudyResult:
    return StudyResult(Path("/tmp/out"), StudyRef("/tmp/study.toml", "0" * 64, "axis"),
                       (StageOutcome("design", True, "done", 1.0), StageOutcome("tune", False, "up to date", 0.0)),
                       3.2, Headline(), requirements, report=Path("/tmp/out/report.pdf"))


def test_print_result_shows_the_verdict_and_each_requirement_with_its_margin():
    reqs = (Requirement("rigidity while cutting", 1126.2, 800.0, "N/um", "min", "[schedule] deflection_max_um"),
            Requirement("preload against the lift-off bound while cutting", 1706.1, 1697.06, "N", "min"),
            Requirement("thermal growth at the table over the shift", 29.5, 25.0, "um", "max"))
    text = str(_result(reqs))
    lines = text.splitlines()
    assert len(lines) == 5 + len(reqs) and repr(_result(reqs)) == text
    assert "1 of 3 requirements missed" in lines[3] and "exit code 4" in lines[0]
    for r in reqs:
        row = next(line for line in lines if line.endswith(r.name))
        assert ("met" if r.met else "MISSED") in row and f"{number(abs(r.margin_pct or 0.0), '%')} %" in row
        assert f"{number(r.value, r.unit)} {r.unit}" in row and f"{number(r.limit, r.unit)} {r.unit}" in row
    html = _result(reqs)._repr_html_()
    assert all(r.name in html for r in reqs) and "40.8 %" in html and "missed" in html


def test_the_least_margin_leaves_the_designs_own_constraint_aside():
    """The schedule is built to sit on its lift-off bound (its margin is small by construction): the least margin
    a user reads is the least of what the physics grants, the design's own constraint named apart."""
    own = Requirement("preload against the schedule's lift-off bound while cutting", 1706.1, 1697.06, "N", "min",
                      basis="design")
    physical = Requirement("lift-off load by the nut law against the cutting load", 1263.0, 1240.0, "N", "min",
                           basis="physics")
    rigid = Requirement("rigidity while cutting", 901.1, 800.0, "N/um", "min")
    assert least_margin((own, physical, rigid)) is physical
    assert own_constraints((rigid, own, physical)) == (own,)
    assert least_margin((own,)) is own  # nothing else has a margin: the constraint is the least there is
    (line,) = verdicts(SimpleNamespace(requirements=lambda: (own, physical, rigid), system=None))
    assert "the nearest to its limit: lift-off load by the nut law against the cutting load: 1,263 N" in line, line
    assert "apart from preload against the schedule's lift-off bound while cutting: 1,706 N" in line, line
    assert ": a bound the design is built to sit on" in line, line


def test_print_result_of_a_run_that_met_everything_names_the_nearest():
    reqs = (Requirement("rigidity while cutting", 1126.2, 800.0, "N/um", "min"),
            Requirement("preload against the lift-off bound while cutting", 1706.1, 1697.06, "N", "min"))
    text = str(_result(reqs))
    assert "every requirement met (2 checked)" in text and "0.53 %: preload against the lift-off bound" in text
    assert str(_result(())).splitlines()[3].strip() == "verdict: no requirement checked"


def test_a_missed_growth_names_its_heat_in_the_verdict():
    """The stiff variant of the machine axis (rigidity at least 1,000 N/um) misses on growth: the verdict says what
    heats the screw, from the thermal record (the figures here are that run's)."""
    growth = Requirement("thermal growth at the table over the shift", 45.3, 25.0, "um", "max",
                         "[thermal] thermal_growth_max_um")
    case = SimpleNamespace(heat_mean_W=50.04, preload_mean_N=1070.2, bearing_heat_mean_W=46.1,
                           temperature_rise_max_K=9.71)
    thermal = SimpleNamespace(shift_h=8.0, schedule=case, mounting=ThermalMounting.PRETENSIONED, pretension_K=3.0,
                              constant=SimpleNamespace(heat_mean_W=107.5, preload_mean_N=1697.1))
    artifacts = SimpleNamespace(requirements=lambda: (growth,),
                                system=SimpleNamespace(thermal=thermal, sensitivity=None))
    (line,) = verdicts(artifacts)
    assert line.startswith("Requirement missed: thermal growth at the table over the shift: 45.3 um against at most "
                           "25 um, missed by 20.3 um (81.2 %)"), line
    assert "the nut's friction heat is 50 W at a mean preload of 1,070 N (108 W at the best constant 1,697 N)" in line
    assert "the support bearings' 46.1 W" in line and "9.7 K" in line and "first 3 K" in line


def test_the_verdict_states_its_robustness_only_where_the_system_stage_judged_it():
    met = Requirement("rigidity while cutting", 1126.2, 800.0, "N/um", "min")

    def row(low_pct: float, flips_at: float | None) -> SensitivityRow:
        return SensitivityRow(assumption="the seals' torque", key="thermal.seal_torque_Nm", unit="N m",
                              source="Rexroth", requirement="thermal.thermal_growth_max_um",
                              requirement_name="thermal growth at the table over the shift", nominal=0.25, low=0.0,
                              high=0.5, margin_pct_nominal=37.0, margin_pct_low=89.0, margin_pct_high=low_pct,
                              domain=(0.0, 2.0), flips_at=flips_at)

    def lead(record: SensitivityRecord | None) -> tuple[str, ...]:
        return verdicts(SimpleNamespace(requirements=lambda: (met,), system=SimpleNamespace(sensitivity=record,
                                                                                            thermal=None)))

    absent, robust = lead(None), lead(SensitivityRecord(rows=(row(12.0, 0.8),)))
    fragile = lead(SensitivityRecord(rows=(row(-4.0, 0.45),)))
    assert len(absent) == 1 and "robust" not in absent[-1]
    assert "verdict robust over 1 assumptions' ranges" in robust[-1], robust
    assert "verdict not robust" in fragile[-1] and "thermal growth at the table over the shift flips with the " \
        "seals' torque 0.5 N m (missed, -4.0 %, flips at 0.45 N m)" in fragile[-1], fragile
