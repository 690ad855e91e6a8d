"""The rig's tables of a study file: ``[export]`` (the controllers' formats) and ``[rig_run]`` (how the
validated gains run on the rig executor, with the interlocks' settings), as frozen records with their
keys as fields.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields

from piezopreload.artifacts.gainset import EXPORT_FORMATS, REFERENCES, RigInterlocks
from piezopreload.core.config import Table
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Rig, RigParams, reach_N
from piezopreload.rig.interlocks import Safety

__all__ = ["ExportTable", "RigRunPlan", "RIG_RUN_REFERENCES", "INTERLOCK_KEYS", "FORCE_MAX_FACTOR", "default_interlocks"]

#: the [rig_run] keys that set the interlocks (and the command-line options that override them)
INTERLOCK_KEYS = ("force_max_N", "force_low_margin_N", "ramp_s", "stall_limit_s")
#: a study that sets no force_max_N gets this times the force its stacks reach at their highest voltage
FORCE_MAX_FACTOR = 1.25

#: what ``[rig_run] reference`` may name besides a CSV: the gain set's references, or the design's schedule
RIG_RUN_REFERENCES = (*REFERENCES, "schedule")


@dataclass(frozen=True)
class ExportTable(Table):
    """[export]: the formats the validated gain set is written in."""

    formats: tuple[str, ...] = EXPORT_FORMATS

    def check(self, fail: Callable[[str, str], InputError]) -> None:
        """Every format is one :data:`EXPORT_FORMATS` names; ``fail(key, message)`` makes the error."""
        for f in self.formats:
            if f not in EXPORT_FORMATS:
                raise fail("export.formats", f"has {f!r}; expected some of {', '.join(EXPORT_FORMATS)}")


@dataclass(frozen=True)
class RigRunPlan(Table):
    """[rig_run]: how ``piezopreload run`` runs the validated gains on the rig."""

    backend: str = "sim"
    reference: str = "step"          # step, trajectory, or a time_s,force_N CSV (relative to the study file)
    realtime: bool | None = None     # None: real time unless the backend is the simulated rig
    seed: int = 0
    force_max_N: float | None = None         # None: FORCE_MAX_FACTOR x what the stacks reach (default_interlocks)
    force_low_margin_N: float | None = None  # None: the executor's default (Safety)
    ramp_s: float | None = None              # None: the executor's default (Safety)
    stall_limit_s: float | None = None       # None: the plant's (rig.stall); a value must not exceed it

    def safety(self) -> dict[str, float | None]:
        """The interlock keys the study sets (None: not set)."""
        return {key: getattr(self, key) for key in INTERLOCK_KEYS}

    def interlocks(self, plant: RigParams, source: str) -> RigInterlocks:
        """The interlock settings a gain set of this study carries: the keys the study sets (``source`` names the
        study), the others as :func:`default_interlocks` derives them for ``plant``."""
        values, sources = default_interlocks(plant)
        for key in INTERLOCK_KEYS:
            if getattr(self, key) is not None:
                values[key], sources[key] = float(getattr(self, key)), f"{source} [rig_run] {key}"
        return RigInterlocks(values["force_max_N"], values["force_low_margin_N"], values["ramp_s"],
                             values.get("stall_limit_s"), sources)

    def checked(self, fail: Callable[[str, str], InputError]) -> RigRunPlan:
        """The plan checked, ``realtime`` decided where it is not given; ``fail(key, message)`` makes the error."""
        if self.reference not in RIG_RUN_REFERENCES and not self.reference.lower().endswith(".csv"):
            raise fail("rig_run.reference", f"must be step, trajectory or a time_s,force_N .csv file (or schedule, where "
                                            f"the plant is the study's design), got {self.reference!r}")
        for key in INTERLOCK_KEYS:
            if getattr(self, key) is not None and not getattr(self, key) > 0.0:
                raise fail(f"rig_run.{key}", f"must be > 0, got {getattr(self, key)!r}")
        if self.seed < 0:
            raise fail("rig_run.seed", f"must be >= 0, got {self.seed!r}")
        # the simulated rig may run back to back when the study says so; anything else runs in real time
        return self if self.realtime is not None else RigRunPlan(**{**asdict(self), "realtime": self.backend != "sim"})


def default_interlocks(plant: RigParams) -> tuple[dict[str, float], dict[str, str]]:
    """The interlock settings for a study that sets none, and where each comes from.

    ``force_max_N``: :data:`FORCE_MAX_FACTOR` times the force the plant's stacks reach from
    rest at their highest voltage, creep settled (:func:`~piezopreload.models.actuator.reach_N`):
    a reading that far beyond what the stacks can push is a load the rig should not see or a
    broken sensor. ``force_low_margin_N`` and ``ramp_s``: the executor's defaults
    (:class:`~piezopreload.rig.interlocks.Safety`). No stall limit: the plant's applies.
    """
    defaults = {f.name: f.default for f in fields(Safety)}
    v_max = float(plant.stack.v_max_V)
    reach = float(reach_N(Rig(plant), v_max))
    values = {"force_max_N": FORCE_MAX_FACTOR * reach, "force_low_margin_N": float(defaults["force_low_margin_N"]),
              "ramp_s": float(defaults["ramp_s"])}
    sources = {"force_max_N": f"derived: {FORCE_MAX_FACTOR:g} x the {reach:.4g} N the plant's stacks reach at "
                              f"their {v_max:g} V",
               "force_low_margin_N": "the executor's default", "ramp_s": "the executor's default"}
    return values, sources
