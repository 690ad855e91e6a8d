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
    return ThermalRecord("contact", "catalogue", 68, True, 0.2, 0.5, 1.0, "pretensioned", 3.0, 2000.0, "linear-scale",
                         2.5, (100.0, 500.0), np.array([0.0, 300.0, 600.0]), np.array([100.0, 500.0]), 20.0, 900.0,
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


# --- the gain schedule: one record from the tuning to the report's figure -----------------------------------------
def _schedule_doc():
    """A gain schedule's record as the tune stage first wrote it (no per-level Ms, no bound), the figures rounded."""
    def worst(tracking, passed=True):
        return {"settling_s": 0.2, "overshoot_N": 10.0, "tracking_rms_N": tracking, "peak_voltage_V": None,
                "passed": passed, "failures": [] if passed else ["tracking_rms_N"]}

    gains = [{"Kc_V_per_N": kc, "Ti_s": ti, "Td_s": 0.0, "Tf_s": 0.0005, "b": 0.5}
             for kc, ti in ((0.012, 0.0034), (0.0115, 0.0447))]
    return {"choice": "schedule", "reason": "the robust set misses the specification at 2,000 N",
            "levels_N": [0.0, 2000.0],
            "table": {"levels_N": [0.0, 2000.0], "Kc_V_per_N": [0.012, 0.0115], "Ti_s": [0.0034, 0.0447],
                      "Td_s": [0.0, 0.0], "interpolation": "linear"},
            "Tf_s": 0.0005, "b": 0.5, "robust": {"Kc_V_per_N": 0.0108, "Ti_s": 0.0486, "Td_s": 0.0, "Tf_s": 0.0005,
                                                 "b": 0.5},
            "levels": [{"level_N": lv, "window_N": [lo, hi], "entry": g, "tuning": {"ms": 1.6}, "robust": worst(r, ok),
                        "scheduled": worst(s)}
                       for lv, (lo, hi), g, r, ok, s in zip((0.0, 2000.0), ((0.0, 1000.0), (1000.0, 2000.0)), gains,
                                                            (30.0, 45.0), (True, False), (15.9, 17.4))],
            "whole_range": {"robust": worst(31.0), "scheduled": worst(20.0)}, "plants": 50,
            "figures": ["settling_s", "overshoot_N", "tracking_rms_N", "peak_voltage_V"],
            "limits": {"tracking_rms_N": 40.0, "overshoot_N": 25.0}, "seconds": 12.0}


def test_a_gain_schedule_written_before_reads_into_its_record_and_writes_back():
    from piezopreload.artifacts.tuning import GainScheduleRecord, TuningSolve

    doc = _schedule_doc()
    sched = GainScheduleRecord.from_dict(doc, "tuning.json", path="solve.schedule")
    back = sched.to_dict()
    back["table"]["interpolation"] = "linear"  # the table states the interpolation as the model writes it now
    assert back == doc
    assert sched.levels[1].of("robust").tracking_rms_N == 45.0 and sched.levels[1].ms is None
    assert sched.chosen_set == "scheduled" and sched.table.Ti_s == (0.0034, 0.0447)
    assert {f.name: f.type for f in dataclasses.fields(TuningSolve)}["schedule"] == "GainScheduleRecord | None"
    with pytest.raises(ValueError, match=r"tuning\.json: field 'solve\.schedule\.levels\[1\]\.robust\.passed' is "
                                         r"missing"):
        bad = _schedule_doc()
        del bad["levels"][1]["robust"]["passed"]
        GainScheduleRecord.from_dict(bad, "tuning.json", path="solve.schedule")


def test_the_gain_schedules_figure_draws_its_record():
    from piezopreload.artifacts.tuning import GainScheduleRecord
    from piezopreload.reports import figures

    sched = GainScheduleRecord.from_dict(_schedule_doc())
    fig = figures.gain_schedule(sched)
    kc = fig.axes[0].lines
    np.testing.assert_allclose(kc[1].get_ydata(), [12.0, 11.5], err_msg="the entries' Kc (mV/N) are not the table's")
    np.testing.assert_allclose(kc[2].get_ydata(), [10.8, 10.8], err_msg="the robust set's Kc is not the record's")
    worst = fig.axes[2].lines
    np.testing.assert_allclose(worst[0].get_ydata(), [30.0, 45.0], err_msg="the robust set's tracking RMS per level")
    assert fig._suptitle.get_text() == "chosen: the scheduled gains"


# --- the study: the parsed tables and nothing derived kept beside them ---------------------------------------------
def test_the_study_keeps_no_twin_of_its_reference_and_design_tables():
    """``references`` and ``design_spec`` are made from the tables when asked: a study whose tables change (a copy
    with another step, another screw) cannot hold the old ones beside them."""
    from piezopreload.spec import StudySpec
    from piezopreload.study import load_study
    from piezopreload.tables import StepTable

    assert {"references", "design_spec"}.isdisjoint(f.name for f in dataclasses.fields(StudySpec))
    study = load_study("machine_axis")
    step = dataclasses.replace(study.reference.step, final_N=study.reference.step.final_N + 100.0)
    changed = dataclasses.replace(study, reference=dataclasses.replace(study.reference, step=step),
                                  ballscrew=dataclasses.replace(study.ballscrew, lead_mm=study.ballscrew.lead_mm * 2))
    assert changed.references["step"].levels_N[-1] == study.references["step"].levels_N[-1] + 100.0
    assert changed.references["step"].levels_N[-1] == StepTable.reference(step).levels_N[-1]
    assert changed.design_spec.lead_mm == 2 * study.design_spec.lead_mm
    assert not study.same_design(changed)


# --- enums where strings chose behaviour ---------------------------------------------------------------------------
MACHINE_AXIS = ROOT / "studies" / "machine_axis.toml"


def _axis_with(tmp_path, line_start: str, value: str) -> Path:
    """The machine axis' study with the key on the line starting ``line_start`` set to ``value``."""
    lines = MACHINE_AXIS.read_text(encoding="utf-8").splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(line_start))
    lines[at] = f'{line_start.split("=")[0].strip()} = "{value}"'
    path = tmp_path / "axis.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


ENUM_KEYS = [("mounting = \"fixed-fixed\"", "feed_drive.mounting", "fixed-fixed, fixed-supported"),
             ("heat_model = ", "thermal.heat_model", "catalogue, contact"),
             ("mounting = \"pretensioned\"", "thermal.mounting", "fixed-free, fixed-fixed, pretensioned"),
             ("feedback = ", "thermal.feedback", "semi-closed, linear-scale"),
             ("signal = ", "simulation.signal", "measured_N, force_N"),
             ("objective = ", "design.objective", "stiffness, drag, life")]


@pytest.mark.parametrize(("line_start", "key", "allowed"), ENUM_KEYS, ids=[k for _, k, _ in ENUM_KEYS])
def test_a_study_key_that_chooses_behaviour_refuses_a_value_it_does_not_know_in_one_line(tmp_path, line_start, key,
                                                                                           allowed):
    from piezopreload.core.errors import InputError
    from piezopreload.study import load_study

    path = _axis_with(tmp_path, line_start, "sideways")
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if text.endswith('= "sideways"'))
    with pytest.raises(InputError) as err:
        load_study(path)
    assert str(err.value) == f"{path}:{line}: '{key}' must be one of {allowed}, got 'sideways'"


def test_the_study_keys_that_choose_behaviour_are_read_into_their_enums_and_written_as_their_strings(tmp_path):
    from piezopreload.core.config import toml_text
    from piezopreload.models.feed_drive import Mounting
    from piezopreload.models.thermal import Feedback, HeatModel, ThermalMounting
    from piezopreload.study import load_study

    study = load_study(_axis_with(tmp_path, "heat_model = ", "contact"))
    t = study.thermal
    assert (t.heat_model, t.mounting, t.feedback) == (HeatModel.CONTACT, ThermalMounting.PRETENSIONED,
                                                      Feedback.SEMI_CLOSED)
    assert all(type(x) is cls for x, cls in ((t.heat_model, HeatModel), (t.mounting, ThermalMounting),
                                             (t.feedback, Feedback), (study.feed_drive.mounting, Mounting)))
    assert study.design_spec.feed_drive.mounting is Mounting.FIXED_FIXED
    assert t.heat_model.other is HeatModel.CATALOGUE
    written = t.to_dict()
    assert type(written["heat_model"]) is str and written["heat_model"] == "contact"
    assert 'heat_model = "contact"' in toml_text({"thermal": written})


def test_the_thermal_record_writes_and_reads_its_enums_as_the_same_strings():
    from piezopreload.artifacts.thermal import ThermalRecord, ThermalSummary
    from piezopreload.core.errors import ArtifactError
    from piezopreload.models.thermal import Feedback, HeatModel, ThermalMounting

    budget = _budget()
    assert (budget.heat_model, budget.other_model, budget.mounting, budget.feedback) == (
        HeatModel.CONTACT, HeatModel.CATALOGUE, ThermalMounting.PRETENSIONED, Feedback.LINEAR_SCALE)
    doc = budget.to_dict()
    assert [type(doc[k]) for k in ("heat_model", "mounting", "feedback")] == [str, str, str]
    assert (doc["heat_model"], doc["mounting"], doc["feedback"]) == ("contact", "pretensioned", "linear-scale")
    back = ThermalRecord.from_dict(doc)
    assert back.mounting is ThermalMounting.PRETENSIONED and back.feedback is Feedback.LINEAR_SCALE
    with pytest.raises(ArtifactError, match=r"s\.json: field 'mounting' must be one of fixed-free, fixed-fixed, "
                                            r"pretensioned, got 'sideways'"):
        ThermalSummary.from_dict({**budget.summary().to_dict(), "mounting": "sideways"}, "s.json")


def _axis_adding(tmp_path, table: str, line: str) -> Path:
    """The machine axis' study with ``line`` added at the top of ``[table]`` (a key the study does not set)."""
    lines = MACHINE_AXIS.read_text(encoding="utf-8").splitlines()
    at = lines.index(f"[{table}]")
    path = tmp_path / "axis.toml"
    path.write_text("\n".join([*lines[:at + 1], line, *lines[at + 1:]]) + "\n", encoding="utf-8")
    return path


#: the keys the machine axis leaves at their defaults: (table, key, what a study may give)
ADDED_ENUM_KEYS = [("design", "method", "sequential, codesign"), ("learning", "method", "norm-optimal, p-type")]


@pytest.mark.parametrize(("table", "name", "allowed"), ADDED_ENUM_KEYS, ids=[f"{t}.{k}" for t, k, _ in ADDED_ENUM_KEYS])
def test_a_method_that_chooses_behaviour_refuses_a_value_it_does_not_know_in_one_line(tmp_path, table, name, allowed):
    from piezopreload.core.errors import InputError
    from piezopreload.study import load_study

    path = _axis_adding(tmp_path, table, f'{name} = "sideways"')
    line = path.read_text().splitlines().index(f"[{table}]") + 2
    with pytest.raises(InputError) as err:
        load_study(path)
    assert str(err.value) == f"{path}:{line}: '{table}.{name}' must be one of {allowed}, got 'sideways'"


def test_the_signal_objective_and_methods_are_read_into_their_enums_and_written_as_their_strings(tmp_path):
    from piezopreload.artifacts.learned import LearningMethod
    from piezopreload.core.config import toml_text
    from piezopreload.design.preload import Objective
    from piezopreload.design.tables import DesignMethod
    from piezopreload.models.metrics import Signal
    from piezopreload.study import load_study

    path = _axis_with(tmp_path, "objective = ", "drag")
    text = path.read_text().replace("[learning]\n", '[learning]\nmethod = "p-type"\n')
    path.write_text(text.replace("[design]\n", '[design]\nmethod = "codesign"\n'))
    study = load_study(path)
    got = (study.simulation.signal, study.design_table.objective, study.design_table.method, study.learning.method)
    assert got == (Signal.MEASURED, Objective.DRAG, DesignMethod.CODESIGN, LearningMethod.P_TYPE)
    assert [type(x) for x in got] == [Signal, Objective, DesignMethod, LearningMethod]
    assert study.signal is Signal.MEASURED and Signal.MEASURED.words == "measured force"
    for table, key, value in ((study.simulation, "signal", "measured_N"), (study.design_table, "objective", "drag"),
                              (study.design_table, "method", "codesign"), (study.learning, "method", "p-type")):
        written = table.to_dict()[key]
        assert type(written) is str and written == value, key
        assert f'{key} = "{value}"' in toml_text({"t": table.to_dict()})


def test_the_artifacts_written_before_read_their_signal_and_learning_law_into_the_enums_and_write_them_back():
    import json

    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.artifacts.learned import LearningMethod
    from piezopreload.artifacts.learning import LearningRecord
    from piezopreload.artifacts.responses import ResponsesRecord
    from piezopreload.core.errors import ArtifactError
    from piezopreload.models.metrics import Signal

    data = ROOT / "tests" / "data" / "artifacts"
    gains = GainSet.load(data / "gains.json")
    assert gains.criteria.signal is Signal.FORCE
    assert gains.to_dict()["criteria"]["signal"] == json.loads((data / "gains.json").read_text())["criteria"]["signal"]
    responses = ResponsesRecord.load(data / "responses.json")
    assert responses.signal is Signal.MEASURED and type(responses.to_dict()["signal"]) is str
    learning = LearningRecord.load(data / "learning.json")
    assert {p.method for p in learning.passes} == {LearningMethod.NORM_OPTIMAL}
    assert [type(p.to_dict()["method"]) for p in learning.passes] == [str] * len(learning.passes)
    doc = json.loads((data / "responses.json").read_text())
    body = {k: v for k, v in doc.items() if k not in ("schema", "package_version", "sha256")}
    with pytest.raises(ArtifactError, match=r"field 'signal' must be one of measured_N, force_N, got 'force'"):
        ResponsesRecord.from_dict({**body, "signal": "force"})  # the old record took any string
    # made in code from the strings, as a caller writes them: the members, and a string that names none refused
    assert dataclasses.replace(responses, signal="force_N").signal is Signal.FORCE
    assert dataclasses.replace(learning.passes[0], method="p-type").method is LearningMethod.P_TYPE
    with pytest.raises(ValueError, match="signal must be one of measured_N, force_N, got 'force'"):
        dataclasses.replace(responses, signal="force")
    with pytest.raises(ValueError, match="method must be one of norm-optimal, p-type, got 'p'"):
        dataclasses.replace(learning.passes[0], method="p")


def test_a_run_scores_the_signal_it_is_given_and_refuses_one_it_does_not_know():
    from piezopreload.models.actuator import Plant, Rig
    from piezopreload.models.closedloop import Reference, simulate
    from piezopreload.models.controller import Controller
    from piezopreload.models.metrics import Signal, step_metrics

    rig = Rig(Plant())
    gains = PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001)  # the paper's (tuning.calibrate.PAPER_GAINS)
    run = simulate(rig, Controller(gains, rig.dt_s), Reference.step(25.0, 60.0, 0.5, 5.0), seed=3)
    k = run.t_s >= 0.5
    for signal, y in ((Signal.MEASURED, run.measured_N), (Signal.FORCE, run.force_N)):
        expected = step_metrics(run.t_s[k], y[k], 60.0, initial=25.0, t_step=float(run.t_s[k][0]), band=1.5)
        assert run.step_metrics(1.5, signal=signal) == expected == run.step_metrics(1.5, signal=str(signal))
    assert np.isfinite(expected.settling_s)  # the step settles: the numbers compared are numbers
    assert run.step_metrics(1.5, signal=Signal.MEASURED) != run.step_metrics(1.5, signal=Signal.FORCE)
    with pytest.raises(ValueError, match="'force' is not a valid Signal"):
        run.step_metrics(1.5, signal="force")


def test_the_thermal_section_words_follow_the_records_enums_given_as_strings():
    """A record given its enums as strings (as a document or a caller writes them) holds the members, so the report's
    words that the members choose follow them: the pretension named, the ends' bearings described."""
    from piezopreload.reports.thermal import thermal_section

    budget = _budget()  # made with "pretensioned" and "linear-scale" as strings
    text = " ".join(p for p in thermal_section(budget).section.paragraphs if isinstance(p, str))
    assert "pretensioned (3 K of pretension)" in text and "Each end is a preloaded bearing pair" in text
    free = dataclasses.replace(budget, mounting="fixed-free")
    text = " ".join(p for p in thermal_section(free).section.paragraphs if isinstance(p, str))
    assert "K of pretension" not in text and "Each end is a preloaded bearing pair" not in text


@pytest.mark.parametrize(("command", "option", "allowed"), [("design", "--objective", "'stiffness', 'drag', 'life'"),
                                                          ("learn", "--method", "'norm-optimal', 'p-type'")])
def test_the_command_line_names_an_enums_values_as_the_strings_it_takes(capsys, command, option, allowed):
    from piezopreload.cli import main

    assert main([command, option, "sideways"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"invalid choice: 'sideways' (choose from {allowed})" in err[0], err
    assert err[0].startswith("error: ")


def test_a_references_interpolation_is_an_enum_read_and_written_as_its_string():
    from piezopreload.core.errors import InputError
    from piezopreload.models.closedloop import Interpolation, Reference

    ramp = Reference(np.array([0.0, 1.0]), np.array([10.0, 30.0]), 2.0, "linear")  # given as a caller writes it
    assert ramp.interpolation is Interpolation.LINEAR and not ramp.is_step
    np.testing.assert_allclose(ramp.at(np.array([0.25, 0.5, 1.5])), [15.0, 20.0, 30.0], rtol=0, atol=1e-12)
    doc = ramp.to_dict()
    assert type(doc["interpolation"]) is str and doc["interpolation"] == "linear"
    assert Reference.from_dict(doc).interpolation is Interpolation.LINEAR
    held = Reference.step(25.0, 60.0, 0.5, 1.0)
    assert held.interpolation is Interpolation.HOLD and held.is_step and "interpolation" not in held.to_dict()
    with pytest.raises(InputError, match="interpolation must be one of hold, linear, got 'ramp'"):
        Reference.from_dict({**doc, "interpolation": "ramp"})


def test_the_gain_schedules_choice_is_an_enum_read_and_written_as_its_string():
    from piezopreload.artifacts.tuning import GainScheduleRecord, ScheduleChoice
    from piezopreload.core.errors import ArtifactError

    sched = GainScheduleRecord.from_dict(_schedule_doc())
    assert sched.choice is ScheduleChoice.SCHEDULE and sched.choice.words == "the scheduled gains"
    assert type(sched.to_dict()["choice"]) is str and sched.to_dict()["choice"] == "schedule"
    with pytest.raises(ArtifactError, match=r"field 'choice' must be one of robust, schedule, got 'both'"):
        GainScheduleRecord.from_dict({**_schedule_doc(), "choice": "both"})
    with pytest.raises(ValueError, match="choice must be one of robust, schedule, got 'both'"):
        dataclasses.replace(sched, choice="both")


# --- the study's verbs: each parameter documented once, on the steps function --------------------------------------
STEP_METHODS = {"design": "design", "measured_loop": "measured_loop", "identify_feedforward": "identify",
                "learn": "learn", "learn_schedule": "learn_schedule", "track_schedule": "track_schedule",
                "tune": "tune", "validate": "validate", "simulate": "simulate", "reproduce": "reproduce"}


@pytest.mark.parametrize("method", list(STEP_METHODS))
def test_a_study_method_documents_its_parameters_in_the_words_of_the_step_it_calls(method):
    """Each parameter of ``Study.<method>`` is documented by the very entry of the steps function it calls (one text,
    so they cannot drift)."""
    import inspect

    from numpydoc.docscrape import NumpyDocString

    from piezopreload import steps
    from piezopreload.study import Study

    def entries(fn):
        return {name.strip(): (p.type, p.desc) for p in NumpyDocString(inspect.getdoc(fn))["Parameters"]
                for name in p.name.split(",")}

    mine, step = entries(getattr(Study, method)), entries(getattr(steps, STEP_METHODS[method]))
    params = [n for n in inspect.signature(getattr(Study, method)).parameters if n != "self"]
    assert sorted(mine) == sorted(params), f"Study.{method} documents {sorted(mine)}, takes {params}"
    for name in params:
        assert mine[name] == step[name], f"Study.{method}'s {name} is not documented as steps.{STEP_METHODS[method]}"


def test_the_shared_parameters_refuse_a_method_they_cannot_document():
    from piezopreload import study

    def step(spec, solved, seed=None):
        """A step.

        Parameters
        ----------
        spec, solved : object
            The study and what it solved.
        seed : int, optional
            The seed.
        """

    def method(self, seed=None, plants=None):
        """A verb."""

    with pytest.raises(TypeError, match="documents no plants; document it there, once"):
        study._parameters_of(step)(method)

    def own(self, seed=None):
        """A verb.

        Parameters
        ----------
        seed : int
            Its own words.
        """

    with pytest.raises(TypeError, match="write none of its own"):
        study._parameters_of(step)(own)


# --- the rig run: its limits and its served pushes as records ------------------------------------------------------
RUN_JSON = ROOT / "tests" / "data" / "artifacts" / "run.json"


def test_a_sidecar_written_before_reads_its_limits_into_the_safety_record_and_writes_them_back():
    import json

    from piezopreload.artifacts.rigrun import RigRunRecord, Safety
    from piezopreload.core.errors import ArtifactError

    written = json.loads(RUN_JSON.read_text())
    record = RigRunRecord.load(RUN_JSON)
    assert isinstance(record.safety, Safety) and record.safety.force_max_N == written["safety"]["force_max_N"]
    assert record.safety.force_low_N == written["safety"]["bolt_preload_N"] - written["safety"]["force_low_margin_N"]
    assert record.to_dict()["safety"] == written["safety"]
    body = {k: v for k, v in written.items() if k not in ("schema", "package_version", "sha256")}
    body["safety"] = {k: v for k, v in written["safety"].items() if k != "stall_limit_s"}
    with pytest.raises(ArtifactError, match=r"field 'safety\.stall_limit_s' is missing"):
        RigRunRecord.from_dict(body)  # a limit the run used is never taken from the defaults


def test_a_sidecars_limit_sources_are_a_record_with_one_field_per_limit_written_back_key_for_key():
    import json

    from piezopreload.artifacts.rigrun import RigRunRecord, Safety, SafetySources
    from piezopreload.core.errors import ArtifactError

    assert {f.name for f in dataclasses.fields(SafetySources)} == {f.name for f in dataclasses.fields(Safety)}
    written = json.loads(RUN_JSON.read_text())
    sources = RigRunRecord.load(RUN_JSON).safety_sources
    assert isinstance(sources, SafetySources)
    assert (sources.force_max_N, sources.stall_limit_s) == (written["safety_sources"]["force_max_N"], "the plant")
    assert list(sources.to_dict().items()) == list(written["safety_sources"].items())  # the same keys, in order
    body = {k: v for k, v in written.items() if k not in ("schema", "package_version", "sha256")}
    body["safety_sources"] = {k: v for k, v in written["safety_sources"].items() if k != "ramp_s"}
    with pytest.raises(ArtifactError, match=r"field 'safety_sources\.ramp_s' is missing"):
        RigRunRecord.from_dict(body)  # a limit whose source the sidecar does not say is not read as said


def test_a_served_rigs_pushes_are_records_that_write_the_keys_the_summary_had():
    from piezopreload.rig.opcua import PushTaken

    identity = {"gain_set_sha256": "ab" * 32, "feedforward_sha256": "cd" * 32, "controller": "PID",
                "interlocks_kept": ["force_max_N 130 N (the pushed set's 150 N)"], "note": "night shift"}
    taken = PushTaken.of("ops", identity, accepted=True)
    assert taken.to_dict() == {"user": "ops", **identity, "accepted": True}
    assert list(taken.to_dict()) == ["user", *identity, "accepted"]
    refused = PushTaken.of("ops", identity, accepted=False, reason="its plant is not this rig's")
    assert refused.to_dict() == {"user": "ops", **identity, "accepted": False, "reason": "its plant is not this rig's"}
    assert PushTaken("guest", reason="no such user").to_dict() == {"user": "guest", "accepted": False,
                                                                   "reason": "no such user"}
    with pytest.raises(ValueError, match="'operator' is not a field"):
        PushTaken.of("ops", {**identity, "operator": "x"}, accepted=True)  # never dropped silently


# --------------------------------------------------------------------------------------
# a requirement's sense: one enum, its words and its verdict defined once
# --------------------------------------------------------------------------------------
def _sense_literals(root: Path) -> list[str]:
    """Comparisons with the literal ``"min"`` or ``"max"`` of an expression that names a sense or a kind
    (``r.sense == "min"``, ``row["kind"] in ("min", "max")``) in the package's modules (the floors at the root, the
    front door's own modules beside their links)."""
    floors = [p for d in ("artifacts", "core", "design", "models", "reports", "rig", "tuning")
              for p in (root / d).rglob("*.py")]
    paths = floors + sorted((root / "piezopreload").glob("*.py")) + sorted((root / "piezopreload" / "cli").glob("*.py"))
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            literal = any(isinstance(c, ast.Constant) and c.value in ("min", "max") for c in ast.walk(node))
            text = ast.unparse(node)
            if literal and ("sense" in text or "kind" in text):
                found.append(f"{path.relative_to(root)}:{node.lineno}: {text}")
    return found


def test_a_requirements_sense_is_an_enum_that_words_and_judges_it_once():
    from piezopreload.artifacts.codesign import RequirementRow
    from piezopreload.artifacts.requirements import Requirement, Sense

    r = Requirement("rigidity while cutting", 761.0, 1000.0, "N/um", "min", "[schedule] stiffness_min_N_per_um")
    assert r.sense is Sense.AT_LEAST and r.to_dict()["sense"] == "min"
    assert Requirement.from_dict(r.to_dict()) == r and Requirement.from_dict(r.to_dict()).sense is Sense.AT_LEAST
    assert (r.margin, r.met) == (-239.0, False) and " against at least 1,000 N/um" in r.sentence()
    deflection = Requirement("nut axial deflection while cutting", 4.0, 5.0, "um", Sense.AT_MOST)
    assert (deflection.margin, deflection.met, deflection.figures()) == (1.0, True, "4 um <= 5 um")
    with pytest.raises(ValueError, match="sense must be one of min, max, got 'least'"):
        Requirement("x", 1.0, 1.0, "N", "least")
    row = RequirementRow.from_dict({"requirement": "rating life", "unit": "h", "kind": "min", "sequential": 20000.0,
                                    "codesigned": 41350.0, "limit": 20000.0})
    assert row.kind is Sense.AT_LEAST and row.to_dict()["kind"] == "min" and row.met("sequential") is True
    assert Sense.AT_MOST.meets(5.0, 5.0) and not Sense.AT_MOST.meets(5.0 + 1e-12, 5.0)


def test_no_module_compares_a_sense_with_its_string():
    """Which side of its limit a requirement lies on is read from ``Sense`` (its words, its margin, its verdict),
    not by comparing a field with "min" or "max" (there were 16 such comparisons in 8 modules)."""
    assert _sense_literals(ROOT) == []
