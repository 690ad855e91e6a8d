"""Preview: the plan a loop that knows its reference ahead can follow, and the floors it is scored against.

A planned reference is known ahead. With a preview horizon ``P`` (``p`` samples) the controller may
start a change before it is due. What it can gain is bounded by the argument
:func:`~piezopreload.tuning.bounds.tracking_floor` makes for a causal controller: the force moves at most
``rate`` per second (the amplifier's slew times the steepest slope of force over voltage), and it
cannot leave its level before the command that knows of the change has come through the delay.
Without preview that is ``delay`` samples after the jump; with preview ``p - delay`` samples
*before* it. Over each jump the best force is then a ramp at full rate from the best admissible
start (centred on the jump when the preview allows), held inside the force the voltage range
reaches (:func:`~piezopreload.models.actuator.reach_N` at the upper limit, the bolt preload at 0 V).
:func:`preview_plan` computes that ramp per jump by searching the start (the same argument as the
causal floor, computed exactly on the sample grid, not a convex program); its RMS error is the
**preview floor** (with ``p = 0`` it is the causal floor, to rounding). The steepest slope holds
only far along a branch; the rig's own branch at full slew (:func:`branch_ramps`: just after a
reversal it is flat) gives each change's fastest path, a tighter floor for the nominal plant and the
**plan** the controller follows: the setpoint becomes the plan, and the feedforward reads the plan
ahead by the delay and the amplifier's lag (:func:`preview_feedforward`), as a previewed
``ff_extra``. With preview a change starts before its jump, so the plan itself scores where a score
"outside 0.1 s after each jump" counts. :func:`plan_preview` puts these together for one loop and
reference (:class:`Preview`): what iterative learning control (:mod:`piezopreload.tuning.learning`)
starts from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from piezopreload.core._typing import Array, IntArray
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Plant, Rig, reach_N
from piezopreload.models.closedloop import Interpolation, Reference
from piezopreload.models.controller import OUTPUT_MAX_V, Controller
from piezopreload.tuning.bounds import tracking_floor

__all__ = ["AFTER_CHANGE_S", "PLAN_SLEW_FRACTION", "advance", "PreviewPlan", "Preview", "plan_preview",
           "default_preview_s", "feedforward_lead", "branch_ramps", "preview_plan", "ramp_plan", "causal_floor",
           "preview_feedforward"]


#: the transport after a jump the after-change error leaves out (as the validation's criteria)
AFTER_CHANGE_S = 0.1
# the planned ramps' share of the slew: on the paper's rig and trajectory 0.85 tracks best (whole-trajectory
# RMS after 10 P-type iterations 0.741 N at 1.0, 0.706 at 0.95, 0.678 at 0.9, 0.657 at 0.85, 0.690 at 0.75)
PLAN_SLEW_FRACTION = 0.85

def advance(x: Array, samples: int, fill: str = "hold") -> Array:
    """``x`` read ``samples`` ahead along its last axis (``y[k] = x[k + samples]``); past the end the last
    value is held (``fill="hold"``, a plan's last level) or 0 (``"zero"``, the lifted shift of the laws)."""
    x = np.asarray(x, float)
    if samples < 0:
        raise InputError(f"advance: samples must be >= 0, got {samples}")
    if samples == 0:
        return x.copy()
    m = min(samples, x.shape[-1])
    tail = np.repeat(x[..., -1:], m, axis=-1) if fill == "hold" else np.zeros(x.shape[:-1] + (m,))
    return np.concatenate([x[..., samples:], tail], axis=-1)[..., : x.shape[-1]]


@dataclass(frozen=True, eq=False)
class PreviewPlan:
    """The best force any controller with this preview reaches under the slew and voltage limits.

    ``force_N`` is the planned force per sample; ``rms_N`` its RMS error against the reference
    (scored from the first change, as :meth:`ClosedLoopRun.tracking_error`): the preview floor.
    ``starts`` is, per jump, the last sample at the old level relative to the jump.
    """

    t_s: Array
    force_N: Array
    rms_N: float
    rate_N_per_s: float
    preview_s: float
    lead_samples: int
    starts: list[int]
    reach_N: tuple[float, float]
    interpolation: Interpolation = Interpolation.HOLD

    @property
    def setpoint(self) -> Reference:
        """The plan as a reference the loop can follow (one level per sample; ramped between them for a
        ramped reference's plan)."""
        return Reference(self.t_s[:-1], self.force_N[:-1], float(self.t_s[-1]), self.interpolation)

    def to_dict(self) -> dict[str, Any]:
        return {"rms_N": self.rms_N, "rate_N_per_s": self.rate_N_per_s, "preview_s": self.preview_s,
                "lead_samples": self.lead_samples, "starts_samples": self.starts, "reach_N": list(self.reach_N)}


def default_preview_s(params: Plant, reference: Reference) -> float:
    """The preview that plans every jump as well as any preview could: the delay and the amplifier's lag
    (the feedforward's lead, :func:`feedforward_lead`) plus the slew time of the largest jump; for a ramped
    reference the lead alone."""
    if reference.interpolation is not Interpolation.HOLD:  # a ramp: the lead alone (ramp_plan follows it exactly then)
        return feedforward_lead(params) * params.sample_period_s
    rate = tracking_floor(params, reference).rate_N_per_s
    jump = float(np.max(np.abs(np.diff(reference.levels_N)))) if reference.levels_N.size > 1 else 0.0
    return feedforward_lead(params) * params.sample_period_s + jump / rate


def feedforward_lead(params: Plant) -> int:
    """Samples the feedforward reads the plan ahead: the delay line, the D/A's sample and the amplifier's lag."""
    tau = 1.0 / (2.0 * np.pi * float(np.max(params.amp_bandwidth_Hz)))
    return int(params.delay_samples) + 1 + int(round(tau / params.sample_period_s))


def branch_ramps(params: Plant, levels_N: Array, u_max_V: float = OUTPUT_MAX_V,
                 slew_fraction: float = 1.0) -> list[Array]:
    """Per change of ``levels_N``, the fastest force path along the rig's own hysteresis branch.

    The quasi-static rig (:meth:`~piezopreload.models.actuator.Rig.quasi_static_loop`: the truth
    hysteresis, no creep, no amplifier lag) is driven from rest at 0 V through the levels with the
    voltage moving at the amplifier's slew, one sample at a time, until the force reaches each
    level (or the voltage its limit). Along a monotone branch the force is monotone in the
    voltage, so no command moves it faster: the path is the least-error ramp's shape for that
    change (just after a reversal the branch is flat, ``1 - alpha`` of the stroke's slope, so the
    ramp starts slowly). Returns one array per change: the force at each sample of its ramp,
    ending at the level (or where the voltage limit stops it). ``slew_fraction`` < 1 moves the voltage
    at that fraction of the slew: a path the loop can follow with authority to spare.
    """
    if not 0.0 < slew_fraction <= 1.0:
        raise InputError(f"slew_fraction must be in (0, 1], got {slew_fraction!r}")
    rig = Rig(params)
    step = float(params.slew_V_per_s) * params.sample_period_s * slew_fraction
    state, v = None, 0.0
    f_now = float(np.min(params.bolt_preload_N))
    ramps = []
    for target in np.asarray(levels_N, float)[1:]:
        direction = 1.0 if target > f_now else -1.0
        n_max = int(np.ceil(u_max_V / step)) + 1
        path = np.clip(v + direction * step * np.arange(1, n_max + 1), 0.0, u_max_V)
        f, _ = rig.quasi_static_loop(path, state)
        reached = np.flatnonzero((f - target) * direction >= 0)
        k = int(reached[0]) + 1 if reached.size else int(np.argmax(path == path[-1])) + 1
        f, state = rig.quasi_static_loop(path[:k], state)
        v = float(path[k - 1])
        ramp = np.concatenate([[f_now], f])
        ramp = np.clip(ramp, min(f_now, target), max(f_now, target))
        ramps.append(ramp[1:] if ramp.size > 1 else ramp)
        f_now = float(f[-1]) if not reached.size else float(target)
    return ramps


def preview_plan(params: Plant, reference: Reference, preview_s: float, *, u_max_V: float = OUTPUT_MAX_V,
                 lead_samples: int | None = None, ramps: list[Array] | None = None,
                 after_change_weight: float = 0.0) -> PreviewPlan:
    """The preview floor and the planned force (see the module docstring).

    Per jump the force ramps at ``rate`` (:func:`~piezopreload.tuning.bounds.tracking_floor`'s)
    from a last sample at the old level ``s`` samples after the jump, ``s`` searched over
    ``[lead - p, lead]`` (``p`` the preview in samples; ``lead`` the delay, the default, for the
    floor, or :func:`feedforward_lead` for the plan a controller can follow); the levels are held
    inside what the voltage range reaches. The jumps' ramps must not overlap (holds longer than a
    ramp and the preview). ``ramps`` (one force path per change, :func:`branch_ramps`) replaces
    the straight ramps at the one steepest rate by the rig's own branch at full slew.
    ``after_change_weight`` ``w`` places each ramp to least ``whole + w * outside``: the squared error
    of every sample plus ``w`` times that of the samples outside :data:`AFTER_CHANGE_S` after the
    jump (the after-change score). 0 is the whole-trajectory floor; a larger ``w`` starts the ramps
    later, trading whole-trajectory error for error after the jumps.
    """
    if not (np.isfinite(preview_s) and preview_s >= 0):
        raise InputError(f"preview_s must be a finite number >= 0, got {preview_s!r}")
    if not (np.isfinite(after_change_weight) and after_change_weight >= 0):
        raise InputError(f"after_change_weight must be a finite number >= 0, got {after_change_weight!r}")
    if reference.interpolation is not Interpolation.HOLD:
        return ramp_plan(params, reference, preview_s, u_max_V=u_max_V, lead_samples=lead_samples)
    dt = params.sample_period_s
    lead = int(params.delay_samples) if lead_samples is None else int(lead_samples)
    p = int(round(preview_s / dt))
    floor = tracking_floor(params, reference)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n, dtype=np.float64) * dt
    r = reference.at(t)
    lo, hi = float(np.min(params.bolt_preload_N)), float(np.min(reach_N(Rig(params), u_max_V)))
    levels = np.clip(reference.levels_N, lo, hi)
    force = np.full(n, levels[0])
    k_jumps = np.searchsorted(t, reference.times_s[1:] - 1e-12)
    after = int(round(AFTER_CHANGE_S / dt))
    starts = []
    prev_end = 0
    for j, k in enumerate(k_jumps):
        old, new = levels[j], levels[j + 1]
        size = abs(new - old)
        rho = floor.rate_N_per_s * dt
        path = None if ramps is None else ramps[j]
        if path is None:
            n_ramp = int(np.ceil(size / rho - 1e-12)) if size > 0 else 0
        else:  # the rig's own path: its samples, then the level (held where the voltage limit stopped it)
            n_ramp = path.size
            new = float(path[-1])
            size = abs(new - old)
        best: tuple[float, int] | None = None
        for s in range(lead - p, lead + 1):
            s0 = int(k) + s
            if s0 < prev_end:
                continue
            # from the jump when the ramp starts after it
            m = np.arange(max(min(s0, int(k)), 0), min(s0 + n_ramp + 1, n))
            sq = (r[m] - _ramp(m, s0, old, new, rho, path)) ** 2
            err = float(np.sum(sq) + after_change_weight * np.sum(sq[(m < k) | (m >= k + after)]))
            if best is None or err < best[0]:
                best = (err, s)
        if best is None:
            raise InputError(f"the reference's change at {reference.times_s[j + 1]:g} s comes "
                             "before the previous one's ramp can end; hold each level longer than the "
                             "slew time and the preview")
        s0 = int(k) + best[1]
        m = np.arange(max(s0, 0), n)  # to the end: the next jump's ramp overwrites from its start
        force[m] = _ramp(m, s0, old, new, rho, path)
        starts.append(best[1])
        prev_end = min(s0 + n_ramp + 1, n)
    scored = t >= reference.times_s[1] if reference.times_s.size > 1 else np.ones(n, bool)
    rms = float(np.sqrt(np.mean((r[scored] - force[scored]) ** 2)))
    return PreviewPlan(t, force, rms, floor.rate_N_per_s, float(preview_s), lead, starts, (lo, hi))


def ramp_plan(params: Plant, reference: Reference, preview_s: float, *, u_max_V: float = OUTPUT_MAX_V,
              lead_samples: int | None = None) -> PreviewPlan:
    """The plan and the preview floor of a ramped (piecewise linear) reference.

    A ramp has no jump to slew across: what the loop's delay costs is the lag at each change of
    slope. The force at sample ``k`` is decided by a command sent ``lead`` samples before it (the
    delay, the default, for the floor; :func:`feedforward_lead` for the plan a controller
    follows); with ``p`` samples of preview that command knows the reference up to ``k - lead + p``.
    Where the preview covers the lead (``p >= lead``) the plan is the reference itself; short of
    it, the best the loop can do is extrapolate the reference's last known slope over the
    ``d = lead - p`` samples it does not know, ``r[k - d] + d (r[k - d] - r[k - d - 1])``. The plan
    is held inside the force the voltage range reaches and, where the reference is steeper than
    :func:`~piezopreload.tuning.bounds.tracking_floor`'s rate, moves toward it at that rate. Its RMS
    error against the reference (from the first point on, as ``tracking_error`` scores) is the
    floor; with ``p = 0`` the causal floor of a ramped reference (:func:`causal_floor`).
    """
    dt = params.sample_period_s
    lead = int(params.delay_samples) if lead_samples is None else int(lead_samples)
    p = int(round(preview_s / dt))
    d = max(lead - p, 0)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n, dtype=np.float64) * dt
    r = reference.at(t)
    # the steepest rate the force can move (tracking_floor's, which depends on the rig alone; one 1 N step asks it)
    rate = float(tracking_floor(params, Reference(np.array([0.0, dt]), np.array([0.0, 1.0]), 2 * dt)).rate_N_per_s)
    known = np.concatenate([np.full(d, r[0]), r[: n - d]]) if d else r.copy()
    before = np.concatenate([np.full(d + 1, r[0]), r[: n - d - 1]])
    target = known + d * (known - before)
    lo, hi = float(np.min(params.bolt_preload_N)), float(np.min(reach_N(Rig(params), u_max_V)))
    target = np.clip(target, lo, hi)
    step = rate * dt
    force = target.copy()
    if np.any(np.abs(np.diff(target)) > step):  # steeper than the force can move: follow at the rate
        for k in range(1, n):
            force[k] = force[k - 1] + np.clip(target[k] - force[k - 1], -step, step)
    scored = t >= reference.times_s[1] if reference.times_s.size > 1 else np.ones(n, bool)
    rms = float(np.sqrt(np.mean((r[scored] - force[scored]) ** 2)))
    return PreviewPlan(t, force, rms, rate, float(preview_s), lead, [], (lo, hi), interpolation=Interpolation.LINEAR)


def causal_floor(params: Plant, reference: Reference) -> float:
    """The causal floor (RMS, N) of ``reference``: :func:`~piezopreload.tuning.bounds.tracking_floor` over a
    held reference's jumps, the extrapolated slope's lag (:func:`ramp_plan` without preview) on a ramped one."""
    if reference.interpolation is Interpolation.HOLD:
        return float(tracking_floor(params, reference).rms_N)
    return ramp_plan(params, reference, 0.0).rms_N


def _ramp(m: IntArray, s0: int, old: float, new: float, rho: float, path: Array | None) -> Array:
    """The force at samples ``m`` of a change from ``old`` to ``new`` whose last sample at ``old`` is ``s0``:
    a straight ramp of ``rho`` per sample, or ``path`` (the rig's own, sample by sample) then held."""
    if path is None:
        return old + np.sign(new - old) * np.minimum((m - s0) * rho, abs(new - old))
    return np.where(m <= s0, old, path[np.clip(m - s0 - 1, 0, path.size - 1)])


def preview_feedforward(controller: Controller, plan: Array, lead: int) -> Array:
    """The previewed ``ff_extra``: the inverse P-I of the plan read ``lead`` samples ahead, less the
    controller's own feedforward of the plan now (which it adds itself); 0 without a feedforward."""
    if controller.feedforward is None or lead == 0:
        return np.zeros_like(plan)
    inverse = controller.feedforward
    ahead = np.asarray(inverse(advance(plan, lead), inverse.initial_state()), float)
    now = np.asarray(inverse(plan, inverse.initial_state()), float)
    return ahead - now


@dataclass(frozen=True, eq=False)
class Preview:
    """What a loop with preview follows over a reference, and the floors it is scored against.

    ``plan`` is the planned force (each change along the rig's own branch at ``slew_fraction`` of
    the slew for a held reference, :func:`branch_ramps`), ``setpoint`` the reference the
    controller follows (the plan; the reference itself without preview), ``target_N`` the force
    per sample learning aims at and ``ff_extra_V`` the previewed feedforward (:func:`preview_feedforward`,
    read ``lead_samples`` ahead): the signal of trial 0. ``floor_N`` is the preview floor (the
    steepest slope), ``branch_floor_N`` the floor along the rig's own branch at full slew and
    ``causal_floor_N`` the floor without preview.
    """

    reference: Reference
    preview_s: float
    plan: PreviewPlan
    setpoint: Reference
    target_N: Array
    ff_extra_V: Array
    lead_samples: int
    floor_N: float
    branch_floor_N: float
    causal_floor_N: float
    slew_fraction: float
    after_change_weight: float

    @property
    def t_s(self) -> Array:
        return self.plan.t_s

    def shifted_reference(self) -> Reference:
        """The reference with each jump moved ahead by the preview: scored from there, a change's whole transition
        (from the preview before the jump to :data:`AFTER_CHANGE_S` after it) is left out."""
        ref = self.reference
        if not (self.preview_s > 0 and ref.interpolation is Interpolation.HOLD):
            return ref
        return Reference(np.concatenate([[0.0], np.maximum(ref.times_s[1:] - self.preview_s, 1e-9)]), ref.levels_N,
                         ref.duration_s)

    def to_dict(self) -> dict[str, Any]:
        return {"preview_s": self.preview_s, "plan_rms_N": self.plan.rms_N,
                "feedforward_lead_samples": self.lead_samples, "preview_floor_N": self.floor_N,
                "preview_floor_branch_N": self.branch_floor_N, "causal_floor_N": self.causal_floor_N,
                "plan_slew_fraction": self.slew_fraction, "after_change_weight": self.after_change_weight}


def plan_preview(params: Plant, controller: Controller, reference: Reference, preview_s: float | None = None, *,
                 after_change_weight: float = 0.0, slew_fraction: float = PLAN_SLEW_FRACTION) -> Preview:
    """The plan, the setpoint, the previewed feedforward and the floors of ``controller`` on
    ``params`` over ``reference``.

    ``preview_s`` None takes :func:`default_preview_s`, 0 none (the setpoint is then the reference and
    the feedforward gets no lead). ``after_change_weight`` places each planned change
    (:func:`preview_plan`); ``slew_fraction`` is the share of the slew the planned ramps use (the rest
    is the loop's authority to correct with).
    """
    if params.batch_shape:
        raise InputError("plan_preview: give one plant (the nominal), not a batch")
    preview = default_preview_s(params, reference) if preview_s is None else float(preview_s)
    u_max = controller.gains.u_max_V
    floor = preview_plan(params, reference, preview, u_max_V=u_max)
    lead = feedforward_lead(params) if preview > 0 else 0
    held = reference.interpolation is Interpolation.HOLD  # a ramped reference has no jumps to slew across
    branch = preview_plan(params, reference, preview, u_max_V=u_max,
                          ramps=branch_ramps(params, reference.levels_N, u_max)
                          ) if held else floor
    plan = preview_plan(params, reference, preview, u_max_V=u_max, lead_samples=max(lead, params.delay_samples),
                        ramps=branch_ramps(params, reference.levels_N, u_max, slew_fraction) if held else None,
                        after_change_weight=after_change_weight)
    target = plan.force_N if preview > 0 else reference.at(plan.t_s)
    return Preview(reference, preview, plan, plan.setpoint if preview > 0 else reference, target,
                   preview_feedforward(controller, target, lead), lead, floor.rms_N, branch.rms_N,
                   causal_floor(params, reference), slew_fraction, after_change_weight)
