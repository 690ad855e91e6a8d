"""The variable preload schedule: the point of piezo preload.

Stiffness grows only as F_p^(1/3) while drag torque grows linearly with the preload, so a
preload that follows the load (high while cutting, low on rapid traverses) keeps the
stiffness where it is needed at a fraction of the friction. Given an axial-load profile
F_a(t) (with the screw speed n(t)), the schedule F_p(t) solves, on the profile's samples,

    minimise    sum_k T_d(F_p,k) |omega_k| dt_k          (friction energy, J)
    subject to  K(F_p,k, F_a,k) >= max(K_min, |F_a,k| / deflection_max)   (stiffness)
                lift_off_margin |F_a,k| <= 2^(3/2) F_p,k                    (no lift-off)
                F_i <= F_p,k <= F_max                    (bolts; the stacks' reach)
                |F_p,k+1 - F_p,k| <= slew dt_k          (the stacks' force slew)

with K the double nut's exact rigidity under load (:meth:`BallScrew.nut_loads`, the same
formulas on CasADi expressions) and the lift-off row the catalogues' rule, as in the design
(design/preload.py). Where the speed is zero the friction energy is zero; a
profile without speeds weighs the drag torque by time instead (N m s). The schedule is
non-causal (it ramps up before a cut begins, as a CNC program knows its next pass); the
slew limit decides how early.

With ``preload_margin_N = m`` the stiffness and lift-off rows hold at ``F_p,k - m``: the room
the force loop's tracking error needs (:mod:`piezopreload.design.system` derives ``m`` from the
error the tuned loop has while it follows the schedule).

The rigidity grows with the preload, so each sample's rows are one lower bound on F_p,k, and
with the slew rows the optimum is the upper envelope of the slew cones on those bounds: exact,
in two passes (:func:`schedule_preload`; ``method="nlp"`` solves the NLP above with IPOPT, to
the same optimum).

The comparison is the best constant preload: the least constant F_p meeting the same
constraints at every sample (so at equal minimum stiffness requirement). Its friction
energy against the schedule's is the saving.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.models.ballscrew import LIFT_OFF_RATIO, BallScrew, _rigidity, nut_forces
from piezopreload.models.ops import CASADI

__all__ = ["LoadProfile", "ScheduleSpec", "PreloadSchedule", "schedule_preload", "example_profile"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LoadProfile:
    """Axial load (N) and screw speed (rpm) against time (s), one row per sample."""

    time_s: Array
    axial_load_N: Array
    speed_rpm: Array | None = None

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
        return 0.5 * (np.concatenate([[0.0], gaps]) + np.concatenate([gaps, [0.0]]))


def example_profile(dt_s: float = 0.01) -> LoadProfile:
    """A machining cycle: rapid approach, a roughing pass (+x), rapid, a finishing pass (-x),
    rapid return; loads change over 50 ms ramps. Used when a study gives no profile."""
    segments = [  # (duration s, axial load N, speed rpm)
        (1.5, 600.0, 3000.0), (5.0, 4000.0, 300.0), (1.5, -600.0, 3000.0),
        (4.0, -1500.0, 600.0), (1.5, 600.0, 3000.0), (1.0, 0.0, 0.0),
    ]
    t_edges = np.cumsum([0.0] + [s[0] for s in segments])
    t = np.arange(0.0, t_edges[-1] + 0.5 * dt_s, dt_s)
    load = np.zeros_like(t)
    speed = np.zeros_like(t)
    ramp = 0.05
    for (dur, F, n), t0 in zip(segments, t_edges[:-1]):
        w = np.clip((t - t0) / ramp, 0.0, 1.0) * (t < t0 + dur + ramp)
        w = np.where(t >= t0 + dur, np.clip(1.0 - (t - t0 - dur) / ramp, 0.0, 1.0), w)
        load += w * F
        speed += w * n
    return LoadProfile(t, load, speed)


@dataclass(frozen=True)
class ScheduleSpec:
    """The schedule's requirements and limits."""

    bolt_preload_N: float
    max_preload_N: float
    slew_N_per_s: float
    stiffness_min_N_per_um: float = 0.0
    deflection_max_um: float = math.inf
    lift_off_margin: float = 1.2
    preload_margin_N: float = 0.0  # the control's room: every requirement holds at the preload less this

    def __post_init__(self) -> None:
        if not 0 < self.bolt_preload_N < self.max_preload_N < math.inf:
            raise ValueError(f"ScheduleSpec needs 0 < bolt_preload_N < max_preload_N, got {self.bolt_preload_N!r} "
                             f"and {self.max_preload_N!r}.")
        if not (self.slew_N_per_s > 0 and math.isfinite(self.slew_N_per_s)):
            raise ValueError(f"ScheduleSpec.slew_N_per_s must be a finite number > 0, got {self.slew_N_per_s!r}.")
        if not (self.stiffness_min_N_per_um >= 0 and self.deflection_max_um > 0 and self.lift_off_margin >= 1):
            raise ValueError("ScheduleSpec needs stiffness_min_N_per_um >= 0, deflection_max_um > 0 and "
                             "lift_off_margin >= 1.")
        if not (math.isfinite(self.preload_margin_N) and self.preload_margin_N >= 0):
            raise ValueError(f"ScheduleSpec.preload_margin_N must be finite and >= 0, got {self.preload_margin_N!r}.")

    def required_stiffness(self, axial_load_N: ArrayLike) -> Array:
        return np.maximum(self.stiffness_min_N_per_um, np.abs(np.asarray(axial_load_N, float)) / self.deflection_max_um)


@dataclass(frozen=True)
class PreloadSchedule:
    """The optimal schedule, the best constant preload, and what the schedule saves."""

    profile: LoadProfile
    spec: ScheduleSpec
    preload_N: Array
    constant_preload_N: float
    rigidity_N_per_um: Array
    required_N_per_um: Array
    constant_rigidity_N_per_um: Array
    friction_energy_J: float
    constant_friction_energy_J: float
    energy_units: str
    status: str

    @property
    def saving_fraction(self) -> float:
        return 1.0 - self.friction_energy_J / self.constant_friction_energy_J

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status, "friction_energy": self.friction_energy_J,
            "constant_friction_energy": self.constant_friction_energy_J, "energy_units": self.energy_units,
            "saving_fraction": self.saving_fraction, "constant_preload_N": self.constant_preload_N,
            "preload_min_N": float(self.preload_N.min()), "preload_max_N": float(self.preload_N.max()),
            "stiffness_margin_min_N_per_um": float(np.min(self.rigidity_N_per_um - self.required_N_per_um)),
            "samples": int(self.preload_N.size), "preload_margin_N": self.spec.preload_margin_N,
        }

    def plot(self, axes: Any = None) -> Any:
        """Load profile, the two preloads, and rigidity against the requirement."""
        import matplotlib.pyplot as plt

        if axes is None:
            _, axes = plt.subplots(3, 1, figsize=(6.0, 6.0), sharex=True)
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
        return axes


def _rigidity_function(screw: BallScrew) -> ca.Function:
    F, Fa = ca.SX.sym("F"), ca.SX.sym("Fa")
    c_h, s = screw.axial_constant_um, screw.structural_compliance_um_per_N
    f_loaded, f_unloaded = nut_forces(ca.fabs(Fa) / F, s * F ** (1.0 / 3.0) / c_h, CASADI)
    k = _rigidity(CASADI, c_h, s, screw.accuracy_factor, F * f_loaded, F * f_unloaded)
    return ca.Function("rigidity", [F, Fa], [k])


def schedule_preload(screw: BallScrew, profile: LoadProfile, spec: ScheduleSpec, method: str = "envelope") -> PreloadSchedule:
    """The least-friction preload schedule and the best constant preload (module docstring).

    ``method="envelope"`` (the default) solves the problem exactly without iterating. The
    rigidity grows with the preload at every load, so each sample's stiffness and lift-off rows
    are one lower bound ``low_k`` on ``F_p,k`` (found by bisection, as for the best constant);
    with the slew rows every feasible schedule lies above every cone ``low_j - slew |t - t_j|``,
    and their upper envelope ``L_k = max_j (low_j - slew |t_k - t_j|)`` is itself feasible (a
    maximum of functions of slope at most ``slew`` has slope at most ``slew``, and it is at most
    ``max_j low_j <= F_max``). So ``L`` lies below every feasible schedule, sample by sample,
    and least ``sum_k w_k F_p,k`` for any weights ``w_k >= 0``: it is the optimum. Two passes
    over the samples (forward, then backward) compute it. ``method="nlp"`` solves the NLP with
    CasADi/IPOPT instead (the statement in the module docstring; the same optimum, and the
    way to go for an objective that is not monotone in the preload).
    """
    if method not in ("envelope", "nlp"):
        raise ValueError(f"method must be 'envelope' or 'nlp', got {method!r}")
    Fa = np.asarray(profile.axial_load_N, float)
    n = Fa.size
    dt = profile.dt_s
    if profile.speed_rpm is not None:
        weight = screw.drag_torque_Nm(1.0) * np.asarray(profile.speed_rpm) * 2.0 * math.pi / 60.0 * dt
        units = "J"
    else:
        weight = screw.drag_torque_Nm(1.0) * dt
        units = "N m s"
    required = spec.required_stiffness(Fa)
    margin = spec.preload_margin_N
    lift = spec.lift_off_margin * np.abs(Fa) / LIFT_OFF_RATIO
    F_lo = np.maximum(spec.bolt_preload_N, np.where(np.abs(Fa) > 0, lift + margin, lift))
    if np.any(F_lo > spec.max_preload_N):
        k = int(np.argmax(F_lo > spec.max_preload_N))
        raise ValueError(f"at t = {profile.time_s[k]:g} s the load {Fa[k]:g} N needs a preload of {F_lo[k]:.0f} N "
                         f"to keep both nuts loaded, above the stacks' reach of {spec.max_preload_N:.0f} N; "
                         f"raise the bolt preload or the stacks' drive, or lower the load.")
    k_fun = _rigidity_function(screw)
    k_map = k_fun.map(n)
    k_max = np.asarray(k_map(spec.max_preload_N - margin, Fa)).ravel()
    short = required - k_max
    if np.any(short > 0):
        k = int(np.argmax(short))
        raise ValueError(f"at t = {profile.time_s[k]:g} s the rigidity required ({required[k]:.0f} N/um) exceeds "
                         f"what the highest preload gives ({k_max[k]:.0f} N/um) by {short[k]:.0f} N/um; lower the "
                         f"stiffness requirement or choose a stiffer screw.")
    low = _least_preloads(k_map, Fa, required, F_lo, spec.max_preload_N, margin)
    constant = float(low.max())
    slew_step = spec.slew_N_per_s * np.diff(profile.time_s)
    if method == "envelope":
        F_opt = low.copy()
        for k in range(1, n):  # forward: the cones of the samples before
            F_opt[k] = max(F_opt[k], F_opt[k - 1] - slew_step[k - 1])
        for k in range(n - 2, -1, -1):  # backward: and of those after
            F_opt[k] = max(F_opt[k], F_opt[k + 1] - slew_step[k])
        status = "Solve_Succeeded (exact: the envelope of the slew cones)"
    else:
        F_opt, status = _schedule_nlp(k_map, Fa, required, weight, dt, F_lo, slew_step, spec, constant)
    rig = np.asarray(k_map(F_opt, Fa)).ravel()
    rig_c = np.asarray(k_map(constant, Fa)).ravel()
    return PreloadSchedule(
        profile=profile, spec=spec, preload_N=F_opt, constant_preload_N=constant, rigidity_N_per_um=rig,
        required_N_per_um=required, constant_rigidity_N_per_um=rig_c,
        friction_energy_J=float(np.dot(weight, F_opt)), constant_friction_energy_J=float(np.sum(weight) * constant),
        energy_units=units, status=status,
    )


def _schedule_nlp(k_map: ca.Function, Fa: Array, required: Array, weight: Array, dt: Array, F_lo: Array,
                  slew_step: Array, spec: ScheduleSpec, constant: float) -> tuple[Array, str]:
    """The schedule as the NLP of the module docstring, solved by CasADi/IPOPT from the best constant."""
    n, scale, margin = Fa.size, 1000.0, spec.preload_margin_N
    # ---- decision variables, objective, constraints, initial guess, solve ----
    y = ca.MX.sym("y", n)
    F = scale * y
    g_stiff = (k_map(ca.fmax(F.T - margin, 1.0), Fa.reshape(1, -1)).T - required) / 100.0
    g_slew = (F[1:] - F[:-1]) / scale
    # where the screw stands still the energy does not see the preload: a small time-weighted
    # drag term (1e-3 of the mean weight per second) takes it to its least value there
    tie = 1e-3 * float(np.sum(weight) / np.sum(dt)) * dt
    nlp = {"x": y, "f": ca.dot(ca.DM(weight + tie), F) / float(np.sum(weight)), "g": ca.vertcat(g_stiff, g_slew)}
    solver = ca.nlpsol("schedule", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                                 "ipopt.tol": 1e-9, "ipopt.max_iter": 1000})
    lbg = np.concatenate([np.zeros(n), -slew_step / scale])
    ubg = np.concatenate([np.full(n, np.inf), slew_step / scale])
    lbx, ubx = F_lo / scale, np.full(n, spec.max_preload_N / scale)
    out = solver(x0=np.full(n, constant / scale), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)  # the constant is feasible
    stats = solver.stats()
    if not stats["success"]:
        raise RuntimeError(f"the preload schedule NLP did not converge: {stats['return_status']}")
    return np.asarray(out["x"]).ravel() * scale, str(stats["return_status"])


def _least_preloads(k_map: ca.Function, Fa: Array, required: Array, F_lo: Array, F_max: float,
                    margin: float = 0.0) -> Array:
    """Each sample's least preload meeting its rows (the rigidity grows with the preload), by bisection
    on all samples at once to 2^-60 of the range. Their maximum is the best constant preload."""
    lo = F_lo.copy()
    hi = np.full_like(lo, F_max)
    ok_lo = np.asarray(k_map(lo - margin, Fa)).ravel() >= required
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ok = np.asarray(k_map(mid - margin, Fa)).ravel() >= required
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
    return np.where(ok_lo, F_lo, hi)
