"""The designed preload system as the plant: Hertz coupling, the plant from a design, references, the schedule's margin."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from piezopreload.core.errors import InputError
from piezopreload.design.plant import plant_from_design
from piezopreload.design.preload import DesignNLP, DesignSpec, optimise
from piezopreload.models.actuator import PlantModel, Rig, RigParams, hertz_force
from piezopreload.models.feed_drive import stack_loop_um
from piezopreload.models.ops import NUMPY


@pytest.fixture(scope="module")
def design():
    spec = DesignSpec()
    return spec, optimise(spec, "stiffness", DesignNLP(spec))


def test_hertz_force_inverts_the_nut_law_as_brentq_does():
    k, c, f0 = 250.0, 0.045, 255.0
    strokes = np.array([-1.0, 0.0, 0.05, 3.0, 15.0, 31.0])
    ours = hertz_force(NUMPY, strokes, k, c, f0)
    for x, f in zip(strokes, ours):
        ref = brentq(lambda fe, x=x: fe / k + c * (np.cbrt(f0 + fe) ** 2 - np.cbrt(f0) ** 2) - x, -f0 + 1e-9, 1e5,
                     xtol=1e-12)
        assert f == pytest.approx(ref, rel=1e-9, abs=1e-9), f"stroke {x} um: Newton {f} N, brentq {ref} N"


def test_plant_from_design_reproduces_the_designs_rigidity_at_its_preload(design):
    spec, opt = design
    plant = plant_from_design(spec, opt, RigParams(), design_sha256="0" * 64)
    p = opt.point
    preloads = np.array([p.bolt_preload_N, 0.5 * (p.bolt_preload_N + p.max_preload_N), p.max_preload_N])
    ours = plant.nut_rigidity_N_per_um(preloads)
    theirs = plant.screw.rigidity_N_per_um(preloads)
    np.testing.assert_allclose(ours, theirs, rtol=1e-6, err_msg="the plant's double-nut rigidity is not the design's")
    # the stroke the plant needs for the design's top preload is the design's stack loop (feed_drive.stack_loop_um)
    s = plant.screw
    need = stack_loop_um(s.axial_constant_um, p.bolt_preload_N, p.max_preload_N, plant.rig.stack_stiffness_N_per_um,
                         s.structural_compliance_um_per_N, s.accuracy_factor)
    assert float(plant.rig.stroke_for_force_um(p.max_preload_N - p.bolt_preload_N)) == pytest.approx(need, rel=1e-9)


def test_plant_force_per_volt_grows_with_the_preload(design):
    spec, opt = design
    plant = plant_from_design(spec, opt, RigParams(bw_alpha=0.2, creep_per_decade=0.0, noise_N=0.0,
                                                   adc_full_scale_N=20000.0), design_sha256="0" * 64)
    f, _ = Rig(plant.rig).quasi_static_loop(np.linspace(0.0, 100.0, 2001))
    slope = np.gradient(f, 0.05)
    assert slope[200] < slope[-200], f"dF/dV at 10 V ({slope[200]:.1f}) should be below that at 90 V ({slope[-200]:.1f})"
    # the data sheet's travel: the rising branch at 100 V gives the stack type's nominal 32 um
    x = float(plant.rig.stroke_for_force_um(f[-1]))
    assert x == pytest.approx(spec.actuator.stack.nominal_travel_um, rel=1e-6)


def test_a_linear_rig_keeps_its_layout_and_document():
    rig = RigParams()
    assert not rig.hertz and "hertz_um_per_N23" not in rig.to_dict()
    assert PlantModel.of(rig).params.names == PlantModel(4, 1).params.names
    with pytest.raises(InputError, match="Hertzian"):
        PlantModel.of(rig).parameters(RigParams(hertz_um_per_N23=0.05, hertz_preload_N=100.0))
    with pytest.raises(ValueError, match="hertz_preload_N"):
        RigParams(hertz_um_per_N23=0.05)


# ---- references -----------------------------------------------------------------------------------
def test_ramps_interpolate_repeat_and_round_trip():
    from piezopreload.models.closedloop import Reference

    ref = Reference.ramps([0.0, 1.0, 3.0], [0.0, 100.0, 50.0], 4.0)
    np.testing.assert_allclose(ref.at([0.5, 1.0, 2.0, 3.5]), [50.0, 100.0, 75.0, 50.0],
                               err_msg="a piecewise linear reference does not interpolate its points")
    twice = ref.repeat(2)
    assert twice.duration_s == 8.0 and twice.at(4.5) == pytest.approx(50.0), "the second cycle is not the first again"
    assert Reference.from_dict(twice.to_dict()).at(6.0) == pytest.approx(twice.at(6.0))
    held = Reference.step(0.0, 10.0, 0.5, 1.0)
    assert "interpolation" not in held.to_dict(), "a held reference's document changed (gain-set hashes would)"
    assert held.at(0.75) == 10.0 and not ref.is_step


# ---- the schedule's margin and the whole system ------------------------------------------------------
@pytest.fixture(scope="module")
def axis(design):
    from piezopreload.design.study import plan_schedule

    spec, opt = design
    hardware = RigParams(amp_bandwidth_Hz=100.0, bw_alpha=0.3238, bw_kappa=0.0931, creep_per_decade=0.0385,
                         noise_N=1.0, adc_full_scale_N=10000.0)
    plant = plant_from_design(spec, opt, hardware, design_sha256="0" * 64, sleeve_stiffness_N_per_um=4000.0)
    schedule, _, _ = plan_schedule(spec, opt.point, stiffness_min_N_per_um=300.0, deflection_max_um=5.0)
    return spec, opt, plant, schedule


def test_a_preload_margin_keeps_every_requirement_at_the_preload_less_the_margin(axis):
    from piezopreload.design.study import plan_schedule

    spec, opt, plant, schedule = axis
    m = 60.0
    # a stiffness floor that binds (above the rigidity at the lift-off bound), so the margin acts on the rigidity row
    plain, _, _ = plan_schedule(spec, opt.point, stiffness_min_N_per_um=1200.0, deflection_max_um=5.0)
    with_margin, _, _ = plan_schedule(spec, opt.point, stiffness_min_N_per_um=1200.0, deflection_max_um=5.0,
                                      preload_margin_N=m)
    assert np.min(plant.screw.rigidity_N_per_um(plain.preload_N - m, plain.profile.axial_load_N)
                  - plain.required_N_per_um) < 0, "without a margin the preload less m would fall short somewhere"
    load = with_margin.profile.axial_load_N
    k_less = plant.screw.rigidity_N_per_um(with_margin.preload_N - m, load)
    short = with_margin.required_N_per_um - k_less
    assert np.max(short) <= 1e-3 * np.max(with_margin.required_N_per_um), \
        f"the rigidity at the preload less {m} N falls {np.max(short):.2f} N/um below the requirement"
    assert with_margin.friction_energy_J > plain.friction_energy_J, "a margin cannot cost nothing"


def test_tracking_numbers_of_a_perfect_run_are_the_plans(axis):
    from dataclasses import replace as dc_replace

    from piezopreload.design.system import evaluate_tracking, schedule_reference
    from piezopreload.models.closedloop import simulate
    from piezopreload.models.controller import Controller, PIDGains

    spec, opt, plant, schedule = axis
    ref = schedule_reference(plant, schedule, cycles=2)
    run = simulate(Rig(plant.rig), Controller(PIDGains(0.001, 0.05), 1e-3), ref)
    perfect = dc_replace(run, force_N=run.reference_N.copy())
    n = evaluate_tracking(plant, schedule, perfect, cycles=2)
    assert n["tracking_rms_N"] == 0.0 and n["preload_shortfall_max_N"] == 0.0
    # the plan meets its requirement (the schedule NLP's constraint), so the perfect run does
    assert n["rigidity_ratio_min"] >= 1.0 - 1e-3 and n["lift_off_ratio_min"] >= 1.0 - 1e-3, n
    # the friction energy per cycle on the loop's 1 ms grid against the schedule's own sum on its 10 ms grid
    assert n["planned_friction_energy_per_cycle"] == pytest.approx(schedule.friction_energy_J, rel=0.01)
    assert n["constant_friction_energy_per_cycle"] == pytest.approx(schedule.constant_friction_energy_J, rel=0.01)


def test_a_lagging_loop_gets_a_margin_and_then_keeps_the_rigidity(axis):
    from piezopreload.design.system import track_schedule
    from piezopreload.models.controller import Controller, PIDGains

    spec, opt, plant, schedule = axis
    # the machine axis's tuned PI without its feedforward: it lags the schedule's ramps
    sluggish = Controller(PIDGains(0.0108, 0.0486, u_min=-20.0, u_max=115.0), 1e-3)
    result = track_schedule(plant, sluggish, schedule, cycles=1, passes=3)
    first, last = result.passes[0], result.passes[-1]
    assert not first["requirements_met"], "the sluggish loop was meant to fall short on the design's own schedule"
    assert len(result.passes) >= 2 and last["preload_margin_N"] > 0, result.passes
    assert min(last["rigidity_ratio_min"], last["lift_off_ratio_min"]) > \
        min(first["rigidity_ratio_min"], first["lift_off_ratio_min"]), result.passes
    assert last["requirements_met"], result.passes
    assert result.margin_N == last["preload_margin_N"] and result.to_dict()["series"]["time_s"]
