"""The rig's tables of a study file: ``[export]`` (the controllers' formats) and ``[rig_run]`` (how the
validated gains run on the rig executor, with the interlocks' settings), as frozen records with their
keys as fields.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

from piezopreload.artifacts.gainset import REFERENCES
from piezopreload.core.config import Table
from piezopreload.core.errors import InputError
from piezopreload.rig.export import FORMATS

__all__ = ["ExportTable", "RigRunPlan", "RIG_RUN_REFERENCES"]

#: what ``[rig_run] reference`` may name besides a CSV: the gain set's references, or the design's schedule
RIG_RUN_REFERENCES = (*REFERENCES, "schedule")


@dataclass(frozen=True)
class ExportTable(Table):
    """[export]: the formats the validated gain set is written in."""

    formats: tuple[str, ...] = FORMATS

    def check(self, fail: Callable[[str, str], InputError]) -> None:
        """Every format is one :data:`FORMATS` names; ``fail(key, message)`` makes the error."""
        for f in self.formats:
            if f not in FORMATS:
                raise fail("export.formats", f"has {f!r}; expected some of {', '.join(FORMATS)}")


@dataclass(frozen=True)
class RigRunPlan(Table):
    """[rig_run]: how ``piezopreload run`` runs the validated gains on the rig."""

    backend: str = "sim"
    reference: str = "step"          # step, trajectory, or a time_s,force_N CSV (relative to the study file)
    realtime: bool | None = None     # None: real time unless the backend is the simulated rig
    seed: int = 0
    force_max_N: float | None = None
    ramp_s: float | None = None
    missed_streak: int | None = None

    def safety(self) -> dict[str, float | None]:
        return {"force_max_N": self.force_max_N, "ramp_s": self.ramp_s, "missed_streak": self.missed_streak}

    def checked(self, fail: Callable[[str, str], InputError]) -> RigRunPlan:
        """The plan checked, ``realtime`` decided where it is not given; ``fail(key, message)`` makes the error."""
        if self.reference not in RIG_RUN_REFERENCES and not self.reference.lower().endswith(".csv"):
            raise fail("rig_run.reference", f"must be step, trajectory or a time_s,force_N .csv file (or schedule, where "
                                            f"the plant is the study's design), got {self.reference!r}")
        for key, low in (("force_max_N", 0.0), ("ramp_s", 0.0)):
            if getattr(self, key) is not None and not getattr(self, key) > low:
                raise fail(f"rig_run.{key}", f"must be > {low:g}, got {getattr(self, key)!r}")
        if self.missed_streak is not None and self.missed_streak < 1:
            raise fail("rig_run.missed_streak", f"must be >= 1, got {self.missed_streak!r}")
        if self.seed < 0:
            raise fail("rig_run.seed", f"must be >= 0, got {self.seed!r}")
        # the simulated rig may run back to back when the study says so; anything else runs in real time
        return self if self.realtime is not None else RigRunPlan(**{**asdict(self), "realtime": self.backend != "sim"})
