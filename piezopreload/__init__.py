"""piezopreload: design and tuning studies for feed drives with piezo-actuated ball-screw preload.

The front door for design-study scripts: ``import piezopreload as pp``. The README's example is
the short tour (``pp.load_study``, ``study.tune``, ``tuned.validate``, ``study.simulate``,
``pp.export``, ``study.run``); the documentation's API reference lists every name exported here.

The physics lives in :mod:`piezopreload.models`, the typed artifacts in
:mod:`piezopreload.artifacts`, identification and tuning in :mod:`piezopreload.tuning`, the design
in :mod:`piezopreload.design`, the rig executor in :mod:`piezopreload.rig`, the report in
:mod:`piezopreload.reports`.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("piezopreload")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.hysteresis import IdentifiedModel
from piezopreload.core.errors import (
    ArtifactError,
    InfeasibleError,
    InputError,
    InternalError,
    PiezopreloadError,
)
from piezopreload.core.tables import Record, read_record
from piezopreload.design.study import DesignResult
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import ClosedLoopRun, Reference
from piezopreload.models.controller import PIDGains
from piezopreload.models.metrics import StepMetrics
from piezopreload.results import ScheduleLearning, StudyRun, TuningResult
from piezopreload.rig.export import export
from piezopreload.study import Study, load_study, shipped_studies
from piezopreload.tuning.autotune import autotune
from piezopreload.tuning.autotune_result import AutotuneResult
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.identification import Identification, Window, identify
from piezopreload.tuning.identify import NotFittedError, PIIdentifier
from piezopreload.tuning.plantfit import FittedPlant, fit_plant

__all__ = [
    "__version__", "load_study", "shipped_studies", "Study", "GainSet", "TuningResult", "StudyRun", "ScheduleLearning",
    "ClosedLoopRun", "Plant",
    "DesignResult", "IdentifiedFeedforward", "PIDGains", "Reference", "StepMetrics", "Record", "read_record",
    "export", "identify", "Identification", "PIIdentifier", "NotFittedError", "IdentifiedModel", "Window",
    "autotune", "AutotuneResult", "fit_plant", "FittedPlant", "PiezopreloadError", "InputError", "ArtifactError",
    "InfeasibleError", "InternalError", "SweepResult",
]


def __getattr__(name: str) -> object:
    # the sweep loads the whole pipeline (the report's figures, the rig): on first use, not on import
    if name == "SweepResult":
        from piezopreload.sweep import SweepResult

        return SweepResult
    raise AttributeError(f"module 'piezopreload' has no attribute '{name}'")
