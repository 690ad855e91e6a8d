"""The verdicts under the modelling assumptions: the designed system as built, judged again at each assumption's ends.

Every margin the system stage reports rests on modelling assumptions the study states once: the screw's
pretension, the share of the nut's heat that enters the screw, the heat model, the drag coefficient K_p, the
contact angle and the conformity the grinding gives. Here each of them (:data:`ASSUMPTIONS`: one row per
assumption, its range and where the range comes from) is set to the low and the high end of its range, one at
a time, every other at the study's value, and the designed system **as built** is judged again: the design's
double nut, the last pass's schedule and the preload the force loop achieved along it (the run is not repeated:
an assumption about the model changes what the achieved preload is worth, not the preload the stacks made).
The requirements are the system stage's own (:func:`~piezopreload.design.system.requirements_of` on the frame
judged with the changed nut, :func:`~piezopreload.design.system.frame_under`, and
:func:`~piezopreload.design.thermal.schedule_requirements` for the shift's growth and positioning error):
nothing is computed a second way.

Where a verdict differs between the range's ends, or between an end and its side of the admissible domain, the
value at which it flips is found by bisection (:func:`flip_value`; the margin is taken as monotonic in the
assumption between the points evaluated). A verdict is robust only where it is the same at both ends of every
range (:attr:`~piezopreload.artifacts.sensitivity.SensitivityRecord.verdict_robust`).

The ranges, in brief (the sources in each row's ``source``; ``docs/thermal.md`` restates them):

* pretension 2-5 K: THK sets the negative travel compensation for a 2-5 K rise; HIWIN pretensions for about 3 K
  and only where the rise stays below 5 K;
* nut heat share 0.25-0.75: no share of the nut's heat into the screw against the nut's body is published; half
  and half is the usual modelling choice, and the bracket is as wide either side of it as the choice is unsure
  (measured feed drives run hottest at the nut, which argues for less into the screw);
* heat model: the catalogue's drag torque or the rolling-contact loss (a two-valued assumption);
* K_p 0.1-0.3: the range the vendors' drag-torque formula is used with (HIWIN, NSK, THK);
* contact angle within +-5 deg and conformity within +-0.01 of the design's: no vendor publishes the grinding's
  tolerance on either; these are the tolerances assumed here (a few microns on the groove's radius or on the
  ball's size move a gothic arch's contact angle by degrees), stated plainly rather than sourced.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from enum import Enum

from piezopreload.artifacts.requirements import Requirement
from piezopreload.artifacts.schedule import ScheduleSpec
from piezopreload.artifacts.sensitivity import SensitivityRecord, SensitivityRow
from piezopreload.core.errors import InputError
from piezopreload.design.preload import WorstCase
from piezopreload.design.system import SystemRun, frame_under, requirements_of
from piezopreload.design.tables import ThermalTable
from piezopreload.design.thermal import ShiftBasis, mounting_of, schedule_requirements, shift_basis
from piezopreload.models.ballscrew import BallScrew
from piezopreload.models.feed_drive import FeedDrive
from piezopreload.models.thermal import HEAT_MODELS, HeatModel, ThermalMounting

__all__ = ["Assumption", "ASSUMPTIONS", "Effect", "Around", "MECHANICS", "THERMAL", "Setting", "flip_value",
           "sensitivity", "evaluate", "worst_case"]

#: the bisection stops when the bracket is narrower than this share of the range (at least 8 halvings of it)
FLIP_TOLERANCE = 1.0 / 256.0


class Effect(Enum):
    """What an assumption changes: the double nut's mechanics (rigidity, deflection, lift-off) or the shift's heat
    (the requirements evaluated again under it, :func:`evaluate`)."""

    MECHANICS = "mechanics"
    THERMAL = "thermal"


MECHANICS, THERMAL = Effect.MECHANICS, Effect.THERMAL


class Around(Enum):
    """How an assumption's range stands to the study's value: the ends themselves, offsets added to it (a
    tolerance), or factors on it."""

    ENDS = "ends"
    ADD = "add"
    TIMES = "times"

    def ends(self, nominal: float, low: float, high: float) -> tuple[float, float]:
        """The range's ends for a study whose value is ``nominal``."""
        if self is Around.ADD:
            return nominal + low, nominal + high
        if self is Around.TIMES:
            return nominal * low, nominal * high
        return low, high


@dataclass(frozen=True)
class Setting:
    """What an assumption changes: the double nut as built, the schedule's specification, the thermal table."""

    screw: BallScrew
    spec: ScheduleSpec
    table: ThermalTable | None


@dataclass(frozen=True)
class Assumption:
    """One modelling assumption and its stated range.

    Parameters
    ----------
    key : str
        The study key or model parameter it stands for (``thermal.pretension_K``).
    name : str
        The assumption in words.
    low, high : float
        The range's ends; where ``around``, offsets added to the study's value.
    unit : str
        Their unit.
    source : str
        Where the range comes from, in words.
    domain : tuple of float
        Where the assumption is admissible at all: the flip is searched there.
    moves : tuple of Effect
        What it changes: :data:`MECHANICS` and/or :data:`THERMAL` (the requirements evaluated again).
    around : Around
        ``Around.ADD``: ``low`` and ``high`` are offsets added to the study's value (a tolerance); ``Around.TIMES``:
        factors on it; ``Around.ENDS``: the ends themselves.
    labels : tuple of str
        A two-valued assumption's values' names (0: the first, 1: the second); empty: a number.
    """

    key: str
    name: str
    low: float
    high: float
    unit: str
    source: str
    domain: tuple[float, float]
    moves: tuple[Effect, ...]
    around: Around = Around.ENDS
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not (self.low <= self.high and self.domain[0] < self.domain[1]):
            raise ValueError(f"Assumption {self.key}: needs low <= high and a domain (lo, hi) with lo < hi")
        if not isinstance(self.around, Around):
            raise ValueError(f"Assumption {self.key}: around must be an Around, got {self.around!r}")
        if not self.moves or not all(isinstance(m, Effect) for m in self.moves):
            raise ValueError(f"Assumption {self.key}: moves must name {MECHANICS} and/or {THERMAL}, got {self.moves!r}")

    def range_for(self, nominal: float) -> tuple[float, float]:
        """The range's ends for a study whose value is ``nominal``, clipped to the domain."""
        lo, hi = self.around.ends(nominal, self.low, self.high)
        return max(lo, self.domain[0]), min(hi, self.domain[1])

    def with_range(self, low: float, high: float) -> Assumption:
        """The same assumption with another range (absolute ends)."""
        return replace(self, low=low, high=high, around=Around.ENDS)


#: the declared table of the assumptions the default study varies, one row each
ASSUMPTIONS: tuple[Assumption, ...] = (
    Assumption("thermal.pretension_K", "the screw's pretension", 2.0, 5.0, "K",
               "THK sets the pretension's negative travel for a 2-5 K rise; HIWIN pretensions for about 3 K and only "
               "where the rise stays below 5 K", (0.1, 10.0), (THERMAL,)),
    Assumption("thermal.seal_torque_Nm", "the seals' torque", 0.0, 2.0, "N m",
               "from none (THK: non-contact seals and gap wipers add no torque) to twice the study's (Rexroth's "
               "reinforced seal is 1.8-2.3 times its standard lip seal for the 25-40 mm sizes that list both)",
               (0.0, 5.0), (THERMAL,), around=Around.TIMES),
    Assumption("thermal.convection_factor", "the convection factor", 0.6, 1.5, "",
               "the film coefficients come from correlations (the rotating shaft's Nusselt number, free convection "
               "of 5-10 W/m^2 K for the study's 8): a factor 0.6-1.5 on them covers that band and the correlations' "
               "scatter", (0.1, 5.0), (THERMAL,)),
    Assumption("ballscrew.rigidity_in_machine_factor", "the in-machine rigidity factor", 0.8, 1.0, "",
               "HIWIN and THK: about 80 % of the table rigidity holds in a machine; Rexroth's and Steinmeyer's "
               "figures carry no factor (1.0)", (0.05, 1.0), (MECHANICS,)),
    Assumption("thermal.nut_heat_share", "the nut's heat share into the screw", 0.25, 0.75, "",
               "no published share: half and half is the usual choice, bracketed by a quarter either side (measured "
               "feed drives run hottest at the nut: less into the screw is the likelier side)", (0.0, 1.0),
               (THERMAL,)),
    Assumption("thermal.heat_model", "the friction model", 0.0, 1.0, "",
               "the vendors' drag torque T_p = K_p F_p l / (2 pi) (HIWIN, NSK, THK) or Jungnickel's rolling-contact "
               "loss (2010, eq. 9.49): two models, neither calibrated on this nut", (0.0, 1.0), (THERMAL,),
               labels=HEAT_MODELS),
    Assumption("ballscrew.drag_coefficient", "the drag coefficient K_p", 0.1, 0.3, "",
               "the range K_p is used with in the vendors' drag-torque formula (HIWIN, NSK, THK: 0.1-0.3)",
               (0.01, 1.0), (THERMAL,)),
    Assumption("ballscrew.contact_angle_deg", "the contact angle", -5.0, 5.0, "deg",
               "assumed grinding tolerance of +-5 deg on the design's angle (no vendor publishes one; a few microns "
               "on the groove's radius or the ball's size move a gothic arch's contact angle by degrees)",
               (20.0, 70.0), (MECHANICS, THERMAL), around=Around.ADD),
    Assumption("ballscrew.conformity", "the groove conformity", -0.01, 0.01, "",
               "assumed grinding tolerance of +-0.01 on the design's conformity, screw and nut alike (no vendor "
               "publishes one; ISO 3408-5 requires > 0.5)", (0.505, 0.6), (MECHANICS, THERMAL), around=Around.ADD),
)


def _heat_model_value(table: ThermalTable) -> float:
    return float(HEAT_MODELS.index(table.heat_model))


#: how each key reads its study value from a setting and makes the setting at another value
_ACCESS: dict[str, tuple[Callable[[Setting], float], Callable[[Setting, float], Setting]]] = {
    "thermal.pretension_K": (lambda s: _table(s).pretension_K,
                             lambda s, x: replace(s, table=replace(_table(s), pretension_K=x))),
    "thermal.seal_torque_Nm": (lambda s: _table(s).seal_torque(s.screw.nominal_diameter_mm, s.screw.lead_mm),
                               lambda s, x: replace(s, table=replace(_table(s), seal_torque_Nm=x))),
    "thermal.convection_factor": (lambda s: _table(s).convection_factor,
                                  lambda s, x: replace(s, table=replace(_table(s), convection_factor=x))),
    "ballscrew.rigidity_in_machine_factor": (lambda s: s.spec.rigidity_factor,
                                             lambda s, x: replace(s, spec=replace(s.spec, in_machine_factor=x))),
    "thermal.nut_heat_share": (lambda s: _table(s).nut_heat_share,
                               lambda s, x: replace(s, table=replace(_table(s), nut_heat_share=x))),
    "thermal.heat_model": (lambda s: _heat_model_value(_table(s)),
                           lambda s, x: replace(s, table=replace(_table(s), heat_model=HEAT_MODELS[round(x)]))),
    "ballscrew.drag_coefficient": (lambda s: s.screw.drag_K,
                                   lambda s, x: replace(s, screw=replace(s.screw, drag_coefficient=x))),
    "ballscrew.contact_angle_deg": (lambda s: s.screw.contact_angle_deg,
                                    lambda s, x: replace(s, screw=replace(s.screw, contact_angle_deg=x))),
    "ballscrew.conformity": (lambda s: s.screw.conformity_screw,
                             lambda s, x: replace(s, screw=replace(s.screw, conformity_screw=x, conformity_nut=x))),
}


def worst_case(assumptions: Sequence[Assumption] = ASSUMPTIONS) -> WorstCase:
    """The worst case a robust design is made against (``[design] robust``), from the assumptions' table: the
    contact angle's and the conformity's tolerances (offsets on the design's values) and K_p's high end."""
    by = {a.key: a for a in assumptions}
    angle, conformity, drag = (by[k] for k in ("ballscrew.contact_angle_deg", "ballscrew.conformity",
                                                "ballscrew.drag_coefficient"))
    if angle.around is not Around.ADD or conformity.around is not Around.ADD:
        raise ValueError("worst_case: the contact angle's and the conformity's ranges must be tolerances (offsets)")
    return WorstCase((angle.low, angle.high), (conformity.low, conformity.high), drag.high)


def _table(s: Setting) -> ThermalTable:
    if s.table is None:
        raise InputError("a thermal assumption needs the study's [thermal] table")
    return s.table


def applies(assumption: Assumption, setting: Setting, drive: FeedDrive) -> bool:
    """Whether the study's axis has what ``assumption`` acts on: a thermal one needs a ``[thermal]`` table with a
    limit, the pretension a pretensioned screw, K_p the catalogue model (the contact model has no K_p)."""
    if assumption.key not in _ACCESS:
        return False
    if THERMAL in assumption.moves and MECHANICS not in assumption.moves:
        t = setting.table
        if t is None or (t.thermal_growth_max_um is None and t.positioning_error_max_um is None):
            return False
        if assumption.key == "thermal.pretension_K":
            return mounting_of(t, drive) is ThermalMounting.PRETENSIONED
        if assumption.key == "ballscrew.drag_coefficient":
            return t.heat_model is HeatModel.CATALOGUE
        if assumption.key == "thermal.seal_torque_Nm":
            return t.sealed
    return True


def evaluate(run: SystemRun, drive: FeedDrive, setting: Setting, moves: Sequence[Effect],
             bases: dict[tuple[float, ...], ShiftBasis] | None = None) -> tuple[Requirement, ...]:
    """The requirements of the system run ``run`` (as built) under ``setting``: the mechanics' (where ``moves``
    names :data:`MECHANICS`) and the shift's (:data:`THERMAL`, where the setting has a thermal table). ``bases``:
    the shift's bases already made, by the nut's geometry (filled as it goes)."""
    out: tuple[Requirement, ...] = ()
    if MECHANICS in moves:
        out += requirements_of(frame_under(run.evaluation.frame, setting.screw, setting.spec), run.schedule,
                               run.design_schedule.binding)  # the design's own constraints, as built
    if THERMAL in moves and setting.table is not None:
        s = setting.screw
        shape = (s.contact_angle_deg, s.conformity_screw, s.conformity_nut)  # what the assumptions change of the nut
        bases = {} if bases is None else bases
        if shape not in bases:
            bases[shape] = shift_basis(run, drive, setting.table, s)
        out += schedule_requirements(run, drive, setting.table, screw=s, basis=bases[shape])
    return out


def flip_value(margin_of: Callable[[float], float], a: float, b: float, *, tolerance: float) -> float | None:
    """The value between ``a`` and ``b`` where the sign of ``margin_of`` (>= 0: met) changes, by bisection to within
    ``tolerance``; None where both ends give the same verdict. The midpoint of the last bracket is returned."""
    ma, mb = margin_of(a), margin_of(b)
    if (ma >= 0) == (mb >= 0):
        return None
    while abs(b - a) > tolerance:
        m = 0.5 * (a + b)
        if (margin_of(m) >= 0) == (ma >= 0):
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def _margin_pct(r: Requirement) -> float:
    return float(r.margin_pct) if r.margin_pct is not None else float(r.margin)


def _rows(run: SystemRun, drive: FeedDrive, base: Setting, a: Assumption, nominal: dict[str, Requirement],
          bases: dict[tuple[float, ...], ShiftBasis]) -> list[SensitivityRow]:
    get, put = _ACCESS[a.key]
    study_value = get(base)
    low, high = a.range_for(study_value)
    cache: dict[tuple[float, Effect], dict[str, Requirement]] = {}

    def at(x: float, group: Effect) -> dict[str, Requirement]:
        if (x, group) not in cache:  # each group apart: a bisection on one requirement evaluates its group alone
            cache[x, group] = {r.key: r for r in evaluate(run, drive, put(base, x), (group,), bases)}
        return cache[x, group]

    rows = []
    for key, r0 in nominal.items():
        group = next((g for g in a.moves if key in at(low, g)), None)
        if group is None:
            continue
        r_low, r_high = at(low, group)[key], at(high, group)[key]
        moved = max(abs(r_low.value - r0.value), abs(r_high.value - r0.value))
        if moved <= 1e-9 * max(abs(r0.limit), 1.0):
            continue

        def margin(x: float, key: str = key, group: Effect = group) -> float:
            return at(x, group)[key].margin

        name = min((r0.name, r_low.name, r_high.name), key=len)  # without a miss's cause, which names one case
        rows.append(SensitivityRow(
            a.name, a.key, a.unit, a.source, key, name, study_value, low, high, _margin_pct(r0), _margin_pct(r_low),
            _margin_pct(r_high), a.domain, _flip(a, margin, low, high), a.labels))
    return rows


def _flip(a: Assumption, margin: Callable[[float], float], low: float, high: float) -> float | None:
    """Where the verdict flips: inside the range where its ends differ, else beyond an end where the domain's end
    on that side differs; None where it does not flip within the domain. A two-valued assumption flips at its value
    whose verdict differs from the other's."""
    if a.labels:
        return high if (margin(low) >= 0) != (margin(high) >= 0) else None
    tol = FLIP_TOLERANCE * ((high - low) or (a.domain[1] - a.domain[0]))
    for lo, hi in ((low, high), (a.domain[0], low), (high, a.domain[1])):
        if hi > lo:
            x = flip_value(margin, lo, hi, tolerance=tol)
            if x is not None:
                return x
    return None


def sensitivity(run: SystemRun, drive: FeedDrive, table: ThermalTable | None, *,
                assumptions: Sequence[Assumption] = ASSUMPTIONS) -> SensitivityRecord:
    """The sensitivity study of the system run ``run`` on the axis ``drive`` with the study's thermal table
    ``table`` (module docstring): one row per assumption and requirement it moves."""
    base = Setting(run.plant.screw, run.schedule.spec, table)
    nominal = {r.key: r for r in run.requirements}
    rows: list[SensitivityRow] = []
    bases: dict[tuple[float, ...], ShiftBasis] = {}
    for a in assumptions:
        if applies(a, base, drive):
            rows += _rows(run, drive, base, a, nominal, bases)
    moved = {r.requirement for r in rows}
    judged = {r.key for g in (MECHANICS, THERMAL) for r in evaluate(run, drive, base, (g,), bases)}
    unmoved = tuple(r.name for k, r in nominal.items() if k in judged and k not in moved)
    return SensitivityRecord(tuple(rows), unmoved, tuple(r.name for k, r in nominal.items() if k not in judged))
