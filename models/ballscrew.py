"""The preloaded double-nut ball screw: geometry, Hertz contact, load sharing, rigidity, ratings.

Section 2.2 of the paper, derived from Hertz theory rather than read off its garbled
eqs. (9)-(13), plus what a selection procedure checks: load ratings, life, drag torque and
static safety. Units are those of ball-screw catalogues, named in every field: mm, N, MPa,
N/um, N m. ``docs/ballscrew.md`` derives the rigidity model and checks it against catalogue
rows (``tests/data/ballscrew_rigidity.csv``).

The model, in the order the functions below build it:

* **Geometry.** Pitch diameter D_pw, ball diameter D_w, lead P, helix angle
  alpha = atan(P / (pi D_pw)), contact angle beta, groove conformities f = r_groove / D_w
  (0.52-0.56) of screw and nut, loaded turns per nut, balls per turn
  Z_1 = floor(pi D_pw / (D_w cos alpha)) unless given.
* **Hertz point contact** of a ball in the screw's and the nut's gothic-arch groove, with the
  Hamrock-Brewe approximations of the ellipticity and the elliptic integrals (smooth, so the
  CasADi design NLP differentiates the same formulas). Rolling-direction curvature
  2/D_w +/- 2 cos(beta) / (D_pw -/+ D_w cos(beta)) (screw +, nut -), transverse
  2/D_w - 1/(f D_w). The normal approach of one contact is ``c Q^(2/3)``.
* **One nut** carrying F (N) shifts axially on the screw by

      delta(F) = [c_h F^(2/3) + s F] / f_ar                                   (um)

  - ``c_h F^(2/3)``: the ball contacts (our form of eq. (12)). A ball load
    Q = F / (z sin(beta) cos(alpha)) (eq. (3)) over the normal approaches' sum, divided by
    sin(beta) cos(alpha). z = eta Z_1 i counts an effective share eta of the balls
    (``load_sharing``, :data:`EFFECTIVE_BALL_SHARE`): catalogue rigidity of every size, ball
    and number of turns is the same fraction of the all-balls Hertz value, which a share of
    the balls expresses; eta is calibrated on catalogue rows (docs/ballscrew.md).
  - ``s F``: the nut body and the screw under the nut, from the geometry. The radial
    components of the ball loads widen the nut (a thick ring, Lame, outer diameter D) and
    squeeze the screw core (a solid cylinder), which the contact angle turns into an axial
    shift: (cot(beta)/cos(alpha))^2 (1 + (r_o^2 + r_n^2) / (r_o^2 - r_n^2)) / (2 pi E L) per N.
    Axially the load passes from the nut body to the screw core over the loaded length L
    through the balls; the elastic load distribution along the nut (the shear-lag
    solution, :meth:`BallScrew.turn_loads`, not all turns equally loaded) adds, to first order
    in (lambda L)^2, L/3 (1/(E A_nut) + 1/(E A_core)) per N (within 0.4 % of the exact one for
    the catalogue rows, where lambda L < 0.66).
  - ``f_ar``: ISO 3408-4's correction for accuracy (``accuracy_factor``). 1 for the
    theoretical rigidity HIWIN and THK tabulate; :data:`ACCURACY_FACTOR_P5` for rigidity
    corrected for tolerance class P5 as Rexroth states it.
* **Double nut.** Both nuts start at delta(F_p); an axial load F_a shifts the assembly by x,
  loading one nut to F_A and unloading the other to F_B: delta(F_A) + delta(F_B) = 2 delta(F_p),
  F_A - F_B = F_a (eqs. (4)-(10), solved exactly by Newton's method, :func:`nut_forces`). The
  unloaded nut lifts off at F_a = rho F_p, rho^(2/3) + sigma rho = 2 + 2 sigma with
  sigma = s F_p^(1/3) / c_h (rho = 2^(3/2), the paper's and the catalogues' figure, for a
  Hertz-only nut). The rigidity dF_a/dx is the two nuts' tangent stiffnesses in parallel,
  f_ar [F^(1/3) / (2/3 c_h + s F^(1/3))] summed over F_A and F_B. With s = 0 and eta = 1 it is
  eq. (13) of the paper, 3 F_p^(1/3) / c_h at no load (:meth:`BallScrew.hertz_rigidity_N_per_um`).

Load ratings follow ISO 3408-5's convention of equal ball loads: the static rating C_0 is
the axial load at which the most pressed contact reaches 4,200 MPa (ISO 76), from the same
Hertz model (HIWIN's rows: +5 % at f = 0.55; the vendors' conformities differ, 0.53-0.565),
and :meth:`BallScrew.from_catalogue` sets the groove conformity from a catalogue's C_0 that
way. The dynamic rating C_dyn, where no catalogue value is given, is the Lundberg-Palmgren
form for angular-contact thrust rows,
``K f_c(gamma) cos(beta)^0.7 tan(beta) cos(alpha)^1.3 Z_1^(2/3) D_w^1.8 i^0.86``, with
gamma = D_w cos(beta) / D_pw, whose one constant K is calibrated on HIWIN's R40-10T4 row and
checked on R32-5T4 (-5 %). A catalogue C_dyn, where known, should be passed instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, entry
from piezopreload.models.ops import NUMPY
from piezopreload.models.thermal import (
    CONTACT_CALIBRATION,
    HEAT_MODELS,
    HeatModel,
    catalogue_heat_W,
    contact_heat_W,
    rexroth_seal_torque_Nm,
    seal_heat_W,
)

__all__ = [
    "Material", "STEEL", "BallScrew", "DutyCase", "ContactState", "NutLoads", "Life",
    "nut_forces", "lift_off_ratio", "hiwin_loaded_nut_force", "lift_off_load_N", "nut_outer_diameter_mm",
    "nut_contact_constants", "axial_contact_constant", "structural_compliance", "double_nut_rigidity",
    "dynamic_load_rating", "drag_torque_coefficient",
    "CONTACT_LIMIT_MPA", "RELIABILITY_FACTORS", "LIFT_OFF_RATIO",
    "EFFECTIVE_BALL_SHARE", "ACCURACY_FACTOR_P5", "RIGIDITY_IN_MACHINE_FACTOR",
]


#: Static contact-pressure limit of hardened bearing steel (ISO 76), MPa.
CONTACT_LIMIT_MPA = 4200.0
#: Life reliability factors of ISO 3408-5 (90 % is the rating life L10).
RELIABILITY_FACTORS = {0.90: 1.00, 0.95: 0.63, 0.99: 0.21}
#: Lift-off load over preload of a double nut whose nuts are Hertz contacts alone (eq. (10)).
LIFT_OFF_RATIO = 2.0 ** 1.5
#: The effective share eta of the balls in the contact compliance (module docstring): the
#: least-squares fit over the theoretical rigidity of HIWIN's and THK's ground double nuts,
#: 0.626 (on THK's rows alone 0.637, on HIWIN's alone 0.623; ``benchmarks/ballscrew_rigidity.py``).
EFFECTIVE_BALL_SHARE = 0.63
#: ISO 3408-4's correction for accuracy f_ar for tolerance class P5, as Rexroth's catalogue
#: applies it: the least-squares fit over Rexroth's double nuts, 0.740 (on their 7 % preload
#: rows alone 0.740, checked on the 10 % rows; ``benchmarks/ballscrew_rigidity.py``).
ACCURACY_FACTOR_P5 = 0.74
#: The share of the table rigidity a nut keeps mounted in a machine, as HIWIN and THK state it: their tables leave
#: out the nut's mounting, and about 80 % of the table figure holds in a machine (HIWIN's selection formula
#: K_n = 0.8 K (F_p / 0.1 C_dyn)^(1/3)). The nut law is calibrated on those tables (:data:`EFFECTIVE_BALL_SHARE`), so
#: its rigidity is a table figure. Rexroth's DIN 69051-5 and Steinmeyer's corrected figures carry no such factor.
RIGIDITY_IN_MACHINE_FACTOR = 0.8
#: The one constant of the C_dyn estimate (N, mm), calibrated on HIWIN R40-10T4-RDI
#: (C_dyn 37,890 N); see the module docstring.
_CDYN_CONSTANT = 70.98
#: Newton steps of :func:`nut_forces` and :func:`lift_off_ratio` (8 reach 3e-12 up to lift-off)
_NEWTON_STEPS = 8

@dataclass(frozen=True)
class Material:
    """Elastic constants of balls, raceways, screw and nut (all the same steel)."""

    E_MPa: float = 206e3
    poisson: float = 0.3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.E_MPa) and self.E_MPa > 0):
            raise InputError(f"Material.E_MPa must be a finite number > 0, got {self.E_MPa!r}.")
        if not 0 <= self.poisson < 0.5:
            raise InputError(f"Material.poisson must be in [0, 0.5), got {self.poisson!r}.")

    @property
    def contact_modulus_MPa(self) -> float:
        """Hamrock's E' = 2 / ((1 - nu1^2)/E1 + (1 - nu2^2)/E2) for two equal bodies."""
        return self.E_MPa / (1.0 - self.poisson ** 2)


STEEL = Material()


# ---- the formulas, once, on numbers or CasADi expressions ----------------------------------


def _contact_constants(ops: Any, E_prime: Any, inv_Rx: Any, inv_Ry: Any) -> tuple[Any, Any]:
    """Hertz point contact (Hamrock-Brewe): ``(c_delta, c_p)`` with approach = c_delta Q^(2/3)
    (mm, Q in N) and peak pressure = c_p Q^(1/3) (MPa)."""
    ratio = inv_Rx / inv_Ry  # R_y / R_x >= 1: the groove's conformal direction is y
    k = 1.0339 * ratio ** 0.636
    e_int = 1.0003 + 0.5968 / ratio
    f_int = 1.5277 + 0.6023 * ops.log(ratio)
    R = 1.0 / (inv_Rx + inv_Ry)
    c_delta = f_int * (9.0 / (2.0 * e_int * R)) ** (1.0 / 3.0) * (math.pi * k * E_prime) ** (-2.0 / 3.0)
    a1 = (6.0 * k ** 2 * e_int * R / (math.pi * E_prime)) ** (1.0 / 3.0)
    b1 = (6.0 * e_int * R / (math.pi * k * E_prime)) ** (1.0 / 3.0)
    return c_delta, 3.0 / (2.0 * math.pi * a1 * b1)


def nut_contact_constants(ops: Any, E_prime: float, D_pw: Any, D_w: Any, beta: Any, f_screw: Any, f_nut: Any
                          ) -> tuple[Any, Any, Any]:
    """A ball's two Hertz contacts, in the screw's and the nut's groove (module docstring).

    Parameters
    ----------
    ops
        The operations: :data:`~piezopreload.models.ops.NUMPY` on numbers, ``CASADI`` on expressions.
    E_prime
        The contact modulus (MPa), :attr:`Material.contact_modulus_MPa`.
    D_pw, D_w
        The pitch and the ball diameter (mm).
    beta
        The contact angle (rad).
    f_screw, f_nut
        The groove conformities of screw and nut.

    Returns
    -------
    tuple
        ``(c_delta, c_p_screw, c_p_nut)``: the summed normal approach of both contacts per
        Q^(2/3) (mm, Q in N), and each contact's peak pressure per Q^(1/3) (MPa).
    """
    cb = ops.cos(beta)
    inv_Ry_s = (2.0 - 1.0 / f_screw) / D_w
    inv_Ry_n = (2.0 - 1.0 / f_nut) / D_w
    inv_Rx_s = 2.0 / D_w + 2.0 * cb / (D_pw - D_w * cb)
    inv_Rx_n = 2.0 / D_w - 2.0 * cb / (D_pw + D_w * cb)
    cd_s, cp_s = _contact_constants(ops, E_prime, inv_Rx_s, inv_Ry_s)
    cd_n, cp_n = _contact_constants(ops, E_prime, inv_Rx_n, inv_Ry_n)
    return cd_s + cd_n, cp_s, cp_n


def axial_contact_constant(ops: Any, c_delta: Any, z: Any, beta: Any, helix: Any) -> Any:
    """c_h of one nut: its balls' contacts shift it axially by c_h F^(2/3) under F (N).

    Parameters
    ----------
    ops
        The operations (NUMPY or CASADI).
    c_delta
        The summed normal approach per Q^(2/3) (:func:`nut_contact_constants`).
    z
        The balls carrying the load (the effective share of them, module docstring).
    beta, helix
        The contact and the helix angle (rad).

    Returns
    -------
    Any
        c_h in mm per N^(2/3).
    """
    s = ops.sin(beta) * ops.cos(helix)
    return c_delta / ((z * s) ** (2.0 / 3.0) * s)


def nut_outer_diameter_mm(pitch_diameter_mm: Any, ball_mm: Any) -> Any:
    """A double nut's body diameter (mm) where no catalogue value is given:
    1.1 D_pw + 2.5 D_w + 5 mm, the least-squares proportion of HIWIN's ground double nuts
    (S99TE20-1610, double nuts with return tubes, 16-100 mm: 1.9 mm RMS)."""
    return 1.1 * pitch_diameter_mm + 2.5 * ball_mm + 5.0


def _structural_parts(ops: Any, E: float, D_pw: Any, D_w: Any, beta: Any, helix: Any, d_out: Any,
                      length: Any) -> tuple[Any, Any]:
    """The nut body and the screw under one nut of loaded length ``length`` (module docstring),
    ``(radial, bars)`` in mm/N: the ring's widening and the core's squeeze under the balls'
    radial load (Lame, plane stress, the screw a solid cylinder), turned axial by the contact
    angle; and the two bars along the nut to first order of the elastic load distribution."""
    cb = ops.cos(beta)
    r_n = 0.5 * (D_pw + D_w * cb)   # the nut's raceway radius at the contact
    r_s = 0.5 * (D_pw - D_w * cb)   # the screw's core (the root diameter's half)
    r_o = 0.5 * d_out
    turn = cb / (ops.sin(beta) * ops.cos(helix))   # radial per axial, and axial per radial
    ring = (r_o ** 2 + r_n ** 2) / (r_o ** 2 - r_n ** 2)
    radial = turn ** 2 * (1.0 + ring) / (2.0 * math.pi * E * length)
    bars = length / 3.0 * (1.0 / (E * math.pi * r_s ** 2) + 1.0 / (E * math.pi * (r_o ** 2 - r_n ** 2)))
    return radial, bars


def structural_compliance(ops: Any, E: float, D_pw: Any, D_w: Any, beta: Any, helix: Any, d_out: Any,
                          length: Any) -> Any:
    """s of one nut: the nut body and the screw under it shift it axially by s F (module docstring).

    Parameters
    ----------
    ops
        The operations (NUMPY or CASADI).
    E
        Young's modulus (MPa).
    D_pw, D_w
        The pitch and the ball diameter (mm).
    beta, helix
        The contact and the helix angle (rad).
    d_out
        The nut body's outer diameter (mm).
    length
        The nut's loaded length (mm).

    Returns
    -------
    Any
        s in mm/N: the ring's widening and the core's squeeze turned axial, plus the two bars along the nut.
    """
    radial, bars = _structural_parts(ops, E, D_pw, D_w, beta, helix, d_out, length)
    return radial + bars


def lift_off_ratio(sigma: Any, ops: Any = NUMPY) -> Any:
    """rho: the unloaded nut lifts off at F_a = rho F_p, where rho^(2/3) + sigma rho = 2 + 2 sigma
    (sigma = s F_p^(1/3) / c_h, module docstring); 2^(3/2) at sigma = 0, 2 as sigma grows.

    Newton's method from rho = 2 (below the root; the left side is concave and increasing, so
    the iterates rise monotonically), unrolled a fixed number of steps: numpy or CasADi.
    """
    rho = 2.0 + 0.0 * sigma
    for _ in range(_NEWTON_STEPS):
        rho = rho - (ops.cbrt(rho) ** 2 + sigma * rho - 2.0 - 2.0 * sigma) / (2.0 / 3.0 / ops.cbrt(rho) + sigma)
    return rho


def nut_forces(ratio: Any, sigma: Any = 0.0, ops: Any = NUMPY) -> tuple[Any, Any]:
    """The double nut's forces over F_p, ``(f_loaded, f_unloaded)``, under F_a = ratio F_p,
    0 <= ratio < rho (:func:`lift_off_ratio`).

    Solves eq. (10) generalised to the nut law (module docstring), phi(f_A) + phi(f_A - ratio)
    = 2 phi(1) with phi(f) = f^(2/3) + sigma f, by Newton's method in f_A from
    max(1 + ratio/2, ratio + 1e-15), which lies below the root (phi is concave), unrolled a
    fixed number of steps so the same expression serves numpy and CasADi (where it is
    differentiable). sigma = 0 is the Hertz-only nut: f = (1 +/- u)^(3/2) with
    (1 + u)^(3/2) - (1 - u)^(3/2) = ratio.
    """
    f_a = ops.maximum(1.0 + 0.5 * ratio, ratio + 1e-15)
    for _ in range(_NEWTON_STEPS):
        t_a, t_b = ops.cbrt(f_a), ops.cbrt(ops.maximum(f_a - ratio, 0.0))
        g = t_a ** 2 + t_b ** 2 + sigma * (2.0 * f_a - ratio) - 2.0 - 2.0 * sigma
        f_a = f_a - g / (2.0 / 3.0 * (1.0 / t_a + 1.0 / ops.maximum(t_b, 1e-100)) + 2.0 * sigma)
    return f_a, ops.maximum(f_a - ratio, 0.0)


def _nut_stiffness(ops: Any, c_h_um: Any, s_um: Any, force_N: Any) -> Any:
    """One nut's tangent stiffness dF/d(delta) (N/um, f_ar = 1) at force F >= 0:
    F^(1/3) / (2/3 c_h + s F^(1/3)), zero for an unloaded nut."""
    t = ops.cbrt(force_N)
    return t / (2.0 / 3.0 * c_h_um + s_um * t)


def double_nut_rigidity(ops: Any, c_h_um: Any, s_um: Any, accuracy: Any, loaded_N: Any, unloaded_N: Any) -> Any:
    """The double nut's rigidity dF_a/dx: both nuts' tangent stiffnesses in parallel, times f_ar.

    Parameters
    ----------
    ops
        The operations (NUMPY or CASADI).
    c_h_um, s_um
        One nut's contact constant (um per N^(2/3)) and structural compliance (um/N).
    accuracy
        ISO 3408-4's accuracy factor f_ar.
    loaded_N, unloaded_N
        The two nuts' forces (N), :func:`nut_forces` times the preload.

    Returns
    -------
    Any
        The rigidity in N/um.
    """
    return accuracy * (_nut_stiffness(ops, c_h_um, s_um, loaded_N) + _nut_stiffness(ops, c_h_um, s_um, unloaded_N))


def dynamic_load_rating(ops: Any, D_pw: Any, D_w: Any, beta: Any, helix: Any, f_screw: Any, f_nut: Any,
                        balls_per_turn: Any, turns: Any) -> Any:
    """The dynamic axial load rating C_dyn estimated by the Lundberg-Palmgren form (module docstring).

    Parameters
    ----------
    ops
        The operations (NUMPY or CASADI).
    D_pw, D_w
        The pitch and the ball diameter (mm).
    beta, helix
        The contact and the helix angle (rad).
    f_screw, f_nut
        The groove conformities of screw and nut.
    balls_per_turn, turns
        Z_1 and the loaded turns i of one nut.

    Returns
    -------
    Any
        C_dyn in N.
    """
    gamma = D_w * ops.cos(beta) / D_pw
    q = (1.04 * ((1.0 - gamma) / (1.0 + gamma)) ** 1.72
         * (f_screw * (2.0 * f_nut - 1.0) / (f_nut * (2.0 * f_screw - 1.0))) ** 0.41)
    f_c = (gamma ** 0.3 * (1.0 - gamma) ** 1.39 / (1.0 + gamma) ** (1.0 / 3.0)
           * (1.0 + q ** (10.0 / 3.0)) ** -0.3 * (2.0 * f_screw / (2.0 * f_screw - 1.0)) ** 0.41)
    return (_CDYN_CONSTANT * f_c * ops.cos(beta) ** 0.7 * ops.tan(beta) * ops.cos(helix) ** 1.3
            * balls_per_turn ** (2.0 / 3.0) * D_w ** 1.8 * turns ** 0.86)


def drag_torque_coefficient(ops: Any, helix: Any) -> Any:
    """K_p of the preload drag torque, HIWIN's 0.05 / sqrt(tan(helix)) (0.1-0.3 in use).

    Parameters
    ----------
    ops
        The operations (NUMPY or CASADI).
    helix
        The helix angle (rad).

    Returns
    -------
    Any
        K_p, dimensionless.
    """
    return 0.05 / ops.sqrt(ops.tan(helix))


# ---- closed forms of the references ---------------------------------------------------------


def lift_off_load_N(preload_N: ArrayLike) -> Array:
    """The catalogue rule for a double nut's lift-off load, 2^(3/2) F_p: exact for nuts that
    are Hertz contacts alone (:meth:`BallScrew.lift_off_load_N` includes the nut body)."""
    return LIFT_OFF_RATIO * np.asarray(preload_N, float)


def hiwin_loaded_nut_force(preload_N: ArrayLike, axial_load_N: ArrayLike) -> Array:
    """HIWIN's catalogue formula for the loaded nut's force.

    (1 + F_a / (2^(3/2) F_p))^(3/2) F_p below lift-off, F_a above; within 2.5 % of the exact
    two-nut solution of Hertz-only nuts (:func:`nut_forces` with sigma = 0).
    """
    fp, fa = np.asarray(preload_N, float), np.abs(np.asarray(axial_load_N, float))
    loaded: Array = np.where(fa < LIFT_OFF_RATIO * fp, (1.0 + fa / (LIFT_OFF_RATIO * fp)) ** 1.5 * fp, fa)
    return loaded


# ---- results --------------------------------------------------------------------------------


@dataclass(frozen=True)
class ContactState:
    """The Hertz contact of the most loaded ball, screw and nut side."""

    ball_load_N: Array
    approach_um: Array
    pressure_screw_MPa: Array
    pressure_nut_MPa: Array

    @property
    def peak_pressure_MPa(self) -> Array:
        return np.maximum(self.pressure_screw_MPa, self.pressure_nut_MPa)


@dataclass(frozen=True)
class NutLoads:
    """The double nut under preload F_p and axial load F_a (the exact two-nut solution)."""

    preload_N: Array
    axial_load_N: Array
    loaded_nut_N: Array
    unloaded_nut_N: Array
    deflection_um: Array  # axial shift of the nut assembly on the screw from the preloaded state
    contact_stiffness_N_per_um: Array  # the ball contacts alone (c_h; no body, f_ar = 1)
    rigidity_N_per_um: Array  # dF_a/dx: contacts, nut body and screw under the nut, times f_ar
    lifted_off: Array


@dataclass(frozen=True)
class DutyCase:
    """One case of a duty cycle: axial load (its sign: direction), speed, share of time."""

    axial_load_N: float
    speed_rpm: float
    time_share: float

    def __post_init__(self) -> None:
        for name in ("axial_load_N", "speed_rpm", "time_share"):
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"DutyCase.{name} must be finite, got {getattr(self, name)!r}.")
        if self.speed_rpm < 0 or self.time_share <= 0:
            raise InputError(f"DutyCase needs speed_rpm >= 0 and time_share > 0, got {self.speed_rpm!r} and "
                             f"{self.time_share!r}.")


@dataclass(frozen=True)
class Life:
    """Rating life of a preloaded double nut over a duty cycle (ISO 3408-5 style)."""

    revolutions: float
    hours: float
    mean_speed_rpm: float
    nut_A_revolutions: float
    nut_B_revolutions: float
    equivalent_load_A_N: float
    equivalent_load_B_N: float


# ---- the screw ------------------------------------------------------------------------------


def _number(doc: dict[str, Any], key: str, integer: bool = False) -> float:
    """A document's finite number (a whole one where ``integer``), :class:`Invalid` naming its key otherwise."""
    x = doc[key]
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) or \
            (integer and not float(x).is_integer()):
        raise Invalid(key, f"must be a finite {'whole ' if integer else ''}number, got {x!r}")
    return int(x) if integer else float(x)


@dataclass(frozen=True)
class BallScrew(Checked):
    """A double-nut ball screw with 2-point (gothic-arch) contact, preloaded between the nuts.

    Parameters
    ----------
    nominal_diameter_mm, lead_mm, ball_mm
        Nominal diameter d_0, lead P and ball diameter D_w.
    turns
        Loaded turns per nut (all circuits together).
    contact_angle_deg
        beta, 45 by default (the optimum of a gothic arch).
    conformity_screw, conformity_nut
        Groove radius over ball diameter, 0.52-0.56 (ISO 3408-5 requires > 0.5).
    pitch_diameter_mm
        D_pw; the nominal diameter when not given.
    balls_per_turn
        Z_1; as many as fit on a turn of the helix when not given.
    load_sharing
        eta, the effective share of the balls in the contact compliance
        (:data:`EFFECTIVE_BALL_SHARE`; 1 for the paper's all-balls eq. (13)).
    nut_outer_diameter_mm
        D, the nut body's outer diameter; :func:`nut_outer_diameter_mm` when not given.
    accuracy_factor
        f_ar of ISO 3408-4: 1 for the theoretical rigidity (HIWIN, THK tables),
        :data:`ACCURACY_FACTOR_P5` for rigidity corrected for tolerance class P5 (Rexroth).
    c_dyn_N, c0_N
        Catalogue ratings; estimated from the geometry when not given.
    drag_coefficient
        K_p of the drag torque; HIWIN's 0.05 / sqrt(tan(helix)) when not given.
    """

    nominal_diameter_mm: float = entry("Nominal diameter d_0.", unit="mm", gt=0)
    lead_mm: float = entry("Lead P.", unit="mm", gt=0)
    ball_mm: float = entry("Ball diameter D_w.", unit="mm", gt=0)
    turns: float = entry("Loaded turns per nut (all circuits together).", gt=0)
    contact_angle_deg: float = entry("beta (45: the optimum of a gothic arch).", unit="deg", ge=20, le=70,
                                     default=45.0)
    conformity_screw: float = entry("The screw's groove radius over the ball diameter (ISO 3408-5 needs > 0.5; "
                                    "0.52-0.56 is usual).", ge=0.505, le=0.6, default=0.55)
    conformity_nut: float = entry("The nut's groove radius over the ball diameter.", ge=0.505, le=0.6, default=0.55)
    pitch_diameter_mm: float | None = entry("D_pw (None: the nominal diameter).", unit="mm", gt=0, default=None)
    balls_per_turn: int | None = entry("Z_1 (None: as many as fit on a turn of the helix).", gt=0, default=None)
    load_sharing: float = entry("eta, the effective share of the balls in the contact compliance.", gt=0, le=1,
                                default=EFFECTIVE_BALL_SHARE)
    nut_outer_diameter_mm: float | None = entry("D, the nut body's outer diameter (None: nut_outer_diameter_mm()).",
                                                unit="mm", gt=0, default=None)
    accuracy_factor: float = entry("f_ar of ISO 3408-4 (1: the theoretical rigidity).", gt=0, le=1, default=1.0)
    c_dyn_N: float | None = entry("The dynamic load rating (None: estimated from the geometry).", unit="N", gt=0,
                                  default=None)
    c0_N: float | None = entry("The static load rating (None: estimated from the geometry).", unit="N", gt=0,
                               default=None)
    drag_coefficient: float | None = entry("K_p of the drag torque (None: HIWIN's 0.05 / sqrt(tan(helix))).", gt=0,
                                           default=None)
    material: Material = entry("The balls' and the grooves' material.", default=STEEL)

    def check(self) -> None:
        if not self.ball_mm < 0.25 * self.pitch_diameter:
            raise InputError(f"BallScrew.ball_mm = {self.ball_mm} is too large for a pitch diameter of "
                             f"{self.pitch_diameter} mm (needs < 0.25 D_pw).")
        if self.ball_mm >= self.lead_mm:
            raise InputError(f"BallScrew.ball_mm = {self.ball_mm} does not fit a lead of {self.lead_mm} mm "
                             f"(a ball must be smaller than the lead of a single-start screw).")
        if self.nut_outer_diameter <= self.pitch_diameter + self.ball_mm:
            raise InputError(f"BallScrew.nut_outer_diameter_mm must exceed D_pw + D_w = "
                             f"{self.pitch_diameter + self.ball_mm} mm, got {self.nut_outer_diameter_mm!r}.")

    # ---- the document (a plant artifact's ``screw`` object) ----------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The screw as a plant artifact holds it: every field, the balls per nut, the material's constants."""
        return {**{name: getattr(self, name) for name in _SCREW_FIELDS}, "balls_per_nut": self.balls_per_nut,
                "material": {"E_MPa": self.material.E_MPa, "poisson": self.material.poisson}}

    @classmethod
    def from_dict(cls, doc: Any) -> BallScrew:
        """The screw of its object (:meth:`to_dict`'s): each field the object gives (null: its default)."""
        if not isinstance(doc, dict):
            raise ValueError(f"expected an object of the screw's fields, got {type(doc).__name__}")
        values: dict[str, Any] = {name: _number(doc, name, integer=name == "balls_per_turn")
                                  for name in _SCREW_FIELDS if doc.get(name) is not None}
        m = doc.get("material")
        if m is not None:
            if not isinstance(m, dict) or "E_MPa" not in m or "poisson" not in m:
                raise Invalid("material", f"must be an object of E_MPa and poisson, got {m!r}")
            values["material"] = Material(_number(m, "E_MPa"), _number(m, "poisson"))
        return cls(**values)

    @classmethod
    def from_catalogue(cls, nominal_diameter_mm: float, lead_mm: float, ball_mm: float, turns: float, *,
                       c_dyn_N: float, c0_N: float, **kwargs: Any) -> BallScrew:
        """A catalogue screw whose groove conformity (screw and nut alike) is the one at which
        the Hertz static rating (4,200 MPa, ISO 76) equals the catalogue's C_0.

        The catalogue states its ratings; with the contact angle (45 deg unless given) they
        fix the conformity the vendor computed with, which the rigidity then uses. Other
        keywords are :class:`BallScrew`'s.
        """
        if "conformity_screw" in kwargs or "conformity_nut" in kwargs:
            raise InputError("BallScrew.from_catalogue sets the conformity from c0_N; pass no conformity, or "
                             "build BallScrew(...) directly with yours.")

        def screw(f: float) -> BallScrew:
            return cls(nominal_diameter_mm, lead_mm, ball_mm, turns, conformity_screw=f, conformity_nut=f,
                       c_dyn_N=c_dyn_N, **kwargs)

        lo, hi = 0.505, 0.6
        c0_lo, c0_hi = screw(lo).static_rating_N, screw(hi).static_rating_N
        if not c0_hi <= c0_N <= c0_lo:
            raise InputError(f"BallScrew.from_catalogue: c0_N = {c0_N!r} N is outside the static ratings this "
                             f"geometry has for conformities 0.505-0.6 ({c0_hi:.0f}-{c0_lo:.0f} N); check the "
                             f"ball diameter, turns and pitch diameter.")
        from scipy.optimize import brentq  # scipy.optimize loads on first use, not on import

        f = brentq(lambda x: screw(x).static_rating_N - c0_N, lo, hi, xtol=1e-12)
        return cls(nominal_diameter_mm, lead_mm, ball_mm, turns, conformity_screw=f, conformity_nut=f,
                   c_dyn_N=c_dyn_N, c0_N=c0_N, **kwargs)

    # ---- geometry -------------------------------------------------------------------------
    @property
    def pitch_diameter(self) -> float:
        return float(self.pitch_diameter_mm or self.nominal_diameter_mm)

    @property
    def helix_rad(self) -> float:
        return math.atan(self.lead_mm / (math.pi * self.pitch_diameter))

    @property
    def contact_rad(self) -> float:
        return math.radians(self.contact_angle_deg)

    @property
    def balls_on_turn(self) -> int:
        """Z_1: given, or as many balls as fit on one turn of the helix."""
        if self.balls_per_turn is not None:
            return int(self.balls_per_turn)
        return int(math.floor(math.pi * self.pitch_diameter / (self.ball_mm * math.cos(self.helix_rad))))

    @property
    def balls_per_nut(self) -> float:
        return self.balls_on_turn * self.turns

    @property
    def root_diameter_mm(self) -> float:
        """d_c = D_pw - D_w cos(beta), the screw's core (HIWIN's and ISO 3408-4's formula)."""
        return self.pitch_diameter - self.ball_mm * math.cos(self.contact_rad)

    @property
    def nut_length_mm(self) -> float:
        """Axial length of one nut's loaded turns."""
        return self.turns * self.lead_mm

    @property
    def nut_outer_diameter(self) -> float:
        return float(self.nut_outer_diameter_mm or nut_outer_diameter_mm(self.pitch_diameter, self.ball_mm))

    # ---- Hertz and the nut law -------------------------------------------------------------
    def _constants(self) -> tuple[float, float, float]:
        return nut_contact_constants(NUMPY, self.material.contact_modulus_MPa, self.pitch_diameter, self.ball_mm,
                              self.contact_rad, self.conformity_screw, self.conformity_nut)

    @property
    def axial_constant_um(self) -> float:
        """c_h (um per N^(2/3)): one nut's contact approach c_h F^(2/3), eta of the balls counted."""
        c_delta = self._constants()[0]
        return 1e3 * float(axial_contact_constant(NUMPY, c_delta, self.load_sharing * self.balls_per_nut,
                                           self.contact_rad, self.helix_rad))

    @property
    def structural_compliance_um_per_N(self) -> float:
        """s (um/N): one nut's body and the screw under it (module docstring)."""
        return 1e3 * float(structural_compliance(NUMPY, self.material.E_MPa, self.pitch_diameter, self.ball_mm,
                                                  self.contact_rad, self.helix_rad, self.nut_outer_diameter,
                                                  self.nut_length_mm))

    def nut_approach_um(self, nut_force_N: ArrayLike) -> Array:
        """delta(F) = (c_h F^(2/3) + s F) / f_ar (um): one nut's axial shift on the screw under F."""
        F = np.asarray(nut_force_N, float)
        approach: Array = (self.axial_constant_um * np.cbrt(F) ** 2
                           + self.structural_compliance_um_per_N * F) / self.accuracy_factor
        return approach

    def sigma(self, preload_N: ArrayLike) -> Array:
        """sigma = s F_p^(1/3) / c_h: the body's share of the nut law at the preload."""
        sigma: Array = (self.structural_compliance_um_per_N * np.cbrt(np.asarray(preload_N, float))
                        / self.axial_constant_um)
        return sigma

    def lift_off_load_N(self, preload_N: ArrayLike) -> Array:
        """The axial load at which the unloaded nut lifts off: rho(sigma) F_p (:func:`lift_off_ratio`)."""
        Fp = np.asarray(preload_N, float)
        load: Array = lift_off_ratio(self.sigma(Fp)) * Fp
        return load

    def preload_for_lift_off_N(self, axial_load_N: ArrayLike) -> Array:
        """The least preload that keeps both nuts loaded up to |F_a|: the F_p with
        delta(F_p) = delta(|F_a|) / 2 (the inverse of :meth:`lift_off_load_N`)."""
        Fa = np.abs(np.asarray(axial_load_N, float))
        c_h, s = self.axial_constant_um, self.structural_compliance_um_per_N
        target = 0.5 * (c_h * np.cbrt(Fa) ** 2 + s * Fa)
        # delta(F) = target in t = F^(1/3): c_h t^2 + s t^3 = target, convex in t; Newton from
        # the Hertz-only root (above the root) descends monotonically
        t = np.sqrt(target / c_h)
        for _ in range(3 * _NEWTON_STEPS):
            t = t - (c_h * t ** 2 + s * t ** 3 - target) / np.maximum(2.0 * c_h * t + 3.0 * s * t ** 2, 1e-300)
        preload: Array = t ** 3
        return preload

    def turn_loads(self, nut_force_N: float) -> Array:
        """Each loaded turn's share of one nut's load F (sums to 1), the exact elastic load
        distribution along the nut.

        The shear-lag solution for a nut whose load enters its body and leaves the screw at
        the same end (the first turn): with the contacts and the ring linearised at F into a
        foundation k' (N/mm per mm) between the nut body (E A_nut) and the screw core
        (E A_core), the transfer per length is proportional to cosh(lambda (L - x)),
        lambda^2 = k' (1/(E A_nut) + 1/(E A_core)); equal shares when the bodies are rigid.
        """
        F = float(nut_force_N)
        if not (math.isfinite(F) and F > 0):
            raise InputError(f"nut_force_N must be a finite number > 0, got {nut_force_N!r}.")
        L, lam = self.nut_length_mm, self.load_distribution_lambda_per_mm(F)
        x = np.minimum(np.arange(math.ceil(self.turns) + 1) * self.lead_mm, L)
        if lam * L < 1e-8:
            return np.asarray(np.diff(x) / L, np.float64)
        return np.asarray(-np.diff(np.sinh(lam * (L - x))) / math.sinh(lam * L), np.float64)

    def load_distribution_lambda_per_mm(self, nut_force_N: float) -> float:
        """lambda (1/mm) of :meth:`turn_loads` at one nut's force F; lambda L small means nearly
        equal turns and the first-order body term of the nut law exact."""
        E, L = self.material.E_MPa, self.nut_length_mm
        radial, bars = _structural_parts(NUMPY, E, self.pitch_diameter, self.ball_mm, self.contact_rad,
                                         self.helix_rad, self.nut_outer_diameter, L)
        contact = 1e-3 * 2.0 / 3.0 * self.axial_constant_um * float(nut_force_N) ** (-1.0 / 3.0)  # mm/N, whole nut
        # the foundation k' = 1 / ((contact + radial) L); the bars' 1/(E A) sum = 3 bars / L
        return math.sqrt(3.0 * float(bars) / ((contact + float(radial)) * L ** 2))

    def contact(self, nut_force_N: ArrayLike) -> ContactState:
        """The ball contact under one nut's axial force, all balls sharing equally (ISO 3408-5)."""
        F = np.asarray(nut_force_N, float)
        c_delta, cp_s, cp_n = self._constants()
        Q = F / (self.balls_per_nut * math.sin(self.contact_rad) * math.cos(self.helix_rad))
        q13 = np.cbrt(Q)
        return ContactState(ball_load_N=Q, approach_um=1e3 * c_delta * q13 ** 2,
                            pressure_screw_MPa=cp_s * q13, pressure_nut_MPa=cp_n * q13)

    # ---- ratings --------------------------------------------------------------------------
    @property
    def static_rating_N(self) -> float:
        """C_0: catalogue value, or the axial load that presses a contact to 4,200 MPa."""
        if self.c0_N is not None:
            return float(self.c0_N)
        _, cp_s, cp_n = self._constants()
        Q0 = (CONTACT_LIMIT_MPA / max(cp_s, cp_n)) ** 3
        return float(Q0 * self.balls_per_nut * math.sin(self.contact_rad) * math.cos(self.helix_rad))

    @property
    def dynamic_rating_N(self) -> float:
        """C_dyn: catalogue value, or the Lundberg-Palmgren estimate of the module docstring."""
        if self.c_dyn_N is not None:
            return float(self.c_dyn_N)
        return float(dynamic_load_rating(NUMPY, self.pitch_diameter, self.ball_mm, self.contact_rad, self.helix_rad,
                            self.conformity_screw, self.conformity_nut, self.balls_on_turn, self.turns))

    @property
    def drag_K(self) -> float:
        return float(self.drag_coefficient if self.drag_coefficient is not None
                     else drag_torque_coefficient(NUMPY, self.helix_rad))

    # ---- the double nut -------------------------------------------------------------------
    def nut_loads(self, preload_N: ArrayLike, axial_load_N: ArrayLike = 0.0) -> NutLoads:
        """Load sharing, deflection and rigidity under preload and axial load (eqs. (2)-(13)).

        The exact two-nut solution of the nut law below lift-off; above it, the loaded nut
        alone carries F_a. The sign of F_a says which nut is loaded; forces are magnitudes.
        """
        Fp, Fa = np.broadcast_arrays(np.asarray(preload_N, float), np.asarray(axial_load_N, float))
        if not np.all(np.isfinite(Fp)) or np.any(Fp <= 0):
            raise InputError(f"preload_N must be finite and > 0, got {preload_N!r}.")
        if not np.all(np.isfinite(Fa)):
            raise InputError(f"axial_load_N must be finite, got {axial_load_N!r}.")
        c_h, s = self.axial_constant_um, self.structural_compliance_um_per_N
        sigma = s * np.cbrt(Fp) / c_h
        rho = lift_off_ratio(sigma)
        ratio = np.abs(Fa) / Fp
        lifted = ratio >= rho
        f_loaded, f_unloaded = nut_forces(np.minimum(ratio, rho), sigma)
        loaded = Fp * np.where(lifted, ratio, f_loaded)
        unloaded = Fp * np.where(lifted, 0.0, f_unloaded)
        k_contact = 1.5 * (np.cbrt(loaded) + np.cbrt(unloaded)) / c_h
        k = double_nut_rigidity(NUMPY, c_h, s, self.accuracy_factor, loaded, unloaded)
        shift = self.nut_approach_um(loaded) - self.nut_approach_um(Fp)
        return NutLoads(preload_N=Fp, axial_load_N=Fa, loaded_nut_N=loaded, unloaded_nut_N=unloaded,
                        deflection_um=np.sign(Fa) * shift, contact_stiffness_N_per_um=k_contact,
                        rigidity_N_per_um=k, lifted_off=lifted)

    def rigidity_N_per_um(self, preload_N: ArrayLike, axial_load_N: ArrayLike = 0.0) -> Array:
        """Axial rigidity of the preloaded double nut (N/um), what catalogues tabulate."""
        return self.nut_loads(preload_N, axial_load_N).rigidity_N_per_um

    def hertz_rigidity_N_per_um(self, preload_N: ArrayLike) -> Array:
        """Eq. (13) of the paper: the double nut's Hertz contact stiffness at no load, all
        balls equally loaded, rigid nut and screw: 3 F_p^(1/3) / c_h with eta = 1."""
        c_delta = self._constants()[0]
        c_h = 1e3 * float(axial_contact_constant(NUMPY, c_delta, self.balls_per_nut, self.contact_rad, self.helix_rad))
        rigidity: Array = 3.0 * np.cbrt(np.asarray(preload_N, float)) / c_h
        return rigidity

    def drag_torque_Nm(self, preload_N: ArrayLike) -> Array:
        """Preload drag torque T_d = K_p F_p P / (2000 pi) (N m)."""
        return self.drag_K * np.asarray(preload_N, float) * self.lead_mm / (2000.0 * math.pi)

    @property
    def seal_torque_Nm(self) -> float:
        """The idle torque of the nut's two lip seals (N m) by Rexroth's table for this nominal diameter and lead
        (:func:`~piezopreload.models.thermal.rexroth_seal_torque_Nm`); independent of the preload."""
        return rexroth_seal_torque_Nm(self.nominal_diameter_mm, self.lead_mm)

    def friction_heat_W(self, preload_N: Any, speed_rpm: Any, *, model: str = "catalogue", lubricant_vg: int = 68,
                        seal_torque_Nm: float | None = None, temperature_C: Any = 40.0,
                        contact_calibration: float = CONTACT_CALIBRATION, ops: Any = NUMPY) -> Any:
        """The double nut's friction heat (W) at ``preload_N`` and ``speed_rpm`` (broadcast; numpy arrays, or
        CasADi expressions with ``ops=CASADI``): the preload's part plus the seals' T_s omega.

        ``model="catalogue"``: the drag torque :meth:`drag_torque_Nm` times the angular speed (linear in the
        preload; the lubricant and the temperature do not enter it); ``"contact"``: Jungnickel's rolling-contact
        loss of the open nut (about F_p^0.48 omega^1.51 nu^0.51, ISO VG ``lubricant_vg`` at the contact's
        ``temperature_C``), times ``contact_calibration`` (the measured torques' level,
        :data:`~piezopreload.models.thermal.CONTACT_CALIBRATION`). ``seal_torque_Nm``: the seals' torque, the same in
        both models and independent of the preload (None: :attr:`seal_torque_Nm`, Rexroth's table; 0: an open nut).
        """
        if model not in HEAT_MODELS:
            raise InputError(f"model must be one of {', '.join(HEAT_MODELS)}, got {model!r}.")
        seals = self.seal_torque_Nm if seal_torque_Nm is None else float(seal_torque_Nm)
        if not (math.isfinite(seals) and seals >= 0):
            raise InputError(f"seal_torque_Nm must be a finite number >= 0, got {seal_torque_Nm!r}.")
        omega = (ops.fabs(speed_rpm) if ops.symbolic else np.abs(np.asarray(speed_rpm, float))) * (math.pi / 30.0)
        preload = preload_N if ops.symbolic else np.asarray(preload_N, float)
        if model == HeatModel.CATALOGUE:
            nut = catalogue_heat_W(ops, self.drag_K, self.lead_mm, preload, omega)
        else:
            nut = contact_heat_W(ops, preload, omega, balls=self.balls_per_nut, contact_rad=self.contact_rad,
                                 helix_rad=self.helix_rad, pitch_diameter_mm=self.pitch_diameter,
                                 ball_mm=self.ball_mm, lubricant_vg=lubricant_vg, temperature_C=temperature_C,
                                 calibration=contact_calibration)
        return nut + seal_heat_W(seals, omega)

    def spacer_preload_N(self, preload_N: float, mismatch_um: ArrayLike,
                         spacer_stiffness_N_per_um: float = math.inf) -> Array:
        """The preload of a spacer-preloaded double nut (N) after its spacer's fit grows by ``mismatch_um`` (> 0: the
        nuts pressed harder, < 0 relieved): the root F >= 0 of 2 delta(F) + F / k_s = 2 delta(F_p) + F_p / k_s + m,
        delta the nut law :meth:`nut_approach_um` (both nuts carry F; k_s the spacer), 0 where the nuts part.

        The tangent of this at F_p is :func:`~piezopreload.models.thermal.spacer_drift_N_per_K`'s; the law softens
        as the preload falls (delta ~ F^(2/3)), so a linear extrapolation of the tangent overstates a large loss.
        """
        Fp = float(preload_N)
        if not (math.isfinite(Fp) and Fp > 0):
            raise InputError(f"preload_N must be a finite number > 0, got {preload_N!r}.")
        m = np.asarray(mismatch_um, float)

        def fit(F: Array) -> Array:
            return 2.0 * self.nut_approach_um(F) + F / spacer_stiffness_N_per_um

        target = float(fit(np.asarray(Fp))) + m
        lo = np.zeros_like(m)
        hi = np.full_like(m, Fp)
        while np.any(fit(hi) < target):  # the law grows without bound: widen until the root is inside
            hi = np.where(fit(hi) < target, 2.0 * hi, hi)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            below = fit(mid) < target
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return np.where(target <= 0.0, 0.0, 0.5 * (lo + hi))

    def nut_stiffness_N_per_um(self, nut_force_N: ArrayLike) -> Array:
        """One nut's tangent stiffness dF/d(delta) (N/um) at its force: F^(1/3) / (2/3 c_h + s F^(1/3)), times f_ar."""
        stiffness: Array = self.accuracy_factor * _nut_stiffness(
            NUMPY, self.axial_constant_um, self.structural_compliance_um_per_N, np.asarray(nut_force_N, float))
        return stiffness

    def life(self, preload_N: float, cases: list[DutyCase] | tuple[DutyCase, ...], load_factor: float = 1.2,
             reliability: float = 0.90) -> Life:
        """Rating life over a duty cycle, from the exact nut loads of each case.

        Each nut's equivalent load is the revolution-weighted cube mean of its force times the
        load factor f_p; L_nut = (C_dyn / F_m)^3 1e6 rev; the pair's life
        L = (L_A^(-10/9) + L_B^(-10/9))^(-9/10), times the reliability factor.
        """
        if not cases:
            raise InputError("life needs at least one duty case.")
        if reliability not in RELIABILITY_FACTORS:
            raise InputError(f"reliability must be one of {sorted(RELIABILITY_FACTORS)}, got {reliability!r}.")
        if not load_factor >= 1.0:
            raise InputError(f"load_factor must be >= 1, got {load_factor!r}.")
        Fa = np.array([c.axial_load_N for c in cases])
        revs = np.array([c.speed_rpm * c.time_share for c in cases])
        if not revs.sum() > 0:
            raise InputError("life needs a duty cycle with some revolutions (all speeds are 0).")
        loads = self.nut_loads(preload_N, Fa)
        # nut B carries positive loads, nut A negative ones
        F_B = np.where(Fa >= 0, loads.loaded_nut_N, loads.unloaded_nut_N)
        F_A = np.where(Fa >= 0, loads.unloaded_nut_N, loads.loaded_nut_N)
        Fm_A = float(np.cbrt(np.sum(F_A ** 3 * revs) / revs.sum()))
        Fm_B = float(np.cbrt(np.sum(F_B ** 3 * revs) / revs.sum()))
        C = self.dynamic_rating_N
        L_A = (C / (load_factor * Fm_A)) ** 3 * 1e6 if Fm_A > 0 else math.inf
        L_B = (C / (load_factor * Fm_B)) ** 3 * 1e6 if Fm_B > 0 else math.inf
        L = (L_A ** (-10.0 / 9.0) + L_B ** (-10.0 / 9.0)) ** (-9.0 / 10.0) * RELIABILITY_FACTORS[reliability]
        n_m = float(revs.sum() / sum(c.time_share for c in cases))
        return Life(revolutions=float(L), hours=float(L / (60.0 * n_m)), mean_speed_rpm=n_m,
                    nut_A_revolutions=float(L_A), nut_B_revolutions=float(L_B),
                    equivalent_load_A_N=Fm_A, equivalent_load_B_N=Fm_B)


#: the screw's fields a plant artifact records (its ``screw`` object), every one BallScrew takes but the material
_SCREW_FIELDS = tuple(f.name for f in fields(BallScrew) if f.name != "material")
