"""The plant artifact (kind ``plant``): the designed preload system as the rig the force loop controls.

:func:`piezopreload.design.plant.plant_from_design` makes a :class:`DesignedPlant` from a design
optimum; :meth:`DesignedPlant.save` writes it and :meth:`DesignedPlant.load` reads it back whole
(the rig, the double nut's screw, the preload range, the sleeve), so the control stages, the system
stage and the report take the plant from the one file the plant stage wrote.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.artifacts._fields import Fields
from piezopreload.core._typing import Array
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.models.actuator import Plant
from piezopreload.models.ballscrew import BallScrew, Material

__all__ = ["DesignedPlant", "KIND"]

KIND = "plant"

#: the screw's fields the artifact records (its ``screw`` object), every one BallScrew takes
_SCREW_FIELDS = tuple(f.name for f in fields(BallScrew) if f.name != "material")


def _screw_to_dict(s: BallScrew) -> dict[str, Any]:
    return {**{name: getattr(s, name) for name in _SCREW_FIELDS}, "balls_per_nut": s.balls_per_nut,
            "material": {"E_MPa": s.material.E_MPa, "poisson": s.material.poisson}}


def _screw_from_fields(f: Fields) -> BallScrew:
    values: dict[str, Any] = {}
    for name in _SCREW_FIELDS:
        if f.has(name):
            values[name] = int(f.integer(name)) if name == "balls_per_turn" else f.number(name)
    m = f.sub("material") if f.has("material") else None
    material = Material() if m is None else m.build(lambda: Material(m.number("E_MPa"), m.number("poisson")))
    return f.build(lambda: BallScrew(**values, material=material))


@dataclass(frozen=True, eq=False)
class DesignedPlant:
    """The rig of a designed preload system and where its numbers come from.

    ``rig`` is the plant (:class:`Plant`, Hertzian coupling); ``screw`` the optimum's
    double nut; ``bolt_preload_N`` and ``max_preload_N`` the design's preload range;
    ``sleeve_stiffness_N_per_um`` the sleeve and bolts (inf: rigid); ``design_sha256`` the design
    artifact the plant was made from; ``inputs`` the hashes the plant artifact records.
    """

    rig: Plant
    screw: BallScrew
    bolt_preload_N: float
    max_preload_N: float
    sleeve_stiffness_N_per_um: float
    design_sha256: str
    inputs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 0 < self.bolt_preload_N < self.max_preload_N < math.inf:
            raise ValueError(f"DesignedPlant needs 0 < bolt_preload_N < max_preload_N, got {self.bolt_preload_N!r} "
                             f"and {self.max_preload_N!r}.")
        if not self.sleeve_stiffness_N_per_um > 0:
            raise ValueError(f"DesignedPlant.sleeve_stiffness_N_per_um must be > 0 (inf: rigid), got "
                             f"{self.sleeve_stiffness_N_per_um!r}.")

    @property
    def nut_structural_um_per_N(self) -> float:
        """Both nuts' bodies and the screw under them, in series: ``2 s / f_ar`` (um/N)."""
        return 2.0 * self.screw.structural_compliance_um_per_N / self.screw.accuracy_factor

    @property
    def stack_force_max_N(self) -> float:
        """The stacks' share at the top of the preload range."""
        return self.max_preload_N - self.bolt_preload_N

    def stack_force_N(self, preload_N: ArrayLike) -> Array:
        """The stacks' share of a preload: the preload less the bolts'."""
        return np.asarray(preload_N, float) - self.bolt_preload_N

    def preload_N(self, stack_force_N: ArrayLike) -> Array:
        """The preload for the stacks' force ``stack_force_N``."""
        return np.asarray(stack_force_N, float) + self.bolt_preload_N

    def nut_rigidity_N_per_um(self, preload_N: ArrayLike, step_N: float = 1e-3) -> Array:
        """The double nut's axial rigidity at ``preload_N`` as the plant has it.

        The plant's local stroke compliance ``dx/dF_E`` (a central difference of
        :meth:`Plant.stroke_for_force_um`) less the stacks' and the sleeve's compliance is the
        two nuts in series, ``2 delta'(F)``; an external load meets them in parallel, so the
        rigidity is ``2 / delta'(F) = 4 / (2 delta'(F))``.
        """
        f = self.stack_force_N(preload_N)
        dx = (self.rig.stroke_for_force_um(f + step_N) - self.rig.stroke_for_force_um(f - step_N)) / (2.0 * step_N)
        nuts = dx - 1.0 / self.rig.stack_stiffness_N_per_um - 1.0 / self.sleeve_stiffness_N_per_um
        return 4.0 / nuts

    def local_stiffness_N_per_um(self) -> dict[str, float]:
        """The coupling's local stiffness the stacks push against, at the bolts' preload and at the top."""
        return {"at_bolts": float(self.rig.local_stiffness_N_per_um(0.0)),
                "at_max": float(self.rig.local_stiffness_N_per_um(self.stack_force_max_N))}

    # ---- the artifact: one writer, one reader ----------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The plant artifact's body: the rig and its origin (the layout the plant artifact has always had, the
        screw's every field added so the artifact makes the plant again)."""
        return {"rig": self.rig.to_dict(), "design_sha256": self.design_sha256,
                "bolt_preload_N": self.bolt_preload_N, "max_preload_N": self.max_preload_N,
                "stack_force_max_N": self.stack_force_max_N,
                "sleeve_stiffness_N_per_um": (None if math.isinf(self.sleeve_stiffness_N_per_um)
                                              else self.sleeve_stiffness_N_per_um),
                "nut_hertz_um_per_N23": float(self.rig.hertz_um_per_N23),
                "nut_structural_um_per_N": self.nut_structural_um_per_N, "screw": _screw_to_dict(self.screw),
                "slew_V_per_s": float(self.rig.slew_V_per_s),
                "local_stiffness_N_per_um": self.local_stiffness_N_per_um(), "inputs": dict(self.inputs)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the plant") -> DesignedPlant:
        """The inverse of :meth:`to_dict`; an :class:`~piezopreload.core.errors.ArtifactError` names the field."""
        f = Fields(doc, shown)
        try:
            rig = Plant.from_dict(f.mapping("rig"))
        except (KeyError, TypeError, ValueError) as exc:
            raise f.fail("rig", f"is not a rig: {exc}") from None
        sleeve = f.optional_number("sleeve_stiffness_N_per_um")
        return f.build(lambda: cls(
            rig=rig, screw=_screw_from_fields(f.sub("screw")), bolt_preload_N=f.number("bolt_preload_N"),
            max_preload_N=f.number("max_preload_N"), sleeve_stiffness_N_per_um=math.inf if sleeve is None else sleeve,
            design_sha256=f.text("design_sha256"), inputs=f.mapping("inputs", {})))

    def save(self, path: str | Path, inputs: dict[str, Any] | None = None) -> Path:
        """Write the plant artifact (kind ``plant``) atomically; ``inputs`` replaces the recorded inputs."""
        record = self if inputs is None else replace(self, inputs=dict(inputs))
        write_artifact(path, KIND, record.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> DesignedPlant:
        """Read a plant artifact: its schema and every field checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))
