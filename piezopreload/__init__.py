"""piezopreload: design and tuning studies for feed drives with piezo-actuated ball-screw preload.

The front door for design-study scripts::

    import piezopreload as pp
    study = pp.load_study()                            # the default study (the machine axis); a name or a file
    s2 = study.replace(rig={"bolt_preload_N": 30.0})   # a validated, changed copy
    ff = study.identify_feedforward()                  # honours [feedforward] data
    tuned = study.tune(feedforward=ff)                 # TuningResult: .gains, .table, .to_dict(), .plot()
    gain_set = tuned.validate(plants=200, seed=0)      # GainSet: .validated, .gains, .validation
    run = study.simulate(gain_set, reference="step")   # StudyRun: .step_metrics(), .plot()
    design = study.design()                            # DesignResult: .optimum, .fronts, .schedule, .plot()
    gain_set.save("gains.json"); pp.GainSet.load("gains.json")
    gain_set.export("labview")                         # the text the CLI writes
    result = study.run(out="piezopreload-out")         # the whole pipeline, as ``piezopreload run``
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
from piezopreload.results import StudyRun, TuningResult
from piezopreload.study import Study, load_study, shipped_studies
from piezopreload.tuning.autotune import autotune
from piezopreload.tuning.autotune_result import AutotuneResult
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.holdout import HoldoutFit, Window
from piezopreload.tuning.holdout import identify_record as identify
from piezopreload.tuning.plantfit import FittedPlant, fit_plant

__all__ = [
    "__version__", "load_study", "shipped_studies", "Study", "GainSet", "TuningResult", "StudyRun", "ClosedLoopRun",
    "DesignResult", "IdentifiedFeedforward", "PIDGains", "Reference", "StepMetrics", "Record", "read_record",
    "identify", "HoldoutFit", "Window", "autotune", "AutotuneResult", "fit_plant", "FittedPlant", "PiezopreloadError", "InputError", "ArtifactError", "InfeasibleError",
    "InternalError",
]
