"""The study's specification: a TOML file parsed once into typed tables, its plant, and what the tables make.

A study names its plant's hardware (``[rig]``), the controller's starting gains, the feedforward's
identification experiment, the references, the simulation settings, the ball-screw design
(``[ballscrew]``, ``[feed_drive]``, ``[duty]``, ``[design]``, ``[schedule]``), the plant
(``[plant]``: the design's, or ``[rig]`` itself), the shift's heat and growth (``[thermal]``) and the
one-command study's ``[tuning]``, ``[validation]``, ``[learning]``, ``[export]`` and ``[rig_run]``. Every key
is declared once on its table's dataclass (:mod:`piezopreload.tables`) and checked on load: an unknown key, a
wrong type or an out-of-range value is an :class:`~piezopreload.core.errors.InputError` naming the file, the
key's line and its path. A key the designed plant sets is refused where the plant is the
design: a study never ignores what it is given.

A :class:`StudySpec` is the parsed study and nothing else: it solves nothing and keeps nothing solved. The steps
that take it (the design, the feedforward's identification, the tuning, learning, tracking the schedule) are the
functions of :mod:`piezopreload.steps`, which keep what they solve (the design's optimum, the plant every control
step runs on) in a :class:`~piezopreload.steps.Solved`; :class:`piezopreload.study.Study` is the subclass that
offers them as methods (``study.plant``, ``study.design()``, ``study.tune()``, ...).

>>> spec = StudySpec.load("paper2021")
>>> spec.name, spec.plant_from_design, spec.rig.bolt_preload_N
('paper2021', False, 25.0)
>>> type(spec.replace(rig={"bolt_preload_N": 30.0})).__name__       # a changed copy is of the same class
'StudySpec'
"""

from __future__ import annotations

import copy
import hashlib
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self, TypedDict, TypeVar

from piezopreload.artifacts.manifest import StudyRef
from piezopreload.artifacts.validation import Criteria
from piezopreload.core.config import Lines, Table, read_toml, toml_text
from piezopreload.core.errors import InputError
from piezopreload.core.records import TableOf
from piezopreload.design.plant import DESIGNED_FIELDS
from piezopreload.design.preload import DesignSpec
from piezopreload.design.study import design_spec_from_tables
from piezopreload.design.tables import (
    BallscrewTable,
    DesignTable,
    DutyTable,
    FeedDriveTable,
    PlantTable,
    ScheduleTable,
    ThermalTable,
)
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import TIME_UNITS, PIDGains
from piezopreload.models.metrics import Signal
from piezopreload.progress import ProgressLike, say_of
from piezopreload.rig.tables import ExportTable, RigRunPlan
from piezopreload.tables import (
    CONTROLLER,
    DESIGN_TABLES,
    FEEDFORWARD,
    REQUIRED_TABLES,
    RIG,
    STUDY_TABLES,
    PublishedTable,
    ReferenceTables,
    SimulationTable,
    StudyTable,
)
from piezopreload.tuning.feedforward import LoopExcitation
from piezopreload.tuning.pid import TuningSpec
from piezopreload.tuning.tables import TUNING, VALIDATION, LearningTable

if TYPE_CHECKING:  # learning loads its solvers when a study learns, not when one is read
    pass

__all__ = ["StudySpec", "default_study", "paper_study", "shipped_studies", "DEFAULT_STUDY", "PAPER_STUDY"]

DEFAULT_STUDY = "machine_axis"  # the whole system: the designed preload system is the plant
PAPER_STUDY = "paper2021"       # the paper's rig and gains
Say = Callable[[str], None]
S = TypeVar("S", bound="StudySpec")


def _stderr(message: str) -> None:
    """A study's progress where its caller gives none: a line on standard error.

    Parameters
    ----------
    message : str
        The progress line, printed after ``piezopreload:``.
    """
    print(f"piezopreload: {message}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class _Source:
    """Where a study came from, for messages: ``fail`` names the file, the line of a key and the key."""

    shown: str
    lines: Lines
    folder: Path

    def fail(self, key_path: str, message: str) -> InputError:
        line = self.lines.of(key_path)
        return InputError(f"{self.shown}:{line}: '{key_path}' {message}" if line
                          else f"{self.shown}: '{key_path}' {message}")


# --------------------------------------------------------------------------------------
# the study
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StudySpec:
    """A loaded, validated study: its tables (typed, as in the file) and what the tables make; nothing solved.

    What a script holds is its subclass :class:`~piezopreload.study.Study` (:func:`~piezopreload.study.load_study`),
    which adds the steps that take a study as methods (``design``, ``tune``, ``learn``, ``simulate``, ``run``, ...:
    the functions of :mod:`piezopreload.steps` and of the application layer) and keeps what they solve (``plant``);
    the pipeline and those steps take any :class:`StudySpec`. Read one with :meth:`load`, a changed copy with
    :meth:`replace`. The ``[design]`` table is ``design_table``, the ``[plant]`` table ``plant_table``.
    """

    path: str
    sha256: str
    name: str
    title: str
    rig: Plant
    controller: PIDGains
    feedforward: LoopExcitation
    reference: ReferenceTables
    simulation: SimulationTable
    tuning: TuningSpec
    validation: Criteria
    export: ExportTable
    rig_run: RigRunPlan
    ballscrew: BallscrewTable | None
    feed_drive: FeedDriveTable | None
    duty: DutyTable | None
    design_table: DesignTable | None
    schedule: ScheduleTable | None
    plant_table: PlantTable | None
    learning: LearningTable | None
    published: PublishedTable | None
    where: _Source = field(repr=False)
    source_text: bytes = field(repr=False)  # the file as read, or as :meth:`replace` wrote it
    given: dict[str, Any] = field(repr=False)  # the tables and keys the file gives, as it gives them
    description: str = ""
    thermal: ThermalTable | None = None  # [thermal]: the shift's heat, temperature and growth (the system stage)
    say: Say = field(default=_stderr, repr=False, compare=False)  # progress where a step is given none

    @classmethod
    def load(cls, study: str | Path | None = None, *, progress: ProgressLike | None = None) -> Self:
        """Read and validate a study: None for the default (``machine_axis``), a shipped study's name
        (``"paper2021"``), or a file.

        Parameters
        ----------
        study : str or Path, optional
            The study file, or a shipped study's name; None: the default study.
        progress : ProgressLike, optional
            What the study says where a step is given no progress of its own (solving the design for the plant,
            say): a function given each line, or a :class:`~piezopreload.progress.Progress`; default: a line on
            standard error.

        Returns
        -------
        StudySpec
            The study, of the class this is called on (:func:`piezopreload.study.load_study` gives a
            :class:`~piezopreload.study.Study`).
        """
        if study is None:
            path = default_study()
        elif isinstance(study, str) and not study.endswith(".toml") and study in shipped_studies():
            path = shipped_studies()[study]
        else:
            path = Path(study)
        data, lines, raw = read_toml(path, "study file")
        shown = str(path)
        return _build(data, _Source(shown, lines, Path(shown).parent), shown, raw, say_of(progress) or _stderr, cls)

    @property
    def references(self) -> dict[str, Reference]:
        """The step and the staircase its ``[reference]`` tables make (:meth:`ReferenceTables.references
        <piezopreload.tables.ReferenceTables.references>`), made each time: nothing is kept beside the tables."""
        return self.reference.references()

    @property
    def design_spec(self) -> DesignSpec | None:
        """The design its ``[ballscrew]``, ``[design]``, ``[feed_drive]``, ``[duty]`` and ``[thermal]`` tables make
        (None: no ``[ballscrew]``), made each time from the tables (checked when the study was read)."""
        return design_spec_of_tables(self)

    def __repr__(self) -> str:
        plant = "its design" if self.plant_from_design else "its [rig]"
        published = "; published numbers: " + self.published.source if self.published is not None else ""
        return f"Study({self.name!r}: {self.title or 'untitled'}; plant: {plant}{published}; file {self.path})"

    def _repr_html_(self) -> str:
        import html

        rows = [("name", self.name), ("title", self.title), ("file", self.path),
                ("plant", "the designed preload system ([plant] from_design)" if self.plant_from_design else "[rig]"),
                ("step", " -> ".join(f"{x:g}" for x in self.references["step"].levels_N) + " N"),
                ("trajectory", " -> ".join(f"{x:g}" for x in self.references["trajectory"].levels_N) + " N"),
                ("published numbers", self.published.source if self.published is not None else "none declared")]
        body = "".join(f"<tr><td>{k}</td><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
        return f"<p><b>Study</b></p><table>{body}</table>"

    # ---- the tables --------------------------------------------------------------------------
    @property
    def ref(self) -> StudyRef:
        """Which study this is, as the artifacts name it: its file, its SHA-256 and its name."""
        return StudyRef(self.path, self.sha256, self.name)

    @property
    def folder(self) -> Path:
        """The study file's folder: the files it names are relative to it."""
        return self.where.folder

    @property
    def seed(self) -> int:
        """The noise seed of the study's simulations (``[simulation] seed``)."""
        return self.simulation.seed

    @property
    def band_N(self) -> float:
        """The error band settling is read in, in N (``[simulation] band_N``)."""
        return self.simulation.band_N

    @property
    def signal(self) -> Signal:
        """What the step numbers are read on (``[simulation] signal``): ``measured_N``, the sensor's reading, or
        ``force_N``, the true force.
        """
        return self.simulation.signal

    def resolve(self, relative: str | None) -> Path | None:
        """A file the study names (``feedforward.data``, ``schedule.profile``,
        ``rig_run.reference``), from its folder.

        Parameters
        ----------
        relative : str or None
            The file's path as the study names it, relative to the study's folder (an absolute path stays as it is).

        Returns
        -------
        Path or None
            The file's path from the study's folder; None where ``relative`` is None.
        """
        return None if relative is None else self.folder / relative

    def files(self) -> dict[str, Path]:
        """The input files the study names, by key (``feedforward.data``, ``schedule.profile``,
        ``rig_run.reference``, ``tuning.warm_start``).

        Returns
        -------
        dict of str to Path
            Each input file the study names, by its key, resolved from the study's folder; a key the study leaves unset
            (or a rig run's reference that is no CSV file) is left out.
        """
        named = {"feedforward.data": self.feedforward.data,
                 "schedule.profile": None if self.ballscrew is None or self.schedule is None else self.schedule.profile,
                 "rig_run.reference": (self.rig_run.reference if self.rig_run.reference.lower().endswith(".csv")
                                       else None),
                 "tuning.warm_start": self.tuning.warm_start}
        return {key: self.folder / rel for key, rel in named.items() if rel is not None}

    def check_files(self) -> None:
        """Refuse a study whose named files are missing, naming the key and its line."""
        for key, path in self.files().items():
            if not path.is_file():
                raise self.where.fail(key, f"names {path}, which is not a file; give a path relative to the study file")

    def tables(self) -> dict[str, Any]:
        """The study's tables as the file holds them, every key with its value (defaults filled): a stage's key.

        Returns
        -------
        dict
            ``study`` (name, title, description) and each table the study has, by name, as the file would hold it.
        """
        out: dict[str, Any] = {"study": {"name": self.name, "title": self.title, "description": self.description}}
        for table in STUDY_TABLES:
            value, declared = getattr(self, _ATTRIBUTE.get(table, table), None), STUDY_TABLES[table]
            if isinstance(value, Table):
                out[table] = value.to_dict()
            elif isinstance(declared, TableOf) and value is not None:
                out[table] = declared.values(value)
        if self.plant_from_design:  # the design sets these: the plant's own, not [rig]'s
            out["rig"] = {k: v for k, v in out["rig"].items() if k not in DESIGNED_FIELDS}
        return out

    def replace(self, **changes: dict[str, Any] | None) -> Self:
        """A validated copy with some keys changed: ``study.replace(rig={"noise_N": 0.5})``.

        Each argument names a table (``reference={"step": {"final_N": 80.0}}`` for a nested one) and
        holds the keys to change; a key (or a table) given as None is removed. The copy is checked as a
        file is: a bad key or value, or a key the designed plant sets where the plant is the design,
        raises :class:`InputError`.

        Parameters
        ----------
        **changes : dict or None
            By table's name, the keys to change (a dict, nested for a nested table), or None to remove the table.

        Returns
        -------
        StudySpec
            The changed study, checked as a file is.

        Raises
        ------
        InputError
            Where a name is not a table of the study, or a key or a value is refused.
        """
        data = copy.deepcopy(self.given)
        for table, keys in changes.items():
            if table not in STUDY_TABLES or not (keys is None or isinstance(keys, dict)):
                raise InputError(f"Study.replace: '{table}' must be a table of the study given as a dict of keys (or "
                                 f"None to remove it), got {keys!r}; tables: {', '.join(STUDY_TABLES)}")
            if keys is None:
                data.pop(table, None)
            else:
                _merge(data.setdefault(table, {}), keys)
        for table, rel in (("feedforward", "data"), ("schedule", "profile"), ("rig_run", "reference"),
                           ("tuning", "warm_start")):
            value = data.get(table, {}).get(rel)  # files stay where they were, wherever the copy is written
            if isinstance(value, str) and (table != "rig_run" or value.lower().endswith(".csv")):
                data[table][rel] = str(self.folder / value)
        where = _Source(f"{self.path} (replaced)", Lines(""), self.folder)
        return _build(data, where, self.path, toml_text(data).encode("utf-8"), self.say, type(self))

    def same_design(self, other: StudySpec) -> bool:
        """Whether ``other`` (a changed copy, say) has this study's design: the same design tables and objective.

        Parameters
        ----------
        other : StudySpec
            The other study.

        Returns
        -------
        bool
            True where a design solved for one is the other's.
        """
        objective = (other.design_table or DesignTable()).objective == (self.design_table or DesignTable()).objective
        mine = design_spec_of_tables(self)
        return mine is not None and design_spec_of_tables(other) == mine and objective

    def to_toml(self) -> str:
        """The study as a TOML file (the file itself when it was not changed).

        Returns
        -------
        str
            The study's TOML text.
        """
        return self.source_text.decode("utf-8")

    @property
    def controller_units(self) -> str:
        """The unit the file entered ``[controller]`` ``Ti`` and ``Td`` in (:attr:`controller` holds them in seconds).

        Returns
        -------
        str
            ``"seconds"`` or ``"minutes"`` (LabVIEW's), as the file's ``units`` says (``"seconds"`` where it says
            nothing).
        """
        entered = self.given.get("controller", {}).get(TIME_UNITS.key, TIME_UNITS.default)
        return str(entered)

    # ---- the plant ---------------------------------------------------------------------------
    @property
    def plant_from_design(self) -> bool:
        """Whether the plant is the designed preload system (``[plant] from_design``) rather than ``[rig]`` itself."""
        return self.plant_table is not None and self.plant_table.from_design

    @property
    def reference_range_N(self) -> tuple[float, float]:
        """The least and the largest force of the study's references (step and trajectory): what the feedforward
        must have been identified over."""
        levels = [self.references[k].levels_N for k in ("step", "trajectory")]
        return float(min(x.min() for x in levels)), float(max(x.max() for x in levels))

#: the attribute of each table whose name is taken (``study.design()`` is a method, ``study.plant`` the plant)
_ATTRIBUTE = {"design": "design_table", "plant": "plant_table"}


def _merge(into: dict[str, Any], changes: dict[str, Any]) -> None:
    for key, value in changes.items():
        if value is None:
            into.pop(key, None)
        elif isinstance(value, dict) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = list(value) if isinstance(value, tuple) else copy.deepcopy(value)


# --------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------
def shipped_studies() -> dict[str, Path]:
    """The studies that ship with the package, by name.

    Returns
    -------
    dict of str to Path
        Each shipped study's name (``paper2021``, ``machine_axis``) and its file.
    """
    root = resources.files("piezopreload.studies")
    return {p.name[:-5]: Path(str(p)) for p in root.iterdir() if p.name.endswith(".toml")}


def default_study() -> Path:
    """The default study's file as shipped with the package (the machine axis, the whole system)."""
    return shipped_studies()[DEFAULT_STUDY]


def paper_study() -> Path:
    """The paper's study as shipped with the package (the rig and gains of Zhang, Jin, Lin 2021)."""
    return shipped_studies()[PAPER_STUDY]


class _StudyTables(TypedDict):
    """A study file's tables, each checked against its declaration (:data:`STUDY_TABLES`, in its order); None for
    an optional table the file does not give."""

    study: StudyTable
    rig: Plant
    plant: PlantTable | None
    learning: LearningTable | None
    controller: PIDGains
    feedforward: LoopExcitation
    reference: ReferenceTables
    simulation: SimulationTable
    ballscrew: BallscrewTable | None
    feed_drive: FeedDriveTable | None
    duty: DutyTable | None
    design: DesignTable | None
    schedule: ScheduleTable | None
    thermal: ThermalTable | None
    tuning: TuningSpec
    validation: Criteria
    export: ExportTable
    rig_run: RigRunPlan
    published: PublishedTable | None


def _parse(data: dict[str, Any], where: _Source) -> _StudyTables:
    """Every table of the file checked against its declaration (``None`` for an optional table not given)."""
    for name, value in data.items():
        if name not in STUDY_TABLES:
            raise where.fail(name, f"is an unknown table; a study has: {', '.join(STUDY_TABLES)}")
        if not isinstance(value, dict):
            raise where.fail(name, f"must be a table ([{name}]), got {value!r}")
    for name in REQUIRED_TABLES:
        if name not in data:
            raise InputError(f"{where.shown}: the table [{name}] is missing")
    optional = (*DESIGN_TABLES, "learning", "published")  # None where not given; the others' keys all have defaults

    def table(name: str) -> Any:
        cls: Any = STUDY_TABLES[name]  # a Table's class (the tables read into domain types are read below)
        return cls.parse(data[name], where.fail, name) if name in data else (None if name in optional else cls())

    rig = RIG.parse(data["rig"], where.fail, "rig")  # [rig] read straight into the plant
    study, plant, learning = table("study"), table("plant"), table("learning")
    controller = CONTROLLER.parse(data["controller"], where.fail, "controller")  # [controller] into the gains
    reference = table("reference")
    feedforward = FEEDFORWARD.parse(data.get("feedforward", {}), where.fail, "feedforward")
    simulation: SimulationTable = table("simulation")
    ballscrew, feed_drive, duty, design = table("ballscrew"), table("feed_drive"), table("duty"), table("design")
    schedule, thermal = table("schedule"), table("thermal")
    # [tuning] and [validation] read straight into the tuning's and the validation's types, with the error band,
    # the output range and the seed the study's other tables give
    tuning = TUNING.parse(data.get("tuning", {}), where.fail, "tuning",
                          {"band_N": simulation.band_N, "u_min_V": controller.u_min_V, "u_max_V": controller.u_max_V})
    validation = VALIDATION.parse(data.get("validation", {}), where.fail, "validation",
                                  {"band_N": simulation.band_N, "seed": simulation.seed})
    return _StudyTables(
        study=study, rig=rig, plant=plant, learning=learning, controller=controller, feedforward=feedforward,
        reference=reference, simulation=simulation, ballscrew=ballscrew, feed_drive=feed_drive, duty=duty,
        design=design, schedule=schedule, thermal=thermal, tuning=tuning, validation=validation,
        export=table("export"), rig_run=table("rig_run"), published=table("published"))


def _refuse_ignored(data: dict[str, Any], where: _Source) -> None:
    """No key is ignored: where the plant is the design, the [rig] keys the design sets are refused; where it is
    [rig], the [plant] keys that only a designed plant uses are, and [thermal]. (Before [rig] is checked: its own
    rules may involve a refused key.)"""
    fail = where.fail
    if "plant" not in data:
        _refuse_thermal(data, fail)
        return
    plant = PlantTable.parse(data["plant"], fail, "plant")
    if plant.from_design:
        if "ballscrew" not in data:
            raise fail("plant.from_design", "= true needs the design's tables ([ballscrew], [design], ...) to make "
                                            "the plant from")
        for name in DESIGNED_FIELDS:
            if name in data.get("rig", {}):
                raise fail(f"rig.{name}", "is set by the design where [plant] from_design = true (the designed plant "
                                          f"takes it from the design's optimum): remove {name} from [rig], or set "
                                          "[plant] from_design = false to make [rig] the plant")
        return
    for name in data["plant"]:
        if name != "from_design":
            raise fail(f"plant.{name}", "applies to the designed plant only, and [plant] from_design = false makes "
                                        "[rig] the plant: remove it, or set from_design = true")
    _refuse_thermal(data, fail)


def _refuse_thermal(data: dict[str, Any], fail: Callable[[str, str], InputError]) -> None:
    """[thermal] is the budget of the designed system along its schedule: refused where [rig] is the plant."""
    if "thermal" in data:
        raise fail("thermal", "needs a study whose plant is its design ([plant] from_design = true, with the design's "
                              "tables): the shift's budget is that of the system along its schedule")


def _refuse_unreachable(validation: Criteria, controller: PIDGains,
                        fail: Callable[[str, str], InputError]) -> None:
    """A requirement the study's own clamp makes impossible to miss is refused: the controller clamps its command at
    ``[controller] u_max_V``, so a highest-command limit at or above it could not fail."""
    limit = validation.peak_voltage_max_V
    if limit is not None and limit >= controller.u_max_V:
        raise fail("validation.peak_voltage_max_V",
                   f"= {limit:g} V is at or above controller.u_max_V = {controller.u_max_V:g} V, the clamp on the "
                   "command: the highest command cannot exceed the clamp, so this requirement could not fail; set it "
                   "below controller.u_max_V (the headroom the loop must keep), or leave it out for no such "
                   "requirement")


def _build(data: dict[str, Any], where: _Source, path: str, text: bytes, say: Say, kind: type[S]) -> S:
    """The typed study from a file's tables; every value checked, errors naming the key and its line."""
    fail = where.fail
    _refuse_ignored(data, where)
    t = _parse(data, where)
    rig: Plant = t["rig"]
    c: PIDGains = t["controller"]
    sim: SimulationTable = t["simulation"]
    validation = t["validation"]
    _refuse_unreachable(validation, c, fail)
    _check_references(t["reference"], fail)
    design_spec = None if t["ballscrew"] is None else design_spec_from_tables(
        {**t, "design": t["design"] or DesignTable()}, fail)
    if t["thermal"] is not None and design_spec is not None:
        t["thermal"].against(design_spec.feed_drive, fail)
    if t["design"] is not None and "stiffness:growth" in t["design"].pareto and t["thermal"] is None:
        raise fail("design.pareto", "has stiffness:growth, which needs a [thermal] table (the shift the growth is read "
                                    "over)")
    meta: StudyTable = t["study"]
    return kind(
        path=path, sha256=hashlib.sha256(text).hexdigest(), name=meta.name or Path(path).stem, title=meta.title,
        description=meta.description, rig=rig, controller=c, feedforward=t["feedforward"], reference=t["reference"],
        simulation=sim, tuning=t["tuning"], validation=validation, export=t["export"],
        rig_run=t["rig_run"].resolved(), ballscrew=t["ballscrew"], feed_drive=t["feed_drive"], duty=t["duty"],
        design_table=t["design"], schedule=t["schedule"], plant_table=t["plant"], learning=t["learning"],
        published=t["published"], thermal=t["thermal"],
        where=where, source_text=text,
        given=copy.deepcopy(data), say=say)


def design_spec_of_tables(spec: StudySpec) -> DesignSpec | None:
    """The design a study's tables make (its ``[ballscrew]``, ``[design]``, ``[feed_drive]``, ``[duty]`` and
    ``[thermal]``); None where it has no ``[ballscrew]``.

    Parameters
    ----------
    spec : StudySpec
        The study.

    Returns
    -------
    DesignSpec or None
        Its design's specification.
    """
    if spec.ballscrew is None:
        return None
    return design_spec_from_tables({"ballscrew": spec.ballscrew, "design": spec.design_table or DesignTable(),
                                    "feed_drive": spec.feed_drive, "duty": spec.duty, "thermal": spec.thermal},
                                   spec.where.fail)


def _check_references(tables: ReferenceTables, fail: Callable[[str, str], InputError]) -> None:
    """Refuse reference tables that make no step or no staircase, naming the table."""
    try:
        tables.step.reference()
    except ValueError as exc:
        raise fail("reference.step", f"does not make a step: {exc}") from None
    try:
        tables.trajectory.reference()
    except ValueError as exc:
        raise fail("reference.trajectory", f"does not make a staircase: {exc}") from None
