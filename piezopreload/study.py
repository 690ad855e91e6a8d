"""The study: a TOML file parsed once into typed tables, and the steps a design-study script calls on it.

A study names the rig (the simulated plant), the controller's gains, the feedforward's
identification experiment, the references, the simulation settings, the ball-screw design
(``[ballscrew]``, ``[feed_drive]``, ``[duty]``, ``[design]``, ``[schedule]``) and the
one-command study's ``[tuning]``, ``[validation]``, ``[export]`` and ``[rig_run]``. Every key
is checked on load: an unknown key, a wrong type or an out-of-range value is an
:class:`~piezopreload.core.errors.InputError` naming the file, the line and the key's path.

>>> import piezopreload as pp
>>> study = pp.load_study("paper2021")                 # the paper's study, shipped
>>> study.rig.bolt_preload_N
25.0
>>> study.replace(rig={"bolt_preload_N": 30.0}).rig.bolt_preload_N
30.0
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from dataclasses import replace as _replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezopreload.artifacts.gainset import GainSet
from piezopreload.core.config import NUMBER, Lines, Table, check_tree, read_config, toml_text
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.tables import read_record
from piezopreload.design.plant import DesignedPlant
from piezopreload.design.preload import DesignInfeasible, DesignPoint, DesignSpec
from piezopreload.design.schedule import PreloadSchedule
from piezopreload.design.study import DesignResult, design_spec_from_tables, design_study, plan_schedule, read_profile
from piezopreload.design.system import SystemRun, schedule_reference
from piezopreload.design.tables import BallscrewTable, DesignTable, DutyTable, FeedDriveTable, PlantTable, ScheduleTable
from piezopreload.models.actuator import P888_91, RigParams, StackData
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import PIDGains
from piezopreload.rig.tables import ExportTable, RigRunPlan
from piezopreload.tuning.calibrate import LoopExcitation
from piezopreload.tuning.feedforward import IdentifiedFeedforward, identify
from piezopreload.tuning.pid import TuningSpec
from piezopreload.tuning.tables import LearningTable, TuningTable, ValidationTable
from piezopreload.tuning.validate import Criteria

if TYPE_CHECKING:  # the results module imports this one
    from piezopreload.results import StudyRun, TuningResult
    from piezopreload.tuning.learning import LearningResult

__all__ = ["Study", "load_study", "default_study", "paper_study", "shipped_studies", "DEFAULT_STUDY", "PAPER_STUDY",
           "RigRunPlan", "PlantTable"]

DEFAULT_STUDY = "machine_axis"  # the whole system: the designed preload system is the plant
PAPER_STUDY = "paper2021"       # the paper's rig and gains

_NUM = NUMBER
_RIG_SCALARS = {f.name for f in fields(RigParams)} - {"stack", "creep_tau_s", "n_stacks", "adc_bits", "delay_samples"}
_SCHEMA: dict[str, Any] = {
    "study": {"name": str, "title": str, "description": str},
    "rig": {
        **{name: _NUM for name in _RIG_SCALARS},
        "n_stacks": int, "adc_bits": int, "delay_samples": int, "creep_tau_s": list,
        "stack": {f.name: (str if f.name == "name" else _NUM) for f in fields(StackData)},
    },
    "controller": {
        "Kc": _NUM, "Ti": _NUM, "Td": _NUM, "Tf_s": _NUM, "b": _NUM, "units": str, "u_min_V": _NUM, "u_max_V": _NUM,
    },
    "feedforward": {"v_max_V": _NUM, "frequency_Hz": _NUM, "cycles": int, "n_operators": int, "seed": int,
                    "data": str, "kind": str, "creep": bool},
    "reference": {
        "step": {"initial_N": _NUM, "final_N": _NUM, "t_step_s": _NUM, "duration_s": _NUM},
        "trajectory": {"initial_N": _NUM, "levels_N": list, "hold_s": _NUM, "t_start_s": _NUM},
    },
    "simulation": {"seed": int, "band_N": _NUM, "signal": str},
    # the ball-screw design (piezopreload design): what the machine fixes and the design's bounds
    "ballscrew": {"nominal_diameter_mm": _NUM, "lead_mm": _NUM, "contact_angle_deg": list, "ball_mm": list,
                  "conformity": list, "turns": list, "load_sharing": _NUM},
    "feed_drive": {"table_mass_kg": _NUM, "screw_length_mm": _NUM, "bearing_stiffness_N_per_um": _NUM,
                   "travel_mm": list, "mounting": str},
    "duty": {"axial_load_N": list, "speed_rpm": list, "time_share": list},
    "design": {"objective": str, "pareto": list, "pareto_points": int, "axial_load_max_N": _NUM,
               "failsafe_load_N": _NUM, "lift_off_margin": _NUM, "preload_fraction_max": _NUM,
               "contact_pressure_max_MPa": _NUM, "life_min_h": _NUM, "drag_torque_max_Nm": _NUM,
               "frequency_min_Hz": _NUM, "stiffness_min_N_per_um": _NUM, "nut_length_max_mm": _NUM,
               "ball_lead_ratio_max": _NUM, "load_factor": _NUM, "stack_drive_V": _NUM,
               "amp_current_limit_A": _NUM},
    "schedule": {"profile": str, "stiffness_min_N_per_um": _NUM, "deflection_max_um": _NUM,
                 "lift_off_margin": _NUM},
    # the one-command study (piezopreload run): tuning, validation, export and the rig run
    "tuning": {"overshoot_margin_N": _NUM, "ms_max": _NUM, "noise_gain_max_V_per_N": _NUM,
               "tune_setpoint_weight": bool, "step_N": list, "trajectory_N": list, "schedule_levels": int,
               "schedule_plants": int},
    # the designed preload system as the plant (design/plant.py, design/system.py)
    "plant": {"from_design": bool, "sleeve_stiffness_N_per_um": _NUM, "cycles": int, "passes": int,
              "margin_factor": _NUM, "stack_contact_N": _NUM},
    "learning": {"iterations": int, "preview_s": _NUM, "method": str},
    "validation": {"plants": int, "seed": int, "workers": int, "settling_max_s": _NUM, "overshoot_max_N": _NUM,
                   "tracking_rms_max_N": _NUM, "peak_voltage_max_V": _NUM},
    "export": {"formats": list},
    "rig_run": {"backend": str, "reference": str, "realtime": bool, "seed": int, "force_max_N": _NUM,
                "ramp_s": _NUM, "missed_streak": int},
}
_REQUIRED = ("rig", "controller")
_STRING_LISTS = {"design.pareto", "export.formats"}
_UNITS = ("seconds", "minutes")
_SIGNALS = ("measured_N", "force_N")


# --------------------------------------------------------------------------------------
# the tables: one frozen record per table of the file, its keys as fields
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ControllerTable(Table):
    """[controller]: the gains as entered (``Ti`` and ``Td`` in ``units``), the output range."""

    Kc: float
    Ti: float
    Td: float
    Tf_s: float = 0.0
    b: float = 1.0
    units: str = "seconds"
    u_min_V: float = 0.0
    u_max_V: float = 110.0


@dataclass(frozen=True)
class FeedforwardTable(Table):
    """[feedforward]: the loop measurement the feedforward is identified from (``data``: a measured one), the P-I
    model's ``kind`` and whether it compensates ``creep`` too."""

    v_max_V: float = LoopExcitation.v_max_V
    frequency_Hz: float = LoopExcitation.frequency_Hz
    cycles: int = LoopExcitation.cycles
    n_operators: int = LoopExcitation.n_operators
    seed: int = LoopExcitation.seed
    data: str | None = None
    kind: str = LoopExcitation.kind
    creep: bool = LoopExcitation.creep


@dataclass(frozen=True)
class StepTable(Table):
    initial_N: float = 25.0
    final_N: float = 60.0
    t_step_s: float = 0.5
    duration_s: float = 10.0


@dataclass(frozen=True)
class TrajectoryTable(Table):
    initial_N: float = 25.0
    levels_N: tuple[float, ...] = (60.0, 80.0, 100.0, 80.0, 60.0)
    hold_s: float = 5.0
    t_start_s: float = 0.5


@dataclass(frozen=True)
class ReferenceTables(Table):
    """[reference.step] and [reference.trajectory]: the paper's step and staircase."""

    step: StepTable = StepTable()
    trajectory: TrajectoryTable = TrajectoryTable()


@dataclass(frozen=True)
class SimulationTable(Table):
    """[simulation]: the noise seed, the error band and the signal the step numbers are read on."""

    seed: int = 0
    band_N: float = 1.5
    signal: str = "measured_N"


_TABLES: dict[str, type[Table]] = {
    "controller": ControllerTable, "feedforward": FeedforwardTable, "simulation": SimulationTable,
    "ballscrew": BallscrewTable, "feed_drive": FeedDriveTable, "duty": DutyTable, "design": DesignTable,
    "schedule": ScheduleTable, "tuning": TuningTable, "validation": ValidationTable, "export": ExportTable,
    "rig_run": RigRunPlan, "plant": PlantTable, "learning": LearningTable,
}
#: the attribute of each table whose name is taken by a method (``study.design()``)
_ATTRIBUTE = {"design": "design_table"}


def _table(cls: type[Table], data: dict[str, Any]) -> Any:
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


@dataclass(frozen=True)
class _Source:
    """Where a study came from, for messages: ``fail`` names the file, the line of a key and the key."""

    shown: str
    lines: Lines
    folder: Path

    def fail(self, key_path: str, message: str) -> InputError:
        line = self.lines.of(key_path)
        return InputError(f"{self.shown}:{line}: '{key_path}' {message}" if line else f"{self.shown}: '{key_path}' {message}")


# --------------------------------------------------------------------------------------
# the study
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Study:
    """A loaded, validated study: its tables (typed, as in the file) and what they make (gains, references, specs).

    Make one with :func:`load_study`, a changed copy with :meth:`replace`. The ``[design]``
    table is ``design_table`` (``design()`` runs it).
    """

    path: str
    sha256: str
    name: str
    title: str
    rig: RigParams
    controller: ControllerTable
    feedforward: FeedforwardTable
    reference: ReferenceTables
    simulation: SimulationTable
    tuning: TuningTable
    validation: ValidationTable
    export: ExportTable
    rig_run: RigRunPlan
    ballscrew: BallscrewTable | None
    feed_drive: FeedDriveTable | None
    duty: DutyTable | None
    design_table: DesignTable | None
    schedule: ScheduleTable | None
    plant: PlantTable | None
    learning: LearningTable | None
    # what the tables make, built and checked on load
    gains: PIDGains = field(repr=False)
    references: dict[str, Reference] = field(repr=False)
    excitation: LoopExcitation = field(repr=False)
    tuning_spec: TuningSpec = field(repr=False)
    criteria: Criteria = field(repr=False)
    design_spec: DesignSpec | None = field(repr=False)
    where: _Source = field(repr=False)
    source_text: bytes = field(repr=False)  # the file as read, or as :meth:`replace` wrote it
    description: str = ""
    on_designed_plant: bool = field(default=False, repr=False, compare=False)  # set by with_plant

    # ---- the tables --------------------------------------------------------------------------
    @property
    def folder(self) -> Path:
        """The study file's folder: the files it names are relative to it."""
        return self.where.folder

    @property
    def seed(self) -> int:
        return self.simulation.seed

    @property
    def band_N(self) -> float:
        return self.simulation.band_N

    @property
    def signal(self) -> str:
        return self.simulation.signal

    def resolve(self, relative: str | None) -> Path | None:
        """A file the study names (``feedforward.data``, ``schedule.profile``, ``rig_run.reference``), from its folder."""
        return None if relative is None else self.folder / relative

    def files(self) -> dict[str, Path]:
        """The input files the study names, by key (``feedforward.data``, ``schedule.profile``, ``rig_run.reference``)."""
        named = {"feedforward.data": self.feedforward.data,
                 "schedule.profile": None if self.ballscrew is None or self.schedule is None else self.schedule.profile,
                 "rig_run.reference": self.rig_run.reference if self.rig_run.reference.lower().endswith(".csv") else None}
        return {key: self.folder / rel for key, rel in named.items() if rel is not None}

    def check_files(self) -> None:
        """Refuse a study whose named files are missing, naming the key and its line."""
        for key, path in self.files().items():
            if not path.is_file():
                raise self.where.fail(key, f"names {path}, which is not a file; give a path relative to the study file")

    def tables(self) -> dict[str, Any]:
        """The study's tables as the file holds them (every key, defaults filled), e.g. for a stage's key."""
        out: dict[str, Any] = {"study": {"name": self.name, "title": self.title, "description": self.description},
                               "rig": self.rig.to_dict(), "reference": self.reference.to_dict()}
        for table in _TABLES:
            value = getattr(self, _ATTRIBUTE.get(table, table))
            if value is not None:
                out[table] = value.to_dict()
        return out

    def replace(self, **changes: dict[str, Any]) -> Study:
        """A validated copy with some keys changed: ``study.replace(rig={"bolt_preload_N": 30.0})``.

        Each argument names a table (``reference={"step": {"final_N": 80.0}}`` for a nested
        one) and holds the keys to change; a bad key or value raises :class:`InputError`. A study
        given its plant (:meth:`with_plant`) keeps it.
        """
        data = self.tables()
        for table, keys in changes.items():
            if table not in _SCHEMA or not isinstance(keys, dict):
                raise InputError(f"Study.replace: '{table}' must be a table of the study given as a dict of keys, got "
                                 f"{keys!r}; tables: {', '.join(_SCHEMA)}")
            _merge(data.setdefault(table, {}), keys)
        for table, rel in (("feedforward", "data"), ("schedule", "profile")):  # files stay where they were
            if data.get(table, {}).get(rel) is not None:
                data[table][rel] = str(self.folder / data[table][rel])
        if data["rig_run"]["reference"].lower().endswith(".csv"):
            data["rig_run"]["reference"] = str(self.folder / data["rig_run"]["reference"])
        where = _Source(f"{self.path} (replaced)", Lines(""), self.folder)
        check_tree(data, _SCHEMA, where.lines, where.shown, string_lists=_STRING_LISTS)
        # a study given its plant (with_plant) keeps it: its [rig] is that plant's, changed as asked
        return _replace(_build(data, where, self.path, toml_text(data).encode("utf-8")),
                        on_designed_plant=self.on_designed_plant)

    def to_toml(self) -> str:
        """The study as a TOML file (the file itself when it was not changed)."""
        return self.source_text.decode("utf-8")

    # ---- the steps -----------------------------------------------------------------------------
    def identify_feedforward(self, progress: Callable[[str], None] | None = None) -> IdentifiedFeedforward:
        """The feedforward's P-I model: from ``[feedforward] data`` (a measured V -> N loop) when the study names
        one, else from the loop measurement simulated on the rig; with its open-loop compensation check."""
        say = progress or (lambda _m: None)
        if not self._on_plant:
            return self.plant_study(progress).identify_feedforward(progress)
        ex, data = self.excitation, self.resolve(self.feedforward.data)
        if data is None:
            say(f"simulating the {ex.v_max_V:g} V, {ex.frequency_Hz:g} Hz loop measurement on the rig's truth model")
        else:
            say(f"reading the measured loop {data}")
        levels = self.references["trajectory"].levels_N
        low = float(min(self.references["step"].levels_N.min(), levels.min()))
        ff = identify(self.rig, ex, None if data is None else read_record(data), check_range_N=(low, float(levels.max())))
        say(f"P-I model ({ff.model.kind}): {ff.model.n_operators} operators, fit RMS {ff.fit['rms_pct']:.2f} % "
            f"(max {ff.fit['max_pct']:.2f} %) of the force span")
        return ff

    def tune(self, feedforward: IdentifiedFeedforward | None = None, *, seed: int | None = None,
             progress: Callable[[str], None] | None = None,
             iterations: Callable[[int], None] | None = None) -> TuningResult:
        """Tune the PID around the rig compensated by ``feedforward`` (default: :meth:`identify_feedforward`);
        compare it with the paper's and SIMC's gains and bound it. Returns a :class:`~piezopreload.results.TuningResult`."""
        from piezopreload.results import tune

        study = self.plant_study(progress)
        return tune(study, feedforward or study.identify_feedforward(progress), seed=seed, progress=progress,
                    iterations=iterations)

    def simulate(self, gains: GainSet | PIDGains | None = None, *, controller: str = "ff+pid", reference: str = "step",
                 feedforward: IdentifiedFeedforward | None = None, seed: int | None = None) -> StudyRun:
        """One controller on the study's rig over one of its references: a
        :class:`~piezopreload.results.StudyRun` (``.step_metrics()``, ``.plot()``, ``.to_dict()``).

        ``gains``: a gain set (its feedforward too, unless ``feedforward`` is given), PID gains, or
        None for the study's ``[controller]``; ``controller``: ``pid`` or ``ff+pid``.
        """
        from piezopreload.results import simulate

        return simulate(self.plant_study(), gains, controller=controller, reference=reference, feedforward=feedforward, seed=seed)

    def learn(self, gains: GainSet | None = None, *, reference: Any = "trajectory", iterations: int = 10,
              preview_s: float | None = None, method: str = "norm-optimal", plants: int | None = None,
              seed: int | None = None, after_change_weight: float = 0.0,
              progress: Callable[[str], None] | None = None) -> LearningResult:
        """Preview and iterative learning control over a repeated reference: a
        :class:`~piezopreload.tuning.learning.LearningResult` (``.ff_extra_V``, ``.history``, ``.trials``,
        ``.signal(gain_set_sha256)``, ``.to_dict()``, ``.plot()``); see :func:`piezopreload.tuning.learning.learn`.

        ``gains`` a gain set (its controller) or None (the study's ``[controller]`` with the identified
        feedforward); ``reference`` a name of :attr:`references`, ``"schedule"`` (the design's preload
        schedule, :meth:`schedule_reference`) or a ``Reference``; ``iterations`` the most learning trials
        (fewer where more no longer pay); ``preview_s`` None for the default horizon, 0 for none;
        ``method`` ``norm-optimal`` or ``p-type``; ``plants`` N to learn on N Monte Carlo plants (each its
        own learning; the result reports the worst); ``after_change_weight`` how the plan places each change.
        """
        from piezopreload.models.actuator import Rig
        from piezopreload.models.controller import Controller
        from piezopreload.tuning.learning import learn

        if isinstance(reference, str) and reference == "schedule":
            study, reference = self._on_schedule(progress)
        else:
            study = self.plant_study(progress)
            if not isinstance(reference, Reference):
                if reference not in study.references:
                    raise InputError(f"reference must be one of {', '.join([*study.references, 'schedule'])} or a "
                                     f"Reference, got {reference!r}")
                reference = study.references[reference]
        controller = gains.controller() if gains is not None else Controller(
            study.gains, study.rig.sample_period_s, study.identify_feedforward().inverse())
        return learn(controller, Rig(study.rig), reference, iterations=iterations, preview_s=preview_s, method=method,
                     plants=plants, seed=self.seed if seed is None else seed, after_change_weight=after_change_weight,
                     progress=progress)

    def schedule_reference(self, progress: Callable[[str], None] | None = None) -> Reference:
        """The design's preload schedule as the force loop follows it: the stacks' share, ``[plant] cycles`` times in a
        row, as planned (the first of the system's passes, no margin). Designs the optimum (no Pareto fronts)."""
        return self._on_schedule(progress)[1]

    def _on_schedule(self, progress: Callable[[str], None] | None) -> tuple[Study, Reference]:
        """This study on its designed plant, and the design's schedule as that plant's reference."""
        if not self.plant_from_design:
            raise InputError(f"{self.path}: the reference 'schedule' is the design's preload schedule; the study needs "
                             "a [ballscrew] table and [plant] from_design = true (see studies/machine_axis.toml)")
        (progress or (lambda _m: None))("the reference is the design's schedule: designing the optimum first")
        result = self.design(pareto=[], progress=progress)
        plant = self.designed_plant(result)
        table = self.plant or PlantTable()
        reference = schedule_reference(plant, result.schedule, table.cycles, table.stack_contact_N)
        return (self if self._on_plant else self.with_plant(plant)), reference

    def reproduce(self, *, seed: int | None = None, repeats: int = 1,
                  feedforward: IdentifiedFeedforward | None = None) -> dict[str, Any]:
        """The paper's six step numbers beside the simulation's (medians over ``repeats`` noise draws)."""
        from piezopreload.results import reproduce

        study = self.plant_study()
        return reproduce(study, feedforward or study.identify_feedforward(), seed=seed, repeats=repeats)

    def design(self, *, objective: str | None = None, pareto: list[str] | None = None, points: int | None = None,
               schedule: str | Path | None = None, progress: Callable[[str], None] | None = None,
               bar: Callable[[int, int], None] | None = None) -> DesignResult:
        """The ball-screw preload design: the optimum for ``objective``, the Pareto fronts and the preload schedule
        for a load profile (``schedule``, a CSV; default: the study's, or a machining cycle)."""
        if self.design_spec is None:
            raise InputError(f"{self.path}: the study has no [ballscrew] table; the design needs the screw's nominal "
                             "diameter and lead (see studies/paper2021.toml)")
        d, s = self.design_table or DesignTable(), self.schedule or ScheduleTable()
        profile_path = Path(schedule) if schedule is not None else self.resolve(s.profile)
        try:
            return design_study(
                self.design_spec, objective or d.objective, list(d.pareto if pareto is None else pareto),
                d.pareto_points if points is None else points,
                profile=None if profile_path is None else read_profile(profile_path), profile_name=str(profile_path),
                **s.limits(), progress=progress, bar=bar)
        except DesignInfeasible as exc:
            raise InfeasibleError(f"{self.path}: {exc}") from exc

    @property
    def plant_from_design(self) -> bool:
        """Whether the plant is the designed preload system (``[plant] from_design``) rather than ``[rig]`` itself."""
        return self.plant is not None and bool(self.plant.from_design) and self.design_spec is not None

    def designed_plant(self, design: DesignResult | DesignPoint, design_sha256: str = "") -> DesignedPlant:
        """The plant of ``design`` (a design result or its optimum's point): its stacks, amplifier current limit
        and coupling, the rest of the hardware from ``[rig]`` (:func:`piezopreload.design.plant.plant_from_design`)."""
        if self.design_spec is None:
            raise InputError(f"{self.path}: the plant from a design needs the [ballscrew] table")
        point = design.point if isinstance(design, DesignResult) else design
        return (self.plant or PlantTable()).plant(self.design_spec, point, self.rig, design_sha256)

    def schedule_for(self, point: DesignPoint) -> PreloadSchedule:
        """The study's preload schedule on the screw of ``point``, as :meth:`design` plans it."""
        if self.design_spec is None:
            raise InputError(f"{self.path}: the schedule needs the [ballscrew] table")
        s = self.schedule or ScheduleTable()
        path = self.resolve(s.profile)
        schedule, _, _ = plan_schedule(self.design_spec, point, None if path is None else read_profile(path),
                                       profile_name=str(path), **s.limits())
        return schedule

    def with_plant(self, plant: DesignedPlant | dict[str, Any]) -> Study:
        """This study with the designed plant as its ``[rig]``: what identification, tuning and validation run on.

        ``plant``: a :class:`DesignedPlant`, or the ``[rig]`` table of one (as the plant stage writes it).
        """
        rig = plant.rig.to_dict() if isinstance(plant, DesignedPlant) else plant
        return _replace(self.replace(rig=rig), on_designed_plant=True)

    @property
    def _on_plant(self) -> bool:
        return self.on_designed_plant or not self.plant_from_design

    def plant_study(self, progress: Callable[[str], None] | None = None) -> Study:
        """The study the control steps (identify, tune, simulate, learn) run on: this one, or, where the plant is
        the design (``[plant] from_design``) and :meth:`with_plant` has not given it, this study on the plant of
        :meth:`design`'s optimum (designed once, then kept)."""
        if self._on_plant:
            return self
        cached = self.__dict__.get("_plant_study")
        if cached is None:
            (progress or (lambda _m: None))("the plant is the designed preload system: designing it first")
            cached = self.with_plant(self.designed_plant(self.design(progress=progress)))
            object.__setattr__(self, "_plant_study", cached)  # a frozen study keeps what it derived, as a cache
        return cached

    def track_schedule(self, plant: DesignedPlant, schedule: PreloadSchedule, gain_set: GainSet, *,
                       ff_extra_V: Any = None, progress: Callable[[str], None] | None = None) -> SystemRun:
        """The validated gains with their feedforward following ``schedule`` on ``plant`` for ``[plant] cycles``,
        the schedule planned again with a margin while the rigidity falls short (:func:`design.system.track_schedule`)."""
        return (self.plant or PlantTable()).track(plant, gain_set.controller(), schedule, seed=self.seed,
                                                  ff_extra_V=ff_extra_V, progress=progress)

    def learn_schedule(self, plant: DesignedPlant, schedule: PreloadSchedule, gain_set: GainSet, *,
                       progress: Callable[[str], None] | None = None) -> tuple[SystemRun, list[LearningResult]]:
        """:meth:`track_schedule` with the loop learning on each pass's repeated reference first (``[learning]``:
        :func:`piezopreload.tuning.learning.learn` on the plant, its best signal played in the pass), so the
        schedule's margin is planned from the tuned and learned loop's error. Returns the last pass's run and
        each pass's learning."""
        from piezopreload.tuning.learning import schedule_learner

        table = self.learning or LearningTable()
        learned, results = schedule_learner(plant.rig, gain_set.controller(), iterations=table.iterations,
                                            preview_s=table.preview_s, method=table.method, seed=self.seed,
                                            progress=progress)
        return self.track_schedule(plant, schedule, gain_set, ff_extra_V=learned, progress=progress), results

    def run(self, out: str | Path = "piezopreload-out", *, force: bool = False, progress: Any = None) -> dict[str, Any]:
        """The whole study, as ``piezopreload run``: its stages into ``out``, unchanged ones not run again."""
        from piezopreload.pipeline import run_study

        return run_study(self, out, force=force, progress=progress)


def _merge(into: dict[str, Any], changes: dict[str, Any]) -> None:
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = list(value) if isinstance(value, tuple) else value


# --------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------
def shipped_studies() -> dict[str, Path]:
    """The studies that ship with the package, by name."""
    root = resources.files("piezopreload.studies")
    return {p.name[:-5]: Path(str(p)) for p in root.iterdir() if p.name.endswith(".toml")}


def default_study() -> Path:
    """The default study's file as shipped with the package (the machine axis, the whole system)."""
    return shipped_studies()[DEFAULT_STUDY]


def paper_study() -> Path:
    """The paper's study as shipped with the package (the rig and gains of Zhang, Jin, Lin 2021)."""
    return shipped_studies()[PAPER_STUDY]


def load_study(study: str | Path | None = None) -> Study:
    """Read and validate a study: None for the default (``machine_axis``), a shipped study's name
    (``"paper2021"``), or a file."""
    if study is None:
        path = default_study()
    elif isinstance(study, str) and not study.endswith(".toml") and study in shipped_studies():
        path = shipped_studies()[study]
    else:
        path = Path(study)
    data, lines, raw = read_config(path, _SCHEMA, "study file", _STRING_LISTS)
    shown = str(path)
    where = _Source(shown, lines, Path(shown).parent)
    for table in _REQUIRED:
        if table not in data:
            raise InputError(f"{shown}: the table [{table}] is missing")
    return _build(data, where, shown, raw)


def _build(data: dict[str, Any], where: _Source, path: str, text: bytes) -> Study:
    """The typed study from its checked tables; every value checked, errors naming the key and its line."""
    fail = where.fail
    rig = _rig(dict(data["rig"]), fail)
    c = data["controller"]
    for key in ("Kc", "Ti", "Td"):
        if key not in c:
            raise fail("controller", f"needs '{key}'")
    controller = _table(ControllerTable, c)
    if controller.units not in _UNITS:
        raise fail("controller.units", f"must be one of {', '.join(_UNITS)}, got {controller.units!r}")
    scale = 60.0 if controller.units == "minutes" else 1.0
    try:
        gains = PIDGains(Kc=float(c["Kc"]), Ti_s=scale * float(c["Ti"]), Td_s=scale * float(c["Td"]),
                         Tf_s=float(controller.Tf_s), b=float(controller.b), u_min=float(controller.u_min_V),
                         u_max=float(controller.u_max_V))
    except ValueError as exc:
        raise fail("controller", f"is not valid: {exc}") from None
    feedforward = _table(FeedforwardTable, data.get("feedforward", {}))
    try:
        excitation = LoopExcitation(**{k: v for k, v in asdict(feedforward).items() if k != "data"})
    except ValueError as exc:
        raise fail("feedforward", f"is not valid: {exc}") from None
    reference, references = _references(data.get("reference", {}), fail)
    simulation = _table(SimulationTable, data.get("simulation", {}))
    if not simulation.band_N > 0:
        raise fail("simulation.band_N", f"must be > 0, got {simulation.band_N}")
    if simulation.signal not in _SIGNALS:
        raise fail("simulation.signal", f"must be one of {', '.join(_SIGNALS)}, got {simulation.signal!r}")
    if simulation.seed < 0:
        raise fail("simulation.seed", f"must be >= 0, got {simulation.seed}")
    tuning = _table(TuningTable, data.get("tuning", {}))
    try:
        spec = tuning.spec(band_N=simulation.band_N, u_min_V=gains.u_min, u_max_V=gains.u_max)
    except ValueError as exc:
        key = next((k for k in data.get("tuning", {}) if k in str(exc)), "")
        raise fail(f"tuning.{key}" if key else "tuning", f"is not valid: {exc}") from None
    validation = _table(ValidationTable, data.get("validation", {})).checked(simulation.seed, fail)
    try:
        criteria = validation.criteria(simulation.band_N)
    except ValueError as exc:
        key = next((k for k in data.get("validation", {}) if k in str(exc)), "")
        raise fail(f"validation.{key}" if key else "validation", f"is not valid: {exc}") from None
    export = _table(ExportTable, data.get("export", {}))
    export.check(fail)
    design_tables = {t: _table(_TABLES[t], data[t]) if t in data else None
                     for t in ("ballscrew", "feed_drive", "duty", "design", "schedule", "plant")}
    if design_tables["plant"] is not None:
        design_tables["plant"].check("ballscrew" in data, fail)
    design_spec = design_spec_from_tables({**design_tables, "design": design_tables["design"] or DesignTable()}, where.fail) if design_tables["ballscrew"] is not None else None
    meta = data.get("study", {})
    return Study(
        path=path, sha256=hashlib.sha256(text).hexdigest(), name=meta.get("name", Path(path).stem),
        title=meta.get("title", ""), description=meta.get("description", ""), rig=rig, controller=controller,
        feedforward=feedforward, reference=reference, simulation=simulation, tuning=tuning, validation=validation,
        export=export, rig_run=_table(RigRunPlan, data.get("rig_run", {})).checked(fail), ballscrew=design_tables["ballscrew"],
        feed_drive=design_tables["feed_drive"], duty=design_tables["duty"], design_table=design_tables["design"],
        schedule=design_tables["schedule"], plant=design_tables["plant"],
        learning=_table(LearningTable, data["learning"]).checked(fail) if "learning" in data else None, gains=gains, references=references, excitation=excitation,
        tuning_spec=spec, criteria=criteria, design_spec=design_spec, where=where, source_text=text)


def _rig(rig_data: dict[str, Any], fail: Callable[[str, str], InputError]) -> RigParams:
    if "stack" in rig_data:
        try:
            rig_data["stack"] = StackData(**{f.name: rig_data["stack"].get(f.name, getattr(P888_91, f.name))
                                             for f in fields(StackData)})
        except ValueError as exc:
            raise fail("rig.stack", f"is not valid: {exc}") from None
    if "creep_tau_s" in rig_data:
        rig_data["creep_tau_s"] = tuple(float(x) for x in rig_data["creep_tau_s"])
    try:
        return RigParams(**rig_data)
    except ValueError as exc:
        name = next((k for k in rig_data if f"RigParams.{k} " in str(exc)), "")
        raise fail(f"rig.{name}" if name else "rig", f"is not valid: {exc}") from None


def _references(refs: dict[str, Any], fail: Callable[[str, str], InputError]) -> tuple[ReferenceTables, dict[str, Reference]]:
    tables = ReferenceTables(_table(StepTable, refs.get("step", {})), _table(TrajectoryTable, refs.get("trajectory", {})))
    references: dict[str, Reference] = {}
    try:
        s = tables.step
        references["step"] = Reference.step(float(s.initial_N), float(s.final_N), float(s.t_step_s), float(s.duration_s))
    except ValueError as exc:
        raise fail("reference.step", f"is not valid: {exc}") from None
    try:
        tr = tables.trajectory
        if not tr.hold_s > 0:
            raise ValueError(f"hold_s must be > 0, got {tr.hold_s}")
        references["trajectory"] = Reference.staircase(float(tr.initial_N), list(tr.levels_N), float(tr.hold_s),
                                                       float(tr.t_start_s))
    except ValueError as exc:
        raise fail("reference.trajectory", f"is not valid: {exc}") from None
    return tables, references
