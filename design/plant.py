"""The designed preload system as the plant: from the design optimum to the rig the controller runs on.

The design (:mod:`piezopreload.design.preload`) fixes the screw, the bolts' preload and the
stacks (type, count, drive, the amplifier's current limit). The plant the force loop controls
is then (``docs/models.md``, section 3 and the ball screw):

* the stacks' free stroke per volt from the stack type (nominal travel at 100 V), their
  hysteresis and creep, the amplifier's bandwidth and range and the force sensors' range,
  resolution and noise from the study's hardware table (``[rig]``, the parts the design does
  not set);
* the slew limit from the amplifier's current limit on the stacks' capacitance (the design's
  amplifier, ``n`` stacks in parallel);
* the coupling the stacks push against: the two nuts in series (each with the nut law
  ``delta(F) = (c_h F^(2/3) + s F) / f_ar``, evaluated at the bolts' preload plus the stacks'
  force: the Hertz part stays nonlinear in the plant step, :func:`~piezopreload.models.actuator.hertz_force`),
  the stacks themselves, and the sleeve and bolts (linear);
* the sensors sit in series with the stacks and read the stacks' share of the preload, so the
  reference is the scheduled preload less the bolts'.

The plant records the design artifact's hash: a changed design makes another plant, and the
pipeline runs everything after it again. Its type, :class:`DesignedPlant`, is the plant artifact's
(:mod:`piezopreload.artifacts.plant`): what this module makes is what the plant stage writes and
every later stage loads.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from piezopreload.artifacts.design import DesignPoint
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.core.errors import InputError
from piezopreload.design.preload import DesignOptimum, DesignSpec
from piezopreload.models.actuator import Plant, bouc_wen_increment

__all__ = ["plant_from_design", "DESIGNED_FIELDS"]

#: the rig parameters the design sets (:func:`plant_from_design`); the others come from the study's hardware table
DESIGNED_FIELDS = ("stack", "n_stacks", "amp_current_limit_A", "stroke_um_per_V", "coupling_stiffness_N_per_um",
                   "bolt_preload_N", "hertz_um_per_N23", "hertz_preload_N")


def plant_from_design(spec: DesignSpec, design: DesignOptimum | DesignPoint, hardware: Plant, *,
                      design_sha256: str, sleeve_stiffness_N_per_um: float = math.inf) -> DesignedPlant:
    """The plant of ``design``, an optimum or its point (module docstring).

    ``hardware`` gives what the design does not set: the amplifier's bandwidth and range, the
    force sensors (range, bits, noise), the stacks' hysteresis and creep, the sample period and
    the delay. The design sets the stack type and count, the amplifier's current limit, the
    stroke per volt (the type's nominal travel on the rising branch at 100 V) and the coupling (the nuts' Hertz law
    at the bolts' preload, their bodies, the sleeve and bolts). ``sleeve_stiffness_N_per_um``:
    the sleeve and the bolts in series (inf: rigid).
    """
    if not (sleeve_stiffness_N_per_um > 0):
        raise InputError(f"sleeve_stiffness_N_per_um: must be > 0 (inf for a rigid sleeve), got "
                         f"{sleeve_stiffness_N_per_um!r}")
    p = design.point if isinstance(design, DesignOptimum) else design
    screw = spec.screw(p)
    act = spec.actuator
    # the data sheet's nominal travel is the rising branch's at 100 V, hysteresis included: the
    # anhysteretic stroke per volt that gives it on the study's Bouc-Wen loop (exact on a monotone rise)
    v = 100.0
    h = float(bouc_wen_increment(0.0, v, hardware.bw_alpha, hardware.bw_beta_per_V, hardware.bw_gamma_per_V))
    stroke_um_per_V = act.stack.nominal_travel_um / (v + float(hardware.bw_kappa) * v * v / 100.0 - h)
    linear_um_per_N = (2.0 * screw.structural_compliance_um_per_N / screw.accuracy_factor
                       + 1.0 / sleeve_stiffness_N_per_um)
    designed: dict[str, Any] = {
                "stack": act.stack, "n_stacks": act.n_stacks, "amp_current_limit_A": act.amp_current_limit_A,
                "stroke_um_per_V": stroke_um_per_V, "coupling_stiffness_N_per_um": 1.0 / linear_um_per_N,
                "bolt_preload_N": 0.0, "hertz_um_per_N23": 2.0 * screw.axial_constant_um / screw.accuracy_factor,
                "hertz_preload_N": float(p.bolt_preload_N)}
    try:
        rig = replace(hardware, **{name: designed[name] for name in DESIGNED_FIELDS})
    except ValueError as exc:
        raise InputError(f"the plant of the design is not valid: {exc}") from exc
    return DesignedPlant(rig=rig, screw=screw, bolt_preload_N=float(p.bolt_preload_N),
                         max_preload_N=float(p.max_preload_N),
                         sleeve_stiffness_N_per_um=float(sleeve_stiffness_N_per_um), design_sha256=design_sha256)
