"""One declared type per concept (issue 42's leftovers): no result forwards another's fields, the records that
carry the thermal figures, the gain schedule and the rig run's safety and pushes, the enums that choose behaviour
in the study's tables, and the study's verbs documented once."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from piezopreload.artifacts.manifest import StudyRef
from piezopreload.models.controller import PIDGains
from piezopreload.results import StudyReproduction
from piezopreload.tuning.compare import PublishedRow

ROOT = Path(__file__).parents[1]


def _forwarders(source: str) -> list[str]:
    """The properties whose body (past a docstring) only returns an attribute of one of the object's own fields
    (``return self.field.attr``): a result that forwards what another result holds."""
    found = []
    for cls in (n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef)):
        for fn in cls.body:
            if not (isinstance(fn, ast.FunctionDef)
                    and any(isinstance(d, ast.Name) and d.id == "property" for d in fn.decorator_list)):
                continue
            body = [s for s in fn.body if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))]
            value = body[0].value if len(body) == 1 and isinstance(body[0], ast.Return) else None
            if (isinstance(value, ast.Attribute) and isinstance(value.value, ast.Attribute)
                    and isinstance(value.value.value, ast.Name) and value.value.value.id == "self"):
                found.append(f"{cls.name}.{fn.name} -> {ast.unparse(value)}")
    return found


def test_the_forwarder_check_can_fail():
    source = '''
class Outer:
    @property
    def rows(self):
        """The rows."""
        return self.comparison.rows

    @property
    def within(self):
        return all(r.ok for r in self.rows)
'''
    assert _forwarders(source) == ["Outer.rows -> self.comparison.rows"]


def test_the_study_results_forward_nothing():
    """What the study's simulating steps return holds its own numbers: no property hands on another result's."""
    found = _forwarders((ROOT / "piezopreload" / "results.py").read_text(encoding="utf-8"))
    assert not found, "forwarding properties:\n" + "\n".join(found)


def _reproduction(within: tuple[bool, ...]) -> StudyReproduction:
    rows = tuple(PublishedRow("pid", m, 0.1, 0.1 * (1.1 if ok else 1.5), 1.1 if ok else 1.5, ok, (0.1, 0.2))
                 for m, ok in zip(("rise_s", "peak_s", "settling_s"), within, strict=True))
    return StudyReproduction(StudyRef("s.toml", "0" * 64, "s"), PIDGains(Kc=0.1, Ti_s=0.08, Td_s=0.0), "s", 0.5,
                             "force", "paper", (0.0, 100.0), rows, {"pid": 1.5}, {"rms_pct": 1.0, "max_pct": 2.0},
                             3, 0.25)


def test_a_reproduction_holds_its_rows_and_prints_the_same_keys():
    """``reproduce --json`` prints the keys it printed when the comparison was a record of its own."""
    rep = _reproduction((True, False, True))
    assert list(rep.to_dict()) == ["study", "gains", "band_N", "signal", "published", "step", "feedforward_fit",
                                   "rows", "overshoot_N", "all_within_25pct", "repeats", "seconds"]
    assert rep.to_dict()["all_within_25pct"] is False and _reproduction((True,) * 3).all_within_25pct
    assert rep.row("pid", "peak_s").ratio == 1.5 and rep.repeats == 3
    with pytest.raises(KeyError, match="pid/rise_s, pid/peak_s, pid/settling_s"):
        rep.row("ff+pid", "rise_s")


# --- the thermal figures: one record from the system artifact to run --json --------------------------------------
def _case(scale: float):
    from piezopreload.artifacts.thermal import FIGURES, ThermalCase

    times = np.array([0.5, 1.0])
    return ThermalCase(**{name: scale * (i + 1) for i, name in enumerate(FIGURES)}, times_h=times,
                       rise_along_K=np.ones((2, 3)), nut_rise_K=times, nut_over_screw_K=-times,
                       growth_um=np.ones((2, 2)), elastic_um=np.ones(2), budget_um=np.ones((2, 2)))


def _budget():
    from piezopreload.artifacts.thermal import PreloadDrift, ThermalRecord

    drift = PreloadDrift(100.0, 350.0, -500.0, 1200.0, -520.0, 1700.0, 3.0, 9.0, 70.0)
    return ThermalRecord("contact", "viscous", 68, True, 0.2, 0.5, 1.0, "pretensioned", 3.0, 2000.0, "rotary", 2.5,
                         (100.0, 500.0), np.array([0.0, 300.0, 600.0]), np.array([100.0, 500.0]), 20.0, 900.0,
                         _case(1.0), _case(2.0), drift)


def test_the_figures_are_the_thermal_cases_own_scalar_fields():
    """The summary's and the sweep's figure names are the case's fields, in their order (as they were listed)."""
    from piezopreload.artifacts.thermal import FIGURES

    assert FIGURES == ("heat_mean_W", "heat_mean_other_W", "seal_heat_mean_W", "bearing_heat_mean_W",
                       "preload_mean_N", "temperature_rise_max_K", "rise_max_at_mm", "temperature_rise_max_other_K",
                       "nut_rise_max_K", "nut_over_screw_end_K", "end_force_max_N", "bearing_force_max_N",
                       "growth_max_um", "growth_max_other_um", "positioning_error_max_um", "tracking_um")


def test_the_system_summarys_thermal_figures_are_a_record_that_writes_the_same_document():
    from piezopreload.artifacts.summaries import SystemSummary
    from piezopreload.artifacts.thermal import FIGURES, ThermalSummary

    budget = _budget()
    summary = budget.summary()
    doc = summary.to_dict()
    # run --json's and system.json's keys: each figure as {"schedule", "constant"}, then the settings and the words
    assert list(doc)[:len(FIGURES)] == list(FIGURES)
    assert all(doc[name] == {"schedule": 1.0 * (i + 1), "constant": 2.0 * (i + 1)} for i, name in enumerate(FIGURES))
    assert list(doc)[len(FIGURES):] == ["heat_model", "other_model", "lubricant_vg", "sealed", "seal_torque_Nm",
                                        "nut_heat_share", "convection_factor", "mounting", "pretension_K",
                                        "bearing_lift_off_N", "feedback", "shift_h", "stroke_mm",
                                        "film_mean_W_per_m2K", "screw_time_constant_s", "drift", "rise_max_place",
                                        "nut_against_screw", "ends"]
    assert doc["drift"]["held"] is True and doc["ends"]["schedule"] == budget.ends_words(budget.schedule)
    back = ThermalSummary.from_dict(doc)
    assert back == summary and back.figure("growth_max_um", "constant") == budget.constant.growth_max_um
    assert {f.name: f.type for f in dataclasses.fields(SystemSummary)}["thermal"] == "ThermalSummary | None"


def test_a_thermal_summary_names_a_wrong_figure_where_the_document_holds_it():
    from piezopreload.artifacts.thermal import FigurePair, ThermalSummary
    from piezopreload.core.errors import ArtifactError

    doc = _budget().summary().to_dict()
    doc["growth_max_um"] = {"schedule": 1.0}
    with pytest.raises(ArtifactError, match=r"s\.json: field 'thermal\.growth_max_um\.constant' is missing"):
        ThermalSummary.from_dict(doc, "s.json", path="thermal")
    with pytest.raises(ValueError, match="growth_um is no figure of a thermal case"):
        dataclasses.replace(_budget().summary(), figures={"growth_um": FigurePair(1.0, 2.0)})
