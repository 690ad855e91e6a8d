"""The preloaded double-nut ball screw: geometry, Hertz contact, load sharing, rigidity, ratings.

Section 2.2 of the paper, derived from Hertz theory rather than read off its garbled
eqs. (9)-(13) (see ``docs/models.md``, section 5), plus what a selection procedure checks: load ratings,
life, drag torque and static safety. Units are those of ball-screw catalogues, named in
every field: mm, N, MPa, N/um, N m.

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
* **One nut.** A ball load Q = F / (z sin(beta) cos(alpha)) (eq. (3) of the paper) moves the
  nut axially by the summed normal approaches over sin(beta) cos(alpha): delta = c_h F^(2/3)
  (our form of eq. (12); the paper's extracted exponents are unreliable).
* **Double nut.** Both nuts start at delta_p = c_h F_p^(2/3); an axial load F_a shifts the
  assembly by x, so the loaded nut carries F_p (1 + u)^(3/2) and the other F_p (1 - u)^(3/2),
  u = x / delta_p, with F_a = F_p [(1 + u)^(3/2) - (1 - u)^(3/2)]: eq. (10) solved exactly
  (Newton, unrolled, :func:`load_share`), not its linearisation eq. (11). The unloaded nut
  lifts off at u = 1, F_a = 2^(3/2) F_p. The contact stiffness dF_a/dx =
  (3 F_p / (2 delta_p)) (sqrt(1 + u) + sqrt(1 - u)) is 3 F_p^(1/3) / c_h at no load: it grows
  as F_p^(1/3) and, through c_h, as z^(2/3) and sin(beta)^(5/3), as eq. (13) says.

Where this departs from a Hertz-only model (and from the paper): catalogue rigidity is
lower than the Hertz-only value (``docs/references.md``, Steinmeyer's hierarchy). Two
corrections, the same for every screw, not fitted per catalogue row:

1. **Unequal ball loads** (pitch and ball-size errors of the accuracy class, elastic load
   distribution along the nut): only an effective share ``load_sharing`` = 0.7 of the balls
   is counted in the rigidity (stiffness scales as its 2/3 power, 0.79). The value is a
   round engineering figure chosen once; the two HIWIN rows then land at +4 % and +9 %
   (``tests/test_ballscrew.py``), and a per-row fit would have needed 0.63 and 0.57.
2. **Nut body and screw shaft** within the nut, each loaded over half the loaded length,
   in series with the contacts (``nut_outer_diameter_mm`` defaults to 1.7 times the
   nominal diameter, typical of flanged double nuts).

Load ratings follow ISO 3408-5's convention of equal ball loads: the static rating C_0 is
the axial load at which the most pressed contact reaches 4,200 MPa (ISO 76), from the same
Hertz model (HIWIN rows: +5 %); the dynamic rating C_dyn, where no catalogue value is given,
is the Lundberg-Palmgren form for angular-contact thrust rows,
``K f_c(gamma) cos(beta)^0.7 tan(beta) cos(alpha)^1.3 Z_1^(2/3) D_w^1.8 i^0.86``, with
gamma = D_w cos(beta) / D_pw, whose one constant K is calibrated on the R40-10T4 row and
checked on R32-5T4 (-5 %). A catalogue C_dyn, where known, should be passed instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Material", "STEEL", "BallScrew", "DutyCase", "ContactState", "NutLoads", "Life",
    "load_share", "hiwin_loaded_nut_force", "lift_off_load_N", "NUMPY_OPS", "CASADI_OPS",
    "CONTACT_LIMIT_MPA", "RELIABILITY_FACTORS",
]

Array = NDArray[np.float64]

#: Static contact-pressure limit of hardened bearing steel (ISO 76), MPa.
CONTACT_LIMIT_MPA = 4200.0
#: Life reliability factors of ISO 3408-5 (90 % is the rating life L10).
RELIABILITY_FACTORS = {0.90: 1.00, 0.95: 0.63, 0.99: 0.21}
LIFT_OFF_RATIO = 2.0 ** 1.5
#: The one constant of the C_dyn estimate (N, mm), calibrated on HIWIN R40-10T4-RDI
#: (C_dyn 37,890 N); see the module docstring.
_CDYN_CONSTANT = 70.98
#: Nut outer diameter over nominal diameter when not given (flanged double nuts).
NUT_OUTER_RATIO = 1.7
_NEWTON_STEPS = 8  # load_share: 7 steps reach 1e-15 over 0..2^(3/2) (Newton from below)

#: The operations the formulas below need, on numpy arrays or CasADi expressions: one
#: implementation serves the numpy model and the CasADi design NLPs.
NUMPY_OPS = SimpleNamespace(sin=np.sin, cos=np.cos, tan=np.tan, log=np.log, exp=np.exp,
                            sqrt=np.sqrt, fmin=np.minimum, fmax=np.maximum)
CASADI_OPS = SimpleNamespace(sin=ca.sin, cos=ca.cos, tan=ca.tan, log=ca.log, exp=ca.exp,
                             sqrt=ca.sqrt, fmin=ca.fmin, fmax=ca.fmax)


@dataclass(frozen=True)
class Material:
    """Elastic constants of balls and raceways (both the same steel)."""

    E_MPa: float = 206e3
    poisson: float = 0.3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.E_MPa) and self.E_MPa > 0):
            raise ValueError(f"Material.E_MPa must be a finite number > 0, got {self.E_MPa!r}.")
        if not 0 <= self.poisson < 0.5:
            raise ValueError(f"Material.poisson must be in [0, 0.5), got {self.poisson!r}.")

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


def _nut_constants(ops: Any, E_prime: float, D_pw: Any, D_w: Any, beta: Any, f_screw: Any, f_nut: Any
                   ) -> tuple[Any, Any, Any]:
    """``(c_delta, c_p_screw, c_p_nut)``: the summed normal approach of screw and nut
    contacts per Q^(2/3), and the peak-pressure constants of each contact."""
    cb = ops.cos(beta)
    inv_Ry_s = (2.0 - 1.0 / f_screw) / D_w
    inv_Ry_n = (2.0 - 1.0 / f_nut) / D_w
    inv_Rx_s = 2.0 / D_w + 2.0 * cb / (D_pw - D_w * cb)
    inv_Rx_n = 2.0 / D_w - 2.0 * cb / (D_pw + D_w * cb)
    cd_s, cp_s = _contact_constants(ops, E_prime, inv_Rx_s, inv_Ry_s)
    cd_n, cp_n = _contact_constants(ops, E_prime, inv_Rx_n, inv_Ry_n)
    return cd_s + cd_n, cp_s, cp_n


def _axial_constant(ops: Any, c_delta: Any, z: Any, beta: Any, helix: Any) -> Any:
    """c_h (mm per N^(2/3)): one nut's axial approach delta = c_h F^(2/3) under F (N)."""
    s = ops.sin(beta) * ops.cos(helix)
    return c_delta / ((z * s) ** (2.0 / 3.0) * s)


def load_share(ratio: Any, ops: Any = NUMPY_OPS) -> Any:
    """u = x / delta_p of the double nut under F_a = ratio F_p, for 0 <= ratio < 2^(3/2).

    Solves eq. (10) of the paper exactly, (1 + u)^(3/2) - (1 - u)^(3/2) = ratio, by Newton's
    method from u = 0 unrolled a fixed number of steps, so the same expression serves numpy
    and CasADi (where it is differentiable). The left side is increasing and concave in u,
    so the iterates rise monotonically to the root and never pass u = 1.
    """
    u = 0.0 * ratio
    for _ in range(_NEWTON_STEPS):
        up, um = ops.sqrt(1.0 + u), ops.sqrt(ops.fmax(1.0 - u, 0.0))
        u = ops.fmin(u - ((1.0 + u) * up - ops.fmax(1.0 - u, 0.0) * um - ratio) / (1.5 * (up + um)), 1.0)
    return u


def _c_dyn(ops: Any, D_pw: Any, D_w: Any, beta: Any, helix: Any, f_screw: Any, f_nut: Any,
           balls_per_turn: Any, turns: Any) -> Any:
    """Dynamic axial load rating estimate (N): the Lundberg-Palmgren form, see the module."""
    gamma = D_w * ops.cos(beta) / D_pw
    q = 1.04 * ((1.0 - gamma) / (1.0 + gamma)) ** 1.72 * (f_screw * (2.0 * f_nut - 1.0) / (f_nut * (2.0 * f_screw - 1.0))) ** 0.41
    f_c = (gamma ** 0.3 * (1.0 - gamma) ** 1.39 / (1.0 + gamma) ** (1.0 / 3.0)
           * (1.0 + q ** (10.0 / 3.0)) ** -0.3 * (2.0 * f_screw / (2.0 * f_screw - 1.0)) ** 0.41)
    return (_CDYN_CONSTANT * f_c * ops.cos(beta) ** 0.7 * ops.tan(beta) * ops.cos(helix) ** 1.3
            * balls_per_turn ** (2.0 / 3.0) * D_w ** 1.8 * turns ** 0.86)


def _body_stiffness(ops: Any, E: float, D_pw: Any, D_w: Any, beta: Any, d_out: Any, nut_length: Any) -> Any:
    """Nut body and screw under the nut (N/um), each over half the loaded length, in series."""
    cb = ops.cos(beta)
    half = 0.5 * nut_length
    k_screw = E * math.pi * (D_pw - D_w * cb) ** 2 / 4.0 / half
    k_nut = E * math.pi * (d_out ** 2 - (D_pw + D_w * cb) ** 2) / 4.0 / half
    return 1e-3 / (1.0 / k_screw + 1.0 / k_nut)


def _contact_stiffness(ops: Any, c_h_um: Any, preload_N: Any, u: Any) -> Any:
    """dF_a/dx of the double nut's contacts (N/um) at preload F_p and load share u:
    (3 F_p / (2 delta_p)) (sqrt(1 + u) + sqrt(1 - u)), delta_p = c_h F_p^(2/3)."""
    return 1.5 * preload_N ** (1.0 / 3.0) / c_h_um * (ops.sqrt(1.0 + u) + ops.sqrt(ops.fmax(1.0 - u, 0.0)))


def _rigidity(ops: Any, c_h_um: Any, k_body: Any, preload_N: Any, u: Any) -> Any:
    """Rigidity (N/um) of the double nut: the contacts' stiffness in series with the body."""
    return 1.0 / (1.0 / _contact_stiffness(ops, c_h_um, preload_N, u) + 1.0 / k_body)


def _drag_coefficient(ops: Any, helix: Any) -> Any:
    """K_p of the preload drag torque, HIWIN's 0.05 / sqrt(tan(helix)) (0.1-0.3 in use)."""
    return 0.05 / ops.sqrt(ops.tan(helix))


# ---- closed forms of the references ---------------------------------------------------------


def lift_off_load_N(preload_N: ArrayLike) -> Array:
    """The axial load at which the unloaded nut of a double nut lifts off: 2^(3/2) F_p."""
    return LIFT_OFF_RATIO * np.asarray(preload_N, float)


def hiwin_loaded_nut_force(preload_N: ArrayLike, axial_load_N: ArrayLike) -> Array:
    """HIWIN's catalogue formula for the loaded nut's force (``docs/references.md``, [HIWIN]).

    (1 + F_a / (2^(3/2) F_p))^(3/2) F_p below lift-off, F_a above; within 2.5 % of
    :meth:`BallScrew.nut_loads`, which solves the two-nut Hertz problem exactly.
    """
    fp, fa = np.asarray(preload_N, float), np.abs(np.asarray(axial_load_N, float))
    return np.where(fa < LIFT_OFF_RATIO * fp, (1.0 + fa / (LIFT_OFF_RATIO * fp)) ** 1.5 * fp, fa)


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
    """The double nut under preload F_p and axial load F_a (exact two-nut Hertz solution)."""

    preload_N: Array
    axial_load_N: Array
    loaded_nut_N: Array
    unloaded_nut_N: Array
    deflection_um: Array  # axial shift of the nut assembly on the screw from the preloaded state
    contact_stiffness_N_per_um: Array
    rigidity_N_per_um: Array  # contacts in series with the nut body and the screw under the nut
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
                raise ValueError(f"DutyCase.{name} must be finite, got {getattr(self, name)!r}.")
        if self.speed_rpm < 0 or self.time_share <= 0:
            raise ValueError(f"DutyCase needs speed_rpm >= 0 and time_share > 0, got {self.speed_rpm!r} and "
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


@dataclass(frozen=True)
class BallScrew:
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
    load_sharing, nut_outer_diameter_mm
        The rigidity corrections (module docstring).
    c_dyn_N, c0_N
        Catalogue ratings; estimated from the geometry when not given.
    drag_coefficient
        K_p of the drag torque; HIWIN's 0.05 / sqrt(tan(helix)) when not given.
    """

    nominal_diameter_mm: float
    lead_mm: float
    ball_mm: float
    turns: float
    contact_angle_deg: float = 45.0
    conformity_screw: float = 0.55
    conformity_nut: float = 0.55
    pitch_diameter_mm: float | None = None
    balls_per_turn: int | None = None
    load_sharing: float = 0.7
    nut_outer_diameter_mm: float | None = None
    c_dyn_N: float | None = None
    c0_N: float | None = None
    drag_coefficient: float | None = None
    material: Material = field(default=STEEL)

    def __post_init__(self) -> None:
        def positive(name: str) -> None:
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"BallScrew.{name} must be a finite number > 0, got {value!r}.")

        for name in ("nominal_diameter_mm", "lead_mm", "ball_mm", "turns", "pitch_diameter_mm",
                     "nut_outer_diameter_mm", "c_dyn_N", "c0_N", "drag_coefficient", "balls_per_turn"):
            positive(name)
        if not 20.0 <= self.contact_angle_deg <= 70.0:
            raise ValueError(f"BallScrew.contact_angle_deg must be in [20, 70], got {self.contact_angle_deg!r}.")
        for name in ("conformity_screw", "conformity_nut"):
            if not 0.505 <= getattr(self, name) <= 0.6:
                raise ValueError(f"BallScrew.{name} must be in [0.505, 0.6] (ISO 3408-5 needs > 0.5; "
                                 f"0.52-0.56 is usual), got {getattr(self, name)!r}.")
        if not 0 < self.load_sharing <= 1:
            raise ValueError(f"BallScrew.load_sharing must be in (0, 1], got {self.load_sharing!r}.")
        if not self.ball_mm < 0.25 * self.pitch_diameter:
            raise ValueError(f"BallScrew.ball_mm = {self.ball_mm} is too large for a pitch diameter of "
                             f"{self.pitch_diameter} mm (needs < 0.25 D_pw).")
        if self.ball_mm >= self.lead_mm:
            raise ValueError(f"BallScrew.ball_mm = {self.ball_mm} does not fit a lead of {self.lead_mm} mm "
                             f"(a ball must be smaller than the lead of a single-start screw).")
        if self.nut_outer_diameter <= self.pitch_diameter + self.ball_mm:
            raise ValueError(f"BallScrew.nut_outer_diameter_mm must exceed D_pw + D_w = "
                             f"{self.pitch_diameter + self.ball_mm} mm, got {self.nut_outer_diameter_mm!r}.")

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
        """d_c = D_pw - D_w cos(beta), the screw's core (``docs/models.md``, section 6)."""
        return self.pitch_diameter - self.ball_mm * math.cos(self.contact_rad)

    @property
    def nut_length_mm(self) -> float:
        """Axial length of one nut's loaded turns."""
        return self.turns * self.lead_mm

    # ---- Hertz ----------------------------------------------------------------------------
    def _constants(self) -> tuple[float, float, float]:
        return _nut_constants(NUMPY_OPS, self.material.contact_modulus_MPa, self.pitch_diameter, self.ball_mm,
                              self.contact_rad, self.conformity_screw, self.conformity_nut)

    @property
    def axial_constant_um(self) -> float:
        """c_h (um per N^(2/3)) of one nut with the effective share of loaded balls."""
        c_delta = self._constants()[0]
        return 1e3 * float(_axial_constant(NUMPY_OPS, c_delta, self.load_sharing * self.balls_per_nut,
                                           self.contact_rad, self.helix_rad))

    @property
    def body_stiffness_N_per_um(self) -> float:
        """Nut body and screw under the nut, each over half the loaded length, in series."""
        return float(_body_stiffness(NUMPY_OPS, self.material.E_MPa, self.pitch_diameter, self.ball_mm,
                                     self.contact_rad, self.nut_outer_diameter, self.nut_length_mm))

    @property
    def nut_outer_diameter(self) -> float:
        return float(self.nut_outer_diameter_mm or NUT_OUTER_RATIO * self.nominal_diameter_mm)

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
        return float(_c_dyn(NUMPY_OPS, self.pitch_diameter, self.ball_mm, self.contact_rad, self.helix_rad,
                            self.conformity_screw, self.conformity_nut, self.balls_on_turn, self.turns))

    @property
    def drag_K(self) -> float:
        return float(self.drag_coefficient if self.drag_coefficient is not None
                     else _drag_coefficient(NUMPY_OPS, self.helix_rad))

    # ---- the double nut -------------------------------------------------------------------
    def nut_loads(self, preload_N: ArrayLike, axial_load_N: ArrayLike = 0.0) -> NutLoads:
        """Load sharing, deflection and rigidity under preload and axial load (eqs. (2)-(13)).

        Exact two-nut Hertz solution below lift-off; above it, the loaded nut alone
        carries F_a. The sign of F_a says which nut is loaded; forces are magnitudes.
        """
        Fp, Fa = np.broadcast_arrays(np.asarray(preload_N, float), np.asarray(axial_load_N, float))
        if not np.all(np.isfinite(Fp)) or np.any(Fp <= 0):
            raise ValueError(f"preload_N must be finite and > 0, got {preload_N!r}.")
        if not np.all(np.isfinite(Fa)):
            raise ValueError(f"axial_load_N must be finite, got {axial_load_N!r}.")
        ratio = np.abs(Fa) / Fp
        lifted = ratio >= LIFT_OFF_RATIO
        u = np.where(lifted, np.maximum(ratio, LIFT_OFF_RATIO) ** (2.0 / 3.0) - 1.0,
                     load_share(np.minimum(ratio, LIFT_OFF_RATIO)))
        loaded = Fp * (1.0 + u) ** 1.5
        unloaded = Fp * np.maximum(1.0 - u, 0.0) ** 1.5
        c_h = self.axial_constant_um
        delta_p = c_h * Fp ** (2.0 / 3.0)
        k_contact = _contact_stiffness(NUMPY_OPS, c_h, Fp, u)
        k_total = 1.0 / (1.0 / k_contact + 1.0 / self.body_stiffness_N_per_um)
        return NutLoads(preload_N=Fp, axial_load_N=Fa, loaded_nut_N=loaded, unloaded_nut_N=unloaded,
                        deflection_um=np.sign(Fa) * u * delta_p, contact_stiffness_N_per_um=k_contact,
                        rigidity_N_per_um=k_total, lifted_off=lifted)

    def rigidity_N_per_um(self, preload_N: ArrayLike, axial_load_N: ArrayLike = 0.0) -> Array:
        """Axial rigidity of the preloaded double nut (N/um), what catalogues tabulate."""
        return self.nut_loads(preload_N, axial_load_N).rigidity_N_per_um

    def drag_torque_Nm(self, preload_N: ArrayLike) -> Array:
        """Preload drag torque T_d = K_p F_p P / (2000 pi) (N m)."""
        return self.drag_K * np.asarray(preload_N, float) * self.lead_mm / (2000.0 * math.pi)

    def life(self, preload_N: float, cases: list[DutyCase] | tuple[DutyCase, ...], load_factor: float = 1.2,
             reliability: float = 0.90) -> Life:
        """Rating life over a duty cycle, from the exact nut loads of each case.

        Each nut's equivalent load is the revolution-weighted cube mean of its force times the
        load factor f_p; L_nut = (C_dyn / F_m)^3 1e6 rev; the pair's life
        L = (L_A^(-10/9) + L_B^(-10/9))^(-9/10), times the reliability factor.
        """
        if not cases:
            raise ValueError("life needs at least one duty case.")
        if reliability not in RELIABILITY_FACTORS:
            raise ValueError(f"reliability must be one of {sorted(RELIABILITY_FACTORS)}, got {reliability!r}.")
        if not load_factor >= 1.0:
            raise ValueError(f"load_factor must be >= 1, got {load_factor!r}.")
        Fa = np.array([c.axial_load_N for c in cases])
        revs = np.array([c.speed_rpm * c.time_share for c in cases])
        if not revs.sum() > 0:
            raise ValueError("life needs a duty cycle with some revolutions (all speeds are 0).")
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
