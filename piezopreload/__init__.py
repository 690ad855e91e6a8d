"""piezopreload: design and tuning studies for feed drives with piezo-actuated ball-screw preload.

The front door for design-study scripts: ``import piezopreload as pp``. The README's example is
the short tour (``pp.load_study``, ``study.tune``, ``tuned.validate``, ``study.simulate``,
``pp.export``, ``study.run``); the documentation's API reference lists every name exported here.

The physics lives in :mod:`piezopreload.models`, the typed artifacts in
:mod:`piezopreload.artifacts`, identification and tuning in :mod:`piezopreload.tuning`, the design
in :mod:`piezopreload.design`, the rig executor in :mod:`piezopreload.rig`, the report in
:mod:`piezopreload.reports`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = [
    "__version__", "load_study", "shipped_studies", "Study", "GainSet", "TuningResult", "StudyRun", "ScheduleLearning",
    "ClosedLoopRun", "Plant",
    "DesignResult", "IdentifiedFeedforward", "PIDGains", "Reference", "StepMetrics", "MeasuredRecord", "read_record",
    "export", "identify", "Identification", "PIIdentifier", "NotFittedError", "IdentifiedModel", "Window",
    "autotune", "AutotuneResult", "fit_plant", "FittedPlant", "PiezopreloadError", "InputError", "ArtifactError",
    "InfeasibleError", "InternalError", "SweepResult",
    # the results a study's steps give back, and the records they carry (what a script reads off them)
    "StudyResult", "SystemRun", "LearningResult", "ValidationResult", "Metrics", "Failure", "Requirement",
    "ComparisonRow", "ActiveBound", "MinimumTimeBound", "TrackingFloor", "TuningSolve", "DesignRecord", "DesignPoint",
    "DesignedPlant", "PreloadSchedule", "SystemRecord", "TrackingNumbers", "FitError", "LearnedSignal", "SweepPoint",
    "RunSummary", "StudyRef", "StudyReproduction", "PublishedRow", "SimulationInfo",
    "FeedforwardInfo", "ScheduleSummary", "SystemSummary", "SampledCheck", "DataSource", "LearnedWritten",
    "CodesignResult", "CodesignWeights", "DesignSpec",
]

#: the module each public name comes from: a name is imported on its first use (a module ``__getattr__``, as numpy
#: and scipy load their submodules), so ``import piezopreload`` loads no floor and no solver
_EXPORTS: dict[str, str] = {name: module for module, names in {
    "piezopreload.study": ("load_study", "shipped_studies", "Study"),
    "piezopreload.results": ("StudyRun", "StudyReproduction", "SimulationInfo"),
    "piezopreload.schedule": ("ScheduleLearning",),
    "piezopreload.sweep": ("SweepResult",),
    "piezopreload.codesign": ("CodesignResult", "CodesignWeights"),
    "piezopreload.outcome": ("StudyResult", "RunSummary"),
    "piezopreload.artifacts.manifest": ("StudyRef",),
    "piezopreload.tuning.compare": ("PublishedRow",),
    "piezopreload.core.errors": ("PiezopreloadError", "InputError", "ArtifactError", "InfeasibleError",
                                 "InternalError"),
    "piezopreload.core.tables": ("MeasuredRecord", "read_record"),
    "piezopreload.models.actuator": ("Plant",),
    "piezopreload.models.closedloop": ("ClosedLoopRun", "Reference"),
    "piezopreload.models.controller": ("PIDGains",),
    "piezopreload.models.metrics": ("StepMetrics",),
    "piezopreload.artifacts.gainset": ("GainSet",),
    "piezopreload.artifacts.hysteresis": ("IdentifiedModel", "FitError", "DataSource"),
    "piezopreload.artifacts.validation": ("ValidationResult", "Metrics", "Failure"),
    "piezopreload.artifacts.requirements": ("Requirement",),
    "piezopreload.artifacts.tuning": ("TuningResult", "ComparisonRow", "ActiveBound", "MinimumTimeBound",
                                      "TrackingFloor", "TuningSolve"),
    "piezopreload.artifacts.design": ("DesignRecord", "DesignPoint"),
    "piezopreload.artifacts.plant": ("DesignedPlant",),
    "piezopreload.artifacts.schedule": ("PreloadSchedule", "ScheduleSummary"),
    "piezopreload.artifacts.summaries": ("SystemSummary",),
    "piezopreload.artifacts.system": ("SystemRecord", "TrackingNumbers"),
    "piezopreload.artifacts.learned": ("LearnedSignal",),
    "piezopreload.artifacts.sweep": ("SweepPoint",),
    "piezopreload.design.preload": ("DesignSpec",),
    "piezopreload.design.study": ("DesignResult",),
    "piezopreload.design.system": ("SystemRun",),
    "piezopreload.tuning.feedforward": ("IdentifiedFeedforward", "FeedforwardInfo"),
    "piezopreload.tuning.learning": ("LearningResult", "LearnedWritten"),
    "piezopreload.tuning.identification": ("identify", "Identification", "Window"),
    "piezopreload.tuning.identify": ("PIIdentifier", "NotFittedError"),
    "piezopreload.tuning.autotune": ("autotune",),
    "piezopreload.tuning.autotune_result": ("AutotuneResult", "SampledCheck"),
    "piezopreload.tuning.plantfit": ("fit_plant", "FittedPlant"),
    "piezopreload.rig.export": ("export",),
}.items() for name in names}

if TYPE_CHECKING:  # the same names, imported, for type checkers and IDEs (tests/test_typing.py holds the three equal)
    __version__: str
    from piezopreload.artifacts.design import DesignPoint, DesignRecord
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.artifacts.hysteresis import DataSource, FitError, IdentifiedModel
    from piezopreload.artifacts.learned import LearnedSignal
    from piezopreload.artifacts.manifest import StudyRef
    from piezopreload.artifacts.plant import DesignedPlant
    from piezopreload.artifacts.requirements import Requirement
    from piezopreload.artifacts.schedule import PreloadSchedule, ScheduleSummary
    from piezopreload.artifacts.summaries import SystemSummary
    from piezopreload.artifacts.sweep import SweepPoint
    from piezopreload.artifacts.system import SystemRecord, TrackingNumbers
    from piezopreload.artifacts.tuning import (
        ActiveBound,
        ComparisonRow,
        MinimumTimeBound,
        TrackingFloor,
        TuningResult,
        TuningSolve,
    )
    from piezopreload.artifacts.validation import Failure, Metrics, ValidationResult
    from piezopreload.codesign import CodesignResult, CodesignWeights
    from piezopreload.core.errors import ArtifactError, InfeasibleError, InputError, InternalError, PiezopreloadError
    from piezopreload.core.tables import MeasuredRecord, read_record
    from piezopreload.design.preload import DesignSpec
    from piezopreload.design.study import DesignResult
    from piezopreload.design.system import SystemRun
    from piezopreload.models.actuator import Plant
    from piezopreload.models.closedloop import ClosedLoopRun, Reference
    from piezopreload.models.controller import PIDGains
    from piezopreload.models.metrics import StepMetrics
    from piezopreload.outcome import RunSummary, StudyResult
    from piezopreload.results import SimulationInfo, StudyReproduction, StudyRun
    from piezopreload.rig.export import export
    from piezopreload.schedule import ScheduleLearning
    from piezopreload.study import Study, load_study, shipped_studies
    from piezopreload.sweep import SweepResult
    from piezopreload.tuning.autotune import autotune
    from piezopreload.tuning.autotune_result import AutotuneResult, SampledCheck
    from piezopreload.tuning.compare import PublishedRow
    from piezopreload.tuning.feedforward import FeedforwardInfo, IdentifiedFeedforward
    from piezopreload.tuning.identification import Identification, Window, identify
    from piezopreload.tuning.identify import NotFittedError, PIIdentifier
    from piezopreload.tuning.learning import LearnedWritten, LearningResult
    from piezopreload.tuning.plantfit import FittedPlant, fit_plant


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("piezopreload")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"


#: names exported before under another name: the measured record was ``Record``, the name of every artifact
#: record's base class (:class:`piezopreload.core.records.Record`)
_FORMER = {"Record": "MeasuredRecord"}

if not TYPE_CHECKING:  # hidden from type checkers, which would otherwise take any name as defined here

    def __getattr__(name: str) -> Any:
        if name == "__version__":
            value = _version()
        elif name in _EXPORTS:
            value = getattr(importlib.import_module(_EXPORTS[name]), name)
        elif name in _FORMER:  # a name this module exported before, kept so that existing scripts run
            value = getattr(importlib.import_module(_EXPORTS[_FORMER[name]]), _FORMER[name])
        else:
            raise AttributeError(f"module 'piezopreload' has no attribute '{name}'")
        globals()[name] = value  # the next use is a plain attribute
        return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
