"""A P-I model from its document (:meth:`to_dict` of each model): plain dicts, the artifact layer adds the envelope."""

from __future__ import annotations

from typing import Any

from piezopreload.core.errors import InputError, InternalError
from piezopreload.models.hysteresis.creep import CREEP_SUFFIX, Creep, CreepPI
from piezopreload.models.hysteresis.pi import AsymmetricPI, ClassicalPI, HysteresisModel, ModifiedPI

__all__ = ["model_from_dict", "MODEL_KINDS"]

_FIELDS: dict[str, tuple[type[HysteresisModel], tuple[str, ...]]] = {
    "classical": (ClassicalPI, ("thresholds", "weights", "offset")),
    "paper-asymmetric": (AsymmetricPI, ("thresholds", "weights_rising", "weights_falling", "offset")),
    "modified": (
        ModifiedPI,
        ("thresholds", "weights", "deadzone_thresholds", "deadzone_weights", "bias", "offset"),
    ),
}
#: every kind a model document may name
MODEL_KINDS = tuple(sorted(_FIELDS)) + tuple(sorted(k + CREEP_SUFFIX for k in _FIELDS))


def model_from_dict(data: dict[str, Any], where: str = "model") -> HysteresisModel | CreepPI:
    """Rebuild a model from :meth:`to_dict` output; errors (:class:`InputError`, a ValueError) name the field.

    A kind ending in ``+creep`` (``"classical+creep"``, ...) is a :class:`CreepPI`: the
    hysteresis model's fields plus a ``creep`` object. Documents written before creep existed
    read as they did.
    """
    if not isinstance(data, dict):
        raise InputError(f"{where} must be an object, got {type(data).__name__}.")
    kind = data.get("kind")
    if isinstance(kind, str) and kind.endswith(CREEP_SUFFIX) and kind[: -len(CREEP_SUFFIX)] in _FIELDS:
        return _creep_model_from_dict(data, kind, where)
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise InputError(f"{where}.kind must be one of {list(MODEL_KINDS)}, got {kind!r}.")
    cls, names = _FIELDS[kind]
    missing = [n for n in names if n not in data]
    if missing:
        raise InputError(f"{where}.{missing[0]} is missing (a {kind} model needs {', '.join(names)}).")
    try:
        return cls(**{n: data[n] for n in names})
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {exc}") from None


def _creep_model_from_dict(data: dict[str, Any], kind: str, where: str) -> CreepPI:
    base = kind[: -len(CREEP_SUFFIX)]
    creep = data.get("creep")
    if not isinstance(creep, dict):
        raise InputError(f"{where}.creep must be an object with time_constants_s, weights and sample_period_s "
                         f"(a {kind} model), got {type(creep).__name__}.")
    missing = [n for n in ("time_constants_s", "weights", "sample_period_s") if n not in creep]
    if missing:
        raise InputError(f"{where}.creep.{missing[0]} is missing (a creep bank needs time_constants_s, "
                         "weights, sample_period_s).")
    hysteresis = model_from_dict({k: v for k, v in data.items() if k != "creep"} | {"kind": base}, where)
    if isinstance(hysteresis, CreepPI):  # not reached: the caller checked that base is a plain kind
        raise InternalError(f"{where}.kind {kind!r}: a creep model inside a creep model.")
    try:
        bank = Creep(creep["time_constants_s"], creep["weights"], creep["sample_period_s"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}.creep: {exc}") from None
    return CreepPI(hysteresis, bank)
