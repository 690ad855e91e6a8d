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
formulas on CasADi expressions) in the machine: the nut law's table rigidity times
``ScheduleSpec.in_machine_factor`` (the vendors' 0.8 for the nut's mounting, ``[ballscrew]
rigidity_in_machine_factor``) and the lift-off row the catalogues' rule, as in the design
(design/preload.py). Where the speed is zero the friction energy is zero; a
profile without speeds weighs the drag torque by time instead (N m s). The schedule is
non-causal (it ramps up before a cut begins, as a CNC program knows its next pass); the
slew limit decides how early.

With a margin ``m_k`` the stiffness and lift-off rows of sample ``k`` hold at ``F_p,k - m_k``: the
room the force loop's tracking error needs there. ``ScheduleSpec.preload_margin_N`` is a margin
everywhere; ``local_margin_N`` (one per sample) adds one only where the loop needs it
(:mod:`piezopreload.design.system` derives it from the loop's shortfall below each sample's
requirement, sample by sample). A local margin the stacks' reach cannot give is capped there and
recorded (``PreloadSchedule.margin_short_N``): the requirement no schedule within the stacks' force
can meet with the loop's error, and by how much.

The rigidity grows with the preload, so each sample's rows are one lower bound on F_p,k, and
with the slew rows the optimum is the upper envelope of the slew cones on those bounds: exact,
in two passes (:func:`schedule_preload`; ``method="nlp"`` solves the NLP above with IPOPT, to
the same optimum).

The comparison is the best constant preload: the least constant F_p meeting the same
requirements at every sample, with no margin (a constant reference is held within the sensor
noise; the margins are the room a changing reference needs). Its friction energy against the
schedule's is the saving. The types (:class:`LoadProfile`, :class:`ScheduleSpec`,
:class:`PreloadSchedule`) are the design artifact's, :mod:`piezopreload.artifacts.schedule`.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from piezopreload.artifacts.schedule import LoadProfile, PreloadSchedule, ScheduleSpec
from piezopreload.core._typing import Array
from piezopreload.models.ballscrew import LIFT_OFF_RATIO, BallScrew, double_nut_rigidity, nut_forces
from piezopreload.models.ops import CASADI

__all__ = ["schedule_preload", "least_preload", "example_profile", "headroom_schedule"]


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


def _rigidity_function(screw: BallScrew, in_machine_factor: float = 1.0) -> ca.Function:
    """The double nut's rigidity in the machine (its table rigidity times ``in_machine_factor``) as a CasADi
    function of the preload and the axial load."""
    F, Fa = ca.SX.sym("F"), ca.SX.sym("Fa")
    c_h, s = screw.axial_constant_um, screw.structural_compliance_um_per_N
    f_loaded, f_unloaded = nut_forces(ca.fabs(Fa) / F, s * F ** (1.0 / 3.0) / c_h, CASADI)
    k = in_machine_factor * double_nut_rigidity(CASADI, c_h, s, screw.accuracy_factor, F * f_loaded, F * f_unloaded)
    return ca.Function("rigidity", [F, Fa], [k])


def _weights(screw: BallScrew, profile: LoadProfile) -> tuple[Array, str]:
    """Each sample's friction energy per newton of preload: the drag torque per newton times the screw's angle
    over the sample's time (J/N); a profile without speeds weighs the time alone (N m s per N)."""
    dt = profile.dt_s
    if profile.speed_rpm is not None:
        return screw.drag_torque_Nm(1.0) * np.asarray(profile.speed_rpm) * 2.0 * math.pi / 60.0 * dt, "J"
    return screw.drag_torque_Nm(1.0) * dt, "N m s"


def _check_reach(k_map: ca.Function, profile: LoadProfile, spec: ScheduleSpec, required: Array, lift: Array) -> None:
    """Refuse a profile whose requirements (with the spec's margin) no preload within the stacks' reach meets."""
    Fa, margin = np.asarray(profile.axial_load_N, float), spec.preload_margin_N
    F_lo = np.maximum(spec.bolt_preload_N, np.where(profile.cutting, lift + margin, lift))
    if np.any(F_lo > spec.max_preload_N):
        k = int(np.argmax(F_lo > spec.max_preload_N))
        raise ValueError(f"at t = {profile.time_s[k]:g} s the load {Fa[k]:g} N needs a preload of {F_lo[k]:.0f} N "
                         f"to keep both nuts loaded, above the stacks' reach of {spec.max_preload_N:.0f} N; "
                         f"raise the bolt preload or the stacks' drive, or lower the load.")
    short = required - np.asarray(k_map(spec.max_preload_N - margin, Fa)).ravel()
    if np.any(short > 0):
        k = int(np.argmax(short))
        raise ValueError(f"at t = {profile.time_s[k]:g} s the rigidity required ({required[k]:.0f} N/um) exceeds "
                         f"what the highest preload gives ({required[k] - short[k]:.0f} N/um) by {short[k]:.0f} N/um; "
                         "lower the stiffness requirement or choose a stiffer screw.")


def _margins(spec: ScheduleSpec, needed: Array, local_margin_N: ArrayLike | None) -> tuple[Array, Array]:
    """Each sample's margin (the spec's everywhere plus the local one, capped where the stacks' reach cannot give
    it: at most ``F_max - needed``) and the local margin the reach could not give."""
    n = needed.size
    if local_margin_N is None:
        return np.full(n, spec.preload_margin_N), np.zeros(n)
    local = np.asarray(local_margin_N, float)
    if local.shape != (n,) or not np.all(np.isfinite(local)) or np.any(local < 0):
        raise ValueError(f"local_margin_N must hold one finite number >= 0 per sample ({n}), got shape {local.shape}.")
    given = np.minimum(local, np.maximum(spec.max_preload_N - needed - spec.preload_margin_N, 0.0))
    return spec.preload_margin_N + given, local - given


def least_preload(screw: BallScrew, spec: ScheduleSpec, axial_load_N: ArrayLike) -> Array:
    """The least preload meeting the schedule's requirements (rigidity, deflection, lift-off; no margin) under each
    load of ``axial_load_N``, within ``[bolt_preload_N, max_preload_N]`` (the top where even it does not)."""
    Fa = np.atleast_1d(np.asarray(axial_load_N, float))
    if Fa.size == 0:
        return np.zeros(0)
    lift = spec.lift_off_margin * np.abs(Fa) / LIFT_OFF_RATIO
    k_map = _rigidity_function(screw, spec.rigidity_factor).map(Fa.size)
    floor = np.minimum(np.maximum(spec.bolt_preload_N, lift), spec.max_preload_N)
    return _least_preloads(k_map, Fa, spec.required_stiffness(Fa), floor, spec.max_preload_N)


def schedule_preload(screw: BallScrew, profile: LoadProfile, spec: ScheduleSpec, method: str = "envelope",
                     local_margin_N: ArrayLike | None = None, heat: dict[str, Any] | None = None) -> PreloadSchedule:
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

    ``local_margin_N``: a margin per sample on top of the spec's (capped where the stacks' reach
    cannot give it, the rest recorded in ``margin_short_N``). The best constant preload is the
    margin-free one.

    ``heat``: the objective is the nut's friction heat over the cycle instead of the friction energy,
    ``sum_k P(F_p,k, n_k) dt_k`` (J), ``P`` :meth:`BallScrew.friction_heat_W` with these keywords (``model``,
    ``lubricant_vg``, ``seal_torque_Nm``, ``temperature_C``): the NLP minimises it; the envelope is its optimum too
    (the heat grows with the preload at every sample, under either model; the seals' part does not depend on it). The
    schedule still records its friction energy.
    """
    if method not in ("envelope", "nlp"):
        raise ValueError(f"method must be 'envelope' or 'nlp', got {method!r}")
    if heat is not None and profile.speed_rpm is None:
        raise ValueError("a heat objective needs the load profile's speed_rpm: the heat is the drag times the speed")
    Fa = np.asarray(profile.axial_load_N, float)
    n = Fa.size
    weight, units = _weights(screw, profile)
    required = spec.required_stiffness(Fa)
    lift = spec.lift_off_margin * np.abs(Fa) / LIFT_OFF_RATIO
    k_map = _rigidity_function(screw, spec.rigidity_factor).map(n)
    _check_reach(k_map, profile, spec, required, lift)
    needed = _least_preloads(k_map, Fa, required, np.maximum(spec.bolt_preload_N, lift), spec.max_preload_N)
    constant = float(needed.max())
    margin, short = _margins(spec, needed, local_margin_N)
    F_lo = np.maximum(spec.bolt_preload_N, np.where(profile.cutting, lift + margin, lift))
    low = _least_preloads(k_map, Fa, required, F_lo, spec.max_preload_N, margin)
    slew_step = spec.slew_N_per_s * np.diff(profile.time_s)
    if method == "envelope":
        F_opt = _slew_envelope(low, slew_step)
        status = "Solve_Succeeded (exact: the envelope of the slew cones)"
    else:
        objective = None if heat is None else _heat_objective(screw, profile, heat)
        F_opt, status = _schedule_nlp(k_map, Fa, required, weight, profile.dt_s, F_lo, slew_step, spec, margin,
                                      float(low.max()), objective)
    return PreloadSchedule(
        profile=profile, spec=spec, preload_N=F_opt, constant_preload_N=constant,
        rigidity_N_per_um=np.asarray(k_map(F_opt, Fa)).ravel(), required_N_per_um=required,
        constant_rigidity_N_per_um=np.asarray(k_map(constant, Fa)).ravel(),
        friction_energy_J=float(np.dot(weight, F_opt)), constant_friction_energy_J=float(np.sum(weight) * constant),
        energy_units=units, status=status, needed_N=needed, margin_N=margin, margin_short_N=short,
    )


def _slew_envelope(low: Array, slew_step: Array) -> Array:
    """The least schedule at or above ``low`` whose steps are within ``slew_step``: the upper envelope of the slew
    cones on ``low``, in two passes (forward: the cones of the samples before; backward: of those after)."""
    F = np.array(low, float)
    for k in range(1, F.size):
        F[k] = max(F[k], F[k - 1] - slew_step[k - 1])
    for k in range(F.size - 2, -1, -1):
        F[k] = max(F[k], F[k + 1] - slew_step[k])
    return F


def headroom_schedule(screw: BallScrew, plan: PreloadSchedule, factor: float, lead_s: float = 0.0) -> PreloadSchedule:
    """``plan`` with headroom: every sample the stacks drive above the bolts' preload at least ``factor`` times its
    planned level, the samples at the bolts' preload kept there (the stacks off), and the least such schedule within
    the stacks' slew (the envelope of the slew cones on those levels, as :func:`schedule_preload`'s): its plateaus
    are exactly ``factor`` times the plan's, its ramps start earlier. ``factor = 1`` gives ``plan`` back.

    ``lead_s``: the transitions advanced by this time: each sample takes the most of the raised levels over the
    next ``lead_s`` (a forward running maximum), so every rise begins ``lead_s`` earlier and every fall stays where
    it was: the room a force loop that lags its reference needs at the load's steps. A running maximum of a
    schedule within the slew is within it on uniform samples; the slew envelope is taken again for any other.

    The rigidity and the friction energy are those of the raised levels; the best constant preload, the
    requirements and the margins stay the plan's (the headroom is room above them). Raises ``ValueError`` where
    ``factor`` is below 1, ``lead_s`` below 0 or the raised levels pass the stacks' reach
    (``plan.spec.max_preload_N``).
    """
    if not (math.isfinite(factor) and factor >= 1.0):
        raise ValueError(f"a schedule's headroom must be a finite factor >= 1, got {factor!r}")
    if not (math.isfinite(lead_s) and lead_s >= 0.0):
        raise ValueError(f"a schedule's lead must be a finite time >= 0 s, got {lead_s!r}")
    if factor == 1.0 and lead_s == 0.0:
        return plan
    spec, profile = plan.spec, plan.profile
    F = np.asarray(plan.preload_N, float)
    slew_step = spec.slew_N_per_s * np.diff(profile.time_s)
    driven = spec.bolt_preload_N * (1.0 + 1e-9) < F
    raised = _slew_envelope(np.where(driven, factor * F, F), slew_step)
    if lead_s > 0.0:
        raised = _slew_envelope(_running_max_ahead(raised, np.asarray(profile.time_s, float), lead_s), slew_step)
    top = float(raised.max())
    if top > spec.max_preload_N * (1.0 + 1e-9):
        raise ValueError(f"a headroom of {factor:g} raises the schedule's top level to {top:.0f} N, above the "
                         f"stacks' reach of {spec.max_preload_N:.0f} N")
    Fa = np.asarray(profile.axial_load_N, float)
    k_map = _rigidity_function(screw, spec.rigidity_factor).map(Fa.size)
    weight, _ = _weights(screw, profile)
    lead = f", its transitions {1e3 * lead_s:.3g} ms earlier" if lead_s > 0.0 else ""
    return replace(plan, preload_N=raised, rigidity_N_per_um=np.asarray(k_map(raised, Fa)).ravel(),
                   friction_energy_J=float(np.dot(weight, raised)),
                   status=f"{plan.status}; headroom {factor:g} on the levels above the bolts' preload{lead}")


def _running_max_ahead(F: Array, t: Array, lead_s: float) -> Array:
    """Each sample's most of ``F`` over the samples from it to ``lead_s`` later (the last sample's own at the end)."""
    end = np.searchsorted(t, t + lead_s * (1.0 + 1e-12), side="right")
    return np.array([F[k:e].max() for k, e in enumerate(end)])


def _heat_objective(screw: BallScrew, profile: LoadProfile, heat: dict[str, Any]) -> ca.Function:
    """The cycle's friction heat (J) as a CasADi function of the preloads on the profile's samples."""
    F = ca.MX.sym("F", profile.time_s.size)
    power = screw.friction_heat_W(F, np.asarray(profile.speed_rpm, float), ops=CASADI, **heat)
    return ca.Function("heat", [F], [ca.dot(power, ca.DM(profile.dt_s))])


def _schedule_nlp(k_map: ca.Function, Fa: Array, required: Array, weight: Array, dt: Array, F_lo: Array,
                  slew_step: Array, spec: ScheduleSpec, margin: Array, start: float,
                  objective: ca.Function | None = None) -> tuple[Array, str]:
    """The schedule as the NLP of the module docstring, solved by CasADi/IPOPT from the constant ``start``
    (the largest of the samples' least preloads with their margins: feasible); ``objective`` a function of the
    preloads to minimise instead of the friction energy (the heat)."""
    n, scale = Fa.size, 1000.0
    # ---- decision variables, objective, constraints, initial guess, solve ----
    y = ca.MX.sym("y", n)
    F = scale * y
    g_stiff = (k_map(ca.fmax(F.T - ca.DM(margin).T, 1.0), Fa.reshape(1, -1)).T - required) / 100.0
    g_slew = (F[1:] - F[:-1]) / scale
    # where the screw stands still the energy does not see the preload: a small time-weighted
    # drag term (1e-3 of the mean weight per second) takes it to its least value there
    tie = 1e-3 * float(np.sum(weight) / np.sum(dt)) * dt
    if objective is None:
        f = ca.dot(ca.DM(weight + tie), F) / float(np.sum(weight))
    else:  # scaled by its value at the start; the tie term 1e-3 of the start's heat per newton, by time
        base = abs(float(objective(np.full(n, start)))) or 1.0
        f = (objective(F) + ca.dot(ca.DM(1e-3 * base / (start * float(np.sum(dt))) * dt), F)) / base
    nlp = {"x": y, "f": f, "g": ca.vertcat(g_stiff, g_slew)}
    solver = ca.nlpsol("schedule", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                                 "ipopt.tol": 1e-9, "ipopt.max_iter": 1000})
    lbg = np.concatenate([np.zeros(n), -slew_step / scale])
    ubg = np.concatenate([np.full(n, np.inf), slew_step / scale])
    lbx, ubx = F_lo / scale, np.full(n, spec.max_preload_N / scale)
    out = solver(x0=np.full(n, start / scale), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    stats = solver.stats()
    if not stats["success"]:
        raise RuntimeError(f"the preload schedule NLP did not converge: {stats['return_status']}")
    return np.asarray(out["x"]).ravel() * scale, str(stats["return_status"])


def _least_preloads(k_map: ca.Function, Fa: Array, required: Array, F_lo: Array, F_max: float,
                    margin: Array | float = 0.0) -> Array:
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
