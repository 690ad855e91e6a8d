"""The preload schedule's types: the load profile, what the schedule must keep, and the planned schedule.

:func:`piezopreload.design.schedule.schedule_preload` computes a :class:`PreloadSchedule`; the design
artifact (:class:`~piezopreload.artifacts.design.DesignRecord`) records it, and every reader
(the system stage, the report) takes it from there: the best constant preload and its friction
energy are computed once, by the design, and read from this record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core._typing import Array
from piezopreload.core.records import Record, entry, record
from piezopreload.models.ballscrew import LIFT_OFF_RATIO

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LoadProfile", "ScheduleSpec", "PreloadSchedule", "ScheduleSummary", "RIGIDITY_KEY", "LIFT_OFF_KEY",
           "BINDS_WITHIN"]

#: the key of the requirement the schedule's rigidity row keeps (the least rigidity and the deflection's share of it)
RIGIDITY_KEY = "schedule.rigidity_while_cutting"
#: the key of the requirement the schedule's lift-off row keeps (``lift_off_margin |F_a| / 2^(3/2)``)
LIFT_OFF_KEY = "schedule.lift_off_margin"
#: a row binds the plan where the plan less its margin lies within this share of the least preload the row sets: the
#: envelope's plan is that preload to round-off (1e-13 of it), IPOPT's (``ipopt.tol`` 1e-9 on rows scaled to O(1))
#: within 1e-8 of it, and a margin a report states is 1e-4 of the limit at the finest
BINDS_WITHIN = 1e-6


@record
class LoadProfile(Record):
    """Axial load (N) and screw speed (rpm) against time (s), one row per sample."""

    time_s: Array = entry("The samples' times, strictly increasing.", unit="s")
    axial_load_N: Array = entry("The axial load at each (its sign the direction).", unit="N", size="time_s")
    speed_rpm: Array | None = entry("The screw's speed at each (None: not given).", unit="rpm", size="time_s",
                                    default=None)

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s, float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"LoadProfile.time_s must be 1-D with at least 2 samples, got shape {t.shape}.")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("LoadProfile.time_s must be finite and strictly increasing.")
        for name in ("axial_load_N", "speed_rpm"):
            v = getattr(self, name)
            if v is None:
                continue
            v = np.asarray(v, float)
            if v.shape != t.shape or not np.all(np.isfinite(v)):
                raise ValueError(f"LoadProfile.{name} must be finite with the shape of time_s {t.shape}.")
        if self.speed_rpm is not None and np.any(np.asarray(self.speed_rpm) < 0):
            raise ValueError("LoadProfile.speed_rpm must be >= 0 (the load's sign carries the direction).")

    @property
    def dt_s(self) -> Array:
        """Each sample's share of time (half the gaps to its neighbours)."""
        t = np.asarray(self.time_s, float)
        gaps = np.diff(t)
        return np.asarray(0.5 * (np.concatenate([[0.0], gaps]) + np.concatenate([gaps, [0.0]])), np.float64)

    @property
    def cutting(self) -> NDArray[np.bool_]:
        """The samples under load (where the schedule's requirements are judged)."""
        loaded: NDArray[np.bool_] = np.abs(np.asarray(self.axial_load_N, float)) > 0
        return loaded


def _limit_from(x: Any) -> float:
    if x is None:
        return math.inf
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ValueError(f"expected a finite number, or null for no limit, got {x!r}")
    return float(x)


def _limit_to(x: float) -> float | None:
    return None if math.isinf(x) else x


@record
class ScheduleSpec(Record):
    """The schedule's requirements and limits."""

    bolt_preload_N: float = entry("The bolts' preload: the least preload.", unit="N")
    max_preload_N: float = entry("The highest preload the stacks reach.", unit="N")
    slew_N_per_s: float = entry("The preload's slew limit.", unit="N/s")
    stiffness_min_N_per_um: float = entry("The least rigidity while cutting.", unit="N/um", default=0.0)
    deflection_max_um: float = entry("The largest axial deflection under the load (inf: no limit; null in the "
                                     "document).", unit="um", read=_limit_from, write=_limit_to,
                                     takes="a finite number, or null for no limit", default=math.inf)
    lift_off_margin: float = entry("The least ratio of the preload to the lift-off bound.", default=1.2)
    preload_margin_N: float = entry("The control's room everywhere: every requirement holds at the preload less "
                                    "this.", unit="N", default=0.0)
    in_machine_factor: float | None = entry("The share of the nut's table rigidity it keeps mounted in a machine "
                                            "(HIWIN's and THK's 0.8): the rigidity and deflection rows hold in the "
                                            "machine (None, a document written before it: the table figure, 1).",
                                            default=None, omit=True)

    def __post_init__(self) -> None:
        if not 0 < self.bolt_preload_N < self.max_preload_N < math.inf:
            raise ValueError(f"ScheduleSpec needs 0 < bolt_preload_N < max_preload_N, got {self.bolt_preload_N!r} "
                             f"and {self.max_preload_N!r}.")
        if not (self.slew_N_per_s > 0 and math.isfinite(self.slew_N_per_s)):
            raise ValueError(f"ScheduleSpec.slew_N_per_s must be a finite number > 0, got {self.slew_N_per_s!r}.")
        if not (self.stiffness_min_N_per_um >= 0 and self.deflection_max_um > 0 and self.lift_off_margin >= 1):
            raise ValueError("ScheduleSpec needs stiffness_min_N_per_um >= 0, deflection_max_um > 0 and "
                             "lift_off_margin >= 1.")
        if not (self.in_machine_factor is None or (math.isfinite(self.in_machine_factor)
                                                   and 0 < self.in_machine_factor <= 1)):
            raise ValueError(f"ScheduleSpec.in_machine_factor must be in (0, 1], got {self.in_machine_factor!r}.")
        if not (math.isfinite(self.preload_margin_N) and self.preload_margin_N >= 0):
            raise ValueError(f"ScheduleSpec.preload_margin_N must be finite and >= 0, got {self.preload_margin_N!r}.")

    @property
    def rigidity_factor(self) -> float:
        """What the nut's table rigidity is multiplied by for the rows: ``in_machine_factor`` (1 where not set)."""
        return 1.0 if self.in_machine_factor is None else float(self.in_machine_factor)

    def lift_off_bound_N(self, axial_load_N: ArrayLike) -> Array:
        """The lift-off row's least preload under each load: ``lift_off_margin |F_a| / 2^(3/2)`` (the catalogues'
        rule, the safety factor included)."""
        bound: Array = self.lift_off_margin * np.abs(np.asarray(axial_load_N, float)) / LIFT_OFF_RATIO
        return bound

    def required_stiffness(self, axial_load_N: ArrayLike) -> Array:
        """The rigidity row's requirement under each load: the least rigidity, or ``|F_a| / deflection_max_um``
        where that is more."""
        required: Array = np.maximum(self.stiffness_min_N_per_um,
                                     np.abs(np.asarray(axial_load_N, float)) / self.deflection_max_um)
        return required


#: the per-sample series a schedule records (beside the profile's time, load and speed)
_SERIES = ("preload_N", "needed_N", "margin_N", "margin_short_N", "rigidity_N_per_um", "required_N_per_um",
           "constant_rigidity_N_per_um")


@dataclass(frozen=True)
class ScheduleSummary:
    """A preload schedule's numbers without its series (:meth:`PreloadSchedule.summary`); :meth:`to_dict` is what
    ``design --json`` prints as ``schedule``.

    Parameters
    ----------
    status : str
        The schedule's status.
    friction_energy : float
        Its friction energy per cycle (in ``energy_units``).
    constant_friction_energy : float
        The best constant preload's.
    energy_units : str
        The unit of the energies.
    saving_fraction : float
        The fraction of the constant preload's energy the schedule saves.
    constant_preload_N : float
        The best constant preload, N.
    preload_min_N, preload_max_N : float
        The schedule's range, N.
    stiffness_margin_min_N_per_um : float
        Its least margin of rigidity over the requirement, N/um.
    samples : int
        Its samples.
    spec : ScheduleSpec
        What it must keep.
    local_margin_max_N : float
        Its largest local margin over the spec's, N.
    """

    status: str
    friction_energy: float
    constant_friction_energy: float
    energy_units: str
    saving_fraction: float
    constant_preload_N: float
    preload_min_N: float
    preload_max_N: float
    stiffness_margin_min_N_per_um: float
    samples: int
    spec: ScheduleSpec
    local_margin_max_N: float

    def to_dict(self) -> dict[str, Any]:
        """The summary as ``design --json`` prints it.

        Returns
        -------
        dict
            Its numbers by name, the schedule spec's keys (:meth:`ScheduleSpec.to_dict`) among them.
        """
        return {"status": self.status, "friction_energy": self.friction_energy,
                "constant_friction_energy": self.constant_friction_energy, "energy_units": self.energy_units,
                "saving_fraction": self.saving_fraction, "constant_preload_N": self.constant_preload_N,
                "preload_min_N": self.preload_min_N, "preload_max_N": self.preload_max_N,
                "stiffness_margin_min_N_per_um": self.stiffness_margin_min_N_per_um, "samples": self.samples,
                **self.spec.to_dict(), "local_margin_max_N": self.local_margin_max_N}


@record(eq=False)
class PreloadSchedule(Record):
    """The planned schedule, the best constant preload, and what the schedule saves.

    ``needed_N`` is each sample's least preload meeting its requirements (no margin): the
    requirement's own bound, and its maximum is the best constant preload. ``margin_N`` is the
    room each sample leaves the force loop (every requirement holds at ``preload_N - margin_N``:
    the spec's uniform margin plus the local margins the whole system asked for), and
    ``margin_short_N`` the local margin the stacks' reach could not give (0 where it could).
    """

    profile: LoadProfile = entry("The load profile it was planned for (its fields beside the schedule's).",
                                 inline=True)
    spec: ScheduleSpec = entry("What the schedule must keep (its fields beside the schedule's).", inline=True)
    preload_N: Array = entry("The planned preload at each sample.", unit="N", size="profile.time_s")
    constant_preload_N: float = entry("The best constant preload.", unit="N")
    rigidity_N_per_um: Array = entry("The rigidity at each sample.", unit="N/um", size="profile.time_s")
    required_N_per_um: Array = entry("The rigidity each sample requires.", unit="N/um", size="profile.time_s")
    constant_rigidity_N_per_um: Array = entry("The rigidity at the best constant preload.", unit="N/um",
                                              size="profile.time_s")
    friction_energy_J: float = entry("The plan's friction energy per cycle.", name="friction_energy")
    constant_friction_energy_J: float = entry("The best constant preload's friction energy per cycle.",
                                              name="constant_friction_energy")
    energy_units: str = entry("The friction energy's unit.")
    status: str = entry("The solver's status.")
    needed_N: Array = entry("Each sample's least preload meeting its requirements (no margin).", unit="N",
                            size="profile.time_s")
    margin_N: Array = entry("The room each sample leaves the force loop.", unit="N", size="profile.time_s")
    margin_short_N: Array = entry("The local margin the stacks' reach could not give.", unit="N",
                                  size="profile.time_s")

    def __post_init__(self) -> None:
        n = np.asarray(self.profile.time_s).size
        for name in _SERIES:
            value = np.asarray(getattr(self, name), float)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise ValueError(f"PreloadSchedule.{name} must hold one finite number per sample ({n}).")
            object.__setattr__(self, name, value)
        for name in ("constant_preload_N", "friction_energy_J", "constant_friction_energy_J"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"PreloadSchedule.{name} must be finite, got {getattr(self, name)!r}.")

    def binding_samples(self) -> dict[str, NDArray[np.bool_]]:
        """Where each of the plan's rows binds it, by the key of the requirement it keeps (:data:`RIGIDITY_KEY`,
        :data:`LIFT_OFF_KEY`): the samples under load where the plan less its margin sits on the least preload its
        requirements need (within :data:`BINDS_WITHIN`; not on a slew cone nor above it) and that row sets that
        preload.

        The least preload of a sample is the lift-off row's bound or the bolts' preload, whichever is more, where
        that already gives the rigidity, else the rigidity row's own (``design.schedule``'s bisection returns the
        floor itself where it suffices): the lift-off row binds where the need is its bound, the rigidity row where
        the need lies above both. Where both rows need the same preload to within :data:`BINDS_WITHIN` the lift-off
        row is named. Where the need is the bolts' preload alone, no row binds (the bolts do).

        Returns
        -------
        dict of str to ndarray of bool
            One mask over the profile's samples per key, both keys always present.
        """
        load = np.asarray(self.profile.axial_load_N, float)
        lift, need = self.spec.lift_off_bound_N(load), np.asarray(self.needed_N, float)
        sits = (self.profile.cutting & (need > 0)
                & (np.asarray(self.preload_N, float) - np.asarray(self.margin_N, float) <= need * (1.0 + BINDS_WITHIN)))
        return {RIGIDITY_KEY: sits & (need > np.maximum(self.spec.bolt_preload_N, lift) * (1.0 + BINDS_WITHIN)),
                LIFT_OFF_KEY: sits & (lift >= need * (1.0 - BINDS_WITHIN))}

    @property
    def binding(self) -> tuple[str, ...]:
        """The keys of the requirements whose rows bind the plan somewhere (:meth:`binding_samples`): the design's own
        constraints, whose margin in a run is the force loop's error, not what the physics grants. Empty where the
        bolts' preload alone holds every sample under load."""
        return tuple(key for key, where in self.binding_samples().items() if bool(np.any(where)))

    @property
    def saving_fraction(self) -> float:
        """The plan's friction energy against the best constant preload's: the fraction it saves."""
        return 1.0 - self.friction_energy_J / self.constant_friction_energy_J

    def summary(self) -> ScheduleSummary:
        """The schedule's numbers (no series): what ``design --json`` prints.

        Returns
        -------
        ScheduleSummary
            The status, the friction energies of the schedule and of the best constant preload, the saving, the range of
            the preload (N), the least rigidity margin (N/um), the samples and the spec.
        """
        return ScheduleSummary(
            status=self.status, friction_energy=self.friction_energy_J,
            constant_friction_energy=self.constant_friction_energy_J, energy_units=self.energy_units,
            saving_fraction=self.saving_fraction, constant_preload_N=self.constant_preload_N,
            preload_min_N=float(self.preload_N.min()), preload_max_N=float(self.preload_N.max()),
            stiffness_margin_min_N_per_um=float(np.min(self.rigidity_N_per_um - self.required_N_per_um)),
            samples=int(self.preload_N.size), spec=self.spec,
            local_margin_max_N=(0.0 if self.margin_N is None else
                                float(np.max(self.margin_N - self.spec.preload_margin_N, initial=0.0))),
        )

    def to_dict(self) -> dict[str, Any]:
        """:meth:`summary`'s, the profile and every series: the design artifact's ``schedule``.

        Returns
        -------
        dict
            Its object.
        """
        return {**self.summary().to_dict(), **super().to_dict()}

    def plot(self) -> Figure:
        """Load profile, the two preloads, and rigidity against the requirement, on three axes: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            Three axes against time: the axial load (N); the scheduled and the best constant preload (N); the rigidity
            of each and the required rigidity (N/um).
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.0, 6.0), layout="constrained")
        axes = fig.subplots(3, 1, sharex=True)
        t = self.profile.time_s
        axes[0].plot(t, self.profile.axial_load_N, color="0.3")
        axes[0].set_ylabel("axial load (N)")
        axes[1].plot(t, self.preload_N, label="schedule")
        axes[1].axhline(self.constant_preload_N, color="C1", ls="--", label="best constant")
        axes[1].set_ylabel("preload (N)")
        axes[1].legend(fontsize="small")
        axes[2].plot(t, self.rigidity_N_per_um, label="schedule")
        axes[2].plot(t, self.constant_rigidity_N_per_um, "--", label="best constant")
        axes[2].plot(t, self.required_N_per_um, ":", color="k", label="required")
        axes[2].set_ylabel("rigidity (N/um)")
        axes[2].set_xlabel("time (s)")
        axes[2].legend(fontsize="small")
        return fig
