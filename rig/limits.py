"""A run's limits: every interlock's number and where it came from, the stall limit, the reference held to them.

:func:`run_limits` gathers the :class:`~piezopreload.rig.interlocks.Safety` of one run, in this
order of precedence, and records each value's source:

1. an override: the command line's ``--force-max-N``, ``--force-low-margin-N``, ``--ramp-s``,
   ``--stall-limit-s`` (or a study's ``[rig_run]`` when its rig stage runs);
2. the gain set's :class:`~piezopreload.artifacts.gainset.RigInterlocks`: its study's
   ``[rig_run]`` settings, carried with the gains;
3. derived from the gain set's plant where neither says (a gain set written before gain sets
   carried them: :func:`~piezopreload.rig.tables.default_interlocks`);

and from the gain set's plant and gains always: the command range (the gains' output range
within the stacks'), the bolt preload, the sensor's range (its A/D's). The stall limit is the
plant's (:func:`~piezopreload.rig.stall.derive_stall_limit`), or shorter where an override or
the study asks for less, or where the simulated rig's watchdog would cut the output sooner; a
longer one than the plant tolerates is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.rigrun import SafetySources, StallLimit
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Plant, Rig, reach_N
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller
from piezopreload.rig.interlocks import Safety
from piezopreload.rig.stall import derive_stall_limit
from piezopreload.rig.tables import INTERLOCK_KEYS, default_interlocks

__all__ = ["RunLimits", "run_limits", "check_reference", "study_values", "plant_of", "OVERRIDE_OPTIONS", "check_fit",
           "FIT_TOLERANCE"]

#: the command-line option of each overridable key
OVERRIDE_OPTIONS = {"force_max_N": "--force-max-N", "force_low_margin_N": "--force-low-margin-N", "ramp_s": "--ramp-s",
                    "stall_limit_s": "--stall-limit-s"}
_DEFAULTS = {f.name: f.default for f in fields(Safety)}


@dataclass(frozen=True)
class RunLimits:
    """The limits a run uses (``safety``), where each came from (``sources``) and how the stall limit was derived."""

    safety: Safety
    sources: SafetySources
    stall: StallLimit


def study_values(gain_set: GainSet) -> tuple[dict[str, float | None], dict[str, str]]:
    """The gain set's study's interlock settings, or the plant's defaults for a gain set that carries none."""
    carried = gain_set.rig_interlocks
    if carried is not None:
        values = {k: getattr(carried, k) for k in INTERLOCK_KEYS}
        return values, {k: f"the gain set: {carried.sources.get(k, 'its study')}" for k in INTERLOCK_KEYS}
    values, sources = default_interlocks(plant_of(gain_set))
    note = " (the gain set carries no [rig_run] settings)"
    return {**values, "stall_limit_s": None}, {**{k: v + note for k, v in sources.items()}, "stall_limit_s": "not set"}


def plant_of(gain_set: GainSet) -> Plant:
    """The gain set's plant; an :class:`InputError` where it names none."""
    if gain_set.plant is None:
        raise InputError("field 'plant.rig' is missing: the gain set does not name its plant; write it again with "
                         "'piezopreload tune'")
    return gain_set.plant


def _plant_values(controller: Controller, gain_set: GainSet) -> tuple[dict[str, float], dict[str, str]]:
    """What the gain set's plant and gains fix: the command range, the safe level, the bolt preload, the sensor."""
    g, plant = controller.gains, plant_of(gain_set)
    values = {"v_min_V": max(g.u_min_V, float(plant.stack.v_min_V)),
              "v_max_V": min(g.u_max_V, float(plant.stack.v_max_V)),
              "safe_V": max(g.u_min_V, 0.0), "bolt_preload_N": float(plant.bolt_preload_N),
              "sensor_min_N": -float(plant.adc_full_scale_N),
              "sensor_max_N": float(plant.adc_full_scale_N) - float(plant.adc_lsb_N)}
    sources = {"v_min_V": "the gains' output range within the plant's stacks' voltage range",
               "v_max_V": "the gains' output range within the plant's stacks' voltage range",
               "safe_V": "0 V, or the gains' lowest output where that is above it",
               "bolt_preload_N": "the gain set's plant", "sensor_min_N": "the gain set's plant's A/D range",
               "sensor_max_N": "the gain set's plant's A/D range (its top code)"}
    return values, sources


def _stall(plant_stall: StallLimit, asked: float | None, asked_source: str, watchdog_s: float | None) -> StallLimit:
    """The stall limit used: the plant's, or less where asked (never more), or the watchdog's timeout if shorter."""
    out = plant_stall
    if asked is not None:
        if asked > plant_stall.limit_s:
            raise InputError(f"{asked_source}: a stall limit of {asked:g} s exceeds what the plant tolerates "
                             f"({plant_stall.limit_s:g} s: {plant_stall.how}); give at most that")
        out = replace(out, limit_s=float(asked), source=asked_source)
    if watchdog_s is not None and watchdog_s < out.limit_s:
        out = replace(out, limit_s=float(watchdog_s),
                      source=f"the simulated rig's watchdog timeout ({watchdog_s:g} s): it cuts the output sooner")
    return out


def run_limits(gain_set: GainSet, controller: Controller, reference: Reference, reference_name: str, *,
               overrides: dict[str, float | None] | None = None, override_source: str = "the command line",
               ff_extra_V: np.ndarray | None = None, seed: int = 0, watchdog_s: float | None = None,
               checked: tuple[tuple[Reference, str], ...] = ()) -> RunLimits:
    """The run's :class:`RunLimits` (see the module docstring); an :class:`InputError` says what is inconsistent.

    ``reference`` (with ``ff_extra_V``) is what the loop runs, the run the stall limit is derived
    on; each ``(reference, shown)`` of ``checked`` is held to the force range first
    (:func:`check_reference`), before anything is computed on it.
    """
    values: dict[str, Any] = {k: _DEFAULTS[k] for k in ("slew_V_per_s", "stale_after_s")}
    sources = {k: "the executor's default" for k in values}
    plant_values, plant_sources = _plant_values(controller, gain_set)
    values.update(plant_values)
    sources.update(plant_sources)
    study, study_sources = study_values(gain_set)
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    unknown = sorted(set(given) - set(INTERLOCK_KEYS))
    if unknown:
        raise InputError(f"interlocks: '{unknown[0]}' cannot be overridden; the keys are {', '.join(INTERLOCK_KEYS)}")
    for key in ("force_max_N", "force_low_margin_N", "ramp_s"):
        if key in given:
            values[key], sources[key] = float(given[key]), f"{override_source} ({OVERRIDE_OPTIONS[key]})"
        else:
            values[key], sources[key] = float(study[key]), study_sources[key]  # type: ignore[arg-type]
    values["stall_limit_s"] = _DEFAULTS["stall_limit_s"]
    try:
        safety = Safety(**values)
    except (TypeError, ValueError) as exc:
        raise InputError(f"interlocks: {exc}") from None
    for ref, shown in checked:
        check_reference(ref, shown, safety, gain_set)
    plant_stall = derive_stall_limit(plant_of(gain_set), controller, reference, force_low_N=safety.force_low_N,
                                     force_max_N=safety.force_max_N, v_range=(safety.v_min_V, safety.v_max_V),
                                     reference_name=reference_name, ff_extra_V=ff_extra_V, seed=seed)
    asked: float | None
    if "stall_limit_s" in given:
        asked, asked_source = float(given["stall_limit_s"]), f"{override_source} (--stall-limit-s)"
    else:
        asked, asked_source = study["stall_limit_s"], study_sources["stall_limit_s"]
    stall = _stall(plant_stall, asked, asked_source, watchdog_s)
    sources["stall_limit_s"] = stall.source
    return RunLimits(replace(safety, stall_limit_s=stall.limit_s), SafetySources(**sources), stall)


def check_reference(reference: Reference, shown: str, limits: Safety, gain_set: GainSet) -> None:
    """Refuse, before arming, a reference outside the interlocks' force range or the plant's reach.

    A level must lie strictly inside the force interlocks (above the bolt preload less the
    margin, below ``force_max_N``: at either limit the run would trip at once), and within what
    the gain set's plant's stacks reach over their voltage range (creep settled,
    :func:`~piezopreload.models.actuator.reach_N`). A CSV's level is named by its line (the
    header is line 1).
    """
    lo, hi = limits.force_low_N, limits.force_max_N
    plant = plant_of(gain_set)
    rig = Rig(plant)
    tol = 3.0 * plant.adc_lsb_N
    v_lo, v_hi = plant.stack.v_min_V, plant.stack.v_max_V
    reach = (float(reach_N(rig, v_lo)) - tol, float(reach_N(rig, v_hi)) + tol)
    csv = shown.lower().endswith(".csv")
    for j, level in enumerate(reference.levels_N.tolist()):
        where = f"{shown}:{j + 2}: field 'force_N'" if csv else f"the reference '{shown}', level {j + 1}"
        if not math.isfinite(level) or not lo < level < hi:
            raise InputError(f"{where}: {level:g} N is outside the rig's safe force range ({lo:g} N, {hi:g} N) "
                             "(the bolt preload less the margin, force_max_N); refused before arming")
        if not reach[0] <= level <= reach[1]:
            raise InputError(f"{where}: {level:g} N is beyond what the gain set's plant reaches between "
                             f"its stacks' {v_lo:g} V and {v_hi:g} V ({reach[0]:.4g}..{reach[1]:.4g} N); "
                             "refused before arming")


# --------------------------------------------------------------------------------------
# a gain set pushed to a running rig: do its limits fit the interlocks the rig was armed with?
# --------------------------------------------------------------------------------------
#: the relative tolerance a pushed gain set's limit is compared with the armed one's: a limit derived from the design
#: (a force the stacks reach, a stall limit from the plant's drift) agrees far closer on the same plant; a value
#: written by hand to four significant digits is within it
FIT_TOLERANCE = 1e-3

#: the limits fixed by the plant and the executor: a gain set for the same plant has the same
_SAME = ("bolt_preload_N", "sensor_min_N", "sensor_max_N", "slew_V_per_s", "stale_after_s")


def _misfit(key: str, a: Safety, p: RunLimits, armed_sources: SafetySources) -> str:
    """The sentence that says why the armed limit ``key`` does not fit the pushed one."""
    pa, pp, src_a, src_p = getattr(a, key), getattr(p.safety, key), getattr(armed_sources, key), getattr(p.sources, key)
    if key == "force_max_N":
        return (f"the pushed gain set's limits trip the force above {pp:g} N ({src_p}), this rig trips only above "
                f"{pa:g} N ({src_a})")
    if key == "force_low_margin_N":
        return (f"the pushed gain set's limits trip the force below {a.bolt_preload_N - pp:g} N (the bolts' "
                f"{a.bolt_preload_N:g} N less {pp:g} N: {src_p}), this rig trips only below {a.bolt_preload_N - pa:g} "
                f"N ({src_a})")
    if key == "stall_limit_s":
        return (f"the pushed controller tolerates the output held {pp * 1e3:.4g} ms without an update on this rig's "
                f"reference ({src_p}), this rig trips only after {pa * 1e3:.4g} ms ({src_a})")
    return (f"the pushed gain set's study ramps the rig down over {pp:g} s on a stop ({src_p}), this rig over {pa:g} s "
            f"({src_a})")


def check_fit(armed: Safety, armed_sources: SafetySources, pushed: RunLimits,
              tol: float = FIT_TOLERANCE) -> list[str]:
    """Refuse a pushed gain set whose limits a running rig armed with ``armed`` cannot keep; the notes of the limits
    it keeps that are stricter than the pushed set's.

    ``pushed`` are the limits the rig would arm with for the pushed gain set (:func:`run_limits` on the rig's
    reference, with its command line's overrides). They fit when the armed rig is at least as strict (within
    ``tol``, relative): it trips the force no later (``force_max_N``, ``force_low_margin_N``) and the output held
    no longer (``stall_limit_s``); it ramps down over the same time (``ramp_s``); and it commands the same range
    (``v_min_V``, ``v_max_V``, ``safe_V``: a command clamped otherwise than in the validation, or outside the
    new range at the switch, would not be bumpless). A running rig's interlocks do not change; an
    :class:`InputError` says which limit does not fit and what to do.
    """
    p = pushed.safety
    same = next((k for k in _SAME if not math.isclose(getattr(armed, k), getattr(p, k), rel_tol=1e-12)), None)
    if same is not None:
        raise InputError(f"the pushed gain set's {same} is {getattr(p, same):g}, this rig's {getattr(armed, same):g}: "
                         "it is not for this rig's plant")
    span = armed.v_max_V - armed.v_min_V
    if not all(math.isclose(getattr(armed, k), getattr(p, k), rel_tol=tol, abs_tol=tol * span)
               for k in ("v_min_V", "v_max_V", "safe_V")):
        raise InputError(f"the pushed gain set commands {p.v_min_V:g} to {p.v_max_V:g} V (safe level {p.safe_V:g} V), "
                         f"this rig was armed for {armed.v_min_V:g} to {armed.v_max_V:g} V (safe level "
                         f"{armed.safe_V:g} V): its command would be clamped otherwise than in its validation and "
                         "could jump at the switch; serve the rig with this gain set instead")
    notes = []
    for key in ("force_max_N", "force_low_margin_N", "stall_limit_s", "ramp_s"):
        a, b = getattr(armed, key), getattr(p, key)
        # the armed limit stops the rig no later than the pushed gain set asks; the ramp is the one it asks
        fits = math.isclose(a, b, rel_tol=tol) if key == "ramp_s" else a <= b * (1.0 + tol)
        if not fits:
            option = OVERRIDE_OPTIONS[key]
            raise InputError(f"{_misfit(key, armed, pushed, armed_sources)}. A running rig's interlocks stay as it "
                             f"was armed: serve the rig with this gain set, or start it with {option} {b:g}")
        if not math.isclose(a, b, rel_tol=tol):
            notes.append(f"{key}: the rig keeps {a:g} ({getattr(armed_sources, key)}), stricter than the pushed gain "
                         f"set's {b:g} ({getattr(pushed.sources, key)})")
    return notes
