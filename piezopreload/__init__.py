"""piezopreload: design and tuning studies for feed drives with piezo-actuated ball-screw preload.

The front door for design-study scripts::

    import piezopreload as pp
    study = pp.load_study()                            # the default study (the machine axis); a name or a file
    study.plant                                        # the plant every step runs on (here: its design's)
    s2 = study.replace(design={"failsafe_load_N": 800.0})  # a validated, changed copy
    ff = study.identify_feedforward()                  # honours [feedforward] data
    tuned = study.tune(feedforward=ff)                 # TuningResult: .gains, .table, .to_dict(), .plot()
    gain_set = tuned.validate(plants=200, seed=0)      # GainSet: .validated, .gains, .validation
    run = study.simulate(gain_set, reference="step")   # StudyRun: .step_metrics(), .plot()
    design = study.design()                            # DesignResult: .optimum, .fronts, .schedule, .plot()
    gain_set.save("gains.json"); pp.GainSet.load("gains.json")
    pp.export(gain_set, "labview")                     # the text the CLI writes; a model alone: pp.export(ff.record, "plc")
    learned = study.learn(gain_set, reference="schedule")  # ScheduleLearning: along the preload schedule
    result = study.run(out="piezopreload-out")         # the whole pipeline, as ``piezopreload run``
    sweep = study.sweep({"tuning.ms_max": [1.4, 1.6]})  # SweepResult: .rows, .plot(x, y), as ``piezopreload sweep``
    tuned = pp.autotune(plant, Ms=1.4, delay_s=0.001)  # AutotuneResult for any python-control plant: .gains, .plot()
    fit = pp.fit_plant("step.csv")                     # FittedPlant from a measured step response; pp.autotune(fit, ...)

The physics lives in :mod:`piezopreload.models`, identification and tuning in
:mod:`piezopreload.tuning`, the design in :mod:`piezopreload.design`, the rig executor in
:mod:`piezopreload.rig`; ``docs/`` has the equations and the architecture.
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
    "ClosedLoopRun",
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
