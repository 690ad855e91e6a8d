"""The design, plant and system artifacts as typed records: each round-trips, and a missing, mistyped or non-finite
field is refused with its name."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.system import SystemRecord
from piezopreload.core.errors import ArtifactError
from piezopreload.design.plant import plant_from_design
from piezopreload.design.preload import DesignSpec
from piezopreload.design.study import design_study
from piezopreload.design.system import track_schedule
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller, PIDGains


@pytest.fixture(scope="module")
def designed():
    spec = DesignSpec()
    result = design_study(spec, "stiffness", ["stiffness:drag"], 3, stiffness_min_N_per_um=300.0, deflection_max_um=5.0)
    hardware = Plant(amp_bandwidth_Hz=100.0, bw_alpha=0.3238, bw_kappa=0.0931, creep_per_decade=0.0385,
                         noise_N=1.0, adc_full_scale_N=10000.0)
    plant = plant_from_design(spec, result.optimum, hardware, design_sha256="a" * 64, sleeve_stiffness_N_per_um=4000.0)
    return result, plant


def test_the_design_record_round_trips_and_holds_the_best_constant_once(designed, tmp_path):
    result, _ = designed
    path = result.save(tmp_path / "design.json", {"study_sha256": "b" * 64})[0]
    record = DesignRecord.load(path)
    s = record.schedule
    assert record.point == result.point and record.optimum.binding == tuple(result.optimum.binding)
    assert len(record.fronts) == 1 and record.fronts[0].points == tuple(result.fronts[0].points)
    np.testing.assert_array_equal(s.preload_N, result.schedule.preload_N)
    np.testing.assert_array_equal(s.needed_N, result.schedule.needed_N)
    assert (s.constant_preload_N, s.constant_friction_energy_J) == (result.schedule.constant_preload_N,
                                                                   result.schedule.constant_friction_energy_J)
    assert s.saving_fraction == result.schedule.saving_fraction and s.spec == result.schedule.spec
    assert record.profile == "example" and record.inputs == {"study_sha256": "b" * 64}
    assert DesignRecord.from_dict(record.to_dict()).to_dict() == record.to_dict(), "a second round trip changed it"
    # the layout the report reads today is kept
    doc = json.loads(path.read_text())
    for key in ("preload_curve", "units", "optimum", "fronts", "schedule", "natural_frequency", "inputs"):
        assert key in doc
    for key in ("constant_preload_N", "constant_friction_energy", "saving_fraction", "max_preload_N", "slew_N_per_s",
                "time_s", "axial_load_N", "preload_N"):
        assert key in doc["schedule"], key


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda d: d["schedule"].pop("needed_N"), "schedule.needed_N"),
    (lambda d: d["schedule"].update(constant_preload_N="high"), "schedule.constant_preload_N"),
    (lambda d: d["schedule"]["preload_N"].pop(), "schedule.preload_N"),
    (lambda d: d["optimum"]["point"].update(ball_mm=None), "optimum.point.ball_mm"),
    (lambda d: d["fronts"][0].pop("pair"), "fronts[0].pair"),
    (lambda d: d["preload_curve"]["cases"][0].pop("rigidity_N_per_um"), "preload_curve.cases[0].rigidity_N_per_um"),
])
def test_a_bad_design_record_is_refused_naming_its_field(designed, mutate, field):
    result, _ = designed
    doc = json.loads(json.dumps(result.record().to_dict()))
    mutate(doc)
    with pytest.raises(ArtifactError, match=re.escape(f"field '{field}'")):
        DesignRecord.from_dict(doc, "design.json")


def test_the_plant_record_makes_the_plant_again(designed, tmp_path):
    _, plant = designed
    path = plant.save(tmp_path / "plant.json", {"design_sha256": plant.design_sha256})
    again = DesignedPlant.load(path)
    assert again.rig.to_dict() == plant.rig.to_dict() and again.screw == plant.screw
    assert again.inputs == {"design_sha256": "a" * 64}
    assert (again.bolt_preload_N, again.max_preload_N, again.sleeve_stiffness_N_per_um) == \
        (plant.bolt_preload_N, plant.max_preload_N, plant.sleeve_stiffness_N_per_um)
    f = np.linspace(plant.bolt_preload_N, plant.max_preload_N, 7)
    np.testing.assert_array_equal(again.nut_rigidity_N_per_um(f), plant.nut_rigidity_N_per_um(f))
    rigid = DesignedPlant.from_dict({**plant.to_dict(), "sleeve_stiffness_N_per_um": None})
    assert math.isinf(rigid.sleeve_stiffness_N_per_um), "a rigid sleeve (null) did not come back as inf"
    doc = plant.to_dict()
    doc["screw"]["ball_mm"] = float("nan")
    with pytest.raises(ArtifactError, match="field 'screw.ball_mm'"):
        DesignedPlant.from_dict(doc, "plant.json")
    doc = plant.to_dict()
    doc.pop("bolt_preload_N")
    with pytest.raises(ArtifactError, match="field 'bolt_preload_N' is missing"):
        DesignedPlant.from_dict(doc, "plant.json")


@pytest.fixture(scope="module")
def system(designed):
    result, plant = designed
    loop = Controller(PIDGains(0.0108, 0.0486, u_min_V=-20.0, u_max_V=115.0), 1e-3)
    return track_schedule(plant, loop, result.schedule, cycles=1, passes=2, settle_s=0.3)


def test_the_system_record_round_trips_with_its_verdicts(system, tmp_path):
    paths = system.save(tmp_path / "system", {"gain_set_sha256": "c" * 64})
    record = SystemRecord.load(paths["system"])
    assert record.requirements == system.requirements and record.requirements_met == system.requirements_met
    assert record.numbers == system.numbers and record.passes == system.passes and record.pre_cycle == system.pre_cycle
    assert record.bounds == system.bounds and record.cycles == 1 and record.inputs == {"gain_set_sha256": "c" * 64}
    np.testing.assert_array_equal(record.schedule.margin_N, system.schedule.margin_N)
    doc = json.loads(paths["system"].read_text())
    assert doc["requirements_met"] == all(r["met"] for r in doc["requirements"])
    assert "constant_preload_N" not in doc and "constant_friction_energy_per_cycle" not in doc, \
        "the best constant preload is the design's, recorded there only"
    # the reference the rig plays starts with the pre-cycle from rest
    from piezopreload.core.tables import read_table

    ref = read_table(paths["reference"], ("time_s", "force_N"))
    assert ref["time_s"][0] == 0.0 and ref["force_N"][0] == 0.0
    first_cut = int(np.searchsorted(ref["time_s"], system.pre_cycle.duration_s - 1e-9))
    assert ref["force_N"][first_cut] == pytest.approx(system.pre_cycle.level_N)


def test_a_system_record_whose_verdict_disagrees_with_its_requirements_is_refused(system):
    doc = json.loads(json.dumps(system.record().to_dict()))
    doc["requirements_met"] = not doc["requirements_met"]
    with pytest.raises(ArtifactError, match="requirements_met"):
        SystemRecord.from_dict(doc, "system.json")
    doc = json.loads(json.dumps(system.record().to_dict()))
    doc["pre_cycle"]["ramp_s"] = -1.0
    with pytest.raises(ArtifactError, match="field 'pre_cycle'"):
        SystemRecord.from_dict(doc, "system.json")
    doc = json.loads(json.dumps(system.record().to_dict()))
    doc["series"]["achieved_N"] = doc["series"]["achieved_N"][:-1]
    with pytest.raises(ArtifactError, match="field 'series.achieved_N'"):
        SystemRecord.from_dict(doc, "system.json")
