"""The rig's tables of a study file: ``[export]`` (the controllers' formats) and ``[rig_run]`` (how the
validated gains run on the rig executor, with the interlocks' settings), as frozen records whose fields
declare their keys (type, default, unit, range, doc: :func:`piezopreload.core.config.key`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from piezopreload.artifacts.gainset import REFERENCES, RigInterlocks
from piezopreload.core.config import Invalid, Table, key
from piezopreload.models.actuator import Plant, Rig, reach_N
from piezopreload.rig.export import FORMATS
from piezopreload.rig.interlocks import Safety

__all__ = ["ExportTable", "RigRunPlan", "RIG_RUN_REFERENCES", "INTERLOCK_KEYS", "FORCE_MAX_FACTOR",
           "LOW_MARGIN_SHARE", "default_interlocks"]

#: the [rig_run] keys that set the interlocks (and the command-line options that override them)
INTERLOCK_KEYS = ("force_max_N", "force_low_margin_N", "ramp_s", "stall_limit_s")
#: a study that sets no force_max_N gets this times the force its stacks reach at their highest voltage
FORCE_MAX_FACTOR = 1.25
#: the share of the force the stacks reach that a reading may fall below the bolts' preload before the low-force
#: interlock trips, where the study sets no margin and this is more than the executor's default
LOW_MARGIN_SHARE = 0.01

#: what ``[rig_run] reference`` may name besides a CSV: the gain set's references, or the design's schedule
RIG_RUN_REFERENCES = (*REFERENCES, "schedule")


@dataclass(frozen=True)
class ExportTable(Table):
    """[export]: the formats the validated gain set is written in."""

    formats: tuple[str, ...] = key(FORMATS, "the export formats", choices=FORMATS)


@dataclass(frozen=True)
class RigRunPlan(Table):
    """[rig_run]: how ``piezopreload run`` runs the validated gains on the rig executor, and the interlocks' settings
    the gain set carries (the rig's limits come from the gain set's study: :meth:`interlocks`)."""

    backend: str = key("sim", "the rig backend (sim: the simulated rig; a hardware plug-in's name)")
    reference: str = key("step", "what the rig plays: step, trajectory, schedule (the design's preload schedule, "
                         "where the plant is the study's design) or a time_s,force_N CSV relative to the study file")
    realtime: bool | None = key(None, "run at the loop's rate in real time (not set: unless the backend is sim)")
    seed: int = key(0, "the simulated rig's noise seed", ge=0)
    force_max_N: float | None = key(None, "the interlock's highest force (not set: 1.25 x the force the stacks reach "
                                    "at their highest voltage)", unit="N", gt=0)
    force_low_margin_N: float | None = key(None, "the margin below the bolts' preload the force may fall to (not set: "
                                           "the larger of the executor's 10 N and 1 % of the force the stacks "
                                           "reach)", unit="N", gt=0)
    ramp_s: float | None = key(None, "the ramp down to the safe voltage on a stop (not set: the executor's default)",
                               unit="s", gt=0)
    stall_limit_s: float | None = key(None, "the longest the loop may go without an update before it trips (not set: "
                                      "the plant's, from the force's drift with the voltage held; a value may only "
                                      "shorten it)", unit="s", gt=0)

    def check(self) -> None:
        if self.reference not in RIG_RUN_REFERENCES and not self.reference.lower().endswith(".csv"):
            raise Invalid("reference", f"must be {', '.join(RIG_RUN_REFERENCES)} or a time_s,force_N .csv file, got "
                                       f"{self.reference!r}")

    def safety(self) -> dict[str, float | None]:
        """The interlock keys the study sets (None: not set)."""
        return {name: getattr(self, name) for name in INTERLOCK_KEYS}

    def interlocks(self, plant: Plant, source: str) -> RigInterlocks:
        """The interlock settings a gain set of this study carries: the keys the study sets (``source`` names the
        study), the others as :func:`default_interlocks` derives them for ``plant``."""
        values, sources = default_interlocks(plant)
        for name in INTERLOCK_KEYS:
            if getattr(self, name) is not None:
                values[name], sources[name] = float(getattr(self, name)), f"{source} [rig_run] {name}"
        return RigInterlocks(values["force_max_N"], values["force_low_margin_N"], values["ramp_s"],
                             values.get("stall_limit_s"), sources)

    def resolved(self) -> RigRunPlan:
        """The plan with ``realtime`` decided where it is not given: the simulated rig may run back to back,
        anything else runs in real time."""
        return self if self.realtime is not None else replace(self, realtime=self.backend != "sim")


def default_interlocks(plant: Plant) -> tuple[dict[str, float], dict[str, str]]:
    """The interlock settings for a study that sets none, and where each comes from.

    ``force_max_N``: :data:`FORCE_MAX_FACTOR` times the force the plant's stacks reach from
    rest at their highest voltage, creep settled (:func:`~piezopreload.models.actuator.reach_N`):
    a reading that far beyond what the stacks can push is a load the rig should not see or a
    broken sensor. ``force_low_margin_N``: the executor's default
    (:class:`~piezopreload.rig.interlocks.Safety`), or :data:`LOW_MARGIN_SHARE` of that reach where that is more
    (the default is sized for a rig of a few hundred newtons; on an axis of thousands, a reading 10 N below the
    bolts' preload is the loop's noise and undershoot, not a preload lost, and it leaves a stalled loop a few
    milliseconds). ``ramp_s``: the executor's default. No stall limit: the plant's applies.
    """
    defaults = Safety()
    v_max = float(plant.stack.v_max_V)
    reach = float(reach_N(Rig(plant), v_max))
    low = max(float(defaults.force_low_margin_N), LOW_MARGIN_SHARE * reach)
    values = {"force_max_N": FORCE_MAX_FACTOR * reach, "force_low_margin_N": low, "ramp_s": float(defaults.ramp_s)}
    sources = {"force_max_N": f"derived: {FORCE_MAX_FACTOR:g} x the {reach:.4g} N the plant's stacks reach at "
                              f"their {v_max:g} V",
               "force_low_margin_N": ("the executor's default" if low == defaults.force_low_margin_N else
                                      f"derived: {LOW_MARGIN_SHARE:.0%} of the {reach:.4g} N the plant's stacks reach"),
               "ramp_s": "the executor's default"}
    return values, sources
