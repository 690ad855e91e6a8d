"""Ball-screw preload design with CasADi: the optimum and its Pareto fronts.

The machine fixes the screw's nominal diameter and lead, the axis (:class:`FeedDrive`), the
duty cycle and the piezo stacks; the design chooses

* the contact angle beta, the ball diameter D_w and the groove conformity f (continuous);
* the loaded turns per nut and the balls per turn (integers, see below);
* the bolts' preload F_i (what holds the nuts when the stacks are off), the highest preload
  F_hi the stacks must reach, and the preload F_p,j of each duty case between them (the
  piezo preload range, used case by case: low on rapid traverses, high when cutting).

Objectives (one, picked by the user): ``stiffness`` maximises the least rigidity over the
duty cases (an epigraph variable t <= K_j); ``drag`` minimises the time-mean preload drag
torque; ``life`` maximises the rating life (its logarithm). Ties are broken (a 1e-3 weight)
towards more stiffness, less drag, mean and at F_hi, and a wider piezo range, a lower F_i,
so no preload and no geometry is left undetermined: the drag a design pays depends on its
preloads and helix alone, and without the stiffness term the least-drag design's contact
angle, balls and conformity would be whatever the solver's path left them at (a weakly
dominated end for the fronts).

Constraints, each a row of :data:`CONSTRAINTS` with its units:
preload <= a fraction of C_dyn; no lift-off at each case's load, at the maximum axial load
(with F_hi) and at the fail-safe load (with the bolts alone); peak contact pressure at the
maximum load; life >= target; drag torque at F_hi <= limit; the first axial mode at the
weakest table position >= a frequency in every case; the stacks' stroke and blocked force
from F_i to F_hi; balls fit on a turn and between the threads; nut length; t >= a stiffness
target (for the drag and life objectives and the epsilon-constraint fronts). Rigidity and nut
loads are those of models/ballscrew.py's nut law (the contacts of an effective share of the
balls and the nut body), and the stacks' stroke counts the same law. The lift-off rows use the
catalogues' rule, no lift-off below 2^(3/2) F_p, with the user's margin: the nut body lowers
the law's lift-off load to rho F_p (:meth:`BallScrew.lift_off_load_N`; rho = 2.6 at the paper's
study's optimum, 8 % below the rule), inside the default margin of 1.2. Written with rho the
rows would let the drag objective trade stiffness for the later lift-off of nuts with fewer,
more loaded balls: the study's least-drag screw becomes 3 turns of 7 balls (245 N/um at
0.205 N m, against 813 N/um at 0.202 N m with the rule).

The integers: the NLP is solved with turns and balls per turn relaxed to reals, then again
with each combination of their floor and ceiling fixed (at most four NLPs, warm-started
from the relaxation; a relaxation already at an integer is not branched on, and a
combination the bounds alone rule out, more balls than fit with the smallest ball or more
turns than the nut length holds, is not tried); the best feasible one is the design. This
is a rounding heuristic, not a global branch-and-bound: the report says which integer
combinations were tried. (CasADi ships Bonmin, but on this nonconvex problem its B-BB is
also heuristic and far slower; the explicit neighbours keep the choice visible.)

Variables are scaled to O(1) (angles in rad, mm over 5, N over 1,000); every solver runs
with the exact Hessian from CasADi's AD. A cold solve is IPOPT's; a warm one (the integer
neighbours, the points of a front) is CasADi's SQP method with qpOASES first, which from a
neighbouring solution converges in a few iterations, with IPOPT behind it (see
:class:`DesignNLP`): on the paper's study the three fronts match IPOPT's point for point
(the same integers, stiffness and objective within 1e-4) at a third of the time or less.
An infeasible request names the requirement that binds (:mod:`piezopreload.design.shortfall`):
each requirement is given a slack in turn with every other kept; one that still needs it is named
with the study key that sets it, the value the closest design reaches and the shortfall, in the
requirement's units.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import TYPE_CHECKING, Any, TypedDict

import casadi as ca
import numpy as np

from piezopreload.artifacts.design import DesignPoint  # the design artifact's record of a design
from piezopreload.core.errors import InfeasibleError
from piezopreload.core.progress import Bar
from piezopreload.core.records import Checked, checked, entry
from piezopreload.design.shortfall import Shortfall, binding, shortfall_message
from piezopreload.models.ballscrew import (
    EFFECTIVE_BALL_SHARE,
    LIFT_OFF_RATIO,
    RIGIDITY_IN_MACHINE_FACTOR,
    STEEL,
    BallScrew,
    DutyCase,
    Material,
    axial_contact_constant,
    double_nut_rigidity,
    drag_torque_coefficient,
    dynamic_load_rating,
    nut_contact_constants,
    nut_forces,
    nut_outer_diameter_mm,
    structural_compliance,
)
from piezopreload.models.feed_drive import FeedDrive, PiezoPreload, stack_loop_um
from piezopreload.models.ops import CASADI, NUMPY
from piezopreload.models.thermal import (
    CONTACT_CALIBRATION,
    HeatModel,
    catalogue_heat_W,
    contact_heat_W,
    rexroth_seal_torque_Nm,
    seal_heat_W,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["DesignSpec", "HeatSpec", "DesignOptimum", "DesignInfeasible", "ParetoFront", "Objective", "OBJECTIVES",
           "PARETO_PAIRS", "CONSTRAINTS", "WEIGHTS", "optimise", "pareto_front", "DesignNLP",
           "NLPSolution", "WorstCase", "RobustCost", "robust_cost", "objective_figure"]

class Objective(StrEnum):
    """What a design's optimum maximises (the least rigidity over the duty cycle, the rating life) or minimises (the
    time-mean drag torque): a study's ``[design] objective`` (its value is what the study file writes)."""

    STIFFNESS = "stiffness"
    DRAG = "drag"
    LIFE = "life"


#: the objectives, in their order
OBJECTIVES = tuple(Objective)
#: fronts a user can ask for: x:y, x swept as an epsilon constraint, y optimised (growth: the duty cycle's nut heat
#: minimised, the shift's growth it makes reported, design/thermal.py)
PARETO_PAIRS = ("stiffness:preload", "stiffness:drag", "stiffness:life", "stiffness:growth")
_TIE_WEIGHT = 1e-3
#: a front's last point: the stiffness optimum's rigidity less this fraction (the solver's tolerance on it)
_FRONT_END_TOL = 1e-6
_BALLS_PER_TURN = (4, 200)  # search range of the relaxed balls per turn
_WARM_START: dict[str, str | float] = {
    "ipopt.warm_start_init_point": "yes", "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_slack_bound_push": 1e-9, "ipopt.warm_start_mult_bound_push": 1e-9, "ipopt.mu_init": 1e-6}
#: a least total scaled violation above this (the rows are O(1)-scaled; a feasible point's
#: is zero) is the SQP's verdict that a warm-started problem is infeasible
_INFEASIBLE_VIOLATION = 1e-5
#: the warm-started solves (front points, integer neighbours): CasADi's SQP method with the
#: exact Hessian and qpOASES's active-set QP solver. From a neighbouring solution and its
#: multipliers it converges in 0-4 iterations (7 at most on the paper's study), where IPOPT's
#: interior point pays its set-up and a barrier path every call; what it has not solved in
#: max_iter goes to the infeasibility check and then to warm IPOPT (:class:`DesignNLP`). Its
#: evaluation warnings are off: a trial step outside the model's domain only fails it over.
_SQP: dict[str, Any] = {
    "qpsol": "qpoases", "max_iter": 12, "tol_pr": 1e-8, "tol_du": 1e-8, "show_eval_warnings": False,
    "print_time": False, "print_header": False, "print_iteration": False, "print_status": False,
    "error_on_fail": False, "qpsol_options": {"error_on_fail": False, "printLevel": "none"}}


@contextlib.contextmanager
def _banner_silenced() -> Iterator[None]:
    """qpOASES prints its licence banner on every solver built, whatever ``printLevel`` says;
    CasADi routes that output through Python's ``sys.stdout``, and this package's ``--json``
    output must stay one JSON object on stdout. The banner is dropped; anything else the
    build prints goes to stderr."""
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        yield
    rest = "\n".join(line for line in buffer.getvalue().splitlines() if line.strip() and not _is_banner(line))
    if rest:
        print(rest, file=sys.stderr)


_BANNER_LINES = ("qpOASES -- An Implementation of the Online Active Set Strategy.", "Copyright (C) 2007-2015",
                 "Christian Kirches et al. All rights reserved.", "qpOASES is distributed under the terms of the",
                 "GNU Lesser General Public License 2.1", "useful, but WITHOUT ANY WARRANTY",
                 "of MERCHANTABILITY or FITNESS FOR A PARTICULAR PURPOSE.",
                 "See the GNU Lesser General Public License for more details.")


def _is_banner(line: str) -> bool:
    return any(line.strip().startswith(b) for b in _BANNER_LINES)


class DesignInfeasible(InfeasibleError):
    """No design meets the constraints; ``violations`` says which and by how much."""

    def __init__(self, message: str, violations: list[Shortfall]) -> None:
        super().__init__(message)
        self.violations = violations


def _positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


class HeatKeywords(TypedDict):
    """:meth:`BallScrew.friction_heat_W`'s keywords of a :class:`HeatSpec`."""

    model: str
    lubricant_vg: int
    seal_torque_Nm: float | None
    temperature_C: float
    contact_calibration: float


class ElasticArgs(TypedDict):
    """The arguments of :attr:`DesignNLP.elastic_problem`'s solver: the start and the bounds."""

    x0: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: float
    ubg: float


@dataclass(frozen=True)
class HeatSpec:
    """How the design counts the nut's friction heat (:meth:`BallScrew.friction_heat_W`'s keywords): what a
    ``stiffness:growth`` front minimises."""

    model: HeatModel = HeatModel.CATALOGUE
    lubricant_vg: int = 68
    seal_torque_Nm: float | None = None
    temperature_C: float = 40.0
    contact_calibration: float = CONTACT_CALIBRATION

    def kwargs(self) -> HeatKeywords:
        return HeatKeywords(model=self.model, lubricant_vg=self.lubricant_vg, seal_torque_Nm=self.seal_torque_Nm,
                            temperature_C=self.temperature_C, contact_calibration=self.contact_calibration)


@dataclass(frozen=True)
class WorstCase:
    """The modelling assumptions' unfavourable ends a robust design is made against (``[design] robust``): the
    contact angle and the conformity as built within these offsets (deg; -) of the design's values, the rigidity and
    the natural frequency required at every corner of that box, and the drag coefficient K_p at least
    ``drag_coefficient`` in the drag and the heat (the ranges: :data:`piezopreload.design.sensitivity.ASSUMPTIONS`)."""

    contact_angle_deg: tuple[float, float] = (-5.0, 5.0)
    conformity: tuple[float, float] = (-0.01, 0.01)
    drag_coefficient: float = 0.3

    def __post_init__(self) -> None:
        for name in ("contact_angle_deg", "conformity"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= 0 <= hi):
                raise ValueError(f"WorstCase.{name} must be offsets (low <= 0 <= high), got {(lo, hi)!r}.")
        if not (math.isfinite(self.drag_coefficient) and self.drag_coefficient > 0):
            raise ValueError(f"WorstCase.drag_coefficient must be > 0, got {self.drag_coefficient!r}.")

    def corners(self) -> list[tuple[float, float]]:
        """The box's corners: (angle offset in rad, conformity offset)."""
        return [(math.radians(a), f) for a in self.contact_angle_deg for f in self.conformity]


@checked
class DesignSpec(Checked):
    """What the machine fixes, the design's bounds, and the constraints' limits; ``worst``: a robust design's
    worst case (None: the nominal design)."""

    nominal_diameter_mm: float = entry("The screw's nominal diameter, fixed by the machine.", unit="mm", gt=0,
                                       default=32.0)
    lead_mm: float = entry("The screw's lead.", unit="mm", gt=0, default=10.0)
    feed_drive: FeedDrive = entry("The axis: table, screw, bearings, travel.", default_factory=lambda: FeedDrive(
        table_mass_kg=350.0, screw_length_mm=1200.0, bearing_stiffness_N_per_um=1000.0, travel_mm=(150.0, 1050.0)))
    duty: tuple[DutyCase, ...] = entry("The duty cycle's cases.", default=(
        DutyCase(axial_load_N=4000.0, speed_rpm=300.0, time_share=0.3),   # roughing, +x
        DutyCase(axial_load_N=-1500.0, speed_rpm=600.0, time_share=0.3),  # finishing, -x
        DutyCase(axial_load_N=600.0, speed_rpm=3000.0, time_share=0.4),   # rapid traverse
    ))
    actuator: PiezoPreload = entry("The piezo stacks and their amplifier.", default_factory=PiezoPreload)
    material: Material = entry("The balls' and the grooves' material.", default=STEEL)
    # bounds of the design variables
    contact_angle_deg: tuple[float, float] = entry("The contact angle's bounds.", unit="deg", ge=20, le=70,
                                                   increasing=True, default=(35.0, 55.0))
    ball_mm: tuple[float, float] = entry("The ball diameter's bounds.", unit="mm", gt=0, increasing=True,
                                         default=(3.0, 7.5))
    conformity: tuple[float, float] = entry("The conformity's bounds.", ge=0.505, le=0.6, increasing=True,
                                            default=(0.52, 0.56))
    turns: tuple[int, int] = entry("The loaded turns' bounds.", ge=1, increasing=True, default=(2, 6))
    # constraints
    axial_load_max_N: float = entry("The largest axial load the nut sees.", unit="N", gt=0, default=6000.0)
    failsafe_load_N: float = entry("The load the bolts' preload alone must carry.", unit="N", ge=0, default=600.0)
    lift_off_margin: float = entry("The margin on the lift-off load.", gt=0, default=1.2)
    preload_fraction_max: float = entry("The largest preload as a share of the dynamic rating.", gt=0, default=0.10)
    contact_pressure_max_MPa: float = entry("The largest Hertz contact pressure.", unit="MPa", gt=0, default=3500.0)
    life_min_h: float = entry("The least rating life.", unit="h", gt=0, default=20000.0)
    drag_torque_max_Nm: float = entry("The largest drag torque.", unit="N m", gt=0, default=1.5)
    frequency_min_Hz: float = entry("The least axial natural frequency.", unit="Hz", gt=0, default=100.0)
    stiffness_min_N_per_um: float = entry("The least axial rigidity.", unit="N/um", ge=0, default=0.0)
    nut_length_max_mm: float = entry("The longest nut.", unit="mm", gt=0, default=60.0)
    ball_lead_ratio_max: float = entry("The largest ball diameter over the lead.", gt=0, default=0.7)
    load_sharing: float = entry("eta, the effective share of the balls.", gt=0, le=1, default=EFFECTIVE_BALL_SHARE)
    accuracy_factor: float = entry("f_ar of ISO 3408-4.", gt=0, le=1, default=1.0)
    rigidity_in_machine_factor: float = entry("The rigidity in the machine over the nut's own.", gt=0, le=1,
                                              default=RIGIDITY_IN_MACHINE_FACTOR)
    load_factor: float = entry("The load factor on the duty cycle.", gt=0, default=1.2)
    heat: HeatSpec = entry("The drag's heat model.", default_factory=HeatSpec)
    worst: WorstCase | None = entry("A robust design's worst case (None: the nominal design).", default=None)

    def check(self) -> None:
        if not self.duty:
            raise ValueError("DesignSpec.duty needs at least one duty case.")
        if max(abs(c.axial_load_N) for c in self.duty) > self.axial_load_max_N:
            raise ValueError(f"DesignSpec.axial_load_max_N ({self.axial_load_max_N}) is below a duty case's load; "
                             f"it must be the largest axial load the nut sees.")

    @property
    def helix_rad(self) -> float:
        """The screw's helix angle from its lead and nominal diameter.

        Returns
        -------
        float
            ``atan(lead / (pi d_0))`` in radians.
        """
        return math.atan(self.lead_mm / (math.pi * self.nominal_diameter_mm))

    def screw(self, point: DesignPoint) -> BallScrew:
        """The ball screw of a design point, for the numpy model (evaluation, plots).

        Parameters
        ----------
        point : DesignPoint
            The design's variables (balls, turns, contact angle, conformity).

        Returns
        -------
        BallScrew
            The screw of this spec's diameter, lead, material and factors with the point's nut.
        """
        return BallScrew(
            nominal_diameter_mm=self.nominal_diameter_mm, lead_mm=self.lead_mm, ball_mm=point.ball_mm,
            turns=point.turns, contact_angle_deg=point.contact_angle_deg, conformity_screw=point.conformity,
            conformity_nut=point.conformity, balls_per_turn=int(point.balls_per_turn), load_sharing=self.load_sharing,
            accuracy_factor=self.accuracy_factor, material=self.material,
        )


#: (name, what it bounds, units) of every constraint row, in the NLP's order after the
#: per-case rows; per-case rows are named "<name>[case j]".
CONSTRAINTS = {
    "preload_limit": ("F_hi <= preload_fraction_max * C_dyn", "N"),
    "lift_off_max_load": ("lift_off_margin * axial_load_max_N <= 2^1.5 F_hi", "N"),
    "lift_off_failsafe": ("lift_off_margin * failsafe_load_N <= 2^1.5 F_i (bolts alone)", "N"),
    "contact_pressure_screw": ("peak pressure, screw side, at axial_load_max_N", "MPa"),
    "contact_pressure_nut": ("peak pressure, nut side, at axial_load_max_N", "MPa"),
    "life": ("rating life >= life_min_h", "log(h)"),
    "drag_torque": ("drag torque at F_hi <= drag_torque_max_Nm", "N m"),
    "stack_stroke": ("stacks' stroke from F_i to F_hi", "um"),
    "stack_force": ("F_hi - F_i <= the stacks' blocked force", "N"),
    "ball_fit": ("balls per turn fit on the helix", "mm"),
    "ball_lead": ("D_w <= ball_lead_ratio_max * lead", "mm"),
    "nut_length": ("turns * lead <= nut_length_max_mm", "mm"),
    "lift_off_case": ("lift_off_margin * |F_a,j| <= 2^1.5 F_p,j", "N"),
    "stiffness_case": ("t <= rigidity in case j", "N/um"),
    "stiffness_worst": ("t <= rigidity in case j at a corner of the robust design's box", "N/um"),
    "frequency_worst": ("first axial mode in case j at a corner of the robust design's box >= frequency_min_Hz", "Hz"),
    "frequency_case": ("first axial mode in case j >= frequency_min_Hz", "Hz"),
    "preload_order_low": ("F_i <= F_p,j", "N"),
    "preload_order_high": ("F_p,j <= F_hi", "N"),
}
_PER_CASE = ("lift_off_case", "stiffness_case", "frequency_case", "preload_order_low", "preload_order_high")


@dataclass(frozen=True)
class DesignOptimum:
    """The optimum: its spec, objective, the design point, what binds, how it was solved."""

    spec: DesignSpec
    objective: str
    point: DesignPoint
    binding: list[str]
    tried: list[dict[str, Any]]
    solve_s: float
    nlp_solves: int

    def to_dict(self) -> dict[str, Any]:
        return {"objective": self.objective, "point": self.point.to_dict(), "binding": self.binding,
                "integer_candidates": self.tried, "solve_s": self.solve_s, "nlp_solves": self.nlp_solves}

    def plot(self) -> Figure:
        """Rigidity against preload for the optimum's screw, the design's preloads marked: a Figure."""
        return _figure(self.draw)

    def draw(self, ax: Axes) -> None:
        """:meth:`plot` on ``ax`` (a figure's panel)."""
        screw = self.spec.screw(self.point)
        fp = np.linspace(0.25 * self.point.bolt_preload_N, 1.5 * self.point.max_preload_N, 200)
        ax.plot(fp, screw.rigidity_N_per_um(fp), label="rigidity, no load")
        for j, (case, f_case) in enumerate(zip(self.spec.duty, self.point.case_preload_N)):
            ax.plot(f_case, screw.rigidity_N_per_um(f_case, case.axial_load_N), "o",
                    label=f"case {j + 1}: F_a = {case.axial_load_N:g} N")
        ax.axvline(self.point.bolt_preload_N, color="0.5", ls=":", label="bolt preload F_i")
        ax.axvline(self.point.max_preload_N, color="0.3", ls="--", label="max preload F_hi")
        ax.set_xlabel("preload F_p (N)")
        ax.set_ylabel("axial rigidity (N/um)")
        ax.legend(fontsize="small")


@dataclass(frozen=True)
class ParetoFront:
    """An epsilon-constraint front: the swept quantity, the optimised one, each point's design."""

    pair: str
    x_name: str
    y_name: str
    x: np.ndarray
    y: np.ndarray
    points: list[DesignPoint]
    solve_s: float
    nlp_solves: int

    def to_dict(self) -> dict[str, Any]:
        return {"pair": self.pair, "x_name": self.x_name, "y_name": self.y_name, "x": self.x.tolist(),
                "y": self.y.tolist(), "points": [p.to_dict() for p in self.points], "solve_s": self.solve_s,
                "nlp_solves": self.nlp_solves}

    def plot(self) -> Figure:
        """The front, the optimised quantity against the swept one: a Figure."""
        return _figure(self.draw)

    def draw(self, ax: Axes) -> None:
        """:meth:`plot` on ``ax`` (a figure's panel)."""
        ax.plot(self.x, self.y, "o-", ms=3)
        ax.set_xlabel(_LABELS[self.x_name])
        ax.set_ylabel(_LABELS[self.y_name])
        ax.set_title(f"Pareto front, {self.pair}")


def _figure(draw: Callable[[Axes], None]) -> Figure:
    """A one-panel Figure (made without pyplot) drawn by ``draw``."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.5, 3.5), layout="constrained")
    draw(fig.subplots())
    return fig


_LABELS = {"stiffness": "least rigidity over the duty cycle (N/um)", "preload": "max preload F_hi (N)",
           "drag": "time-mean drag torque (N m)", "life": "rating life (h)",
           "growth": "the duty cycle's thermal growth over the shift (um)"}


# ---- the NLP ------------------------------------------------------------------------------------

_SCALE = {"beta": 1.0, "ball": 5.0, "conf": 0.05, "turns": 4.0, "z1": 20.0, "force": 1000.0, "t": 1000.0}
_VARIABLES = ("contact_angle_deg", "ball_mm", "conformity", "turns", "balls_per_turn", "bolt_preload_N",
              "max_preload_N", "stiffness_min_N_per_um")


@dataclass(frozen=True, eq=False)
class DesignQuantities:
    """Every quantity of a design as expressions of its physical variables (numbers with numpy, expressions with
    CasADi; the lists one per duty case): the variables (``beta``, ``D_w``, ``f``, ``turns``, ``z1``, ``F_i``,
    ``F_hi``, ``t``, ``F_case``), the nut's constants (``c_h``, ``s``, ``c_dyn``, ``cp_s``, ``cp_n``, ``z``,
    ``helix``), the drag per case and its time mean, the mean friction heat, the rigidity and natural frequency per
    case (and a robust design's at every corner of its worst case's box, ``worst_rigidity``, ``worst_freq``), the log of
    the rating life, the contact pressures, the stacks' stroke and the drag at the top preload."""

    beta: Any
    D_w: Any
    f: Any
    turns: Any
    z1: Any
    F_i: Any
    F_hi: Any
    t: Any
    F_case: list[Any]
    c_h: Any
    s: Any
    c_dyn: Any
    drag: list[Any]
    mean_drag: Any
    mean_heat: Any
    rigidity: list[Any]
    freq: list[Any]
    worst_rigidity: list[Any]
    worst_freq: list[Any]
    log_L: Any
    p_screw: Any
    p_nut: Any
    stroke: Any
    drag_hi: Any
    cp_s: Any
    cp_n: Any
    z: Any
    helix: float


def _expressions(spec: DesignSpec, ops: Any, x: Any) -> DesignQuantities:
    """Every quantity of the design as expressions of the physical variables ``x`` (numbers or
    CasADi): the one implementation the NLP, the scipy peer and the evaluation share."""
    beta, D_w, f, turns, z1, F_i, F_hi, t = (x[k] for k in range(8))
    F_case = [x[8 + j] for j in range(len(spec.duty))]
    D_pw, helix, E_prime = spec.nominal_diameter_mm, spec.helix_rad, spec.material.contact_modulus_MPa
    sb, ch = ops.sin(beta), math.cos(helix)
    _, cp_s, cp_n = nut_contact_constants(ops, E_prime, D_pw, D_w, beta, f, f)
    z = z1 * turns
    c_h, s, rig, freq, F_A, F_B, sigma = _nut_rows(spec, ops, beta, f, D_w, turns, z, F_case)
    worst_rig, worst_freq = [], []
    for db, df in ([] if spec.worst is None else spec.worst.corners()):  # the robust design's box of the as-built nut
        _, _, r_c, fr_c, _, _, _ = _nut_rows(spec, ops, beta + db, f + df, D_w, turns, z, F_case)
        worst_rig += r_c
        worst_freq += fr_c

    c_dyn = dynamic_load_rating(ops, D_pw, D_w, beta, helix, f, f, z1, turns)
    k_p = drag_torque_coefficient(ops, helix)
    if spec.worst is not None:  # K_p at its high end where the formula's is below it
        k_p = max(float(drag_torque_coefficient(NUMPY, helix)), spec.worst.drag_coefficient)
    drag = [k_p * F * spec.lead_mm / (2000.0 * math.pi) for F in F_case]
    share = [c.time_share for c in spec.duty]
    mean_drag = sum(s * d for s, d in zip(share, drag)) / sum(share)
    mean_heat = sum(s * h for s, h in zip(share, _case_heat(spec, ops, F_case, k_p, z, beta, D_w))) / sum(share)
    revs = [c.speed_rpm * c.time_share for c in spec.duty]
    n_m = sum(revs) / sum(share)

    def log_life(forces: list[Any]) -> Any:  # log of (C / (f_p F_m))^3 1e6 / (60 n_m), hours
        cube_mean = sum(r * F ** 3 for r, F in zip(revs, forces)) / sum(revs)
        return 3.0 * ops.log(c_dyn / spec.load_factor) - ops.log(cube_mean) + math.log(1e6 / (60.0 * n_m))

    log_LA, log_LB = log_life(F_A), log_life(F_B)
    # L = (L_A^(-10/9) + L_B^(-10/9))^(-9/10), in logs
    log_L = -0.9 * ops.log(ops.exp(-10.0 / 9.0 * log_LA) + ops.exp(-10.0 / 9.0 * log_LB))
    f_max, _ = nut_forces(spec.axial_load_max_N / F_hi, sigma(F_hi), ops)
    Q_max = F_hi * f_max / (z * sb * ch)
    stroke = stack_loop_um(c_h, F_i, F_hi, spec.actuator.stiffness_N_per_um, s, spec.accuracy_factor)
    return DesignQuantities(beta=beta, D_w=D_w, f=f, turns=turns, z1=z1, F_i=F_i, F_hi=F_hi, t=t, F_case=F_case,
                            c_h=c_h, s=s, c_dyn=c_dyn, drag=drag, mean_drag=mean_drag, mean_heat=mean_heat,
                            rigidity=rig, freq=freq, worst_rigidity=worst_rig, worst_freq=worst_freq, log_L=log_L,
                            p_screw=cp_s * Q_max ** (1.0 / 3.0),
                            p_nut=cp_n * Q_max ** (1.0 / 3.0), stroke=stroke,
                            drag_hi=k_p * F_hi * spec.lead_mm / (2000.0 * math.pi), cp_s=cp_s, cp_n=cp_n, z=z,
                            helix=helix)


def _nut_rows(spec: DesignSpec, ops: Any, beta: Any, f: Any, D_w: Any, turns: Any, z: Any,
              F_case: list[Any]) -> tuple[Any, Any, list[Any], list[Any], list[Any], list[Any], Callable[[Any], Any]]:
    """The double nut of contact angle ``beta`` and conformity ``f`` (screw and nut alike): its axial constant and
    structural compliance, per duty case its rigidity, the natural frequency of the axis at that preload and the two
    nuts' forces (A, B), and the nut body's share of the nut law as a function of the preload."""
    D_pw, helix, E_prime = spec.nominal_diameter_mm, spec.helix_rad, spec.material.contact_modulus_MPa
    c_delta, _, _ = nut_contact_constants(ops, E_prime, D_pw, D_w, beta, f, f)
    c_h = 1e3 * axial_contact_constant(ops, c_delta, spec.load_sharing * z, beta, helix)
    s = 1e3 * structural_compliance(ops, spec.material.E_MPa, D_pw, D_w, beta, helix, nut_outer_diameter_mm(D_pw, D_w),
                                    turns * spec.lead_mm)
    acc = spec.accuracy_factor

    def sigma(F: Any) -> Any:  # the nut body's share of the nut law at preload F
        return s * ops.cbrt(F) / c_h

    k_side = spec.feed_drive.screw_side_stiffness_N_per_um(D_pw - D_w * ops.cos(beta),
                                                           spec.feed_drive.weakest_position_mm())
    rig, freq, F_A, F_B = [], [], [], []
    for case, F in zip(spec.duty, F_case):
        f_loaded, f_unloaded = nut_forces(abs(case.axial_load_N) / F, sigma(F), ops)
        loaded, unloaded = F * f_loaded, F * f_unloaded
        rig.append(double_nut_rigidity(ops, c_h, s, acc, loaded, unloaded))
        k_chain = 1.0 / (1.0 / double_nut_rigidity(ops, c_h, s, acc, F, F) + 1.0 / k_side)
        freq.append(ops.sqrt(k_chain * 1e6 / spec.feed_drive.table_mass_kg) / (2.0 * math.pi))
        F_B.append(loaded if case.axial_load_N >= 0 else unloaded)
        F_A.append(unloaded if case.axial_load_N >= 0 else loaded)
    return c_h, s, rig, freq, F_A, F_B, sigma


def _case_heat(spec: DesignSpec, ops: Any, F_case: list[Any], k_p: Any, z: Any, beta: Any, D_w: Any) -> list[Any]:
    """Each duty case's nut friction heat (W) at its preload and speed, by the spec's heat model
    (:meth:`BallScrew.friction_heat_W`'s formulas on the design's variables)."""
    h = spec.heat
    omegas = [abs(c.speed_rpm) * math.pi / 30.0 for c in spec.duty]
    if h.model == HeatModel.CATALOGUE:
        nut = [catalogue_heat_W(ops, k_p, spec.lead_mm, F, w) for F, w in zip(F_case, omegas)]
    else:
        nut = [contact_heat_W(ops, F, w, balls=z, contact_rad=beta, helix_rad=spec.helix_rad,
                              pitch_diameter_mm=spec.nominal_diameter_mm, ball_mm=D_w, lubricant_vg=h.lubricant_vg,
                              temperature_C=h.temperature_C, calibration=h.contact_calibration)
               for F, w in zip(F_case, omegas)]
    seals = (rexroth_seal_torque_Nm(spec.nominal_diameter_mm, spec.lead_mm) if h.seal_torque_Nm is None
             else h.seal_torque_Nm)
    return [p + seal_heat_W(seals, w) for p, w in zip(nut, omegas)]


def _objective(e: DesignQuantities, w: Any) -> Any:
    """The weighted objective (weights: -stiffness, drag, -log life, preload, the duty cycle's mean nut heat per
    100 W) plus the tie-break towards more stiffness, less drag and a lower bolt preload; numbers or CasADi
    expressions."""
    return (-w[0] * e.t / 1000.0 + w[1] * e.mean_drag - w[2] * e.log_L + w[3] * e.F_hi / 1000.0
            + w[4] * e.mean_heat / 100.0
            + _TIE_WEIGHT * (e.mean_drag + e.drag_hi + e.F_i / 1000.0 - e.t / 1000.0))


def _constraint_rows(spec: DesignSpec, e: DesignQuantities, ops: Any) -> list[tuple[str, Any, float]]:
    """Rows ``(name, g, scale)`` meaning g <= 0, g in the constraint's units."""
    L = LIFT_OFF_RATIO
    rows = [
        ("preload_limit", e.F_hi - spec.preload_fraction_max * e.c_dyn, 1000.0),
        ("lift_off_max_load", spec.lift_off_margin * spec.axial_load_max_N - L * e.F_hi, 1000.0),
        ("lift_off_failsafe", spec.lift_off_margin * spec.failsafe_load_N - L * e.F_i, 1000.0),
        ("contact_pressure_screw", e.p_screw - spec.contact_pressure_max_MPa, 1000.0),
        ("contact_pressure_nut", e.p_nut - spec.contact_pressure_max_MPa, 1000.0),
        ("life", math.log(spec.life_min_h) - e.log_L, 1.0),
        ("drag_torque", e.drag_hi - spec.drag_torque_max_Nm, 1.0),
        ("stack_stroke", e.stroke - spec.actuator.stroke_um, 10.0),
        ("stack_force", e.F_hi - e.F_i - spec.actuator.blocked_force_N, 1000.0),
        ("ball_fit", e.z1 * e.D_w - math.pi * spec.nominal_diameter_mm / math.cos(e.helix), 10.0),
        ("ball_lead", e.D_w - spec.ball_lead_ratio_max * spec.lead_mm, 1.0),
        ("nut_length", e.turns * spec.lead_mm - spec.nut_length_max_mm, 10.0),
    ]
    n = len(spec.duty)
    for k, (r, fr) in enumerate(zip(e.worst_rigidity, e.worst_freq)):  # a robust design's corners
        rows += [(f"stiffness_worst[{k % n + 1}]", e.t - r, 100.0),  # case k % n + 1 at corner k // n
                 (f"frequency_worst[{k % n + 1}]", spec.frequency_min_Hz - fr, 10.0)]
    for j, case in enumerate(spec.duty):
        F = e.F_case[j]
        rows += [
            (f"lift_off_case[{j + 1}]", spec.lift_off_margin * abs(case.axial_load_N) - L * F, 1000.0),
            (f"stiffness_case[{j + 1}]", e.t - e.rigidity[j], 100.0),
            (f"frequency_case[{j + 1}]", spec.frequency_min_Hz - e.freq[j], 10.0),
            (f"preload_order_low[{j + 1}]", e.F_i - F, 1000.0),
            (f"preload_order_high[{j + 1}]", F - e.F_hi, 1000.0),
        ]
    return rows


@dataclass(frozen=True, eq=False)
class NLPSolution:
    """One solve of the design NLP: the scaled point ``y``, its objective ``f``, the constraint rows ``g`` and the
    multipliers of the rows and of the bounds; the integers fixed (None: relaxed), whether the solver succeeded, its
    status and method (``ipopt``, ``sqp``), and whether the point is feasible (every row within 1e-6)."""

    y: np.ndarray
    f: float
    g: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    integers: tuple[int, int] | None
    success: bool
    status: str
    method: str
    feasible: bool


class DesignNLP:
    """The design NLP built once for a spec, solved many times (objective weights as
    parameters, epsilon bounds and fixed integers as variable bounds, warm starts).

    A cold solve is IPOPT's. A warm solve (from a neighbouring solution and its multipliers:
    the integer neighbours, the points of a front) is, with ``warm="sqp"`` (the default):

    1. the SQP method (:data:`_SQP`); if it ends at a feasible KKT point, that is the solution;
    2. if not, the least-violation problem (every constraint row gets a slack, their sum is
       minimised; bounds stay hard) by the same SQP from the same start: a converged least
       violation above :data:`_INFEASIBLE_VIOLATION` is the verdict "infeasible", the local
       certificate IPOPT's restoration phase gives too, at a tenth of its cost;
    3. anything else goes to warm IPOPT.

    ``warm="ipopt"`` sends every warm solve to warm IPOPT, the reference the tests hold the
    fronts to.
    """

    def __init__(self, spec: DesignSpec, ipopt_options: dict[str, Any] | None = None, warm: str = "sqp") -> None:
        if warm not in ("sqp", "ipopt"):
            raise ValueError(f"warm must be 'sqp' or 'ipopt', got {warm!r}.")
        self.spec = spec
        self.warm = warm
        n = 8 + len(spec.duty)
        self.n = n
        s = _SCALE
        self.scale = np.array([s["beta"], s["ball"], s["conf"], s["turns"], s["z1"], s["force"], s["force"], s["t"]]
                              + [s["force"]] * len(spec.duty))
        self.offset = np.zeros(n)
        self.offset[2] = 0.5  # conformity as (f - 0.5) / 0.05
        y = ca.SX.sym("y", n)
        x = self.offset + self.scale * y
        e = _expressions(spec, CASADI, ca.vertsplit(x))
        rows = _constraint_rows(spec, e, CASADI)
        self.row_names = [r[0] for r in rows]
        self.row_scale = np.array([r[2] for r in rows])
        g = ca.vertcat(*[r[1] / r[2] for r in rows])
        w = ca.SX.sym("w", 5)  # weights: -stiffness, drag, -log life, preload, heat
        objective = _objective(e, w)
        opts: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.tol": 1e-8,
                "ipopt.max_iter": 500}
        opts.update(ipopt_options or {})
        problem = {"x": y, "f": objective, "g": g, "p": w}
        #: the scaled variables and rows (g <= 0), for the problems built on them (design/shortfall.py)
        self.problem = problem
        self.solver = ca.nlpsol("design", "ipopt", problem, opts)
        # from a nearby solution and its multipliers (fronts, integer neighbours): start at a
        # small barrier parameter instead of pushing the point back into the interior
        self.warm_solver = ca.nlpsol("design_warm", "ipopt", problem, {**opts, **_WARM_START})
        self.constraints = ca.Function("design_constraints", [y], [g])
        self.objective = ca.Function("design_objective", [y, w], [objective])
        slack = ca.SX.sym("s", len(rows))
        #: least total scaled violation: the slacked rows g - s <= 0, s >= 0, min sum(s)
        self.elastic_problem = {"x": ca.vertcat(y, slack), "f": ca.sum1(slack), "g": g - slack}
        with _banner_silenced():
            self.sqp_solver = ca.nlpsol("design_sqp", "sqpmethod", problem, _SQP)
            self.elastic_sqp = ca.nlpsol("design_elastic_sqp", "sqpmethod", self.elastic_problem, _SQP)
        self._exprs = ca.Function("design_exprs", [y], [
            e.c_dyn, ca.vertcat(*e.rigidity), ca.vertcat(*e.freq), e.p_screw, e.p_nut, e.stroke,
            e.drag_hi, e.t, e.mean_drag, e.log_L])
        self.solves = 0

    # ---- bounds ------------------------------------------------------------------------
    def bounds(self, integers: tuple[int, int] | None = None, stiffness_min: float | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        spec = self.spec
        lo = np.full(self.n, 1e-3)
        hi = np.full(self.n, np.inf)
        lo[0], hi[0] = np.radians(spec.contact_angle_deg)
        lo[1], hi[1] = spec.ball_mm
        lo[2], hi[2] = spec.conformity
        lo[3], hi[3] = spec.turns
        lo[4], hi[4] = _BALLS_PER_TURN
        if integers is not None:
            lo[3] = hi[3] = integers[0]
            lo[4] = hi[4] = integers[1]
        lo[5:7] = 1.0
        lo[7] = max(spec.stiffness_min_N_per_um, 0.0) if stiffness_min is None else stiffness_min
        lo[8:] = 1.0
        return (lo - self.offset) / self.scale, (hi - self.offset) / self.scale

    def initial_guess(self) -> np.ndarray:
        spec = self.spec
        beta = np.radians(np.mean(spec.contact_angle_deg))
        ball = min(float(np.mean(spec.ball_mm)), 0.5 * spec.ball_lead_ratio_max * spec.lead_mm + 0.5 * spec.ball_mm[0])
        z1 = math.floor(math.pi * spec.nominal_diameter_mm / (ball * math.cos(spec.helix_rad)))
        turns = min(spec.turns[1], max(spec.turns[0], math.floor(spec.nut_length_max_mm / spec.lead_mm)))
        F_hi = max(spec.lift_off_margin * spec.axial_load_max_N / LIFT_OFF_RATIO, 100.0) * 1.05
        F_i = max(spec.lift_off_margin * spec.failsafe_load_N / LIFT_OFF_RATIO, 0.3 * F_hi) * 1.05
        F_i = min(F_i, 0.9 * F_hi)
        x = np.array([beta, ball, np.mean(spec.conformity), turns, z1, F_i, F_hi, 1.0]
                     + [0.5 * (F_i + F_hi)] * len(spec.duty))
        return (x - self.offset) / self.scale

    def numpy_functions(self, weights: Iterable[float]) -> tuple[Callable[[np.ndarray], float],
                                                                  Callable[[np.ndarray], np.ndarray]]:
        """The same objective and constraints (g <= 0, scaled) evaluated with numpy, for a peer
        solver (scipy) and for checks independent of CasADi's evaluation."""
        w = np.asarray(list(weights), float)
        spec = self.spec

        def parts(y: np.ndarray) -> tuple[DesignQuantities, list[tuple[str, Any, float]]]:
            x = self.to_physical(y)
            e = _expressions(spec, NUMPY, list(x))
            return e, _constraint_rows(spec, e, NUMPY)

        def f(y: np.ndarray) -> float:
            e, _ = parts(y)
            return float(_objective(e, w))

        def g(y: np.ndarray) -> np.ndarray:
            _, rows = parts(y)
            return np.array([float(r[1]) / r[2] for r in rows])

        return f, g

    def to_physical(self, y: np.ndarray) -> np.ndarray:
        return self.offset + self.scale * np.asarray(y, float).ravel()

    def evaluate(self, y: np.ndarray) -> DesignQuantities:
        """Every quantity of the design at the scaled point ``y``, in numbers (numpy)."""
        return _expressions(self.spec, NUMPY, list(self.to_physical(y)))

    # ---- one solve ---------------------------------------------------------------------
    def solve(self, weights: Iterable[float], y0: np.ndarray, lam_g0: np.ndarray | None = None,
              integers: tuple[int, int] | None = None, stiffness_min: float | None = None,
              lam_x0: np.ndarray | None = None) -> NLPSolution:
        """One solve from ``y0``: cold (IPOPT) without multipliers, warm (see the class
        docstring) with the constraint multipliers ``lam_g0`` and, if given, the bound
        multipliers ``lam_x0`` of a neighbouring solution."""
        lbx, ubx = self.bounds(integers, stiffness_min)
        y0 = np.clip(np.asarray(y0, float).ravel(), lbx, ubx)
        args: dict[str, Any] = dict(x0=y0, p=np.asarray(list(weights), float), lbx=lbx, ubx=ubx,
                                    lbg=-np.inf, ubg=0.0)
        if lam_g0 is None:
            return self._run(self.solver, args, integers)
        args["lam_g0"] = lam_g0
        if lam_x0 is not None:
            args["lam_x0"] = lam_x0
        if self.warm == "sqp":  # the three steps of the class docstring
            sol = self._run(self.sqp_solver, args, integers)
            if sol.success and sol.feasible:
                return sol
            verdict = self._infeasible(args, integers)
            if verdict is not None:
                return verdict
        return self._run(self.warm_solver, args, integers)

    def elastic_args(self, y0: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> ElasticArgs:
        """Arguments of :attr:`elastic_problem` from ``y0`` (clipped to the bounds), each slack
        starting at its row's violation there; the bounds stay hard, the slacks are >= 0."""
        y0 = np.clip(y0, lbx, ubx)
        ns = len(self.row_names)
        s0 = np.maximum(np.asarray(self.constraints(y0)).ravel(), 0.0)
        return ElasticArgs(x0=np.concatenate([y0, s0]), lbx=np.concatenate([lbx, np.zeros(ns)]),
                           ubx=np.concatenate([ubx, np.full(ns, np.inf)]), lbg=-np.inf, ubg=0.0)

    def _infeasible(self, args: dict[str, Any], integers: tuple[int, int] | None) -> NLPSolution | None:
        """The least-violation point from ``args``' start if the SQP converges there with a
        violation above the tolerance (a solution marked infeasible), else None."""
        with contextlib.redirect_stdout(sys.stderr):  # qpOASES' messages (an infeasible QP) stay off stdout
            out = self.elastic_sqp(**self.elastic_args(args["x0"], args["lbx"], args["ubx"]))
        self.solves += 1
        violation = float(out["f"])
        if not (self.elastic_sqp.stats()["success"] and violation > _INFEASIBLE_VIOLATION):
            return None
        y = np.asarray(out["x"]).ravel()[: self.n]
        return self._solution(y, float(self.objective(y, args["p"])), out["lam_g"],
                              np.asarray(out["lam_x"]).ravel()[: self.n], integers, False,
                              f"Infeasible: least total scaled violation {violation:.3g}", "sqp")

    def _run(self, solver: Any, args: dict[str, Any], integers: tuple[int, int] | None) -> NLPSolution:
        with contextlib.redirect_stdout(sys.stderr):  # a solver's messages (qpOASES' on an infeasible QP) stay off
            out = solver(**args)                      # stdout: --json prints one object there
        self.solves += 1
        stats = solver.stats()
        return self._solution(np.asarray(out["x"]).ravel(), float(out["f"]), out["lam_g"], out["lam_x"], integers,
                              bool(stats["success"]), stats["return_status"],
                              "sqp" if solver is self.sqp_solver else "ipopt")

    def _solution(self, y: np.ndarray, f: float, lam_g: Any, lam_x: Any, integers: tuple[int, int] | None,
                  success: bool, status: str, method: str) -> NLPSolution:
        """A solve's result: the point, its objective, constraints and multipliers, and whether
        the solver succeeded and the point is feasible (every row within 1e-6)."""
        g = np.asarray(self.constraints(y)).ravel()
        return NLPSolution(y, f, g, np.asarray(lam_g).ravel(), np.asarray(lam_x).ravel(), integers, success, status,
                           method, bool(np.all(g <= 1e-6)))

    # ---- reporting -------------------------------------------------------------------------
    def point(self, y: np.ndarray, objective: str, integer: bool) -> DesignPoint:
        x = self.to_physical(y)
        if integer:  # fixed integers come back through the scaling as e.g. 0.7 * 20 = 14.000000000000002
            x[3:5] = np.round(x[3:5])
        c_dyn, rig, freq, p_s, p_n, stroke, drag_hi, t, mean_drag, log_L = (np.asarray(v).ravel()
                                                                            for v in self._exprs(y))
        spec = self.spec
        pt = DesignPoint(
            contact_angle_deg=float(np.degrees(x[0])), ball_mm=float(x[1]), conformity=float(x[2]), turns=float(x[3]),
            balls_per_turn=float(x[4]), bolt_preload_N=float(x[5]), max_preload_N=float(x[6]),
            case_preload_N=tuple(float(v) for v in x[8:]), stiffness_N_per_um=float(rig.min()),
            rigidity_at_max_preload_N_per_um=0.0, mean_drag_torque_Nm=float(mean_drag[0]),
            drag_torque_at_max_preload_Nm=float(drag_hi[0]), life_h=float(np.exp(log_L[0])), c_dyn_N=float(c_dyn[0]),
            c0_N=0.0, frequency_min_Hz=float(freq.min()), peak_pressure_MPa=float(max(p_s[0], p_n[0])),
            stack_stroke_used_um=float(stroke[0]), objective=objective, integer=integer,
        )
        if integer:  # the numpy model of the same screw: rigidity at F_hi and C_0
            screw = spec.screw(pt)
            pt = replace(pt, rigidity_at_max_preload_N_per_um=float(screw.rigidity_N_per_um(pt.max_preload_N)),
                         c0_N=screw.static_rating_N)
        return pt

    def binding(self, solution: NLPSolution, tol: float = 1e-4) -> list[str]:
        """Constraints active at the solution (a multiplier above ``tol``) and variables at a bound."""
        names = [n for n, lam in zip(self.row_names, solution.lam_g) if lam > tol]
        fixed = {3, 4} if solution.integers else set()
        for k, lam in enumerate(solution.lam_x[:8]):
            if k not in fixed and abs(lam) > tol:
                names.append(f"{_VARIABLES[k]} at its {'upper' if lam > 0 else 'lower'} bound")
        return names


WEIGHTS = {"stiffness": (1.0, 0.0, 0.0, 0.0, 0.0), "drag": (0.0, 1.0, 0.0, 0.0, 0.0),
           "life": (0.0, 0.0, 1.0, 0.0, 0.0), "preload": (0.0, 0.0, 0.0, 1.0, 0.0),
           "heat": (0.0, 0.0, 0.0, 0.0, 1.0)}


def _turns_and_balls(nlp: DesignNLP, y: np.ndarray) -> tuple[float, float]:
    """The relaxed turns and balls per turn of the NLP's point ``y``."""
    physical = nlp.to_physical(y)
    return float(physical[3]), float(physical[4])


def _integer_candidates(turns: float, z1: float, spec: DesignSpec) -> list[tuple[int, int]]:
    """Floor and ceiling of each relaxed integer, less those the bounds alone rule out: more
    balls per turn than fit with the smallest ball allowed (``ball_fit``), more turns than
    the nut length allows (``nut_length``). Either would be an NLP that can only fail."""
    z1_fit = math.pi * spec.nominal_diameter_mm / (math.cos(spec.helix_rad) * spec.ball_mm[0])
    turns_fit = spec.nut_length_max_mm / spec.lead_mm

    def around(v: float, lo: float, hi: float) -> list[int]:
        if abs(v - round(v)) < 1e-6:
            return [int(round(v))]
        return [int(k) for k in (math.floor(v), math.ceil(v)) if lo <= k <= hi]

    return list(itertools.product([t for t in around(turns, *spec.turns) if t <= turns_fit + 1e-9],
                                  [z for z in around(z1, *_BALLS_PER_TURN) if z <= z1_fit + 1e-9]))


def _solve_mixed(nlp: DesignNLP, weights: tuple[float, ...], y0: np.ndarray, stiffness_min: float | None,
                 lam_g0: np.ndarray | None = None, lam_x0: np.ndarray | None = None,
                 known_infeasible: set[tuple[int, int]] | frozenset[tuple[int, int]] = frozenset(),
                 ) -> tuple[NLPSolution | None, NLPSolution, list[dict[str, Any]]]:
    """Relaxation, then its integer neighbours; returns (best integer solution, relaxation, tried).

    A neighbour in ``known_infeasible`` is not solved again (a front passes the pairs found
    infeasible at a lower stiffness bound: raising the bound only shrinks the feasible set).
    """
    relaxed = nlp.solve(weights, y0, lam_g0=lam_g0, stiffness_min=stiffness_min, lam_x0=lam_x0)
    x = nlp.to_physical(relaxed.y)
    best: NLPSolution | None = None
    tried: list[dict[str, Any]] = []
    for ints in _integer_candidates(x[3], x[4], nlp.spec):
        if ints in known_infeasible:
            tried.append({"turns": ints[0], "balls_per_turn": ints[1], "feasible": False, "infeasible": True,
                          "objective": None, "status": "infeasible at a lower stiffness bound"})
            continue
        sol = nlp.solve(weights, relaxed.y, lam_g0=relaxed.lam_g, integers=ints, stiffness_min=stiffness_min,
                        lam_x0=relaxed.lam_x)
        ok = sol.success and sol.feasible
        tried.append({"turns": ints[0], "balls_per_turn": ints[1], "feasible": ok,
                      "infeasible": sol.status.startswith("Infeasible"), "objective": sol.f,
                      "status": sol.status})
        if ok and (best is None or sol.f < best.f):
            best = sol
    return best, relaxed, tried


#: each objective's figure of merit and its unit, and whether more of it is better
_MERITS = {Objective.STIFFNESS: ("N/um", True), Objective.DRAG: ("N m", False), Objective.LIFE: ("h", True)}


@dataclass(frozen=True)
class RobustCost:
    """What a robust design (``[design] robust``) gives up: the objective's figure (the least rigidity over the duty
    cycle, the mean drag torque or the rating life) of the nominal design and of the robust one, each at the study's
    assumptions and at the worst case of their ranges (:class:`WorstCase`); ``nominal_misses``: the constraint rows
    the nominal design misses at the worst case, each with by how much (in its unit, :data:`CONSTRAINTS`)."""

    objective: Objective
    unit: str
    nominal_at_nominal: float
    nominal_at_worst: float
    robust_at_nominal: float
    robust_at_worst: float
    nominal_misses: tuple[tuple[str, float], ...] = ()

    @property
    def cost(self) -> float:
        """How much worse the robust design's figure is at the study's assumptions, in the objective's unit (> 0: it
        gives that up)."""
        more_is_better = _MERITS[self.objective][1]
        d = self.nominal_at_nominal - self.robust_at_nominal
        return d if more_is_better else -d

    def sentence(self) -> str:
        """The cost in one sentence."""
        return (f"the robust design gives up {self.cost:.4g} {self.unit} of its {self.objective} objective at the "
                f"study's assumptions ({self.robust_at_nominal:.4g} against the nominal design's "
                f"{self.nominal_at_nominal:.4g} {self.unit}); at the worst case of the ranges it keeps "
                f"{self.robust_at_worst:.4g} {self.unit} where the nominal design keeps {self.nominal_at_worst:.4g}"
                + ("" if not self.nominal_misses else " and misses " + ", ".join(
                    f"{name} by {excess:.3g} {CONSTRAINTS[name.split('[')[0]][1]}"
                    for name, excess in self.nominal_misses)))

    def to_dict(self) -> dict[str, Any]:
        return {"objective": str(self.objective), "unit": self.unit, "nominal_at_nominal": self.nominal_at_nominal,
                "nominal_at_worst": self.nominal_at_worst, "robust_at_nominal": self.robust_at_nominal,
                "robust_at_worst": self.robust_at_worst, "cost": self.cost,
                "nominal_misses": [{"constraint": n, "by": x} for n, x in self.nominal_misses]}


def _physical(point: DesignPoint, t: float = 0.0) -> list[float]:
    """A design point as the NLP's physical variables (the epigraph variable ``t`` as given)."""
    return [math.radians(point.contact_angle_deg), point.ball_mm, point.conformity, point.turns, point.balls_per_turn,
            point.bolt_preload_N, point.max_preload_N, t, *point.case_preload_N]


def misses(spec: DesignSpec, point: DesignPoint, tol: float = 1e-6) -> tuple[tuple[str, float], ...]:
    """The constraint rows of ``spec`` a design ``point`` misses, each with by how much (in its unit); the rigidity
    rows are left out (the point's own objective, not a limit)."""
    rows = _constraint_rows(spec, _expressions(spec, NUMPY, _physical(point)), NUMPY)
    return tuple((name, float(g)) for name, g, scale in rows
                 if not name.startswith("stiffness") and float(g) / scale > tol)


def objective_figure(spec: DesignSpec, point: DesignPoint, objective: Objective | str) -> float:
    """The figure ``objective`` judges a design ``point`` by under ``spec`` (with its :class:`WorstCase`: at the
    worst case, the rigidity the least over the box's corners too): the least rigidity over the duty cycle (N/um), the
    mean drag torque (N m) or the rating life (h)."""
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}.")
    e = _expressions(spec, NUMPY, _physical(point))
    judged = Objective(objective)
    if judged is Objective.STIFFNESS:
        return float(min(float(r) for r in [*e.rigidity, *e.worst_rigidity]))
    return float(e.mean_drag) if judged is Objective.DRAG else float(np.exp(float(e.log_L)))


def robust_cost(spec: DesignSpec, nominal: DesignOptimum, robust: DesignOptimum) -> RobustCost:
    """The :class:`RobustCost` of ``robust`` (designed on ``spec``, whose ``worst`` is set) against ``nominal``
    (designed on the same spec without it), for the robust optimum's objective."""
    if spec.worst is None:
        raise ValueError("robust_cost needs the robust design's spec (DesignSpec.worst set)")
    plain = replace(spec, worst=None)
    o = Objective(robust.objective)
    return RobustCost(o, _MERITS[o][0], objective_figure(plain, nominal.point, o),
                      objective_figure(spec, nominal.point, o), objective_figure(plain, robust.point, o),
                      objective_figure(spec, robust.point, o), misses(spec, nominal.point))


def optimise(spec: DesignSpec, objective: str = "stiffness", nlp: DesignNLP | None = None) -> DesignOptimum:
    """The design optimum for one objective (see the module docstring)."""
    return _optimise(spec, objective, nlp)[0]


def _optimise(spec: DesignSpec, objective: str, nlp: DesignNLP | None) -> tuple[DesignOptimum, NLPSolution]:
    """:func:`optimise`, also returning the relaxed solution (a warm start for fronts)."""
    if objective not in (*OBJECTIVES, "heat"):  # the heat: the growth front's other end
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}.")
    nlp = nlp or DesignNLP(spec)
    start_solves, t0 = nlp.solves, time.perf_counter()
    y0 = nlp.initial_guess()
    best, relaxed, tried = _solve_mixed(nlp, WEIGHTS[objective], y0, None)
    if best is None:
        misses = binding(nlp, relaxed.y, lambda y: _integer_candidates(*_turns_and_balls(nlp, y), spec))
        raise DesignInfeasible(_infeasible_message(misses), misses)
    result = DesignOptimum(spec=spec, objective=objective, point=nlp.point(best.y, objective, True),
                          binding=nlp.binding(best), tried=tried, solve_s=time.perf_counter() - t0,
                          nlp_solves=nlp.solves - start_solves)
    return result, relaxed


def _infeasible_message(misses: list[Shortfall]) -> str:
    if not misses:  # the solvers found no point to read a shortfall at
        return ("no design meets the constraints, and none could be found to say which binds. Relax the limits in "
                "the study's [design] table or widen the design's bounds.")
    return ("no design meets the constraints: " + shortfall_message(misses)
            + ". Relax these limits in the study's [design] table or widen the design's bounds.")


def pareto_front(spec: DesignSpec, pair: str, n_points: int = 50, nlp: DesignNLP | None = None,
                 bar: Bar | None = None,
                 growth: Callable[[DesignPoint], float] | None = None) -> ParetoFront:
    """The epsilon-constraint front of ``pair`` ("stiffness:drag" and so on).

    The least rigidity over the duty cycle is swept from that of the other quantity's
    optimum (the least-drag design for preload and drag, the longest-life one for life) to
    the stiffness optimum's (less :data:`_FRONT_END_TOL`); at each epsilon the other quantity is optimised with the
    integers handled as in :func:`optimise`, warm-started from the previous point (the first
    from the other optimum's relaxation), primal and dual. An integer pair found infeasible
    at one epsilon is not tried at the higher ones.

    ``stiffness:growth``: each point minimises the duty cycle's mean nut heat (``spec.heat``'s model; the
    least-heat design at the front's start) and its y is ``growth(point)``, the shift's growth that design makes
    (:func:`piezopreload.design.thermal.duty_growth_um`): the growth grows with the heat, and the root section's
    small change with the ball is in the y, not in the objective.
    """
    if pair not in PARETO_PAIRS:
        raise ValueError(f"pareto must be one of {', '.join(PARETO_PAIRS)}, got {pair!r}.")
    if not (isinstance(n_points, int) and n_points >= 2):
        raise ValueError(f"n_points must be an integer >= 2, got {n_points!r}.")
    nlp = nlp or DesignNLP(spec)
    start_solves, t0 = nlp.solves, time.perf_counter()
    y_name = pair.split(":")[1]
    if y_name == "growth" and growth is None:
        raise ValueError("the stiffness:growth front needs growth, the shift's growth of a design point (a study's "
                         "[thermal] table: design.thermal.duty_growth_um)")
    # the growth grows with the nut's heat: the front minimises the duty cycle's mean heat and reports the growth
    objective = {"preload": "drag", "growth": "heat"}.get(y_name, y_name)
    stiff = optimise(spec, "stiffness", nlp)
    other, other_relaxed = _optimise(spec, objective, nlp)
    k_lo = other.point.stiffness_N_per_um
    # up to the stiffness optimum's own rigidity (less the solver's tolerance): the front ends at the optimum, whose
    # other figures are the least any design that stiff has (its tie-break), where it stood 1 % short of it before
    k_hi = stiff.point.stiffness_N_per_um * (1.0 - _FRONT_END_TOL)
    eps = np.linspace(min(k_lo, k_hi), k_hi, n_points)
    weights = WEIGHTS["heat" if y_name == "growth" else y_name]
    # the first epsilon is the other optimum's own stiffness: start from its relaxation
    y_prev, lam_prev, lam_x_prev = other_relaxed.y, other_relaxed.lam_g, other_relaxed.lam_x
    xs, ys, points = [], [], []
    infeasible: set[tuple[int, int]] = set()
    for i, k in enumerate(eps):
        best, relaxed, tried = _solve_mixed(nlp, weights, y_prev, float(k), lam_prev, lam_x_prev, infeasible)
        infeasible.update((t["turns"], t["balls_per_turn"]) for t in tried if t["infeasible"])
        if relaxed.success:
            y_prev, lam_prev, lam_x_prev = relaxed.y, relaxed.lam_g, relaxed.lam_x
        if best is not None:
            pt = nlp.point(best.y, y_name, True)
            xs.append(pt.stiffness_N_per_um)
            ys.append(growth(pt) if growth is not None and y_name == "growth" else
                      {"preload": pt.max_preload_N, "drag": pt.mean_drag_torque_Nm, "life": pt.life_h}[y_name])
            points.append(pt)
        if bar is not None:
            bar(i + 1, n_points)
    return ParetoFront(pair=pair, x_name="stiffness", y_name=y_name, x=np.array(xs), y=np.array(ys), points=points,
                       solve_s=time.perf_counter() - t0, nlp_solves=nlp.solves - start_solves)
