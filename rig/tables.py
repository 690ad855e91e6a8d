"""The rig's tables of a study file: ``[export]`` (the controllers' formats) and ``[rig_run]`` (how the
validated gains run on the rig executor, with the interlocks' settings), as frozen records whose fields
declare their keys (type, default, unit, range, doc: :func:`piezopreload.core.config.key`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from piezopreload.artifacts.gainset import REFERENCES
from piezopreload.core.config import Invalid, Table, key
from piezopreload.rig.export import FORMATS

__all__ = ["ExportTable", "RigRunPlan", "RIG_RUN_REFERENCES"]

#: what ``[rig_run] reference`` may name besides a CSV: the gain set's references, or the design's schedule
RIG_RUN_REFERENCES = (*REFERENCES, "schedule")


@dataclass(frozen=True)
class ExportTable(Table):
    """[export]: the formats the validated gain set is written in."""

    formats: tuple[str, ...] = key(FORMATS, "the export formats", choices=FORMATS)


@dataclass(frozen=True)
class RigRunPlan(Table):
    """[rig_run]: how ``piezopreload run`` runs the validated gains on the rig executor."""

    backend: str = key("sim", "the rig backend (sim: the simulated rig; a hardware plug-in's name)")
    reference: str = key("step", "what the rig plays: step, trajectory, schedule (the design's preload schedule, "
                         "where the plant is the study's design) or a time_s,force_N CSV relative to the study file")
    realtime: bool | None = key(None, "run at the loop's rate in real time (not set: unless the backend is sim)")
    seed: int = key(0, "the simulated rig's noise seed", ge=0)
    force_max_N: float | None = key(None, "the interlock's highest force (not set: the executor's default)",
                                    unit="N", gt=0)
    ramp_s: float | None = key(None, "the ramp to the reference's first level (not set: the executor's default)",
                               unit="s", gt=0)
    missed_streak: int | None = key(None, "missed deadlines in a row that trip the interlock (not set: the "
                                    "executor's default)", ge=1)

    def check(self) -> None:
        if self.reference not in RIG_RUN_REFERENCES and not self.reference.lower().endswith(".csv"):
            raise Invalid("reference", f"must be {', '.join(RIG_RUN_REFERENCES)} or a time_s,force_N .csv file, got "
                                       f"{self.reference!r}")

    def safety(self) -> dict[str, float | None]:
        return {"force_max_N": self.force_max_N, "ramp_s": self.ramp_s, "missed_streak": self.missed_streak}

    def resolved(self) -> RigRunPlan:
        """The plan with ``realtime`` decided where it is not given: the simulated rig may run back to back,
        anything else runs in real time."""
        return self if self.realtime is not None else replace(self, realtime=self.backend != "sim")
