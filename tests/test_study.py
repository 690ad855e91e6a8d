"""The study: its schema from the tables' declarations (checks, messages at the key's line, the docs' table of
keys), no silent ignores where the plant is the design, and ``study.plant``: the one plant the control steps run
on, its design solved once and kept, Pareto fronts only when asked."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

import piezopreload as pp
import piezopreload.design.study as design_study_module
import piezopreload.steps as study_module
from piezopreload.cli import main
from piezopreload.core.config import Invalid, Table, key, keys_markdown
from piezopreload.core.records import TableOf
from piezopreload.design.plant import DESIGNED_FIELDS, plant_from_design
from piezopreload.design.preload import optimise
from piezopreload.design.tables import DesignTable, PlantTable
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import simulate as simulate_loop
from piezopreload.models.controller import Controller
from piezopreload.tables import RIG, STUDY_TABLES, study_keys_markdown

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "studies" / "machine_axis.toml"
PAPER = ROOT / "studies" / "paper2021.toml"
QUIET = {"progress": lambda _m: None}


def _line(text: str, start: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if line.startswith(start))


def _all_tables():
    """Every table of the schema with its path, nested ones too."""
    todo = list(STUDY_TABLES.items())
    while todo:
        name, cls = todo.pop(0)
        yield name, cls
        todo += [(f"{name}.{sub}", inner) for sub, inner in (cls if isinstance(cls, TableOf) else cls.table()).nested]


def _keys(cls):
    """A table's doc and its keys: (key, doc, unit, whether it is a nested table)."""
    table = cls if isinstance(cls, TableOf) else cls.table()
    return table.doc, [(k, doc, unit, want == "the table") for k, want, _, unit, doc in table.rows()]


# ---- the schema: one declaration per key -------------------------------------------------------------
#: a unit-suffixed key's unit, as its name spells it (STYLE: units in names)
_SUFFIX_UNITS = {"_N_per_um": "N/um", "_V_per_N": "V/N", "_um_per_V": "um/V", "_per_V": "1/V", "_MPa": "MPa",
                 "_Nm": "N m", "_Hz": "Hz", "_mm": "mm", "_um": "um", "_uF": "uF", "_deg": "deg", "_rpm": "rpm",
                 "_kg": "kg", "_N": "N", "_V": "V", "_s": "s", "_A": "A", "_h": "h"}


def test_every_key_is_declared_once_with_a_doc_and_the_unit_its_name_spells():
    seen = 0
    for path, cls in _all_tables():
        doc, keys = _keys(cls)
        assert doc and f"[{path}]" in doc.split(": ")[0], f"{cls!r}'s doc does not open with [{path}]"
        for name, about, unit, nested in keys:
            seen += 1
            assert about.strip(), f"{path}.{name} has no doc"
            suffix = next((s for s in sorted(_SUFFIX_UNITS, key=len, reverse=True) if name.endswith(s)), None)
            if suffix and not nested:
                assert unit == _SUFFIX_UNITS[suffix], f"{path}.{name}: unit {unit!r}"
    assert seen > 120, "the schema lost tables"


def test_a_key_without_a_declaration_is_refused_when_the_table_is_made():
    @dataclasses.dataclass(frozen=True)
    class Loose(Table):
        """[loose]: a table with an undeclared key."""

        mass_kg: float = 1.0

    with pytest.raises(TypeError, match=r"Loose.mass_kg: declare the field with records.entry"):
        Loose()


@pytest.mark.parametrize("study, old, new, key_path, expected", [
    # the case: a negative ball size was reported against [design], at that table's line
    (AXIS, "ball_mm = [3.0, 7.5]", "ball_mm = [-3.0, 7.5]", "ballscrew.ball_mm",
     "must be a list of 2 numbers > 0, increasing, got [-3.0, 7.5]"),
    (AXIS, "ball_mm = [3.0, 7.5]", "ball_mm = [7.5, 3.0]", "ballscrew.ball_mm", "increasing"),
    (AXIS, "turns = [2, 6]", "turns = [2.5, 6]", "ballscrew.turns", "must be a list of 2 integers >= 1"),
    (AXIS, "travel_mm = [150.0, 1050.0]", "travel_mm = [150.0, 1250.0]", "feed_drive.travel_mm",
     "must lie inside the screw"),
    (AXIS, "time_share = [0.3, 0.3, 0.4]", "time_share = [0.3, 0.7]", "duty.time_share", "one entry per case"),
    (AXIS, "axial_load_max_N = 6000.0", "axial_load_max_N = 3000.0", "design.axial_load_max_N",
     "at least the duty cycle's largest axial load (4000 N)"),
    (AXIS, "pareto_points = 30", "pareto_points = 1", "design.pareto_points", "must be an integer >= 2 and <= 500"),
    (AXIS, 'objective = "stiffness"', 'objective = "cost"', "design.objective", "must be one of stiffness, drag"),
    (AXIS, "stack_drive_V = 100.0", "stack_drive_V = 150.0", "design.stack_drive_V", "<= 120"),
    (AXIS, "deflection_max_um = 5.0", "deflection_max_um = 0.0", "schedule.deflection_max_um", "> 0"),
    (AXIS, "noise_N = 1.0", "noise_N = -1.0", "rig.noise_N", "must be a number >= 0, got -1.0"),
    (AXIS, "noise_N = 1.0", "noise = 1.0", "rig.noise", "is an unknown key; [rig] has: stack, n_stacks"),
    (AXIS, "bw_beta_per_V = 0.02", "bw_beta_per_V = 0.0", "rig.bw_beta_per_V", "above |bw_gamma_per_V|"),
    (AXIS, "cycles = 2 ", "cycles = 0 ", "plant.cycles", "must be an integer >= 1, got 0"),
    (AXIS, "iterations = 6", 'iterations = 6\nmethod = "ilc"', "learning.method",
     "must be one of norm-optimal, p-type"),
    (AXIS, 'units = "seconds"', 'units = "hours"', "controller.units", "must be one of seconds, minutes"),
    (AXIS, "u_max_V = 115.0", "u_max_V = -30.0", "controller.u_max_V", "above u_min_V"),
    (AXIS, "duration_s = 3.0", "duration_s = 0.2", "reference.step.duration_s", "after the step"),
    (AXIS, 'signal = "measured_N"', 'signal = "true"', "simulation.signal", "one of measured_N, force_N"),
    (AXIS, "overshoot_margin_N = 10.0", "overshoot_margin_N = 30.0", "tuning.overshoot_margin_N",
     "below [simulation] band_N (25 N)"),
    (AXIS, "schedule_levels = 3", "schedule_levels = 1", "tuning.schedule_levels", "0 (one gain set) or 2.."),
    (AXIS, "plants = 200", "plants = 0", "validation.plants", "must be an integer >= 1 and <= 100000, got 0"),
    (AXIS, 'formats = ["json"', 'formats = ["pdf", "json"', "export.formats", "from json, labview"),
    (AXIS, 'reference = "schedule"', 'reference = "ramp"', "rig_run.reference", "step, trajectory, schedule"),
    (AXIS, "lubricant_vg = 68", "lubricant_vg = 70", "thermal.lubricant_vg", "must be an ISO VG grade, one of 10"),
    (AXIS, 'heat_model = "catalogue"', 'heat_model = "viscous"', "thermal.heat_model",
     "must be one of catalogue, contact"),
    (AXIS, "shift_h = 8.0", "shift_h = 30.0", "thermal.shift_h", "must be a number > 0 and <= 24, got 30.0"),
    (AXIS, "pretension_K = 3.0", "pretension_K = 0.0", "thermal.pretension_K",
     'a pretension needs mounting = "pretensioned" and pretension_K > 0 together'),
    (AXIS, "thermal_growth_max_um = 25.0", "thermal_growth_max_um = -1.0", "thermal.thermal_growth_max_um", "> 0"),
    (PAPER, "creep = false", "creep = 1", "feedforward.creep", "must be true or false, got 1"),
    (PAPER, "band_N = 1.5", 'band_N = "a"', "simulation.band_N", "must be a number > 0, got 'a'"),
    (PAPER, "adc_bits = 16", "adc_bits = 16.0", "rig.adc_bits", "must be an integer >= 2 and <= 32, got 16.0"),
    (PAPER, "coupling_stiffness_N_per_um = 2.168", "coupling_stiffness_N_per_um = 0",
     "rig.coupling_stiffness_N_per_um", "must be a number > 0, got 0"),
])
def test_a_bad_value_is_reported_at_its_key_and_line(tmp_path, study, old, new, key_path, expected):
    text = study.read_text()
    assert old in text, old
    changed = text.replace(old, new, 1)
    path = tmp_path / "study.toml"
    path.write_text(changed)
    line = _line(changed, new.splitlines()[-1].split("=")[0].rstrip() + " =")
    with pytest.raises(pp.InputError) as info:
        pp.load_study(path, **QUIET)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: '{key_path}' "), message
    assert expected in message, message


def test_a_missing_table_a_missing_key_and_an_unknown_table_are_named(tmp_path):
    text = PAPER.read_text()
    path = tmp_path / "study.toml"
    path.write_text(text.replace("Kc = 0.3\n", ""))
    with pytest.raises(pp.InputError, match=rf"{re.escape(str(path))}:{_line(text, '[controller]')}: 'controller' "
                                            r"needs 'Kc' \(a number\)"):
        pp.load_study(path)
    path.write_text(text.replace("[simulation]", "[simulations]"))
    with pytest.raises(pp.InputError, match=r"'simulations' is an unknown table; a study has: study, rig, plant"):
        pp.load_study(path)
    path.write_text(text.split("[controller]")[0])
    with pytest.raises(pp.InputError, match=r"study.toml: the table \[controller\] is missing"):
        pp.load_study(path)


def test_a_copy_is_checked_as_a_file_is_and_names_the_key():
    study = pp.load_study(PAPER)
    for bad, match in (({"rig": {"bolt_preload_N": -1.0}}, r"\(replaced\): 'rig.bolt_preload_N' must be a number >= 0"),
                       ({"rig": {"stiffnes": 2.0}}, r"'rig.stiffnes' is an unknown key"),
                       ({"ballscrew": {"ball_mm": [-3.0, 7.5]}},
                        r"'ballscrew.ball_mm' must be a list of 2 numbers > 0"),
                       ({"validation": {"plants": 0}}, r"'validation.plants' must be an integer >= 1"),
                       ({"simulation": {"band_N": "wide"}}, r"'simulation.band_N' must be a number > 0, got 'wide'"),
                       ({"rigs": {}}, "'rigs' must be a table of the study")):
        with pytest.raises(pp.InputError, match=match):
            study.replace(**bad)


def test_a_table_checks_itself_when_made_in_code():
    with pytest.raises(Invalid, match=r"'DesignTable.pareto_points' must be an integer >= 2 and <= 500, got 1"):
        DesignTable(pareto_points=1)
    with pytest.raises(Invalid, match=r"'PlantTable.cycles' must be an integer >= 1, got 0"):
        PlantTable(cycles=0)
    with pytest.raises(Invalid, match=r"'Plant.stack' must be a valid value, got dict \{'name': 'x'\}"):
        Plant(stack={"name": "x"})  # type: ignore[arg-type]
    assert DesignTable().pareto_points == 50


def test_the_key_table_is_rendered_from_the_declarations():
    @dataclasses.dataclass(frozen=True)
    class Axis(Table):
        """[axis]: an example.

        More text, not shown."""

        mass_kg: float = key(350.0, "the table's mass", unit="kg", gt=0)
        travel_mm: tuple[float, float] | None = key(None, "its travel (not set: the whole screw)", unit="mm", ge=0,
                                                    increasing=True)
        mounting: str = key("fixed-fixed", "the ends", choices=("fixed-fixed", "fixed-supported"))

    assert keys_markdown({"axis": Axis}, {"axis.mounting": "a note"}) == (
        "### `[axis]`\n\nAn example.\n\n"
        "| key | takes | default | unit | description |\n|---|---|---|---|---|\n"
        "| `mass_kg` | a number > 0 | `350` | kg | the table's mass |\n"
        "| `travel_mm` | a list of 2 numbers >= 0, increasing | not set | mm | "
        "its travel (not set: the whole screw) |\n"
        "| `mounting` | one of fixed-fixed, fixed-supported | `\"fixed-fixed\"` |  | the ends; a note |\n")


def test_the_docs_hold_the_generated_table_of_every_key():
    text = (ROOT / "docs" / "study.md").read_text()
    begin, end = "<!-- the table of keys: study_keys_markdown() -->\n", "<!-- end of the table of keys -->"
    assert begin in text and end in text, "docs/study.md has lost its generated table's markers"
    held = text.split(begin, 1)[1].split(end, 1)[0]
    assert held == study_keys_markdown(), "docs/study.md's table of keys is stale: paste study_keys_markdown()"
    for path, cls in _all_tables():
        assert f"### `[{path}]`" in held
        for name, *_ in _keys(cls)[1]:
            assert f"| `{name}` |" in held, f"{path}.{name} is not in the docs"
    for name in DESIGNED_FIELDS:  # the keys a designed plant refuses say so
        row = next(line for line in held.split("### `[rig]`")[1].splitlines() if line.startswith(f"| `{name}` |"))
        assert "refused there" in row, row


# ---- no silent ignores ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", DESIGNED_FIELDS)
def test_a_rig_key_the_design_sets_is_refused_where_the_plant_is_the_design(tmp_path, capsys, name):
    text = AXIS.read_text()
    value = ('\n[rig.stack]\nname = "PI P-888.91"' if name == "stack"
             else f"\n{name} = {3 if name == 'n_stacks' else 0.5}")
    anchor = "delay_samples = 1"
    changed = text.replace(anchor, anchor + value, 1)
    path = tmp_path / "study.toml"
    path.write_text(changed)
    line = _line(changed, "[rig.stack]" if name == "stack" else f"{name} =")
    with pytest.raises(pp.PiezopreloadError) as info:
        pp.load_study(path, **QUIET)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: 'rig.{name}' is set by the design where [plant] from_design = true")
    assert code_and_line(capsys, ["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == (2, message)
    assert not (tmp_path / "out" / "pipeline.json").exists(), "a refused study ran"
    axis = pp.load_study(AXIS, **QUIET)
    change = {"name": "PI P-888.91"} if name == "stack" else 3 if name == "n_stacks" else 0.5
    with pytest.raises(pp.PiezopreloadError, match=rf"'rig.{name}' is set by the design where \[plant\] from_design"):
        axis.replace(rig={name: change})
    if name == "bolt_preload_N":  # the way out the message names: [rig] is the plant, and its value is applied
        # ([thermal] goes too: it is the budget of a designed system, refused where [rig] is the plant)
        assert axis.replace(rig={name: change}, plant=None, thermal=None).plant.bolt_preload_N == change


def code_and_line(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    return code, err[len("error: "):].strip()


def test_the_design_sets_exactly_the_rig_keys_it_refuses():
    """Every [rig] key either reaches the designed plant or is refused: a change of the hardware table changes the
    designed plant in exactly the fields the design does not set (design/plant.py's DESIGNED_FIELDS)."""
    axis = pp.load_study(AXIS, **QUIET)
    opt = optimise(axis.design_spec, "stiffness")
    base = Plant()
    plant = plant_from_design(axis.design_spec, opt, base, design_sha256="").rig
    special = {"stack": {"stack": dataclasses.replace(base.stack, capacitance_uF=7.0)}, "n_stacks": {"n_stacks": 5},
               "adc_bits": {"adc_bits": 12}, "delay_samples": {"delay_samples": 2},
               "creep_tau_s": {"creep_tau_s": (0.2, 2.0)},
               "hertz_um_per_N23": {"hertz_um_per_N23": 0.1, "hertz_preload_N": 100.0}}
    for f in dataclasses.fields(Plant):
        change = special[f.name] if f.name in special else {f.name: 1.3 * float(getattr(base, f.name)) + 0.01}
        made = plant_from_design(axis.design_spec, opt, dataclasses.replace(base, **change), design_sha256="").rig
        moved = getattr(made, f.name) != getattr(plant, f.name)
        if f.name in DESIGNED_FIELDS:
            assert not moved, f"[rig] {f.name} is refused as set by the design, but it changes the designed plant"
        else:
            assert moved, f"[rig] {f.name} is taken beside the design, but the designed plant ignores it"
    assert set(DESIGNED_FIELDS) <= {k for k, *_ in RIG.rows()}, "a designed field is not a [rig] key"


def test_plant_keys_of_a_designed_plant_are_refused_where_rig_is_the_plant(tmp_path):
    axis = pp.load_study(AXIS, **QUIET)
    with pytest.raises(pp.InputError, match=r"'plant.sleeve_stiffness_N_per_um' applies to the designed plant only"):
        axis.replace(plant={"from_design": False})
    with pytest.raises(pp.InputError, match=r"'thermal' needs a study whose plant is its design"):
        axis.replace(plant={"from_design": False, "sleeve_stiffness_N_per_um": None, "cycles": None, "passes": None,
                            "stack_contact_N": None})
    rig_plant = axis.replace(plant={"from_design": False, "sleeve_stiffness_N_per_um": None, "cycles": None,
                                    "passes": None, "stack_contact_N": None}, thermal=None)
    assert not rig_plant.plant_from_design and rig_plant.plant.to_dict() == rig_plant.rig.to_dict()
    text = PAPER.read_text() + "\n[plant]\nfrom_design = true\n"
    path = tmp_path / "study.toml"
    path.write_text(text.replace("[ballscrew]", "[ballscrews]").split("[ballscrews]")[0]
                    + "\n[plant]\nfrom_design = true\n")
    with pytest.raises(pp.InputError, match=r"'plant.from_design' = true needs the design's tables"):
        pp.load_study(path)


# ---- study.plant ------------------------------------------------------------------------------------------
def test_study_plant_is_the_designed_plant_and_what_the_control_steps_run_on():
    said: list[str] = []
    axis = pp.load_study(progress=said.append)
    plant = axis.plant
    assert len(said) == 2 and "solving the design's optimum" in said[0] and "bolts' preload 255 N" in said[1], said
    # the plant of the design's optimum, made here independently of the study
    opt = optimise(axis.design_spec, "stiffness")
    hardware = Plant(**{k: v for k, v in axis.rig.to_dict().items() if k != "stack"})
    expected = plant_from_design(axis.design_spec, opt, hardware, design_sha256="", sleeve_stiffness_N_per_um=4000.0)
    assert plant.to_dict() == expected.rig.to_dict()
    # the numbers: the plant has no bolt preload of its own, a 1,370 N/um coupling, a 255 N Hertz preload
    assert plant.bolt_preload_N == 0.0 and plant.hertz_preload_N == pytest.approx(600 * 1.2 / 2**1.5)
    assert plant.coupling_stiffness_N_per_um == pytest.approx(1370, rel=1e-3)
    # [rig] is the hardware the design completes: the keys the design sets are not [rig]'s to show
    shown = set(axis.tables()["rig"])
    assert not {"bolt_preload_N", "coupling_stiffness_N_per_um"} & shown, "[rig] shows unused values"
    assert axis.plant is plant and axis.designed_plant.rig is plant and len(said) == 2, "the plant was made again"
    # a control step runs on it: the study's simulation is the loop on Rig(plant)
    run = axis.simulate(axis.controller, controller="pid", reference="step")
    alone = simulate_loop(Rig(plant), Controller(axis.controller, plant.sample_period_s), axis.references["step"],
                          seed=axis.seed)
    np.testing.assert_array_equal(run.force_N, alone.force_N, err_msg="Study.simulate did not run on study.plant")
    paper = pp.load_study(PAPER)
    assert paper.plant.to_dict() == paper.rig.to_dict() and paper.plant.bolt_preload_N == 25.0
    assert "plant: its design;" in repr(axis) and "plant: its [rig];" in repr(paper)
    with pytest.raises(pp.InputError, match="there is no designed plant"):
        _ = paper.designed_plant


def test_the_design_is_solved_once_kept_and_fronts_traced_only_when_asked(monkeypatch):
    calls = {"optimise": 0, "front": 0}

    def counted(name, function):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return function(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(study_module, "optimise", counted("optimise", study_module.optimise))
    monkeypatch.setattr(design_study_module, "optimise", counted("optimise", design_study_module.optimise))
    monkeypatch.setattr(design_study_module, "pareto_front", counted("front", design_study_module.pareto_front))
    axis = pp.load_study(**QUIET)
    assert axis.plant.hertz_preload_N > 0
    assert calls == {"optimise": 1, "front": 0}, "making the plant traced fronts, or solved twice"
    axis.identify_feedforward()
    assert axis.preload_schedule.spec.bolt_preload_N == axis.designed_plant.bolt_preload_N
    result = axis.design(pareto=[])
    assert calls == {"optimise": 1, "front": 0} and result.fronts == [], "design() solved the kept optimum again"
    assert result.optimum.point.bolt_preload_N == axis.designed_plant.bolt_preload_N
    axis.design(pareto=["stiffness:drag"], points=3)
    assert calls == {"optimise": 1, "front": 1}
    # a copy keeps the design where its design's tables are the same, and solves its own where they are not
    softer = axis.replace(simulation={"seed": 3}, plant={"sleeve_stiffness_N_per_um": 2000.0}).plant
    assert calls["optimise"] == 1 and softer.coupling_stiffness_N_per_um < axis.plant.coupling_stiffness_N_per_um
    assert axis.replace(design={"failsafe_load_N": 800.0}).plant.hertz_preload_N == pytest.approx(800 * 1.2 / 2**1.5)
    assert calls["optimise"] == 2
    # a study on its own [rig] never solves the design for its plant
    assert pp.load_study(PAPER).plant.bolt_preload_N == 25.0
    assert calls["optimise"] == 2


def test_tune_on_the_default_study_says_what_it_pays_for_the_plant(monkeypatch):
    """``pp.load_study().tune()``: the design's optimum, said through the step's progress, and no Pareto front."""
    from piezopreload.core.parallel import Pool

    fronts = []
    monkeypatch.setattr(design_study_module, "pareto_front", lambda *a, **k: fronts.append(a))
    seen = {}

    class Tuning(Exception):
        """Where the tuning itself would start (its minimum-time bound first): what came before is the plant's."""

    def bound(pool, function, plant, **kwargs):
        seen["plant"] = plant
        raise Tuning

    monkeypatch.setattr(Pool, "beside", bound)
    said: list[str] = []
    axis = pp.load_study(**QUIET)
    with pytest.raises(Tuning):
        axis.tune(progress=said.append)
    assert "solving the design's optimum (stiffness)" in said[0] and any("P-I model" in m for m in said), said
    assert not fronts and seen["plant"] is axis.plant


def test_with_design_gives_the_optimum_instead_of_solving_it(monkeypatch):
    axis = pp.load_study(**QUIET)
    other = optimise(axis.replace(design={"failsafe_load_N": 900.0}).design_spec, "stiffness")
    monkeypatch.setattr(study_module, "optimise", lambda *a, **k: pytest.fail("the given design was solved again"))
    given = axis.with_design(other.point, "ab" * 32)
    assert given.designed_plant.design_sha256 == "ab" * 32
    assert given.plant.hertz_preload_N == pytest.approx(other.point.bolt_preload_N)
    assert given.preload_schedule.spec.bolt_preload_N == pytest.approx(other.point.bolt_preload_N)
    assert math.isclose(given.designed_plant.max_preload_N, other.point.max_preload_N)


def test_learning_on_the_schedule_needs_the_designed_plant_and_its_own_step():
    with pytest.raises(pp.InputError, match=r"along the preload schedule needs a study whose plant is its design"):
        pp.load_study(PAPER).learn_schedule()
    with pytest.raises(pp.InputError, match=r"the preload schedule is learned by learn_schedule"):
        pp.load_study(**QUIET).learn(reference="schedule")  # a name of no reference: the schedule has its own step
    with pytest.raises(TypeError, match="plants"):
        pp.load_study(**QUIET).learn_schedule(plants=4)  # type: ignore[call-arg]


@pytest.mark.slow
def test_learning_along_the_schedule_is_one_call_and_plays_what_it_learned(tmp_path, capsys):
    """``axis.learn_schedule()``: each margin pass learned on the reference that pass tracks, the
    schedule tracked with it (the system run is the loop with the last pass's signal, simulated here again), the
    error smaller after learning; its figure, its JSON, its artifacts; the command line's learn does the same."""
    import json

    from matplotlib.figure import Figure

    from piezopreload.artifacts.learned import LearnedSignal, reference_sha256
    from piezopreload.design.system import schedule_reference

    axis = pp.load_study(**QUIET)
    result = axis.learn_schedule(iterations=2)
    system, designed, table = result.system, axis.designed_plant, axis.plant_table
    assert len(result.passes) == len(system.passes) >= 1
    reference = schedule_reference(designed, system.schedule, table.cycles, table.stack_contact_N, system.pre_cycle)
    assert reference_sha256(result.last.reference) == reference_sha256(reference), "learned on another reference"
    controller = Controller(axis.controller, axis.plant.sample_period_s, axis.identify_feedforward().inverse())
    again = simulate_loop(Rig(designed.rig), controller, reference, seed=axis.seed, ff_extra_V=result.last.ff_extra_V)
    np.testing.assert_array_equal(system.run.force_N, again.force_N, err_msg="the schedule was not played with the "
                                                                             "last pass's learned signal")
    for learned in result.passes:
        before = float(np.max(learned.history[0].tracking_rms_N))
        assert learned.tracking_rms_N < 0.7 * before, f"learning did not reduce the error: {before} -> {learned}"
    doc = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert doc["tracking_rms_N"] == result.last.tracking_rms_N and len(doc["passes"]) == len(result.passes)
    assert doc["system"]["requirements_met"] == system.requirements_met
    assert "ScheduleLearning(" in repr(result) and f"{result.last.tracking_rms_N:.2f} N after learning" in repr(result)
    fig = result.plot()
    assert isinstance(fig, Figure) and len(fig.axes[0].lines) == len(result.passes)
    saved = result.save(tmp_path / "learn", None)
    assert LearnedSignal.load(saved.out).content_sha256 == saved.content_sha256
    code = main(["learn", "--study", str(AXIS), "--reference", "schedule", "--iterations", "2", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out)["tracking_rms_N"] == pytest.approx(result.last.tracking_rms_N, rel=1e-9)


def test_published_numbers_are_a_declared_table_too(tmp_path):
    table = ('\n[published]\nsource = "Zhang, Jin, Lin 2021"\ngains_label = "the paper\'s gains"\n'
             "pid = { rise_s = 1.69, peak_s = 3.38, settling_s = 3.38 }\n"
             "ff_pid = { rise_s = 0.08, peak_s = 0.13, settling_s = 1.43 }\n")
    text = PAPER.read_text()
    bare = text[:text.index("[published]")] + text[text.index("[rig]"):]  # the paper's study without its table
    path = tmp_path / "study.toml"
    path.write_text(bare + table)
    study = pp.load_study(path)
    assert study.published.step() == {"pid": {"rise_s": 1.69, "peak_s": 3.38, "settling_s": 3.38},
                                      "ff+pid": {"rise_s": 0.08, "peak_s": 0.13, "settling_s": 1.43}}
    path.write_text(bare)
    assert pp.load_study(path).published is None
    changed = (bare + table).replace("peak_s = 0.13, ", "")
    path.write_text(changed)
    with pytest.raises(pp.InputError, match=rf":{_line(changed, 'ff_pid =')}: 'published.ff_pid' needs 'peak_s'"):
        pp.load_study(path)


def test_the_parsed_tables_type_names_every_table_of_a_study_in_order():
    """The typed form of a file's tables (what the study is built from) has one key per declared table, in order."""
    from piezopreload.spec import _StudyTables
    from piezopreload.tables import STUDY_TABLES

    assert list(_StudyTables.__annotations__) == list(STUDY_TABLES)


@pytest.mark.parametrize("limit", ["200", "115", "115.0"])
def test_a_peak_voltage_limit_the_commands_clamp_makes_unreachable_is_refused(capsys, tmp_path, limit):
    """The controller clamps its command at [controller] u_max_V (115 V in the machine axis): a highest-command limit
    at or above it could never be missed, so the study is refused (exit 2, one error line naming both keys) rather
    than reporting a requirement that cannot fail."""
    text = AXIS.read_text()
    assert re.search(r"^peak_voltage_max_V = ", text, re.M) and re.search(r"^u_max_V = 115\.0", text, re.M)
    study = tmp_path / "axis.toml"
    study.write_text(re.sub(r"^peak_voltage_max_V = .*$", f"peak_voltage_max_V = {limit}", text, flags=re.M))
    code = main(["run", str(study), "--out", str(tmp_path / "out"), "--json"])
    out, err = capsys.readouterr()
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "validation.peak_voltage_max_V" in err and "controller.u_max_V = 115 V" in err, err
    with pytest.raises(pp.InputError, match="controller.u_max_V"):
        pp.Study.load(study)


def test_the_shipped_studies_set_a_peak_voltage_limit_that_can_fail_or_none():
    """Each shipped study's highest-command limit lies below its controller's clamp (headroom the loop keeps), or is
    left out (no such requirement), never at or above it."""
    for path in (AXIS, PAPER):
        s = pp.Study.load(path)
        limit = s.validation.peak_voltage_max_V
        assert limit is None or limit < s.controller.u_max_V, (path.name, limit, s.controller.u_max_V)
    assert pp.Study.load(AXIS).validation.peak_voltage_max_V == 110.0
