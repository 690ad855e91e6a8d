"""The whole system: the controlled preload follows the design's schedule, and what the axis gets while cutting.

The design's least-friction schedule (:mod:`piezopreload.design.schedule`) is the planned
preload ``F_p(t)`` of a machining cycle. The stacks' share of it, ``F_p(t) - F_i``, is the force
loop's reference (piecewise linear through the schedule's samples, repeated for the cycles
the machine runs); the loop (the tuned gains with the inverse-P-I feedforward, a
:class:`~piezopreload.models.controller.Controller`) runs it on the designed plant
(:mod:`piezopreload.design.plant`). From the true force the run gives:

* the tracking error, RMS and worst, also in % of the schedule's range;
* the axial rigidity the double nut has at the achieved preload under each sample's cutting
  load (:meth:`BallScrew.nut_loads`), against the requirement the schedule was planned for,
  the achieved preload against the lift-off bound with the schedule's margin
  (``lift_off_margin |F_a| / 2^(3/2)``, the other requirement the schedule keeps), and the axial
  deflection under the cutting load;
* the friction energy of the achieved preload against the plan's and the best constant
  preload's.

**The control's room.** The schedule keeps its requirements at the planned preload; the loop
lags it. When the achieved preload misses a requirement somewhere (rigidity or lift-off), the schedule is
planned again with a preload margin ``m``: every requirement must hold at ``F_p - m``
(:class:`ScheduleSpec.preload_margin_N`), with ``m`` the largest shortfall of the achieved
preload below the plan while the requirement binds (times ``margin_factor``), and the loop runs
it again: at most ``passes`` times. Each pass is recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.artifacts import write_artifact
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.tables import write_csv
from piezopreload.design.plant import DesignedPlant
from piezopreload.design.schedule import PreloadSchedule, schedule_preload
from piezopreload.models.actuator import Rig
from piezopreload.models.ballscrew import LIFT_OFF_RATIO
from piezopreload.models.closedloop import ClosedLoopRun, Reference, simulate
from piezopreload.models.controller import Controller

__all__ = ["SystemRun", "schedule_reference", "track_schedule", "evaluate_tracking"]

Array = NDArray[np.float64]

#: the requirement counts as binding where the planned rigidity is within this fraction of it
_BINDING = 0.02


def schedule_reference(plant: DesignedPlant, schedule: PreloadSchedule, cycles: int = 1,
                       contact_N: float = 0.0) -> Reference:
    """The force loop's reference: the stacks' share of the scheduled preload (less the bolts'), piecewise
    linear through the schedule's samples, ``cycles`` times in a row.

    ``contact_N``: the least force the stacks keep on the nuts (they are not bonded to them: where the
    schedule asks for the bolts' preload alone, the stacks still push this much).
    """
    if not (np.isfinite(contact_N) and contact_N >= 0):
        raise InputError(f"contact_N: must be finite and >= 0, got {contact_N!r}")
    t = np.asarray(schedule.profile.time_s, float)
    t = t - t[0]
    dt = float(t[-1] - t[-2])
    share = np.maximum(plant.stack_force_N(schedule.preload_N), contact_N)
    return Reference.ramps(t, share, float(t[-1] + dt)).repeat(cycles)


@dataclass(frozen=True, eq=False)
class SystemRun:
    """One pass of the controlled preload over the schedule's cycles (module docstring).

    Time series on the run's samples (``t_s``): ``planned_N`` and ``achieved_N`` (total preload,
    true force), ``axial_load_N``, ``rigidity_N_per_um`` (at the achieved preload under the load),
    ``required_N_per_um``, ``deflection_um``, ``voltage_V``. ``passes`` records every pass (its
    margin and numbers); ``schedule`` is the schedule of the last.
    """

    schedule: PreloadSchedule
    plant: DesignedPlant
    cycles: int
    run: ClosedLoopRun
    t_s: Array
    planned_N: Array
    achieved_N: Array
    axial_load_N: Array
    rigidity_N_per_um: Array
    required_N_per_um: Array
    planned_rigidity_N_per_um: Array
    deflection_um: Array
    cutting: Array
    numbers: dict[str, Any]
    passes: tuple[dict[str, Any], ...] = ()

    @property
    def margin_N(self) -> float:
        return float(self.schedule.spec.preload_margin_N)

    def summary(self) -> dict[str, Any]:
        """The run's numbers and its passes."""
        return {**self.numbers, "preload_margin_N": self.margin_N, "cycles": self.cycles,
                "passes": [dict(p) for p in self.passes]}

    def to_dict(self, every: int = 10) -> dict[str, Any]:
        """:meth:`summary` and the time series (every ``every``-th sample), as the system artifact holds them."""
        sl = slice(None, None, every)
        return {**self.summary(), "schedule": self.schedule.to_dict(), "series": {
            "time_s": self.t_s[sl].tolist(), "planned_N": self.planned_N[sl].tolist(),
            "achieved_N": self.achieved_N[sl].tolist(), "axial_load_N": self.axial_load_N[sl].tolist(),
            "rigidity_N_per_um": self.rigidity_N_per_um[sl].tolist(),
            "required_N_per_um": self.required_N_per_um[sl].tolist(),
            "planned_rigidity_N_per_um": self.planned_rigidity_N_per_um[sl].tolist(),
            "deflection_um": self.deflection_um[sl].tolist(), "voltage_V": self.run.voltage_V[sl].tolist(),
            "cutting": self.cutting[sl].astype(int).tolist()}}

    def save(self, folder: str | Path, inputs: dict[str, Any]) -> dict[str, Path]:
        """Write ``system.json`` (kind ``system``: :meth:`to_dict` and ``inputs``) and ``reference.csv`` (the
        loop's reference at its rate, ``time_s,force_N``: what the rig executor plays) into ``folder``."""
        folder = Path(folder)
        paths = {"system": folder / "system.json", "reference": folder / "reference.csv"}
        write_artifact(paths["system"], "system", {**self.to_dict(), "inputs": inputs})
        write_csv(paths["reference"], {"time_s": self.run.t_s, "force_N": self.run.reference_N},
                  f"the stacks' share of the preload schedule (less the bolts' {self.plant.bolt_preload_N:.1f} N), "
                  f"{self.cycles} cycles, margin {self.margin_N:.1f} N")
        return paths

    def plot(self) -> Any:
        """Planned against achieved preload, rigidity against the requirement, deflection: a Figure."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7.0, 7.0), layout="constrained")
        ax = fig.subplots(3, 1, sharex=True)
        ax[0].plot(self.t_s, self.planned_N, color="k", lw=1.0, label="planned")
        ax[0].plot(self.t_s, self.achieved_N, color="C0", lw=0.8, label="achieved (true force)")
        ax[0].set_ylabel("preload (N)")
        ax[0].legend(fontsize="small")
        ax[1].plot(self.t_s, self.rigidity_N_per_um, color="C0", lw=0.8, label="achieved")
        ax[1].plot(self.t_s, self.required_N_per_um, ":", color="k", label="required")
        ax[1].set_ylabel("rigidity (N/um)")
        ax[1].legend(fontsize="small")
        ax[2].plot(self.t_s, self.deflection_um, color="C2", lw=0.8)
        ax[2].set(xlabel="time (s)", ylabel="axial deflection (um)")
        return fig


def evaluate_tracking(plant: DesignedPlant, schedule: PreloadSchedule, run: ClosedLoopRun, cycles: int) -> dict[str, Any]:
    """The numbers of one run over the schedule (module docstring): tracking, rigidity, deflection, energy."""
    prof = schedule.profile
    t0 = float(prof.time_s[0])
    period = run.reference.duration_s / cycles
    t_cycle = np.mod(run.t_s, period) + t0
    load = np.interp(t_cycle, prof.time_s, prof.axial_load_N)
    planned = plant.preload_N(run.reference_N)
    achieved = plant.preload_N(run.force_N)
    required = schedule.spec.required_stiffness(load)
    screw = plant.screw
    loads = screw.nut_loads(np.maximum(achieved, 1e-3), load)
    rigidity = np.asarray(loads.rigidity_N_per_um, float)
    planned_rigidity = np.asarray(screw.rigidity_N_per_um(np.maximum(planned, 1e-3), load), float)
    deflection = np.asarray(loads.deflection_um, float)
    cutting = np.abs(load) > 0
    error = run.reference_N - run.force_N
    span = float(np.max(planned) - np.min(planned))
    ratio = np.where(cutting, rigidity / required, np.inf)
    worst = int(np.argmin(ratio))
    # friction energy per cycle: the schedule's weights (drag torque per newton times the screw's angle per sample)
    if prof.speed_rpm is not None:
        omega = np.interp(t_cycle, prof.time_s, prof.speed_rpm) * 2.0 * np.pi / 60.0
    else:
        omega = np.ones_like(t_cycle)
    dt = float(run.t_s[1] - run.t_s[0])
    weight = float(screw.drag_torque_Nm(1.0)) * omega * dt
    # the schedule's other requirement: no lift-off, with its margin (the catalogues' rule, as the schedule plans)
    lift_bound = schedule.spec.lift_off_margin * np.abs(load) / LIFT_OFF_RATIO
    lift_ratio = np.where(cutting, achieved / np.maximum(lift_bound, 1e-9), np.inf)
    binding = cutting & ((planned_rigidity <= (1.0 + _BINDING) * required) | (planned <= (1.0 + _BINDING) * lift_bound))
    shortfall = np.where(binding, planned - achieved, 0.0)
    return {
        "tracking_rms_N": float(np.sqrt(np.mean(error**2))), "tracking_max_N": float(np.max(np.abs(error))),
        "tracking_rms_pct_of_range": float(100.0 * np.sqrt(np.mean(error**2)) / span),
        "schedule_range_N": span,
        "rigidity_min_cutting_N_per_um": float(rigidity[worst]), "rigidity_required_N_per_um": float(required[worst]),
        "rigidity_ratio_min": float(ratio[worst]), "rigidity_worst_t_s": float(run.t_s[worst]),
        "rigidity_below_requirement_s": float(np.sum(cutting & (rigidity < required)) * dt),
        "deflection_max_um": float(np.max(np.abs(np.where(cutting, deflection, 0.0)))),
        "deflection_limit_um": float(schedule.spec.deflection_max_um),
        "lift_off_ratio_min": float(np.min(lift_ratio)),
        "lift_off_margin": float(schedule.spec.lift_off_margin),
        "requirements_met": bool(ratio[worst] >= 1.0 and np.min(lift_ratio) >= 1.0),
        "preload_shortfall_max_N": float(np.max(shortfall, initial=0.0)),
        "friction_energy_per_cycle": float(np.dot(weight, achieved) / cycles),
        "planned_friction_energy_per_cycle": float(np.dot(weight, planned) / cycles),
        "constant_friction_energy_per_cycle": float(np.sum(weight) * schedule.constant_preload_N / cycles),
        "constant_preload_N": float(schedule.constant_preload_N), "energy_units": schedule.energy_units,
        "peak_voltage_V": float(np.max(run.voltage_V)),
        "_series": (planned, achieved, load, rigidity, required, planned_rigidity, deflection, cutting),
    }


def track_schedule(plant: DesignedPlant, controller: Controller, schedule: PreloadSchedule, *, cycles: int = 2,
                   seed: int = 0, passes: int = 3, margin_factor: float = 1.25, contact_N: float = 0.0,
                   ff_extra_V: Any = None,
                   progress: Callable[[str], None] | None = None) -> SystemRun:
    """Run the loop over the schedule on the designed plant; plan again with a margin while the rigidity falls short.

    ``contact_N``: the least force the stacks keep (:func:`schedule_reference`).
    ``ff_extra_V``: a correction added to the feedforward, one value per sample of the cycles (a
    learned one, say); a callable ``f(reference) -> array`` makes it for each pass's reference.
    Returns the last pass's :class:`SystemRun`; its ``passes`` hold every pass's numbers.
    """
    if not (isinstance(cycles, int) and cycles >= 1):
        raise InputError(f"cycles: must be an integer >= 1, got {cycles!r}")
    if not (isinstance(passes, int) and passes >= 1):
        raise InputError(f"passes: must be an integer >= 1, got {passes!r}")
    if not margin_factor >= 1.0:
        raise InputError(f"margin_factor: must be >= 1, got {margin_factor!r}")
    say = progress or (lambda _m: None)
    rig = Rig(plant.rig)
    record: list[dict[str, Any]] = []
    current = schedule
    for k in range(passes):
        reference = schedule_reference(plant, current, cycles, contact_N)
        extra = ff_extra_V(reference) if callable(ff_extra_V) else ff_extra_V
        run = simulate(rig, controller, reference, seed=seed, ff_extra_V=extra)
        numbers = evaluate_tracking(plant, current, run, cycles)
        series = numbers.pop("_series")
        record.append({"pass": k + 1, "preload_margin_N": current.spec.preload_margin_N,
                       **{key: numbers[key] for key in ("tracking_rms_N", "tracking_rms_pct_of_range",
                                                        "rigidity_ratio_min", "lift_off_ratio_min",
                                                        "requirements_met", "preload_shortfall_max_N",
                                                        "friction_energy_per_cycle")}})
        say(f"pass {k + 1}: margin {current.spec.preload_margin_N:.1f} N, tracking RMS "
            f"{numbers['tracking_rms_N']:.2f} N ({numbers['tracking_rms_pct_of_range']:.2f} % of the range), "
            f"least rigidity / requirement {numbers['rigidity_ratio_min']:.3f}, least preload / lift-off bound "
            f"{numbers['lift_off_ratio_min']:.3f}")
        if numbers["requirements_met"] or k + 1 == passes:
            break
        margin = current.spec.preload_margin_N + margin_factor * max(numbers["preload_shortfall_max_N"], 1.0)
        try:
            current = schedule_preload(plant.screw, current.profile, replace(current.spec, preload_margin_N=margin))
        except (ValueError, RuntimeError) as exc:
            raise InfeasibleError(f"the schedule cannot leave the force loop a margin of {margin:.1f} N: {exc}") from exc
    planned, achieved, load, rigidity, required, planned_rigidity, deflection, cutting = series
    return SystemRun(schedule=current, plant=plant, cycles=cycles, run=run, t_s=run.t_s, planned_N=planned,
                     achieved_N=achieved, axial_load_N=load, rigidity_N_per_um=rigidity, required_N_per_um=required,
                     planned_rigidity_N_per_um=planned_rigidity, deflection_um=deflection, cutting=cutting,
                     numbers=numbers, passes=tuple(record))
