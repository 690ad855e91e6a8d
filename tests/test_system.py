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
