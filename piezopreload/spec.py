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

``study.plant`` is the plant every control step (identify, tune, simulate, learn, validate) runs
on: ``[rig]`` as given, or, where ``[plant] from_design = true``, the plant of the design's
optimum, solved once (saying so) and kept. What the study derives from its own tables (the design, the
feedforward's identification, the schedule's tracking and its learning) is here; the steps the application
layer composes (tuning, simulating, the pipeline, the sweep) are functions that take a :class:`StudySpec`, and
:class:`piezopreload.study.Study` is the subclass that offers them as methods.

>>> spec = StudySpec.load("paper2021")
>>> spec.name, spec.plant_from_design, spec.plant.bolt_preload_N
('paper2021', False, 25.0)
>>> type(spec.replace(rig={"bolt_preload_N": 30.0})).__name__       # a changed copy is of the same class
'StudySpec'
"""

from __future__ import annotations

import copy
import hashlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from dataclasses import replace as _replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Self, TypedDict, TypeVar, overload

from piezopreload.artifacts.design import DesignPoint, DesignRecord
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.manifest import StudyRef
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.schedule import PreloadSchedule
from piezopreload.artifacts.validation import Criteria
from piezopreload.core.config import Lines, Table, read_toml, toml_text
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.quantities import number, quantity
from piezopreload.core.records import TableOf
from piezopreload.core.tables import Record, read_record
from piezopreload.design.plant import DESIGNED_FIELDS
from piezopreload.design.preload import DesignInfeasible, DesignOptimum, DesignSpec, optimise
from piezopreload.design.sensitivity import sensitivity
from piezopreload.design.study import DesignResult, design_spec_from_tables, design_study, plan_schedule, read_profile
from piezopreload.design.system import SystemRun
from piezopreload.design.tables import (
    BallscrewTable,
    DesignTable,
    DutyTable,
    FeedDriveTable,
    PlantTable,
    ScheduleTable,
    ThermalTable,
)
from piezopreload.design.thermal import duty_growth_um, thermal_budget
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.progress import ProgressLike, say_of
from piezopreload.rig.tables import ExportTable, RigRunPlan
from piezopreload.tables import (
    DESIGN_TABLES,
    FEEDFORWARD,
    REQUIRED_TABLES,
    RIG,
    STUDY_TABLES,
    ControllerTable,
    PublishedTable,
    ReferenceTables,
    SimulationTable,
    StudyTable,
)
from piezopreload.tuning.feedforward import IdentifiedFeedforward, LoopExcitation, identify_feedforward, loop_covers
from piezopreload.tuning.pid import TuningSpec
from piezopreload.tuning.tables import TUNING, VALIDATION, LearningTable

if TYPE_CHECKING:  # learning loads its solvers when a study learns, not when one is read
    from piezopreload.schedule import ScheduleLearning
    from piezopreload.tuning.learning import LearningResult

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


class _Kept:
    """What a study derives at a cost and keeps: the design's optimum (solved once, or given by
    :meth:`StudySpec.with_design`), and from it the designed plant, the plant and the preload schedule."""

    def __init__(self, optimum: DesignOptimum | None = None, point: DesignPoint | None = None,
                 design_sha256: str = "", plant: Plant | None = None) -> None:
        self.optimum, self.point, self.design_sha256 = optimum, point, design_sha256
        self.plant: Plant | None = plant
        self.designed: DesignedPlant | None = None
        self.schedule: PreloadSchedule | None = None

    def design_of(self) -> _Kept:
        """A cache holding only the design (for a study whose tables around the design changed)."""
        return _Kept(self.optimum, self.point, self.design_sha256)


# --------------------------------------------------------------------------------------
# the study
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StudySpec:
    """A loaded, validated study: its tables (typed, as in the file), its plant and what the tables make.

    What a script holds is its subclass :class:`~piezopreload.study.Study` (:func:`~piezopreload.study.load_study`),
    which adds the steps that take a study (``tune``, ``simulate``, ``reproduce``, ``run``, ``sweep``: functions of
    the application layer); the pipeline and those steps take any :class:`StudySpec`. Read one with :meth:`load`,
    a changed copy with :meth:`replace`. The ``[design]`` table is
    ``design_table`` (``design()`` runs it), the ``[plant]`` table ``plant_table`` (``plant`` is the
    plant itself, a :class:`~piezopreload.models.actuator.Plant`).
    """

    path: str
    sha256: str
    name: str
    title: str
    rig: Plant
    controller: ControllerTable
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
    # what the tables make, built and checked on load
    gains: PIDGains = field(repr=False)
    references: dict[str, Reference] = field(repr=False)
    design_spec: DesignSpec | None = field(repr=False)
    where: _Source = field(repr=False)
    source_text: bytes = field(repr=False)  # the file as read, or as :meth:`replace` wrote it
    given: dict[str, Any] = field(repr=False)  # the tables and keys the file gives, as it gives them
    description: str = ""
    thermal: ThermalTable | None = None  # [thermal]: the shift's heat, temperature and growth (the system stage)
    say: Say = field(default=_stderr, repr=False, compare=False)  # progress where a step is given none
    _kept: _Kept = field(default_factory=_Kept, repr=False, compare=False)

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
    def signal(self) -> str:
        """What the step numbers are read on (``[simulation] signal``): ``measured_N``, the sensor's reading, or
        ``force_N``,
        the true force.
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
        raises :class:`InputError`. The design solved for this study is kept where the copy's design
        is the same.

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
        study = _build(data, where, self.path, toml_text(data).encode("utf-8"), self.say, type(self))
        objective = (study.design_table or DesignTable()).objective == (self.design_table or DesignTable()).objective
        same = self.design_spec is not None and study.design_spec == self.design_spec and objective
        if not same:
            return study
        kept = self._kept.design_of()
        kept.plant = study._kept.plant  # [rig]'s plant is the copy's own
        return _replace(study, _kept=kept)

    def to_toml(self) -> str:
        """The study as a TOML file (the file itself when it was not changed).

        Returns
        -------
        str
            The study's TOML text.
        """
        return self.source_text.decode("utf-8")

    # ---- the plant ---------------------------------------------------------------------------
    @property
    def plant_from_design(self) -> bool:
        """Whether the plant is the designed preload system (``[plant] from_design``) rather than ``[rig]`` itself."""
        return self.plant_table is not None and self.plant_table.from_design

    @property
    def plant(self) -> Plant:
        """The plant every control step runs on: ``[rig]``, or the plant of the design's optimum where
        ``[plant] from_design = true`` (the design solved once, saying so through the study's progress, and kept)."""
        return self._plant(None)

    @property
    def designed_plant(self) -> DesignedPlant:
        """Where the plant is the design: the designed preload system (its rig, :attr:`plant`; its screw, its
        preload range and where it comes from, the design's hash)."""
        if not self.plant_from_design:
            raise InputError(f"{self.path}: the plant is [rig] ([plant] from_design is not true): there is no "
                             "designed plant")
        return self._designed(None)

    @property
    def preload_schedule(self) -> PreloadSchedule:
        """The study's least-friction preload schedule (``[schedule]``) on the screw of the design's optimum."""
        k = self._kept
        if k.schedule is None:
            s = self.schedule or ScheduleTable()
            path = self.resolve(s.profile)
            k.schedule, _, _ = plan_schedule(self._spec("the preload schedule"), self._point(None),
                                             None if path is None else read_profile(path), profile_name=str(path),
                                             **s.limits())
        return k.schedule

    def with_design(self, design: DesignRecord | DesignResult | DesignOptimum | DesignPoint,
                    design_sha256: str = "") -> Self:
        """This study with its design's optimum given (a design artifact, say) instead of solved: its plant,
        designed plant and preload schedule are made from it; a design artifact's (:class:`DesignRecord`) own
        schedule is kept as recorded, so the best constant preload has one source. ``design_sha256``: the design
        artifact's hash, which the designed plant records.

        Parameters
        ----------
        design : DesignRecord, DesignResult, DesignOptimum or DesignPoint
            The design whose optimum (or point) the study takes.
        design_sha256 : str
            The design artifact's hash ("": none), recorded by the designed plant.

        Returns
        -------
        StudySpec
            The study with the design given, its other fields as they are.
        """
        self._spec("a design")
        point = design.point if isinstance(design, DesignRecord | DesignResult | DesignOptimum) else design
        optimum = design.optimum if isinstance(design, DesignResult) else design if isinstance(design, DesignOptimum) \
            else None
        plant = None if self.plant_from_design else self._kept.plant
        kept = _Kept(optimum, point, design_sha256, plant)
        if isinstance(design, DesignRecord):
            kept.schedule = design.schedule
        return _replace(self, _kept=kept)

    def _spec(self, what: str) -> DesignSpec:
        if self.design_spec is None:
            raise InputError(f"{self.path}: {what} needs the design's tables: the study has no [ballscrew] (see "
                             "studies/machine_axis.toml)")
        return self.design_spec

    def _point(self, progress: Say | None) -> DesignPoint:
        """The design's optimum, solved once (its cost said through ``progress``, or the study's)."""
        k = self._kept
        if k.point is None:
            say = progress or self.say
            objective = (self.design_table or DesignTable()).objective
            if (self.design_table or DesignTable()).method == "codesign":  # never the sequential design in its place
                raise InputError(f"{self.path}: [design] method = \"codesign\": the design is chosen with its "
                                 "controller by the co-design, which this step does not run; run the study "
                                 "('piezopreload run', whose design stage runs it), or give it the co-designed design: "
                                 "study.with_design(piezopreload.codesign.codesign_optimum(study))")
            say(f"solving the design's optimum ({objective}) once, for the plant and the preload schedule; every "
                "later step keeps it ...")
            t0 = time.perf_counter()
            try:
                k.optimum = optimise(self._spec("the design's optimum"), objective)
            except DesignInfeasible as exc:
                raise InfeasibleError(f"{self.path}: {exc}") from exc
            k.point = k.optimum.point
            say(f"design optimum in {time.perf_counter() - t0:.1f} s: bolts' preload {k.point.bolt_preload_N:.0f} N, "
                f"stacks' reach {k.point.max_preload_N:.0f} N, least rigidity {k.point.stiffness_N_per_um:.0f} N/um")
        return k.point

    def _designed(self, progress: Say | None) -> DesignedPlant:
        k = self._kept
        if k.designed is None:
            table = self.plant_table or PlantTable()
            k.designed = table.plant(self._spec("the designed plant"), self._point(progress), self.rig,
                                     k.design_sha256)
        return k.designed

    def _plant(self, progress: Say | None) -> Plant:
        k = self._kept
        if k.plant is None:
            k.plant = self._designed(progress).rig if self.plant_from_design else self.rig
        return k.plant

    def solved_plant(self, progress: ProgressLike | None = None) -> Plant:
        """:attr:`plant`, its design solved first where the plant is the design and it has not been, saying so
        through ``progress`` (:data:`~piezopreload.progress.ProgressLike`; default: the study's own).

        Parameters
        ----------
        progress : ProgressLike, optional
            Where the design's solve is said.

        Returns
        -------
        Plant
            The plant every control step runs on.
        """
        return self._plant(say_of(progress))

    def _controller(self, gains: GainSet | None, progress: Say | None) -> Controller:
        """The gain set's controller, or the study's [controller] gains with the identified feedforward."""
        if gains is not None:
            return gains.controller()
        return Controller(self.gains, self._plant(progress).sample_period_s,
                          self.identify_feedforward(progress).inverse())

    # ---- the steps -----------------------------------------------------------------------------
    def identify_feedforward(self, progress: ProgressLike | None = None) -> IdentifiedFeedforward:
        """The feedforward's P-I model: from ``[feedforward] data`` (a measured V -> N loop) when the study names
        one, else from the loop measurement simulated on :attr:`plant`; with its open-loop compensation check.
        ``progress``: :data:`~piezopreload.progress.ProgressLike`.

        Parameters
        ----------
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).

        Returns
        -------
        IdentifiedFeedforward
            The P-I model, its fit, the loop record and the open-loop compensation check.

        Raises
        ------
        InputError
            Where the model's range does not cover the study's references.
        """
        said = say_of(progress)
        say = said or (lambda _m: None)
        record = self.measured_loop(said)  # refused before the design if it does not cover the references
        plant = self._plant(said)
        ex, (low, high) = self.feedforward, self.reference_range_N
        if record is None:
            say(f"simulating the {ex.v_max_V:g} V, {ex.frequency_Hz:g} Hz loop measurement on the plant's truth model")
        ff = identify_feedforward(plant, ex, record, check_range_N=(low, high))
        say(f"P-I model ({ff.model.kind}): {ff.model.n_operators} operators, fit RMS {ff.fit.rms_pct:.2f} % "
            f"(max {ff.fit.max_pct:.2f} %) of the force span, identified over {number(ff.record.output_range[0], 'N')} "
            f"to {quantity(ff.record.output_range[1], 'N')}")
        ff.covers(low, high, f"the study's references ({self.path})")
        return ff

    def measured_loop(self, progress: ProgressLike | None = None) -> Record | None:
        """``[feedforward] data`` read, and refused if its forces do not cover the references (before any design
        or tuning: a measured loop's range is known from the file).

        Parameters
        ----------
        progress : ProgressLike, optional
            Where reading the file is said (default: nowhere).

        Returns
        -------
        Record or None
            The measured loop; None where the study simulates it.
        """
        data = self.resolve(self.feedforward.data)
        if data is None:
            return None
        say = say_of(progress) or (lambda _m: None)
        say(f"reading the measured loop {data}")
        record = read_record(data)
        loop_covers(record, *self.reference_range_N, f"the study's references ({self.path})")
        return record

    @property
    def reference_range_N(self) -> tuple[float, float]:
        """The least and the largest force of the study's references (step and trajectory): what the feedforward
        must have been identified over."""
        levels = [self.references[k].levels_N for k in ("step", "trajectory")]
        return float(min(x.min() for x in levels)), float(max(x.max() for x in levels))

    # "schedule" is also a str: mypy calls the two overlapping; a str that only holds "schedule" at run time is typed
    # as the second (write the literal where the schedule is meant)
    @overload
    def learn(  # type: ignore[overload-overlap]
              self, gains: GainSet | None = None, *, reference: Literal["schedule"], iterations: int | None = None,
              preview_s: float | None = None, method: str | None = None, plants: None = None,
              seed: int | None = None, after_change_weight: float = 0.0,
              progress: ProgressLike | None = None) -> ScheduleLearning: ...

    @overload
    def learn(self, gains: GainSet | None = None, *, reference: str | Reference = "trajectory",
              iterations: int | None = None, preview_s: float | None = None, method: str | None = None,
              plants: int | None = None, seed: int | None = None, after_change_weight: float = 0.0,
              progress: ProgressLike | None = None) -> LearningResult: ...

    def learn(self, gains: GainSet | None = None, *, reference: str | Reference = "trajectory",
              iterations: int | None = None, preview_s: float | None = None, method: str | None = None,
              plants: int | None = None, seed: int | None = None, after_change_weight: float = 0.0,
              progress: ProgressLike | None = None) -> LearningResult | ScheduleLearning:
        """Preview and iterative learning control over a repeated reference on :attr:`plant`.

        ``gains`` a gain set (its controller) or None (the study's ``[controller]`` with the identified
        feedforward); ``reference`` a name of :attr:`references`, a ``Reference``, or ``"schedule"``:
        the design's preload schedule, learned as the pipeline's learn stage does (each margin pass of
        :meth:`track_schedule` on its own reference; a study whose plant is its design). ``iterations``,
        ``preview_s`` (0: none) and ``method`` default to the study's ``[learning]``; ``plants`` N learns
        on N Monte Carlo plants (each its own learning; the result reports the worst); ``iterations`` is the most
        learning trials (fewer where more no longer pay); ``after_change_weight`` how the plan places each change
        (:func:`~piezopreload.tuning.learning.learn`).

        Parameters
        ----------
        gains : GainSet or None
            The gain set whose controller runs (None: the study's ``[controller]`` with the identified feedforward).
        reference : str or Reference
            A name of :attr:`references`, a :class:`Reference`, or ``"schedule"``.
        iterations : int or None
            The most learning trials (None: ``[learning] iterations``).
        preview_s : float or None
            How far ahead the feedforward reads the reference, in s (0: no preview; None: ``[learning] preview_s``).
        method : str or None
            The learning law, ``norm-optimal`` or ``p-type`` (None: ``[learning] method``).
        plants : int or None
            How many Monte Carlo plants to learn on, each its own learning (None: the study's plant alone).
        seed : int or None
            The seed of the plants' draw (None: the study's).
        after_change_weight : float
            The weight ``w`` the plan gives the error outside the time just after each jump (each ramp placed to least
            ``whole + w * outside``; 0: the whole-trajectory floor).
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).

        Returns
        -------
        LearningResult or ScheduleLearning
            A :class:`LearningResult` (``.ff_extra_V``, ``.history``, ``.plot()``); for ``"schedule"`` a
            :class:`ScheduleLearning` (each pass's learning and the last pass's tracking of the schedule).
        """
        from piezopreload.models.actuator import Rig
        from piezopreload.tuning.learning import learn

        table = self.learning or LearningTable()
        iterations = table.iterations if iterations is None else iterations
        preview_s = table.preview_s if preview_s is None else preview_s
        method = table.method if method is None else method
        seed = self.seed if seed is None else seed
        if isinstance(reference, str) and reference == "schedule":
            if plants is not None:
                raise InputError("Study.learn: plants: the schedule is learned on the designed plant itself (each "
                                 "margin pass); give plants=None, or learn on a Reference over Monte Carlo plants")
            return self._learn_schedule(gains, iterations, preview_s, method, seed, say_of(progress))
        if not isinstance(reference, Reference):
            if reference not in self.references:
                raise InputError(f"reference must be one of {', '.join([*self.references, 'schedule'])} or a "
                                 f"Reference, got {reference!r}")
            reference = self.references[reference]
        said = say_of(progress)
        return learn(self._controller(gains, said), Rig(self._plant(said)), reference, iterations=iterations,
                     preview_s=preview_s, method=method, plants=plants, seed=seed,
                     after_change_weight=after_change_weight, progress=said)

    def _learn_schedule(self, gains: GainSet | None, iterations: int, preview_s: float | None, method: str,
                        seed: int, progress: Say | None) -> ScheduleLearning:
        from piezopreload.schedule import ScheduleLearning
        from piezopreload.tuning.learning import schedule_learner

        designed = self._designed_for("reference 'schedule'", progress)
        controller = self._controller(gains, progress)
        learned, passes = schedule_learner(designed.rig, controller, iterations=iterations, preview_s=preview_s,
                                           method=method, seed=seed, progress=progress)
        system = (self.plant_table or PlantTable()).track(designed, controller, self.preload_schedule, seed=seed,
                                                          settle_s=self.validation.settling_max_s, ff_extra_V=learned,
                                                          progress=progress)
        return ScheduleLearning(system, tuple(passes))

    def _designed_for(self, what: str, progress: Say | None) -> DesignedPlant:
        if not self.plant_from_design:
            raise InputError(f"{self.path}: {what} needs a study whose plant is its design ([plant] from_design = "
                             "true, with the design's tables); this study's plant is its [rig]")
        return self._designed(progress)

    def track_schedule(self, gains: GainSet | None = None, *, ff_extra_V: Any = None,
                       progress: ProgressLike | None = None) -> SystemRun:
        """The gains (a gain set, or the study's ``[controller]`` with the identified feedforward) following the
        preload schedule on the designed plant for ``[plant] cycles`` after a pre-cycle to its first level (held the
        validated settling time, ``[validation] settling_max_s``), the schedule planned again with local margins while
        a requirement is missed (:func:`piezopreload.design.system.track_schedule`); ``ff_extra_V`` a correction
        added to the feedforward (one array, or one per pass's reference: a callable).

        Parameters
        ----------
        gains : GainSet or None
            The gain set whose controller runs (None: the study's ``[controller]`` with the identified feedforward).
        ff_extra_V : ndarray, callable or None
            A correction added to the feedforward, in V: one value per sample, or a callable giving one per pass's
            reference (None: none).
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).

        Returns
        -------
        SystemRun
            The run: its tracking, the requirements with their verdicts, the passes, and the thermal budget and the
            sensitivity study.
        """
        from piezopreload.tuning.validate import DEFAULT_SPREAD

        said = say_of(progress)
        designed = self._designed_for("tracking the schedule", said)
        controller = self._controller(gains, said)
        # the physical lift-off over the validation's Monte Carlo plants (its spread and seed; the nominal is the run)
        drawn = self.validation.plants - 1
        seed = self.validation.seed if self.validation.seed is not None else self.seed
        scatter = designed.rig.vary(drawn, DEFAULT_SPREAD, seed=seed) if drawn > 0 else None
        run = (self.plant_table or PlantTable()).track(designed, controller, self.preload_schedule, seed=self.seed,
                                                       settle_s=self.validation.settling_max_s, ff_extra_V=ff_extra_V,
                                                       design=self._spec("tracking the schedule"), scatter=scatter,
                                                       progress=said)
        drive = self._spec("the sensitivity study").feed_drive
        if self.thermal is not None:
            budget = thermal_budget(run, drive, self.thermal,
                                    command_range_V=(controller.gains.u_min_V, controller.gains.u_max_V))
            if said is not None:
                said(f"thermal: {budget.record.sentence()}")
            run = _replace(run, thermal=budget)
        studied = sensitivity(run, drive, self.thermal)
        if said is not None:
            said(f"robustness: {studied.sentence()}")
        return _replace(run, sensitivity=studied)

    def design(self, *, objective: str | None = None, pareto: list[str] | None = None, points: int | None = None,
               schedule: str | Path | None = None, progress: ProgressLike | None = None,
               bar: Callable[[int, int], None] | None = None, optimum: DesignOptimum | None = None) -> DesignResult:
        """The ball-screw preload design: the optimum for ``objective`` (the study's: solved once and kept, shared
        with :attr:`plant`), the Pareto fronts ``pareto`` (default: ``[design] pareto``; ``[]`` for none) and the
        preload schedule for a load profile (``schedule``, a CSV; default: the study's, or a machining cycle).
        ``optimum``: the optimum already chosen (a co-design's, where ``[design] method = "codesign"``: the
        design stage gives it), kept as the study's.

        Parameters
        ----------
        objective : str or None
            The design's objective (None: ``[design] objective``).
        pareto : list of str or None
            The Pareto fronts, each ``x:y`` (None: ``[design] pareto``; ``[]``: none).
        points : int or None
            The points of each front (None: ``[design] pareto_points``).
        schedule : str, Path or None
            A load profile's CSV for the preload schedule (None: ``[schedule] profile``, or a machining cycle).
        progress : ProgressLike or None
            Where progress lines go (None: nowhere).
        bar : callable or None
            Called with (done, total) as the fronts' points are solved (None: no bar).
        optimum : DesignOptimum or None
            The optimum already chosen, kept as the study's (None: solved).

        Returns
        -------
        DesignResult
            The optimum, the fronts, the preload schedule and the curves.

        Raises
        ------
        InfeasibleError
            Where no design meets the study's requirements.
        """
        spec = self._spec("the design")
        d, s = self.design_table or DesignTable(), self.schedule or ScheduleTable()
        objective = objective or d.objective
        k = self._kept
        profile_path = Path(schedule) if schedule is not None else self.resolve(s.profile)
        pairs = list(d.pareto if pareto is None else pareto)
        if "stiffness:growth" in pairs and self.thermal is None:
            raise InputError(f"{self.path}: the Pareto front stiffness:growth needs a [thermal] table (the shift the "
                             "growth is read over)")
        table = self.thermal
        if optimum is not None:  # chosen already (by the co-design): the record names what chose it
            objective = optimum.objective
        if optimum is None and objective == d.objective and d.method == "codesign":
            self._point(say_of(progress))  # refused: the co-design is the application layer's (codesign_optimum)
        try:
            result = design_study(
                spec, objective, pairs, d.pareto_points if points is None else points,
                profile=None if profile_path is None else read_profile(profile_path), profile_name=str(profile_path),
                **s.limits(), progress=say_of(progress), bar=bar,
                optimum=optimum if optimum is not None else k.optimum if objective == d.objective else None,
                growth=None if table is None else lambda point: duty_growth_um(spec, point, table))
        except DesignInfeasible as exc:
            raise InfeasibleError(f"{self.path}: {exc}") from exc
        if optimum is not None or (objective == d.objective and k.point is None):
            k.optimum, k.point = result.optimum, result.point
        return result


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
    controller: ControllerTable
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
    controller, reference = table("controller"), table("reference")
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


def _refuse_unreachable(validation: Criteria, controller: ControllerTable,
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
    kept = _Kept()
    if t["plant"] is None or not t["plant"].from_design:
        kept.plant = rig
    c: ControllerTable = t["controller"]
    sim: SimulationTable = t["simulation"]
    try:
        gains = PIDGains(Kc=c.Kc, Ti_s=c.seconds * c.Ti, Td_s=c.seconds * c.Td, Tf_s=c.Tf_s, b=c.b, u_min_V=c.u_min_V,
                         u_max_V=c.u_max_V)
    except ValueError as exc:  # every key was checked; a rule between them the table misses
        raise fail("controller", f"does not make PID gains: {exc}") from None
    validation = t["validation"]
    _refuse_unreachable(validation, c, fail)
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
        published=t["published"], thermal=t["thermal"], gains=gains,
        references=_references(t["reference"], fail),
        design_spec=design_spec, where=where, source_text=text,
        given=copy.deepcopy(data), say=say, _kept=kept)


def _references(tables: ReferenceTables, fail: Callable[[str, str], InputError]) -> dict[str, Reference]:
    s, tr = tables.step, tables.trajectory
    try:
        step = Reference.step(s.initial_N, s.final_N, s.t_step_s, s.duration_s)
    except ValueError as exc:
        raise fail("reference.step", f"does not make a step: {exc}") from None
    try:
        trajectory = Reference.staircase(tr.initial_N, list(tr.levels_N), tr.hold_s, tr.t_start_s)
    except ValueError as exc:
        raise fail("reference.trajectory", f"does not make a staircase: {exc}") from None
    return {"step": step, "trajectory": trajectory}
