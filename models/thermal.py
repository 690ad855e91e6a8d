"""The preload's heat, the axis' temperature and the screw's thermal growth: the physics, pure.

``docs/thermal.md`` states the model, its sources and its limits; in brief:

**Heat at the nut**, two models (both on the ops table, numpy or CasADi):

* *catalogue*: the preload drag torque T_p = K_p F_p P / (2 pi) (HIWIN, NSK, THK) times the screw's
  angular speed omega: linear in the preload, no dependence on speed, lubricant or temperature. The vendors
  measure it without seals (HIWIN: without wipers, 100 rpm, ISO VG 68) and state it with a band of about
  +-30-50 %;
* *contact*: the rolling-contact loss of Jungnickel (2010, eq. 9.49), restated as
  P = z mu F_c r omega / cos(lambda) with the rolling friction coefficient
  mu = 9.16 G^-0.2 W^-e U^k2, the load parameter W = F_c / (E' r_b^2), the material parameter
  G = alpha_p E', the speed parameter U = eta(T) omega R / (2 E' cos(lambda)), the contact force
  F_c = F_p / (z sin(beta) cos(lambda)) of the z loaded balls of one nut and R = r / r_b. For the double nut
  with two-point contact k2 = 0.512 and e = 0.516: the loss grows as F_p^0.484, omega^1.512 and the
  viscosity^0.512. As restated it gives 5-20 % of the measured drag torques at the vendors' measuring speed,
  so it carries a calibration factor c (:data:`CONTACT_CALIBRATION`, 6): fitted at that speed (100 rpm, VG68
  at a bench's 20 deg C) to THK's worked example (BNFN4010 at 3,000 N, 0.865 N m +-30 %) and the measured
  torques of a run-to-failure dataset (XJTU: lead 8 mm, C 16.4 kN, 1,500 N, 0.25-0.52 N m, diameter not
  stated), each within its band. What the data allow is that level to about +-50 %; none of them tests the
  speed law, so the catalogue's torque (flat in speed) and the calibrated contact loss (torque ~ omega^0.51)
  remain the two bounds at a machining speed.

**The seals** are a torque of their own in both models, T_s omega, independent of the preload: the vendors
list it apart from the preload drag torque (Rexroth, "Friction torques of seals": the idle torque of the two
lip seals of a nut, single or double alike, by nominal diameter and lead, :func:`rexroth_seal_torque_Nm`;
THK books it under "other torque" beside the support bearings). Jungnickel's fit carries a factor s = 2 for
a sealed nut instead; that factor doubles the contacts' loss with the preload, so it is not used: the contact
model is his open nut (s = 1) plus the same seal torque as the catalogue model, and the seals are counted
once in either.

**The support bearings** (Palmgren): M = M0 + M1, M0 = 1e-7 f0 max(nu n, 2000)^(2/3) dm^3 (N mm; nu in
mm^2/s, n in rpm, dm in mm; below nu n = 2000 the constant 160e-7 f0 dm^3), M1 = f1 F dm.

**Temperature.** The screw between its bearings is a row of finite volumes along its length (conduction
k A_c / dx between neighbours, the root section's heat capacity), each losing heat to the air through a
rotating shaft's film coefficient (Nu = 0.133 Re^(2/3) Pr^(1/3), Re = omega d^2 / nu_air, no less than free
convection) and, in a hollow screw with coolant, to the coolant (the pipe flow's Nusselt number); its end
volumes conduct into their bearings (half a volume of screw in series with the bearing's conductance). The
nut and its flange are lumped bodies: the nut takes its share of the friction heat, loses heat to the air
and to the flange, the flange to the table. Every body's temperature is a rise above the ambient, so the
model is linear, C dT/dt = -K T + q, with C the heat capacities and K the symmetric conductance matrix.

**Two time scales.** A machining cycle of seconds is far shorter than the screw's time constant
(rho c d / (4 h), tens of minutes): over a shift of repeated cycles the cycle-averaged heat q and film
coefficient drive the slow model, whose solution :meth:`Network.response` evaluates exactly (the symmetric
eigen-decomposition of C^(-1/2) K C^(-1/2)) at any time, at no cost per hour simulated.
:class:`FineMarch` is the same network stepped through every cycle (Crank-Nicolson, the heat where the nut
is at each step): the reference the averaged model is checked against.

**Growth** from the screw's temperature rise, u(x) = alpha int_0^x dT, for its mounting: fixed-free (the
far end floats), fixed-fixed (both ends held by a preloaded pair of angular-contact bearings), pretensioned
(fixed-fixed, stretched at assembly by F_t = alpha dT_p E A: the ends start in tension, and the warming screw
relieves it, then pushes against them). Both held mountings are one model: the free elongation G = g(L) is
shared between the screw's own compression, (F + F_t) L / (E A), and both ends' shifts, each end a pair whose
rows follow the Hertz law F ~ delta^(3/2) like the double nut's (:func:`pair_shift_m`): stiffness k_b at its
preload F_b (the study's bearing stiffness), one row unloaded beyond the pair's lift-off 2^(3/2) F_b (the
rule the catalogues give for a preloaded double nut, the same law: BALLSCREW_REFERENCES; for a bearing pair,
e.g. Harris, Rolling Bearing Analysis), after which the loaded row alone holds the push at its own, lower
stiffness. The ends' force F (compressive > 0) solves G - (F + F_t) L / (E A) = 2 (delta(F) - delta(-F_t)),
and u(x) = g(x) - (F + F_t) x / (E A) - (delta(F) - delta(-F_t)). Rigid ends (k_b infinite) keep the length;
a pair of no stated preload is a linear spring k_b. In a semi-closed loop (the encoder on the motor, at
bearing A) u at the table's position is its positioning error.

**Passive preload drift.** A double nut preloaded by a spacer of length L_s between its nuts' loaded turns:
when nut and screw warm differently the spacer's fit changes by m = alpha L_s (T_nut - T_screw), and the
preload F moves along the nuts' own law, 2 delta(F) + F / k_s = 2 delta(F_p) + F_p / k_s + m (delta the
nut law of :meth:`~piezopreload.models.ballscrew.BallScrew.nut_approach_um`, k_s the spacer), down to 0 where
the nuts part. :func:`spacer_drift_N_per_K` is its tangent at F_p (the two nuts' tangent stiffnesses and the
spacer's in series): right for small differences only, the law softening as the preload falls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import eigh, solve_banded

from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, entry
from piezopreload.models.ops import NUMPY

__all__ = [
    "EXPANSION_PER_K", "STEEL_CONDUCTIVITY_W_PER_MK", "STEEL_HEAT_CAPACITY_J_PER_M3K", "VG_GRADES", "OIL_DENSITY",
    "HeatModel", "ThermalMounting", "Feedback", "FEEDBACKS", "HEAT_MODELS",
    "CONTACT_CALIBRATION", "MEASURING_SPEED_RPM", "MEASURING_TEMPERATURE_C", "THERMAL_MOUNTINGS",
    "viscosity_m2_s", "pressure_viscosity_per_Pa", "REXROTH_SEAL_TORQUE_NM", "rexroth_seal_torque_Nm", "seal_heat_W",
    "catalogue_heat_W", "contact_heat_W", "bearing_torque_Nm", "shaft_film_W_per_m2K", "pipe_film_W_per_m2K",
    "ScrewBody", "AxisModel", "Network", "FineMarch", "growth_m", "held_force_N", "end_force_N", "pair_shift_m",
    "pair_lift_off_N", "PAIR_LIFT_OFF_RATIO", "spacer_drift_N_per_K", "nut_coverage",
]

Array = NDArray[np.float64]

#: linear expansion of screw steel (1/K), the catalogues' 11.6e-6
EXPANSION_PER_K = 11.6e-6
#: conductivity of screw steel (W/m K) and its heat capacity per volume (J/m^3 K): 7,850 kg/m^3 x 460 J/kg K
STEEL_CONDUCTIVITY_W_PER_MK = 45.0
STEEL_HEAT_CAPACITY_J_PER_M3K = 7850.0 * 460.0
#: Vogel fits nu = a exp(b / (T + 95)) of mineral oils by ISO VG grade: a (m^2/s), b (K)
VG_GRADES: dict[int, tuple[float, float]] = {
    10: (0.1e-6, 623.0), 22: (0.087e-6, 748.0), 32: (0.0813e-6, 808.0), 46: (0.0762e-6, 866.0),
    68: (0.071e-6, 929.0), 100: (0.0662e-6, 990.0), 150: (0.0616e-6, 1055.0), 220: (0.0575e-6, 1116.0)}
#: a mineral oil's density (kg/m^3)
OIL_DENSITY = 870.0
#: the reduced modulus of Jungnickel's fit (Pa)
_E_PRIME = 2.31e11
#: the factor on Jungnickel's loss that brings it to the measured drag torques at the vendors' measuring speed
#: (module docstring; docs/thermal.md; the tests name each source)
CONTACT_CALIBRATION = 6.0
#: the conditions the vendors measure a drag torque at (HIWIN: 100 rpm, ISO VG 68), the bench at 20 deg C
MEASURING_SPEED_RPM, MEASURING_TEMPERATURE_C = 100.0, 20.0
#: Jungnickel's exponents for a double nut with two-point contact: speed parameter k2, load parameter e
_K2, _E_LOAD = 0.512, 0.516


class HeatModel(StrEnum):
    """The nut's friction heat: the catalogue drag torque times the speed, or Jungnickel's rolling-contact loss (its
    value is what a study file and an artifact write)."""

    CATALOGUE = "catalogue"
    CONTACT = "contact"

    @property
    def other(self) -> HeatModel:
        """The other model (the budget shows it beside the study's as a bound)."""
        return HeatModel.CONTACT if self is HeatModel.CATALOGUE else HeatModel.CATALOGUE


class ThermalMounting(StrEnum):
    """How the screw's ends hold its growth: one end free, both held, or both held with a pretension."""

    FIXED_FREE = "fixed-free"
    FIXED_FIXED = "fixed-fixed"
    PRETENSIONED = "pretensioned"


class Feedback(StrEnum):
    """Where the position loop measures: the motor's encoder (semi-closed: the growth is a positioning error) or a
    linear scale on the table (the growth is not)."""

    SEMI_CLOSED = "semi-closed"
    LINEAR_SCALE = "linear-scale"


#: the heat models, the thermal mountings and the feedbacks, each in its order
HEAT_MODELS = tuple(HeatModel)
THERMAL_MOUNTINGS = tuple(ThermalMounting)
FEEDBACKS = tuple(Feedback)


# ---- the lubricant -------------------------------------------------------------------------------------
def _grade(vg: Any) -> tuple[float, float]:
    if vg not in VG_GRADES:
        raise InputError(f"lubricant_vg must be an ISO VG grade of {', '.join(map(str, VG_GRADES))}, got {vg!r}.")
    return VG_GRADES[vg]


def viscosity_m2_s(vg: int, temperature_C: Any, ops: Any = NUMPY) -> Any:
    """Kinematic viscosity (m^2/s) of ISO VG ``vg`` mineral oil at ``temperature_C`` (its Vogel fit)."""
    a, b = _grade(vg)
    return a * ops.exp(b / (temperature_C + 95.0))


def pressure_viscosity_per_Pa(vg: int) -> float:
    """alpha_p = 1.29e-7 nu40^0.204 (1/Pa, nu40 in m^2/s): about 1.8e-8 for VG68."""
    return float(1.29e-7 * float(viscosity_m2_s(vg, 40.0)) ** 0.204)


#: Rexroth's idle torque (N m) of the two standard lip seals of a nut (one at each end; single or double nut
#: alike), by nominal diameter (mm): (lead mm, torque) points, the torque linear in the lead between them and
#: constant beyond (Rexroth, Precision Ball Screw Assemblies, "Friction torques of seals")
REXROTH_SEAL_TORQUE_NM: dict[float, tuple[tuple[float, float], ...]] = {
    16.0: ((5.0, 0.08), (16.0, 0.08)), 20.0: ((5.0, 0.10), (20.0, 0.12)),
    25.0: ((5.0, 0.12), (10.0, 0.15), (25.0, 0.20)), 32.0: ((5.0, 0.25), (32.0, 0.25)),
    40.0: ((5.0, 0.40), (40.0, 0.40)), 50.0: ((5.0, 0.50), (10.0, 0.60), (40.0, 0.70)),
    63.0: ((10.0, 1.2), (40.0, 1.2)), 80.0: ((10.0, 1.4), (20.0, 2.2))}


def rexroth_seal_torque_Nm(nominal_diameter_mm: float, lead_mm: float) -> float:
    """The seals' idle torque (N m) of a nut of this size by :data:`REXROTH_SEAL_TORQUE_NM`: at a listed
    diameter the torque at the lead (linear between the listed leads, constant beyond); between two listed
    diameters linear in the diameter. Outside 16-80 mm the table says nothing: an :class:`InputError` (state the
    torque instead)."""
    d = float(nominal_diameter_mm)
    sizes = sorted(REXROTH_SEAL_TORQUE_NM)
    if not (math.isfinite(d) and sizes[0] <= d <= sizes[-1]):
        raise InputError(f"the seals' torque is tabulated (Rexroth) for nominal diameters of {sizes[0]:g}-"
                         f"{sizes[-1]:g} mm, not {nominal_diameter_mm!r} mm: state it (seal_torque_Nm).")

    def at(size: float) -> float:
        leads, torques = zip(*REXROTH_SEAL_TORQUE_NM[size])
        return float(np.interp(lead_mm, leads, torques))

    above = next(x for x in sizes if x >= d)
    below = max(x for x in sizes if x <= d)
    if above == below:
        return at(above)
    w = (d - below) / (above - below)
    return (1.0 - w) * at(below) + w * at(above)


# ---- heat at the nut (numpy or CasADi) ------------------------------------------------------------------
def seal_heat_W(seal_torque_Nm: float, omega_rad_s: Any) -> Any:
    """The seals' heat T_s omega (W): their torque does not depend on the preload."""
    return seal_torque_Nm * omega_rad_s


def catalogue_heat_W(ops: Any, drag_coefficient: float, lead_mm: float, preload_N: Any, omega_rad_s: Any) -> Any:
    """The vendors' preload drag torque K_p F_p P / (2000 pi) (N m, P in mm) times omega: an open nut's heat."""
    return drag_coefficient * preload_N * lead_mm / (2000.0 * math.pi) * omega_rad_s


def contact_heat_W(ops: Any, preload_N: Any, omega_rad_s: Any, *, balls: Any, contact_rad: Any,
                   helix_rad: float, pitch_diameter_mm: float, ball_mm: Any, lubricant_vg: int = 68,
                   temperature_C: Any = 40.0, calibration: float = CONTACT_CALIBRATION) -> Any:
    """Jungnickel's rolling-contact loss of an open double nut (module docstring; s = 1), W, times the
    ``calibration`` factor (1: his fit as restated).

    ``balls``: z, the loaded balls of one nut; ``omega_rad_s`` >= 0 the screw's speed. The geometry may be CasADi
    expressions too (the design's variables).
    """
    r, r_b = 0.5e-3 * pitch_diameter_mm, 0.5e-3 * ball_mm
    cl = ops.cos(helix_rad)
    f_c = preload_N / (balls * ops.sin(contact_rad) * cl)
    load = f_c / (_E_PRIME * r_b ** 2)
    material = pressure_viscosity_per_Pa(lubricant_vg) * _E_PRIME
    eta = OIL_DENSITY * viscosity_m2_s(lubricant_vg, temperature_C, ops)
    speed = eta * omega_rad_s * (r / r_b) / (2.0 * _E_PRIME * cl)
    mu = 9.16 * material ** -0.2 * load ** -_E_LOAD * speed ** _K2
    return calibration * balls * mu * f_c * r * omega_rad_s / cl


# ---- the support bearings ---------------------------------------------------------------------------------
def bearing_torque_Nm(speed_rpm: ArrayLike, viscosity_mm2_s: float, pitch_diameter_mm: float, axial_load_N: float,
                      f0: float, f1: float) -> Array:
    """Palmgren's friction torque (N m) of a bearing set: M0 (the lubricant) + M1 (the load), module docstring."""
    n = np.abs(np.asarray(speed_rpm, float))
    m0 = 1e-7 * f0 * np.maximum(viscosity_mm2_s * n, 2000.0) ** (2.0 / 3.0) * pitch_diameter_mm ** 3
    m1 = f1 * axial_load_N * pitch_diameter_mm
    return 1e-3 * np.where(n > 0, m0 + m1, 0.0)


# ---- film coefficients ----------------------------------------------------------------------------------
def _air(ambient_C: float) -> tuple[float, float, float]:
    """Air at ``ambient_C`` (0-60 deg C; linear fits of the tables): conductivity W/m K, kinematic viscosity
    m^2/s, Prandtl number."""
    return 0.0241 + 7.6e-5 * ambient_C, 1.33e-5 + 9.0e-8 * ambient_C, 0.71


def shaft_film_W_per_m2K(omega_rad_s: ArrayLike, diameter_m: float, ambient_C: float = 20.0,
                         free_W_per_m2K: float = 8.0) -> Array:
    """A rotating shaft's film coefficient in air, Nu = 0.133 Re^(2/3) Pr^(1/3) with Re = omega d^2 / nu_air,
    and no less than free convection's ``free_W_per_m2K``."""
    k, nu, pr = _air(ambient_C)
    re = np.abs(np.asarray(omega_rad_s, float)) * diameter_m ** 2 / nu
    film: Array = np.maximum(0.133 * re ** (2.0 / 3.0) * pr ** (1.0 / 3.0) * k / diameter_m, free_W_per_m2K)
    return film


def pipe_film_W_per_m2K(flow_l_per_min: float, bore_m: float) -> float:
    """Water at 20 deg C in the screw's bore: laminar Nu = 4.36 below Re = 2,300, Dittus-Boelter
    Nu = 0.023 Re^0.8 Pr^0.4 above 10,000, linear in Re between."""
    k, nu, pr = 0.598, 1.0e-6, 7.0
    velocity = flow_l_per_min / 60e3 / (0.25 * math.pi * bore_m ** 2)
    re = velocity * bore_m / nu
    turbulent = 0.023 * max(re, 1e4) ** 0.8 * pr ** 0.4
    if re <= 2300.0:
        nu_number = 4.36
    elif re >= 1e4:
        nu_number = turbulent
    else:
        nu_number = 4.36 + (turbulent - 4.36) * (re - 2300.0) / (1e4 - 2300.0)
    return nu_number * k / bore_m


# ---- the network -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScrewBody(Checked):
    """The screw between its bearings: its length, the outer diameter its surface loses heat through, the core
    (root) diameter that conducts and stores heat, a bore (0: solid), and the steel's properties."""

    length_m: float = entry("The screw's length between its bearings.", unit="m", gt=0)
    outer_diameter_m: float = entry("The outer diameter its surface loses heat through.", unit="m", gt=0)
    core_diameter_m: float = entry("The core (root) diameter that conducts and stores heat.", unit="m", gt=0)
    bore_m: float = entry("The bore (0: solid).", unit="m", ge=0, default=0.0)
    conductivity_W_per_mK: float = entry("The steel's conductivity.", unit="W/(m K)", gt=0,
                                         default=STEEL_CONDUCTIVITY_W_PER_MK)
    heat_capacity_J_per_m3K: float = entry("The steel's heat capacity per volume.", unit="J/(m^3 K)", gt=0,
                                           default=STEEL_HEAT_CAPACITY_J_PER_M3K)

    def check(self) -> None:
        if not self.bore_m < self.core_diameter_m <= self.outer_diameter_m:
            raise InputError(f"ScrewBody needs bore < core diameter <= outer diameter, got {self.bore_m}, "
                             f"{self.core_diameter_m} and {self.outer_diameter_m} m.")

    @property
    def area_m2(self) -> float:
        """The conducting (and heat-storing) section."""
        return 0.25 * math.pi * (self.core_diameter_m ** 2 - self.bore_m ** 2)

    def time_constant_s(self, film_W_per_m2K: float) -> float:
        """A lumped length of screw losing heat through its surface alone: rho c A / (h pi d_o)
        (rho c d / (4 h) for a solid screw whose core is its outer diameter)."""
        return self.heat_capacity_J_per_m3K * self.area_m2 / (film_W_per_m2K * math.pi * self.outer_diameter_m)


def _conductances(value: Any) -> tuple[float, float]:
    """Two bearings' conductances (inf allowed: an end held at the ambient); checked by :meth:`AxisModel.check`."""
    return (float(value[0]), float(value[1]))


@dataclass(frozen=True)
class AxisModel(Checked):
    """The axis as a network: the screw in ``volumes`` equal volumes (nodes 0..N-1 from bearing A), the nut
    (node N) and its flange (node N+1).

    ``bearing_W_per_K``: each end bearing's conductance to its housing (A, B; inf holds the end at the
    ambient); ``nut_area_m2`` the nut's surface in air; the flange conducts to the table
    (``flange_table_W_per_K``, the table at the ambient); ``coolant_W_per_m2K`` the film in the bore (0: none).
    """

    screw: ScrewBody = entry("The screw between its bearings.")
    volumes: int = entry("The screw's equal volumes.", ge=1)
    bearing_W_per_K: tuple[float, float] = entry("Each end bearing's conductance to its housing, A and B (inf: the "
                                                 "end held at the ambient).", unit="W/K", ge=0, read=_conductances)
    nut_capacity_J_per_K: float = entry("The nut's heat capacity.", unit="J/K", gt=0)
    nut_area_m2: float = entry("The nut's surface in air.", unit="m^2", ge=0)
    flange_capacity_J_per_K: float = entry("The flange's heat capacity.", unit="J/K", gt=0)
    nut_flange_W_per_K: float = entry("The nut's conductance to its flange.", unit="W/K", ge=0)
    flange_table_W_per_K: float = entry("The flange's conductance to the table (at the ambient).", unit="W/K", ge=0)
    coolant_W_per_m2K: float = entry("The film in the bore (0: none).", unit="W/(m^2 K)", ge=0, default=0.0)

    def check(self) -> None:
        if not (len(self.bearing_W_per_K) == 2 and all(x >= 0 for x in self.bearing_W_per_K)):
            raise Invalid("bearing_W_per_K", "must be two conductances >= 0 (inf: the end held at the ambient), got "
                                             f"{list(self.bearing_W_per_K)!r}", "AxisModel")
        if self.coolant_W_per_m2K > 0 and self.screw.bore_m <= 0:
            raise InputError("AxisModel: a coolant needs a hollow screw (ScrewBody.bore_m > 0).")

    @property
    def dx_m(self) -> float:
        return self.screw.length_m / self.volumes

    @property
    def centres_m(self) -> Array:
        """The volumes' centres from bearing A."""
        return (np.arange(self.volumes, dtype=float) + 0.5) * float(self.dx_m)

    @property
    def faces_m(self) -> Array:
        """The volumes' faces from bearing A (0 .. L)."""
        return np.arange(self.volumes + 1, dtype=float) * float(self.dx_m)

    @property
    def size(self) -> int:
        return self.volumes + 2

    def capacities_J_per_K(self) -> Array:
        s = self.screw
        return np.concatenate([np.full(self.volumes, s.heat_capacity_J_per_m3K * s.area_m2 * self.dx_m),
                               [self.nut_capacity_J_per_K, self.flange_capacity_J_per_K]])

    def surface_W_per_K(self) -> Array:
        """Each node's conductance to the air per W/m^2 K of its film (the screw's volumes' surfaces)."""
        return np.concatenate([np.full(self.volumes, math.pi * self.screw.outer_diameter_m * self.dx_m), [0.0, 0.0]])

    def coolant_W_per_K(self) -> Array:
        """Each node's conductance to the coolant."""
        g = self.coolant_W_per_m2K * math.pi * self.screw.bore_m * self.dx_m
        return np.concatenate([np.full(self.volumes, g), [0.0, 0.0]])

    def _half_W_per_K(self) -> float:
        return self.screw.conductivity_W_per_mK * self.screw.area_m2 / (0.5 * self.dx_m)

    def _end_W_per_K(self, bearing: float) -> float:
        half = self._half_W_per_K()
        return half if math.isinf(bearing) else (0.0 if bearing == 0 else 1.0 / (1.0 / half + 1.0 / bearing))

    def face_share(self, end: int) -> float:
        """The share of a heat entering the screw at its end face ``end`` (0: bearing A, 1: B) that reaches the
        end volume: the face sits between half a volume of screw (G_h) and the bearing (G_b), so G_h / (G_h + G_b)
        goes into the screw and the rest straight into the housing (placing it in the volume's middle instead
        would warm it by q dx / (2 k A), an error of the first order in dx)."""
        bearing, half = self.bearing_W_per_K[end], self._half_W_per_K()
        return 0.0 if math.isinf(bearing) else half / (half + bearing)

    def ambient_W_per_K(self, screw_film_W_per_m2K: float, nut_film_W_per_m2K: float) -> Array:
        """Each node's conductance to the ambient (air, bearings' housings, the table) at the given films."""
        g = self.surface_W_per_K() * screw_film_W_per_m2K
        g[0] += self._end_W_per_K(self.bearing_W_per_K[0])
        g[self.volumes - 1] += self._end_W_per_K(self.bearing_W_per_K[1])
        g[self.volumes] += nut_film_W_per_m2K * self.nut_area_m2
        g[self.volumes + 1] += self.flange_table_W_per_K
        return g

    def coupling_W_per_K(self) -> Array:
        """The conductance between node i and node i + 1 (the screw's neighbours, then nut-flange); the last
        screw volume and the nut are not coupled (the nut's heat share is its coupling)."""
        s = self.screw
        axial = s.conductivity_W_per_mK * s.area_m2 / self.dx_m
        return np.concatenate([np.full(self.volumes - 1, axial), [0.0, self.nut_flange_W_per_K]])

    def network(self, screw_film_W_per_m2K: float, nut_film_W_per_m2K: float) -> Network:
        """The linear network C dT/dt = -K T + q at the given films (the cycle's means, for the slow model)."""
        return Network(self.capacities_J_per_K(), self.coupling_W_per_K(),
                       self.ambient_W_per_K(screw_film_W_per_m2K, nut_film_W_per_m2K) + self.coolant_W_per_K())


def nut_coverage(model: AxisModel, centre_m: ArrayLike, zones: Sequence[tuple[float, float]]) -> Array:
    """Where the nut's heat enters the screw: for the nut's centre at each of ``centre_m``, each volume's share
    (rows sum to 1) of ``zones``, the nut's loaded lengths as (offset of its middle from the centre, length), m,
    each taking an equal part."""
    centre = np.atleast_1d(np.asarray(centre_m, float))
    faces = model.faces_m
    out = np.zeros((centre.size, model.volumes))
    for offset, length in zones:
        lo = np.clip(centre[:, None] + offset - 0.5 * length, 0.0, model.screw.length_m)
        hi = np.clip(centre[:, None] + offset + 0.5 * length, 0.0, model.screw.length_m)
        overlap = np.clip(np.minimum(hi, faces[None, 1:]) - np.maximum(lo, faces[None, :-1]), 0.0, None)
        out += overlap / np.maximum(overlap.sum(axis=1, keepdims=True), 1e-300) / len(zones)
    return out


class Network:
    """C dT/dt = -K T + q with C diagonal (``capacities``) and K symmetric, tridiagonal: ``coupling[i]`` between
    node i and i + 1, ``ambient[i]`` from node i to the ambient (T the rise above it).

    The exact solution for a constant q from T0: T(t) = T_ss + C^(-1/2) V exp(-Lambda t) V' C^(1/2) (T0 - T_ss)
    with V Lambda V' = C^(-1/2) K C^(-1/2) (symmetric: real, orthogonal eigenvectors) and K T_ss = q.
    """

    def __init__(self, capacities: ArrayLike, coupling: ArrayLike, ambient: ArrayLike) -> None:
        self.C: Array = np.asarray(capacities, np.float64)
        self.coupling: Array = np.asarray(coupling, np.float64)
        self.ambient: Array = np.asarray(ambient, np.float64)
        n = self.C.size
        if self.coupling.shape != (n - 1,) or self.ambient.shape != (n,):
            raise InputError(f"Network: {n} capacities need {n - 1} couplings and {n} ambient conductances.")
        if np.any(self.C <= 0) or np.any(self.coupling < 0) or np.any(self.ambient < 0):
            raise InputError("Network: capacities must be > 0 and conductances >= 0.")
        self.K = np.diag(self.ambient + np.concatenate([self.coupling, [0.0]]) + np.concatenate([[0.0], self.coupling]))
        self.K -= np.diag(self.coupling, 1) + np.diag(self.coupling, -1)
        s = 1.0 / np.sqrt(self.C)
        lam, V = eigh(s[:, None] * self.K * s[None, :])
        if lam[0] <= 1e-12 * max(lam[-1], 1e-300):
            raise InputError("Network: a body loses no heat to the ambient (every path to it is 0): no steady state.")
        self.rates_per_s: Array = np.asarray(lam, np.float64)
        self._left: Array = np.asarray(s[:, None] * V, np.float64)  # C^(-1/2) V
        self._right: Array = np.asarray(V.T * np.sqrt(self.C), np.float64)  # V' C^(1/2)

    @property
    def time_constants_s(self) -> Array:
        """The network's time constants, slowest first."""
        return 1.0 / self.rates_per_s

    def steady(self, q: ArrayLike) -> Array:
        """The steady rise under the heat ``q`` (W per node)."""
        return np.linalg.solve(self.K, np.asarray(q, float))

    def response(self, q: ArrayLike, times_s: ArrayLike, start: ArrayLike | None = None) -> Array:
        """The rises at ``times_s`` (rows) under the constant heat ``q`` from ``start`` (default: the ambient)."""
        t = np.atleast_1d(np.asarray(times_s, float))
        steady = self.steady(q)
        first = np.zeros_like(steady) if start is None else np.asarray(start, float)
        modes = self._right @ (first - steady)
        return steady[None, :] + (np.exp(-np.outer(t, self.rates_per_s)) * modes[None, :]) @ self._left.T

    def losses_W(self, rise: ArrayLike) -> Array:
        """The heat each state loses to the ambient (W), per row of ``rise``."""
        return np.asarray(rise, float) @ self.ambient


class FineMarch:
    """The same network stepped through every cycle: each step's own film coefficient on the screw and heat
    where the nut is (Crank-Nicolson with the step's mean film; one tridiagonal solve per step).

    ``heat_W`` (steps x nodes), ``screw_film_W_per_m2K`` and ``dt_s`` (steps, or one step for all) are one
    cycle; the cycle repeats. ``model`` gives the network's parts; ``nut_film_W_per_m2K`` is constant.
    """

    def __init__(self, model: AxisModel, heat_W: ArrayLike, screw_film_W_per_m2K: ArrayLike, dt_s: ArrayLike,
                 nut_film_W_per_m2K: float) -> None:
        self.q = np.asarray(heat_W, float)
        self.h = np.asarray(screw_film_W_per_m2K, float)
        self.dt = np.broadcast_to(np.asarray(dt_s, float), self.h.shape).copy()
        if self.q.ndim != 2 or self.q.shape != (self.h.size, model.size) or not np.all(self.dt > 0):
            raise InputError(f"FineMarch: heat_W must be (steps, {model.size}) with one film and one step > 0 per "
                             "step.")
        self.C = model.capacities_J_per_K()
        self.coupling = model.coupling_W_per_K()
        self.base = model.ambient_W_per_K(0.0, nut_film_W_per_m2K) + model.coolant_W_per_K()
        self.surface = model.surface_W_per_K()
        self.n = model.size

    @property
    def period_s(self) -> float:
        return float(np.sum(self.dt))

    def _band(self, ambient: Array, dt: float) -> Array:
        """C/dt + K/2 as a banded (1, 1) matrix for solve_banded."""
        ab = np.zeros((3, self.n))
        diag = ambient + np.concatenate([self.coupling, [0.0]]) + np.concatenate([[0.0], self.coupling])
        ab[1] = self.C / dt + 0.5 * diag
        ab[0, 1:] = -0.5 * self.coupling
        ab[2, :-1] = -0.5 * self.coupling
        return ab

    def run(self, cycles: int, start: ArrayLike | None = None) -> tuple[Array, Array, Array]:
        """March ``cycles`` cycles from ``start`` (default: the ambient): the state at each cycle's end, each
        cycle's mean state (trapezoid over its steps) and the heat lost to the ambient per cycle (J), each a row
        per cycle."""
        T = np.zeros(self.n) if start is None else np.asarray(start, float).copy()
        ambient = [self.base + h * self.surface for h in self.h]
        lhs = [self._band(a, dt) for a, dt in zip(ambient, self.dt)]
        scale = [self.C / dt for dt in self.dt]
        weights = 0.5 * (self.dt + np.roll(self.dt, -1)) / self.period_s  # the trapezoid's weight of each step's end
        ends, means, lost = np.empty((cycles, self.n)), np.empty((cycles, self.n)), np.empty(cycles)
        for c in range(cycles):
            total, loss = 0.5 * self.dt[0] / self.period_s * T, 0.0
            for k in range(self.h.size):
                rhs = scale[k] * T - 0.5 * (ambient[k] * T + self._couple(T)) + self.q[k]
                new = solve_banded((1, 1), lhs[k], rhs, check_finite=False)
                loss += 0.5 * self.dt[k] * float(ambient[k] @ (T + new))
                T = new
                total += (weights[k] if k < self.h.size - 1 else 0.5 * self.dt[k] / self.period_s) * T
            ends[c], means[c], lost[c] = T, total, loss
        return ends, means, lost

    def _couple(self, T: Array) -> Array:
        """The coupling's part of K T."""
        flow = self.coupling * (T[:-1] - T[1:])
        return np.asarray(np.concatenate([flow, [0.0]]) - np.concatenate([[0.0], flow]), np.float64)


# ---- growth ------------------------------------------------------------------------------------------------
#: a preloaded pair of equal Hertz rows lifts off (one row unloaded) at 2^(3/2) its preload
PAIR_LIFT_OFF_RATIO = 2.0 ** 1.5
_BISECTIONS = 80


def pair_lift_off_N(preload_N: float) -> float:
    """The axial force at which a preloaded bearing pair's second row unloads: 2^(3/2) F_b (module docstring)."""
    return PAIR_LIFT_OFF_RATIO * float(preload_N)


def pair_shift_m(force_N: ArrayLike, preload_N: float, stiffness_N_per_m: float) -> Array:
    """A preloaded pair's axial shift (m, signed as the force) under the axial force ``force_N``: its rows Hertz
    contacts (F ~ delta^(3/2)), their tangent stiffness together ``stiffness_N_per_m`` at no load.

    With the shift delta = 3 F_b u / k_b the rows carry F_b (1 + u)^(3/2) and F_b max(1 - u, 0)^(3/2), so the
    force is F_b ((1 + u)^(3/2) - max(1 - u, 0)^(3/2)): k_b at u = 0, the second row unloaded at u = 1
    (F = 2^(3/2) F_b), the loaded row alone beyond. ``preload_N`` = 0: a linear spring; infinite stiffness: no
    shift.
    """
    F = np.asarray(force_N, float)
    if math.isinf(stiffness_N_per_m):
        return np.zeros_like(F)
    if preload_N <= 0:
        return F / stiffness_N_per_m
    r = np.abs(F) / preload_N
    lo, hi = np.zeros_like(r), np.ones_like(r)
    for _ in range(_BISECTIONS):  # (1 + u)^1.5 - (1 - u)^1.5 rises from 0 to 2^1.5 on [0, 1]
        mid = 0.5 * (lo + hi)
        low = (1.0 + mid) ** 1.5 - (1.0 - mid) ** 1.5 < r
        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
    u = np.where(r >= PAIR_LIFT_OFF_RATIO, np.cbrt(r) ** 2 - 1.0, 0.5 * (lo + hi))
    shift: Array = np.sign(F) * 3.0 * preload_N * u / stiffness_N_per_m
    return shift


def _mounted(mounting: str) -> None:
    if mounting not in THERMAL_MOUNTINGS:
        raise InputError(f"mounting must be one of {', '.join(THERMAL_MOUNTINGS)}, got {mounting!r}.")


def end_force_N(rise_K: ArrayLike, dx_m: float, mounting: str, *, EA_N: float, bearing_N_per_m: float = math.inf,
                bearing_preload_N: float = 0.0, pretension_K: float = 0.0,
                expansion_per_K: float = EXPANSION_PER_K) -> Array:
    """The axial force (N) on each end's bearing pair under the volumes' rises ``rise_K`` (last axis; leading axes a
    batch): compressive > 0 (the screw pushes), tensile < 0 (the pretension left); 0 fixed-free. The root F of
    G - (F + F_t) L / EA = 2 (delta(F) - delta(-F_t)) (module docstring), by bisection: the left side falls and the
    right rises with F."""
    _mounted(mounting)
    rise = np.asarray(rise_K, float)
    if mounting == ThermalMounting.FIXED_FREE:
        return np.zeros(rise.shape[:-1])
    length = rise.shape[-1] * dx_m
    f_t = expansion_per_K * pretension_K * EA_N if mounting == ThermalMounting.PRETENSIONED else 0.0
    grown = expansion_per_K * dx_m * np.sum(rise, axis=-1)
    start = float(pair_shift_m(-f_t, bearing_preload_N, bearing_N_per_m))
    held = grown * EA_N / length  # the force that keeps the length
    lo, hi = -f_t + np.minimum(held, 0.0), -f_t + np.maximum(held, 0.0)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        short = grown - (mid + f_t) * length / EA_N - 2.0 * (pair_shift_m(mid, bearing_preload_N,
                                                                          bearing_N_per_m) - start) > 0
        lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
    force: Array = 0.5 * (lo + hi)
    return force


def held_force_N(rise_K: ArrayLike, dx_m: float, mounting: str, *, EA_N: float, bearing_N_per_m: float = math.inf,
                 bearing_preload_N: float = 0.0, pretension_K: float = 0.0,
                 expansion_per_K: float = EXPANSION_PER_K) -> Array:
    """The force (N) the held ends take up from the growth: the change of :func:`end_force_N` from assembly (the
    compression added, and the pretension's loss); 0 fixed-free."""
    f_t = expansion_per_K * pretension_K * EA_N if mounting == ThermalMounting.PRETENSIONED else 0.0
    return end_force_N(rise_K, dx_m, mounting, EA_N=EA_N, bearing_N_per_m=bearing_N_per_m,
                       bearing_preload_N=bearing_preload_N, pretension_K=pretension_K,
                       expansion_per_K=expansion_per_K) + f_t


def growth_m(rise_K: ArrayLike, dx_m: float, mounting: str, *, EA_N: float, bearing_N_per_m: float = math.inf,
             bearing_preload_N: float = 0.0, pretension_K: float = 0.0,
             expansion_per_K: float = EXPANSION_PER_K) -> Array:
    """The screw's axial displacement (m) at its volumes' faces (0 .. L from bearing A) under the volumes' rises
    ``rise_K`` (last axis; leading axes a batch, times say), for its mounting (module docstring).

    fixed-free: u = g(x) = alpha int_0^x dT. Held ends (fixed-fixed, pretensioned): u = g(x) - dF x / EA -
    (delta(F) - delta(-F_t)), F the ends' force (:func:`end_force_N`), dF = F + F_t its change from assembly and
    delta the pair's shift (:func:`pair_shift_m`; F / k_b for a linear end).
    """
    rise = np.asarray(rise_K, float)
    g = expansion_per_K * dx_m * np.concatenate([np.zeros(rise.shape[:-1] + (1,)), np.cumsum(rise, axis=-1)], axis=-1)
    _mounted(mounting)
    if mounting == ThermalMounting.FIXED_FREE:
        return g
    f_t = expansion_per_K * pretension_K * EA_N if mounting == ThermalMounting.PRETENSIONED else 0.0
    force = end_force_N(rise, dx_m, mounting, EA_N=EA_N, bearing_N_per_m=bearing_N_per_m,
                        bearing_preload_N=bearing_preload_N, pretension_K=pretension_K,
                        expansion_per_K=expansion_per_K)
    shift = (pair_shift_m(force, bearing_preload_N, bearing_N_per_m)
             - float(pair_shift_m(-f_t, bearing_preload_N, bearing_N_per_m)))
    x = np.arange(rise.shape[-1] + 1) * dx_m
    return g - (force + f_t)[..., None] * x / EA_N - shift[..., None]


def spacer_drift_N_per_K(nut_stiffness_N_per_um: ArrayLike, spacer_length_mm: float,
                         spacer_stiffness_N_per_um: float = math.inf,
                         expansion_per_K: float = EXPANSION_PER_K) -> Array:
    """A spacer-preloaded double nut's preload change per kelvin of nut over screw: the two nuts (each of
    tangent stiffness ``nut_stiffness_N_per_um``) and the spacer in series, times alpha L_s (um/K)."""
    k = np.asarray(nut_stiffness_N_per_um, float)
    pair = 1.0 / (2.0 / k + 1.0 / spacer_stiffness_N_per_um)
    return pair * expansion_per_K * spacer_length_mm * 1e3
