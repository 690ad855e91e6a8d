"""Prandtl-Ishlinskii hysteresis: play operators, P-I models, creep, their inverses and their documents.

Section 3.2 of Zhang, Jin, Lin (2021), restated in ``docs/models.md`` (section 2). One module
per job:

* :mod:`~piezopreload.models.hysteresis.operators`: the play operator, eq. (14); the
  one-sided dead-zone operators; the algebra of the inverse weights, eqs. (19)-(20);
* :mod:`~piezopreload.models.hysteresis.pi`: the classical model, eq. (15), the paper's
  direction-switched asymmetric model, eq. (18), and Kuhnen's modified model;
* :mod:`~piezopreload.models.hysteresis.creep`: creep, a bank of first-order lags on the input
  (Kuhnen's linear creep operators) added to any of the three models (:class:`CreepPI`);
* :mod:`~piezopreload.models.hysteresis.inverse`: the real-time inverse of every one of them,
  with or without creep: one one-sample step (:class:`InverseStep`, over the ops table of
  :mod:`piezopreload.models.ops`) that the numpy simulation, the compiled rig step and every
  export run;
* :mod:`~piezopreload.models.hysteresis.serialise`: a model from its document.

Everything here is pure: parameters are frozen dataclasses that validate themselves, the
functions take explicit initial states and return final states, nothing is printed or read.
Arrays broadcast over leading batch dimensions: an input of shape ``(..., N)`` gives operator
outputs of shape ``(..., N, n)``.
"""

from piezopreload.models.hysteresis.creep import (
    CREEP_SUFFIX,
    Creep,
    CreepPI,
    LagCoefficients,
    creep_lags,
    inverse_at,
    lag_coefficients,
    log_spaced_time_constants,
)
from piezopreload.models.hysteresis.inverse import (
    InverseAsymmetricPI,
    InverseClassicalPI,
    InverseCreepPI,
    InverseModel,
    InverseModifiedPI,
    InverseSpec,
    InverseStep,
    inverse_realtime,
)
from piezopreload.models.hysteresis.operators import (
    DeadZone,
    NotInvertibleError,
    deadzone,
    play,
    play_step,
    rising,
    uniform_thresholds,
)
from piezopreload.models.hysteresis.pi import AsymmetricPI, ClassicalPI, HysteresisModel, ModifiedPI
from piezopreload.models.hysteresis.serialise import MODEL_KINDS, model_from_dict

__all__ = [
    "NotInvertibleError", "play", "play_step", "rising", "deadzone", "DeadZone", "uniform_thresholds",
    "ClassicalPI", "AsymmetricPI", "ModifiedPI", "HysteresisModel",
    "InverseClassicalPI", "InverseAsymmetricPI", "InverseModifiedPI", "InverseCreepPI", "InverseModel",
    "InverseSpec", "InverseStep", "inverse_realtime", "inverse_at",
    "log_spaced_time_constants", "LagCoefficients", "lag_coefficients", "creep_lags", "Creep", "CreepPI",
    "CREEP_SUFFIX", "model_from_dict", "MODEL_KINDS",
]
