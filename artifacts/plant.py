"""The plant artifact (kind ``plant``): the designed preload system as the rig the force loop controls.

:func:`piezopreload.design.plant.plant_from_design` makes a :class:`DesignedPlant` from a design
optimum; :meth:`DesignedPlant.save` writes it and :meth:`DesignedPlant.load` reads it back whole
(the rig, the double nut's screw, the preload range, the sleeve), so the control stages, the system
stage and the report take the plant from the one file the plant stage wrote.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.core._typing import Array
from piezopreload.core.records import SavedArtifact, entry, record
from piezopreload.models.actuator import Plant
from piezopreload.models.ballscrew import BallScrew

__all__ = ["DesignedPlant", "KIND"]

KIND = "plant"

def _sleeve_from(x: Any) -> float:
    if x is None:
        return math.inf
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ValueError(f"expected a finite number, or null for a rigid sleeve, got {x!r}")
    return float(x)


def _sleeve_to(x: float) -> float | None:
    return None if math.isinf(x) else x


@record(eq=False)
class DesignedPlant(SavedArtifact):
    """The rig of a designed preload system and where its numbers come from."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the plant"
    AGAIN: ClassVar[str] = "run the plant stage again"

    rig: Plant = entry("The plant (:class:`~piezopreload.models.actuator.Plant`, Hertzian coupling).",
                       read=Plant.from_dict, write=Plant.to_dict, takes="a rig's parameters")
    screw: BallScrew = entry("The optimum's double nut.", read=BallScrew.from_dict, write=BallScrew.to_dict,
                             takes="an object of the screw's fields")
    bolt_preload_N: float = entry("The bolts' preload: the bottom of the design's preload range.", unit="N")
    max_preload_N: float = entry("The top of the design's preload range.", unit="N")
    sleeve_stiffness_N_per_um: float = entry("The sleeve and bolts (inf: rigid, null in the document).",
                                             unit="N/um", read=_sleeve_from, write=_sleeve_to, absent=math.inf,
                                             takes="a finite number, or null for a rigid sleeve")
    design_sha256: str = entry("The design artifact the plant was made from.")
    inputs: dict[str, Any] = entry("The hashes the plant artifact records.", default={}, required=True)

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
        """The stacks' share of a preload: the preload less the bolts'.

        Parameters
        ----------
        preload_N : array_like
            The nut's preload, in N.

        Returns
        -------
        ndarray
            The force the stacks carry, in N: ``preload_N`` less :attr:`bolt_preload_N` (same shape).
        """
        return np.asarray(preload_N, float) - self.bolt_preload_N

    def preload_N(self, stack_force_N: ArrayLike) -> Array:
        """The preload for the stacks' force ``stack_force_N``.

        Parameters
        ----------
        stack_force_N : array_like
            The force the stacks carry, in N.

        Returns
        -------
        ndarray
            The nut's preload, in N: ``stack_force_N`` plus :attr:`bolt_preload_N` (same shape).
        """
        return np.asarray(stack_force_N, float) + self.bolt_preload_N

    def nut_rigidity_N_per_um(self, preload_N: ArrayLike, step_N: float = 1e-3) -> Array:
        """The double nut's axial rigidity at ``preload_N`` as the plant has it.

        The plant's local stroke compliance ``dx/dF_E`` (a central difference of
        :meth:`Plant.stroke_for_force_um`) less the stacks' and the sleeve's compliance is the
        two nuts in series, ``2 delta'(F)``; an external load meets them in parallel, so the
        rigidity is ``2 / delta'(F) = 4 / (2 delta'(F))``.

        Parameters
        ----------
        preload_N : array_like
            The nut's preload, in N.
        step_N : float
            The half step of the central difference of the stroke, in N.

        Returns
        -------
        ndarray
            The double nut's axial rigidity at each preload, in N/um (same shape as ``preload_N``).
        """
        f = self.stack_force_N(preload_N)
        dx = (self.rig.stroke_for_force_um(f + step_N) - self.rig.stroke_for_force_um(f - step_N)) / (2.0 * step_N)
        nuts = dx - 1.0 / self.rig.stack_stiffness_N_per_um - 1.0 / self.sleeve_stiffness_N_per_um
        return 4.0 / nuts

    def local_stiffness_N_per_um(self) -> dict[str, float]:
        """The coupling's local stiffness the stacks push against, at the bolts' preload and at the top.

        Returns
        -------
        dict of str to float
            ``at_bolts``: the local stiffness at the bolts' preload alone (no stack force); ``at_max``: at the stacks'
            largest force :attr:`stack_force_max_N`; both in N/um.
        """
        return {"at_bolts": float(self.rig.local_stiffness_N_per_um(0.0)),
                "at_max": float(self.rig.local_stiffness_N_per_um(self.stack_force_max_N))}

    # ---- the artifact: one writer, one reader ----------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The plant artifact's body: the rig and its origin, and the figures derived from them (the stacks' force
        at the top, the nut's compliances, the slew limit, the coupling's stiffness).

        Returns
        -------
        dict
            The document's body.
        """
        return {**super().to_dict(), "stack_force_max_N": self.stack_force_max_N,
                "nut_hertz_um_per_N23": float(self.rig.hertz_um_per_N23),
                "nut_structural_um_per_N": self.nut_structural_um_per_N, "slew_V_per_s": float(self.rig.slew_V_per_s),
                "local_stiffness_N_per_um": self.local_stiffness_N_per_um()}

    def save(self, path: str | Path, inputs: dict[str, Any] | None = None) -> Path:
        """Write the plant artifact (kind ``plant``) atomically.

        Parameters
        ----------
        path : str or Path
            The file.
        inputs : dict or None
            The recorded inputs to write instead of its own (None: its own).

        Returns
        -------
        Path
            The file written.
        """
        return super().save(path) if inputs is None else replace(self, inputs=dict(inputs)).save(path)
