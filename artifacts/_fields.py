"""Reading an artifact's fields: each one checked, a missing, mistyped or non-finite one named with its path.

>>> f = Fields({"force_N": 3.0, "series": {"t_s": [0.0, 1.0]}}, "system.json")
>>> f.number("force_N"), f.sub("series").array("t_s").tolist()
(3.0, [0.0, 1.0])
>>> f.number("stiffness_N_per_um")
Traceback (most recent call last):
...
piezopreload.core.errors.ArtifactError: system.json: field 'stiffness_N_per_um' is missing
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.errors import ArtifactError

__all__ = ["Fields", "number", "optional_number", "count", "optional_count", "text", "optional_text", "flag",
           "mapping"]

T = TypeVar("T")
_MISSING = object()


# ---- one value: converters for readers that name the field themselves (a ValueError says what was expected) -------
def number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ValueError(f"expected a finite number, got {x!r}")
    return float(x)


def optional_number(x: Any) -> float | None:
    return None if x is None else number(x)


def count(x: Any) -> int:
    if isinstance(x, bool) or not isinstance(x, int | float) or not float(x).is_integer() or x < 0:
        raise ValueError(f"expected a whole number >= 0, got {x!r}")
    return int(x)


def optional_count(x: Any) -> int | None:
    return None if x is None else count(x)


def text(x: Any) -> str:
    if not isinstance(x, str):
        raise ValueError(f"expected text, got {x!r}")
    return x


def optional_text(x: Any) -> str | None:
    return None if x is None else text(x)


def flag(x: Any) -> bool:
    if not isinstance(x, bool):
        raise ValueError(f"expected true or false, got {x!r}")
    return x


def mapping(x: Any) -> dict[str, Any]:
    if not isinstance(x, dict):
        raise ValueError(f"expected an object, got {type(x).__name__}")
    return dict(x)


class Fields:
    """The fields of one object of an artifact (``doc``), its path in the document ``prefix``, the file ``shown``."""

    def __init__(self, doc: Any, shown: str, prefix: str = "") -> None:
        self.shown, self.prefix = shown, prefix
        if not isinstance(doc, dict):
            raise self.fail(None, f"expected an object, got {type(doc).__name__}")
        self.doc = doc

    def path(self, key: str | None) -> str:
        return self.prefix if key is None else f"{self.prefix}.{key}" if self.prefix else key

    def fail(self, key: str | None, message: str) -> ArtifactError:
        where = self.path(key)
        return ArtifactError(f"{self.shown}: field '{where}' {message}" if where else f"{self.shown}: {message}")

    def has(self, key: str) -> bool:
        return self.doc.get(key) is not None

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        if key not in self.doc:
            if default is _MISSING:
                raise self.fail(key, "is missing")
            return default
        return self.doc[key]

    def sub(self, key: str) -> Fields:
        """The fields of the object at ``key``."""
        return Fields(self.raw(key), self.shown, self.path(key))

    def number(self, key: str, default: Any = _MISSING) -> float:
        x = self.raw(key, default)
        if isinstance(x, bool) or not isinstance(x, int | float):
            raise self.fail(key, f"must be a number, got {x!r}")
        if not math.isfinite(x):
            raise self.fail(key, f"must be finite, got {x!r}")
        return float(x)

    def optional_number(self, key: str) -> float | None:
        """A number, or None where the field is null or absent (a limit that is not set, say)."""
        return None if self.doc.get(key) is None else self.number(key)

    def integer(self, key: str, default: Any = _MISSING) -> int:
        x = self.number(key, default)
        if not float(x).is_integer():
            raise self.fail(key, f"must be a whole number, got {x!r}")
        return int(x)

    def flag(self, key: str, default: Any = _MISSING) -> bool:
        x = self.raw(key, default)
        if not isinstance(x, bool):
            raise self.fail(key, f"must be true or false, got {x!r}")
        return x

    def text(self, key: str, default: Any = _MISSING) -> str:
        x = self.raw(key, default)
        if not isinstance(x, str):
            raise self.fail(key, f"must be text, got {x!r}")
        return x

    def texts(self, key: str, default: Any = _MISSING) -> tuple[str, ...]:
        x = self.raw(key, default)
        if not isinstance(x, list | tuple) or not all(isinstance(s, str) for s in x):
            raise self.fail(key, f"must be a list of text, got {x!r}")
        return tuple(x)

    def array(self, key: str, size: int | None = None) -> NDArray[np.float64]:
        """A list of finite numbers (``size`` of them, where given) as a float array."""
        x = self.raw(key)
        if not isinstance(x, list | tuple) or any(isinstance(v, bool) or not isinstance(v, int | float) for v in x):
            raise self.fail(key, "must be a list of numbers")
        a = np.asarray(x, float)
        if not np.all(np.isfinite(a)):
            raise self.fail(key, "must hold finite numbers only")
        if size is not None and a.size != size:
            raise self.fail(key, f"must have {size} entries (one per sample), got {a.size}")
        return a

    def optional_array(self, key: str, size: int | None = None) -> NDArray[np.float64] | None:
        return None if self.doc.get(key) is None else self.array(key, size)

    def mapping(self, key: str, default: Any = _MISSING) -> dict[str, Any]:
        x = self.raw(key, default)
        if not isinstance(x, dict):
            raise self.fail(key, f"must be an object, got {type(x).__name__}")
        return dict(x)

    def items(self, key: str, read: Callable[[Fields], T]) -> tuple[T, ...]:
        """Each object of the list at ``key`` read by ``read`` (its errors name the entry's index)."""
        x = self.raw(key)
        if not isinstance(x, list | tuple):
            raise self.fail(key, f"must be a list, got {type(x).__name__}")
        return tuple(read(Fields(d, self.shown, f"{self.path(key)}[{i}]")) for i, d in enumerate(x))

    def build(self, make: Callable[[], T]) -> T:
        """``make()``, its ``ValueError`` (a record that does not validate itself) named as this object's."""
        try:
            return make()
        except ValueError as exc:
            raise self.fail(None, f"is not valid: {exc}") from None
