"""The study file's schema: its tables, each a frozen record whose fields declare their keys once.

The tables of the design, the tuning and the rig live on their floors (:mod:`piezopreload.design.tables`,
:mod:`piezopreload.tuning.tables`, :mod:`piezopreload.rig.tables`); the ones here are the study's own:
``[study]``, ``[rig]`` (the plant's hardware), ``[controller]``, ``[feedforward]``, ``[reference.*]`` and
``[simulation]``. :data:`STUDY_TABLES` is the whole file's schema; :func:`study_keys_markdown` renders it
as the documentation's table of keys (``docs/study.md`` holds it).

Where the plant is the design (``[plant] from_design = true``) the design sets the ``[rig]`` keys
:data:`~piezopreload.design.plant.DESIGNED_FIELDS` names: a study that sets one too is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from piezopreload.core.config import Invalid, Table, key, keys_markdown
from piezopreload.core.records import TableOf
from piezopreload.design.plant import DESIGNED_FIELDS
from piezopreload.design.tables import (
    BallscrewTable,
    DesignTable,
    DutyTable,
    FeedDriveTable,
    PlantTable,
    ScheduleTable,
    ThermalTable,
)
from piezopreload.models.actuator import Plant, StackData
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import TIME_UNITS, PIDGains
from piezopreload.models.metrics import Signal
from piezopreload.rig.tables import ExportTable, RigRunPlan
from piezopreload.tuning.feedforward import LoopExcitation
from piezopreload.tuning.tables import TUNING, VALIDATION, LearningTable

__all__ = ["StudyTable", "STACK", "RIG", "CONTROLLER", "FEEDFORWARD", "StepTable",
           "TrajectoryTable", "ReferenceTables", "SimulationTable", "StepNumbers", "PublishedTable", "STUDY_TABLES",
           "REQUIRED_TABLES",
           "study_keys_markdown"]

@dataclass(frozen=True)
class StudyTable(Table):
    """[study]: the study's name and title, as the report and the artifacts give them."""

    name: str | None = key(None, "the study's name (not set: the file's name without .toml)")
    title: str = key("", "the study's title")
    description: str = key("", "a paragraph on what the study is for")


#: [rig.stack]: the stack type, read straight into :class:`~piezopreload.models.actuator.StackData`
STACK = TableOf(StackData, StackData.__doc__ or "")

#: [rig]: the plant's hardware, read straight into :class:`~piezopreload.models.actuator.Plant` (a key not given takes
#: the model's default; where the plant is the design, the keys the design sets are refused)
RIG = TableOf(Plant, Plant.__doc__ or "", nested=(("stack", STACK),))


#: [controller]: the study's starting gains, read straight into :class:`~piezopreload.models.controller.PIDGains`
#: (``Ti`` and ``Td`` entered in ``units``, held in seconds)
CONTROLLER = TableOf(PIDGains, "[controller]: the study's starting gains and the output range, read straight into "
                               "`PIDGains`: `Ti` and `Td` are entered in `units` (seconds, or LabVIEW's minutes, "
                               "converted to seconds as the file is read).", PIDGains.TABLE_KEYS, unit=TIME_UNITS)


#: [feedforward]: the loop measurement, read straight into :class:`~piezopreload.tuning.feedforward.LoopExcitation`
FEEDFORWARD = TableOf(LoopExcitation, LoopExcitation.__doc__ or "")


@dataclass(frozen=True)
class StepTable(Table):
    """[reference.step]: the step the study's step numbers are read on."""

    initial_N: float = key(25.0, "the level before the step", unit="N")
    final_N: float = key(60.0, "the level after it", unit="N")
    t_step_s: float = key(0.5, "when it steps", unit="s", gt=0)
    duration_s: float = key(10.0, "the run's length (after the step)", unit="s", gt=0)

    def check(self) -> None:
        if not self.duration_s > self.t_step_s:
            raise Invalid("duration_s",
                          f"must be after the step (t_step_s = {self.t_step_s:g} s), got {self.duration_s:g}")

    def reference(self) -> Reference:
        """The step this table describes.

        Returns
        -------
        Reference
            From ``initial_N`` to ``final_N`` at ``t_step_s``, ``duration_s`` long.
        """
        return Reference.step(self.initial_N, self.final_N, self.t_step_s, self.duration_s)


@dataclass(frozen=True)
class TrajectoryTable(Table):
    """[reference.trajectory]: the staircase the study's tracking numbers are read on."""

    initial_N: float = key(25.0, "the rest level", unit="N")
    levels_N: tuple[float, ...] = key((60.0, 80.0, 100.0, 80.0, 60.0), "the levels, each held hold_s", unit="N",
                                      min_length=1)
    hold_s: float = key(5.0, "how long each level is held", unit="s", gt=0)
    t_start_s: float = key(0.5, "when the first level starts", unit="s", gt=0)

    def reference(self) -> Reference:
        """The staircase this table describes.

        Returns
        -------
        Reference
            From ``initial_N`` through ``levels_N``, each held ``hold_s``, the first at ``t_start_s``.
        """
        return Reference.staircase(self.initial_N, list(self.levels_N), self.hold_s, self.t_start_s)


@dataclass(frozen=True)
class ReferenceTables(Table):
    """[reference]: the study's step and staircase (the stacks' share of the preload where the plant is a design)."""

    step: StepTable = key(StepTable(), "the step")
    trajectory: TrajectoryTable = key(TrajectoryTable(), "the staircase")

    def references(self) -> dict[str, Reference]:
        """The study's references, made from the tables each time they are asked for (nothing kept beside them).

        Returns
        -------
        dict of str to Reference
            ``step`` and ``trajectory``.
        """
        return {"step": self.step.reference(), "trajectory": self.trajectory.reference()}


@dataclass(frozen=True)
class SimulationTable(Table):
    """[simulation]: the noise seed, the error band and the signal the step numbers are read on."""

    seed: int = key(0, "noise seed of the simulations", ge=0)
    band_N: float = key(1.5, "the error band settling is read in", unit="N", gt=0)
    signal: Signal = key(Signal.MEASURED, "what the numbers are read on: the sensor's reading or the true force")


@dataclass(frozen=True)
class StepNumbers(Table):
    """[published.pid], [published.ff_pid]: one controller's published step numbers."""

    rise_s: float = key(None, "rise time", unit="s", gt=0, required=True)
    peak_s: float = key(None, "peak time", unit="s", gt=0, required=True)
    settling_s: float = key(None, "settling time", unit="s", gt=0, required=True)


@dataclass(frozen=True)
class PublishedTable(Table):
    """[published]: step numbers a publication reports for this study's rig and gains, which the report and
    ``reproduce`` set beside the simulation's (a study without the table compares with nothing published)."""

    source: str = key(None, "where the numbers are published", required=True)
    gains_label: str = key(None, "what the report calls the study's [controller] gains beside them", required=True)
    pid: StepNumbers = key(None, "PID alone", required=True)
    ff_pid: StepNumbers = key(None, "the feedforward with PID", required=True)

    def step(self) -> dict[str, dict[str, float]]:
        """The numbers by controller (``pid``, ``ff+pid``) and metric."""
        return {"pid": self.pid.to_dict(), "ff+pid": self.ff_pid.to_dict()}


#: the study file's tables, by name, in the order a file has them
STUDY_TABLES: dict[str, type[Table] | TableOf] = {
    "study": StudyTable, "rig": RIG, "plant": PlantTable, "learning": LearningTable,
    "controller": CONTROLLER, "feedforward": FEEDFORWARD, "reference": ReferenceTables,
    "simulation": SimulationTable, "ballscrew": BallscrewTable, "feed_drive": FeedDriveTable, "duty": DutyTable,
    "design": DesignTable, "schedule": ScheduleTable, "thermal": ThermalTable, "tuning": TUNING,
    "validation": VALIDATION, "export": ExportTable, "rig_run": RigRunPlan, "published": PublishedTable,
}
#: the tables every study has
REQUIRED_TABLES = ("rig", "controller")
#: the tables that are only read where the study has the design's ([ballscrew])
DESIGN_TABLES = ("ballscrew", "feed_drive", "duty", "design", "schedule", "plant", "thermal")


def study_keys_markdown() -> str:
    """Every key of a study file as Markdown tables (what ``docs/study.md`` includes): per table, each key's type,
    default, unit, range and doc, from the tables' declarations."""
    notes = {f"rig.{name}": "set by the design where `[plant] from_design = true`: refused there"
             for name in DESIGNED_FIELDS}
    return keys_markdown(STUDY_TABLES, notes)
