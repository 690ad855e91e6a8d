"""Validation tables: a frozen dataclass checks its fields against rows of (field, test, requirement).

A parameter object states its rules once, as data, and :func:`check_fields` runs them in
order; the first field that fails is named in the error with its value and what it must be:

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Axis:
...     mass_kg: float
...     def __post_init__(self) -> None:
...         check_fields(self, "Axis", (("mass_kg", lambda m: m > 0, "must be > 0"),))
>>> Axis(-1.0)
Traceback (most recent call last):
...
ValueError: Axis.mass_kg must be > 0, got -1.0.

Rules between fields (one bound below another) are written as code after the table.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["FieldRule", "check_fields"]

#: (field name, test of the field's value, what the value must be: "must be finite and > 0")
FieldRule = tuple[str, Callable[[Any], Any], str]


def check_fields(obj: object, owner: str, rules: Iterable[FieldRule], error: type[Exception] = ValueError) -> None:
    """Raise ``error("<owner>.<field> <requirement>, got <value>.")`` for the first rule whose test fails.

    Parameters
    ----------
    obj : object
        The object whose fields are checked (read with ``getattr``).
    owner : str
        The name shown before the field (the class's public name).
    rules : iterable of (str, callable, str)
        ``(field, test, requirement)`` rows, checked in order; ``test(value)`` is true when the
        value is acceptable.
    error : type of Exception
        The exception raised (``ValueError`` or a subclass such as ``InputError``).
    """
    for name, test, requirement in rules:
        value = getattr(obj, name)
        if not test(value):
            raise error(f"{owner}.{name} {requirement}, got {value!r}.")
