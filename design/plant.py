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
pipeline runs everything after it again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.artifacts import write_artifact
from piezopreload.core.errors import InputError
from piezopreload.design.preload import DesignOptimum, DesignPoint, DesignSpec
from piezopreload.models.actuator import RigParams, bouc_wen_increment
from piezopreload.models.ballscrew import BallScrew

__all__ = ["DesignedPlant", "plant_from_design", "DESIGNED_FIELDS"]

#: the rig parameters the design sets (:func:`plant_from_design`); the others come from the study's hardware table
DESIGNED_FIELDS = ("stack", "n_stacks", "amp_current_limit_A", "stroke_um_per_V", "coupling_stiffness_N_per_um",
                   "bolt_preload_N", "hertz_um_per_N23", "hertz_preload_N")

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class DesignedPlant:
    """The rig of a designed preload system and where its numbers come from.

    ``rig`` is the plant (:class:`RigParams`, Hertzian coupling); ``screw`` the optimum's
    double nut; ``bolt_preload_N`` and ``max_preload_N`` the design's preload range;
    ``sleeve_stiffness_N_per_um`` the sleeve and bolts; ``design_sha256`` the design artifact
    the plant was made from.
    """

    rig: RigParams
    screw: BallScrew
    bolt_preload_N: float
    max_preload_N: float
    sleeve_stiffness_N_per_um: float
    design_sha256: str

    @property
    def nut_structural_um_per_N(self) -> float:
        """Both nuts' bodies and the screw under them, in series: ``2 s / f_ar`` (um/N)."""
        return 2.0 * self.screw.structural_compliance_um_per_N / self.screw.accuracy_factor

    def stack_force_N(self, preload_N: ArrayLike) -> Array:
        """The stacks' share of a preload: the preload less the bolts'."""
        return np.asarray(preload_N, float) - self.bolt_preload_N

    def preload_N(self, stack_force_N: ArrayLike) -> Array:
        """The preload for the stacks' force ``stack_force_N``."""
        return np.asarray(stack_force_N, float) + self.bolt_preload_N

    def nut_rigidity_N_per_um(self, preload_N: ArrayLike, step_N: float = 1e-3) -> Array:
        """The double nut's axial rigidity at ``preload_N`` as the plant has it.

        The plant's local stroke compliance ``dx/dF_E`` (a central difference of
        :meth:`RigParams.stroke_for_force_um`) less the stacks' and the sleeve's compliance is the
        two nuts in series, ``2 delta'(F)``; an external load meets them in parallel, so the
        rigidity is ``2 / delta'(F) = 4 / (2 delta'(F))``.
        """
        f = self.stack_force_N(preload_N)
        dx = (self.rig.stroke_for_force_um(f + step_N) - self.rig.stroke_for_force_um(f - step_N)) / (2.0 * step_N)
        nuts = dx - 1.0 / self.rig.stack_stiffness_N_per_um - 1.0 / self.sleeve_stiffness_N_per_um
        return 4.0 / nuts

    def save(self, path: str | Path, inputs: dict[str, Any]) -> Path:
        """Write the plant artifact (kind ``plant``): :meth:`to_dict` and ``inputs``."""
        write_artifact(path, "plant", {**self.to_dict(), "inputs": inputs})
        return Path(path)

    def to_dict(self) -> dict[str, Any]:
        """The plant artifact's body: the rig and its origin."""
        s = self.screw
        return {"rig": self.rig.to_dict(), "design_sha256": self.design_sha256,
                "bolt_preload_N": self.bolt_preload_N, "max_preload_N": self.max_preload_N,
                "stack_force_max_N": self.max_preload_N - self.bolt_preload_N,
                "sleeve_stiffness_N_per_um": (None if math.isinf(self.sleeve_stiffness_N_per_um)
                                              else self.sleeve_stiffness_N_per_um),
                "nut_hertz_um_per_N23": float(self.rig.hertz_um_per_N23),
                "nut_structural_um_per_N": self.nut_structural_um_per_N,
                "screw": {"nominal_diameter_mm": s.nominal_diameter_mm, "lead_mm": s.lead_mm, "ball_mm": s.ball_mm,
                          "turns": s.turns, "contact_angle_deg": s.contact_angle_deg,
                          "balls_per_nut": s.balls_per_nut},
                "slew_V_per_s": float(self.rig.slew_V_per_s),
                "local_stiffness_N_per_um": {
                    "at_bolts": float(self.rig.local_stiffness_N_per_um(0.0)),
                    "at_max": float(self.rig.local_stiffness_N_per_um(self.max_preload_N - self.bolt_preload_N))}}


def plant_from_design(spec: DesignSpec, design: DesignOptimum | DesignPoint, hardware: RigParams, *,
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
    linear_um_per_N = 2.0 * screw.structural_compliance_um_per_N / screw.accuracy_factor + 1.0 / sleeve_stiffness_N_per_um
    designed = {"stack": act.stack, "n_stacks": act.n_stacks, "amp_current_limit_A": act.amp_current_limit_A,
                "stroke_um_per_V": stroke_um_per_V, "coupling_stiffness_N_per_um": 1.0 / linear_um_per_N,
                "bolt_preload_N": 0.0, "hertz_um_per_N23": 2.0 * screw.axial_constant_um / screw.accuracy_factor,
                "hertz_preload_N": float(p.bolt_preload_N)}
    try:
        rig = replace(hardware, **{name: designed[name] for name in DESIGNED_FIELDS})
    except ValueError as exc:
        raise InputError(f"the plant of the design is not valid: {exc}") from exc
    return DesignedPlant(rig=rig, screw=screw, bolt_preload_N=float(p.bolt_preload_N),
                         max_preload_N=float(p.max_preload_N), sleeve_stiffness_N_per_um=float(sleeve_stiffness_N_per_um),
                         design_sha256=design_sha256)
