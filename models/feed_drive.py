"""The feed drive's axial stiffness chain, its first axial mode, and the piezo stacks' reach.

Figure 2 and eq. (1) of the paper: the table (mass m) sits on the double nut; the nut on the
screw; the screw in a bearing at each end. Axially,

* each side of the nut is a screw segment (E A / length, A from the root diameter) in series
  with its end bearing: k_left = (1/k_ba + x/(E A))^-1, k_right likewise over L - x;
* with both ends fixed axially ("fixed-fixed") the two sides act in parallel; with one end
  fixed and the other floating ("fixed-supported") only the fixed side carries axial load;
* the nut's rigidity (the contacts, the nut body and the screw under the nut: the paper's
  k_bsb and k_nut, what a catalogue tabulates; :meth:`BallScrew.nut_loads`) is in series:
  1/k = 1/k_nut + 1/k_screw_and_bearings;

and the axial natural frequency is f = sqrt(k / m) / (2 pi) (eq. (1), undamped). It changes
with the preload (through k_nut, as F_p^(1/3)) and with the table's position x (through the
screw segments).

The stacks between the nuts (the paper's three P-888.91) push the nuts apart: raising the
preload from the bolts' F_i to F_p shifts both nuts on the screw by their nut law,
2 (delta(F_p) - delta(F_i)) with delta(F) = (c_h F^(2/3) + s F) / f_ar (contacts and nut body,
:meth:`BallScrew.nut_approach_um`), and compresses the stacks themselves by
(F_p - F_i) / (n k_stack); the two together cannot exceed the stacks' free stroke at the drive
voltage.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.core._typing import Array
from piezopreload.models.actuator import P888_91, StackData
from piezopreload.models.ballscrew import BallScrew

__all__ = ["FeedDrive", "PiezoPreload", "Mounting", "MOUNTINGS", "stack_loop_um"]


class Mounting(StrEnum):
    """How a feed drive's screw ends are held axially: both fixed, or one fixed and the other floating (its value is
    what a study file and an artifact write)."""

    FIXED_FIXED = "fixed-fixed"
    FIXED_SUPPORTED = "fixed-supported"


#: the mountings, in their order
MOUNTINGS = tuple(Mounting)


@dataclass(frozen=True)
class FeedDrive:
    """One linear axis: table mass, screw length between bearings, bearings, travel.

    ``position_mm`` everywhere is the distance of the nut's centre from the fixed bearing A.
    """

    table_mass_kg: float
    screw_length_mm: float
    bearing_stiffness_N_per_um: float
    travel_mm: tuple[float, float]
    mounting: Mounting = Mounting.FIXED_FIXED
    E_MPa: float = 206e3

    def __post_init__(self) -> None:
        for name in ("table_mass_kg", "screw_length_mm", "bearing_stiffness_N_per_um", "E_MPa"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"FeedDrive.{name} must be a finite number > 0, got {value!r}.")
        if self.mounting not in MOUNTINGS:
            raise ValueError(f"FeedDrive.mounting must be one of {', '.join(MOUNTINGS)}, got {self.mounting!r}.")
        object.__setattr__(self, "mounting", Mounting(self.mounting))  # given as its string: held as the member
        lo, hi = self.travel_mm
        if not 0 < lo < hi < self.screw_length_mm:
            raise ValueError(f"FeedDrive.travel_mm must satisfy 0 < start < end < screw_length_mm "
                             f"({self.screw_length_mm}), got {self.travel_mm!r}.")

    def screw_side_stiffness_N_per_um(self, root_diameter_mm: Any, position_mm: ArrayLike) -> Any:
        """Screw segments and bearings as seen from the nut at ``position_mm`` (the root
        diameter may be a number or a CasADi expression, the position a number or array)."""
        x: Any = np.asarray(position_mm, float)
        if x.ndim == 0:
            x = float(x)
        EA = self.E_MPa * math.pi * root_diameter_mm ** 2 / 4.0 * 1e-3  # N/um * mm
        kb = self.bearing_stiffness_N_per_um
        left = 1.0 / (1.0 / kb + x / EA)
        if self.mounting is Mounting.FIXED_SUPPORTED:
            return left
        right = 1.0 / (1.0 / kb + (self.screw_length_mm - x) / EA)
        return left + right

    def axial_stiffness_N_per_um(self, screw: BallScrew, preload_N: ArrayLike, position_mm: ArrayLike,
                                 axial_load_N: ArrayLike = 0.0) -> Array:
        """The chain's axial stiffness at the table (N/um)."""
        k_nut = screw.rigidity_N_per_um(preload_N, axial_load_N)
        k_side = self.screw_side_stiffness_N_per_um(screw.root_diameter_mm, position_mm)
        stiffness: Array = 1.0 / (1.0 / k_nut + 1.0 / k_side)
        return stiffness

    def natural_frequency_Hz(self, screw: BallScrew, preload_N: ArrayLike, position_mm: ArrayLike) -> Array:
        """First axial mode of the table on the chain, eq. (1) of the paper: sqrt(k/m)/(2 pi)."""
        k = self.axial_stiffness_N_per_um(screw, preload_N, position_mm) * 1e6
        return np.sqrt(k / self.table_mass_kg) / (2.0 * math.pi)

    def weakest_position_mm(self) -> float:
        """Where in the travel the screw side is softest (the end farthest from both bearings)."""
        if self.mounting is Mounting.FIXED_SUPPORTED:
            return float(self.travel_mm[1])
        lo, hi = self.travel_mm
        mid = 0.5 * self.screw_length_mm
        return float(min(max(mid, lo), hi))


def stack_loop_um(c_h_um: Any, bolt_preload_N: Any, preload_N: Any, stack_stiffness_N_per_um: Any,
                  structural_um_per_N: Any = 0.0, accuracy_factor: Any = 1.0) -> Any:
    """Stroke (um) the stacks need to raise the preload from the bolts' F_i to F_p.

    Both nuts shift by their nut law, 2 [c_h (F_p^(2/3) - F_i^(2/3)) + s (F_p - F_i)] / f_ar,
    and the stacks themselves (n in parallel, stiffness ``stack_stiffness_N_per_um`` together)
    compress by (F_p - F_i) / k. Works on numbers and on CasADi expressions.
    """
    return (2.0 * (c_h_um * (preload_N ** (2.0 / 3.0) - bolt_preload_N ** (2.0 / 3.0))
                   + structural_um_per_N * (preload_N - bolt_preload_N)) / accuracy_factor
            + (preload_N - bolt_preload_N) / stack_stiffness_N_per_um)


@dataclass(frozen=True)
class PiezoPreload:
    """n stacks between the nuts, driven up to ``drive_V`` by an amplifier of limited current."""

    stack: StackData = P888_91
    n_stacks: int = 3
    drive_V: float = 100.0
    amp_current_limit_A: float = 0.1

    def __post_init__(self) -> None:
        if not (isinstance(self.n_stacks, int) and self.n_stacks >= 1):
            raise ValueError(f"PiezoPreload.n_stacks must be a positive integer, got {self.n_stacks!r}.")
        if not 0 < self.drive_V <= self.stack.v_max_V:
            raise ValueError(f"PiezoPreload.drive_V must be in (0, {self.stack.v_max_V}] (the stack's limit), "
                             f"got {self.drive_V!r}.")
        if not (math.isfinite(self.amp_current_limit_A) and self.amp_current_limit_A > 0):
            raise ValueError(f"PiezoPreload.amp_current_limit_A must be > 0, got {self.amp_current_limit_A!r}.")

    @property
    def stroke_um(self) -> float:
        """Free stroke at the drive voltage (nominal travel is at 100 V)."""
        return self.stack.nominal_travel_um * self.drive_V / 100.0

    @property
    def stiffness_N_per_um(self) -> float:
        return self.n_stacks * self.stack.stiffness_N_per_um

    @property
    def blocked_force_N(self) -> float:
        return self.n_stacks * self.stack.blocked_force_N * self.drive_V / 100.0

    @property
    def voltage_slew_V_per_s(self) -> float:
        """The amplifier's current limit charging the stacks' capacitance."""
        return self.amp_current_limit_A / (self.n_stacks * self.stack.capacitance_uF * 1e-6)

    def max_preload_N(self, screw: BallScrew, bolt_preload_N: float) -> float:
        """The highest preload the stacks reach at the drive voltage from the bolts' preload."""
        if not bolt_preload_N > 0:
            raise ValueError(f"bolt_preload_N must be > 0, got {bolt_preload_N!r}.")
        c_h, s, k = screw.axial_constant_um, screw.structural_compliance_um_per_N, self.stiffness_N_per_um

        def gap(fp: float) -> float:
            return float(stack_loop_um(c_h, bolt_preload_N, fp, k, s, screw.accuracy_factor) - self.stroke_um)

        hi = bolt_preload_N + self.blocked_force_N * 1.01
        from scipy.optimize import brentq  # scipy.optimize loads on first use, not on import

        return float(brentq(gap, bolt_preload_N, hi, xtol=1e-9, rtol=1e-12))

    def preload_slew_N_per_s(self, screw: BallScrew, preload_N: float, bolt_preload_N: float) -> float:
        """How fast the preload can change at ``preload_N``: voltage slew times dF_p/dV."""
        c_h, s, k = screw.axial_constant_um, screw.structural_compliance_um_per_N, self.stiffness_N_per_um
        dloop_dF = 2.0 * (c_h * (2.0 / 3.0) * preload_N ** (-1.0 / 3.0) + s) / screw.accuracy_factor + 1.0 / k
        dstroke_dV = self.stack.nominal_travel_um / 100.0
        return float(self.voltage_slew_V_per_s * dstroke_dV / dloop_dF)
