"""Artifact records whose fields are declared once: their reader, writer, required fields and docs come from it.

A record of an artifact is a frozen dataclass made with :func:`record` from :class:`Record` (or, for a
whole document of one kind, :class:`Artifact`), each of its fields declared with :func:`entry`: its
documentation, its unit and its range (the one schema dialect: a study's tables are declared the same way,
:func:`piezopreload.core.config.key` writing an entry in a table's order), and, where it does not sit at the
top of its object under its own name, its place in the document. Its
type is the field's annotation: ``float`` (a finite number), ``int``, ``bool``, ``str``, a tuple or a list
of them, a float array (``Array``), another record, a tuple or a list of records, a dict of numbers,
strings or records, a dict of anything (an object kept as it is), with ``| None`` where null stands for
"not set". A type the declaration does not know (a model of :mod:`piezopreload.models`) is read by the
entry's ``read`` and written by its ``write``.

From that one declaration come

* the reader, :meth:`Record.from_dict`: every field checked in the order of the fields, the first that
  is missing or wrong named with its path in the document, in one message format::

      FILE: field 'PATH' is missing; expected WHAT; HOW TO WRITE IT AGAIN
      FILE: field 'PATH' must be WHAT, got VALUE; HOW TO WRITE IT AGAIN
      FILE: field 'PATH' is not valid: WHY; HOW TO WRITE IT AGAIN

  (the last where the record's own checks refuse the values it was given);
* the writer, :meth:`Record.to_dict` (a record that writes more, a figure derived from its fields,
  adds it to this one's);
* the fields a document of an artifact's kind must hold, :meth:`Artifact.required`, from which
  :data:`piezopreload.artifacts.registry.KINDS` is made;
* the record's numpydoc ``Parameters`` section: its fields, their types, units and docs.

>>> @record
... class Fit(Record):
...     '''A fit's error on a window of its record.'''
...     rms_pct: float = entry("The RMS error.", unit="%", ge=0)
...     window_s: tuple[float, float] | None = entry("The window it was scored on.", unit="s", default=None)
>>> Fit.from_dict({"rms_pct": 0.5, "window_s": [0, 6]})
Fit(rms_pct=0.5, window_s=(0.0, 6.0))
>>> Fit.from_dict({"rms_pct": -1}, "fit.json")
Traceback (most recent call last):
...
piezopreload.core.errors.ArtifactError: fit.json: field 'rms_pct' must be a finite number >= 0, got -1
>>> Fit(0.5).to_dict()
{'rms_pct': 0.5, 'window_s': None}
"""

from __future__ import annotations

import dataclasses
import enum
import math
import re
import textwrap
import types
from collections.abc import Callable
from dataclasses import MISSING, Field, dataclass, field, fields, replace
from pathlib import Path
from typing import (
    Any,
    ClassVar,
    Self,
    TypeVar,
    Union,
    dataclass_transform,
    get_args,
    get_origin,
    get_type_hints,
    overload,
)

import numpy as np

from piezopreload.core.artifacts import ArtifactKind, field_message, read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError, InputError

__all__ = ["Entry", "entry", "record", "Record", "Artifact", "SavedArtifact", "Raw", "load_one_of", "object_without",
           "kind_of", "Checked", "checked", "check_entries", "as_members", "hold_members", "read_table", "Invalid",
           "MANY", "table_values", "TableOf",
           "UnitKey",
           "takes"]

#: the metadata entry of a field declared with :func:`entry`
ENTRY = "piezopreload.entry"


class Invalid(InputError):
    """A value that is not what its field declares, with the field's key (``ball_mm``) and, made in code, its type.

    Parameters
    ----------
    path : str
        The key (or its path inside the value: ``rig.noise_N``).
    message : str
        What is wrong, as a predicate: ``must be a number > 0, got -1.0``.
    owner : str
        The type's name where it was made in code ("": the key alone).
    """

    def __init__(self, path: str, message: str, owner: str = "") -> None:
        super().__init__(f"'{owner}.{path}' {message}" if owner else f"'{path}' {message}")
        self.path = path
        self.message = message


class _Nothing:
    """No value: a field whose document may not leave it out (:attr:`Entry.absent`)."""

    def __repr__(self) -> str:
        return "NOTHING"


NOTHING: Any = _Nothing()

_R = TypeVar("_R")


@dataclass(frozen=True)
class Entry:
    """What a field of a record declares beside its type and default.

    Parameters
    ----------
    doc : str
        What the field holds, in a sentence (the record's ``Parameters`` section shows it).
    unit : str
        Its unit ("" where it has none or its name carries it).
    name : str
        Its key in the document ("": the field's own name).
    at : str
        The dotted path of the object that holds it in the document ("": the record's own object).
    required : bool
        Whether a document must hold it even though the field has a default (a default for code, not for files).
    omit : bool
        Whether :meth:`Record.to_dict` leaves the field out where it is None (or, its default empty, empty).
    inline : bool
        For a field that is a record: its fields sit in this record's own object, not in one of their own.
    stored : bool
        Whether the document holds it at all (False: set by the reader or the writer of the file, a hash).
    ge, gt, le, lt : float or None
        Bounds of a number (or of each number of a list).
    choices : tuple of str
        The strings a string may be.
    size : str, int, (int, int) or None
        A list's or an array's length: a number, a range (least, most), or the name of an earlier field of the
        same length.
    increasing : bool
        Whether a list's numbers must be strictly increasing.
    rows : bool
        Whether an array is 2-D: a list of rows of one length (``size`` counts the rows).
    read : callable or None
        ``read(value)`` makes the field from its document's value, for a type the declaration does not know;
        a ``ValueError``, ``TypeError`` or ``KeyError`` it raises is the field's "is not valid".
    each : bool
        Whether ``read`` and ``write`` take each entry of a list or a dict (the field a tuple or a dict of them).
    via : type or None
        A record that is the document's form of the field's type: the field is read as that record and made
        with its ``to_value()``, and written as ``via.from_value(value)``.
    spread : tuple of str
        For a dict field: the keys its entries may have, each entry sitting at the top of the record's own object
        beside its other fields (not in an object of its own); a document lacking one of them lacks that entry.
    absent : object
        What a document without the key (or with null there) reads as, for a field the constructor requires (files
        written before the field was recorded); none: such a document is refused.
    write : callable or None
        ``write(value)``: the field's document value, the inverse of ``read``.
    takes : str
        What a field read by ``read`` takes, in words ("a rig's parameters"), for the messages.
    """

    doc: str
    unit: str = ""
    name: str = ""
    at: str = ""
    required: bool = False
    omit: bool = False
    inline: bool = False
    stored: bool = True
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[str, ...] = ()
    size: str | int | tuple[int, int] | None = None
    increasing: bool = False
    rows: bool = False
    read: Callable[[Any], Any] | None = None
    write: Callable[[Any], Any] | None = None
    takes: str = ""
    each: bool = False
    via: Any = None
    absent: Any = NOTHING
    spread: tuple[str, ...] = ()


def entry(doc: str, *, default: Any = MISSING, default_factory: Any = MISSING, unit: str = "", name: str = "",
          at: str = "", required: bool = False, omit: bool = False, inline: bool = False, stored: bool = True,
          ge: float | None = None, gt: float | None = None, le: float | None = None, lt: float | None = None,
          choices: tuple[str, ...] | list[str] = (), size: str | int | tuple[int, int] | None = None,
          increasing: bool = False, rows: bool = False, read: Callable[[Any], Any] | None = None,
          write: Callable[[Any], Any] | None = None, takes: str = "", each: bool = False, via: Any = None,
          absent: Any = NOTHING, spread: tuple[str, ...] = ()) -> Any:
    """Declare a field of a :class:`Record`: see :class:`Entry` for what each argument declares.

    Parameters
    ----------
    doc : str
        What the field holds, in a sentence.
    default, default_factory : object, optional
        The field's default (a dict or a list default is copied for each record); none: the field is required.
    unit, name, at, required, omit, inline, stored, ge, gt, le, lt, choices, size, increasing, rows, read, write,
    takes, each, via, absent, spread
        As :class:`Entry` has them.

    Returns
    -------
    dataclasses.Field
        The dataclass field, its declaration in its metadata.
    """
    meta = {ENTRY: Entry(doc, unit, name, at, required, omit, inline, stored, ge, gt, le, lt, tuple(choices), size,
                         increasing, rows, read, write, takes, each, via, absent, tuple(spread))}
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=meta)
    if isinstance(default, dict | list):
        copy = type(default)
        return field(default_factory=lambda: copy(default), metadata=meta)
    return field(default=default, metadata=meta)


# --------------------------------------------------------------------------------------
# what a field holds, from its annotation
# --------------------------------------------------------------------------------------
_SCALARS: dict[Any, str] = {float: "number", int: "integer", bool: "flag", str: "text"}
_A = {"number": "a finite number", "integer": "a whole number", "flag": "true or false", "text": "a string",
      "any": "a value", "object": "an object"}
_PLURAL = {"number": "finite numbers", "integer": "whole numbers", "flag": "booleans", "text": "strings",
           "any": "values",
           "object": "objects", "number|null": "finite numbers or nulls", "integer|null": "whole numbers or nulls",
           "text|null": "strings or nulls"}


@dataclass(frozen=True)
class _Spec:
    """A declared field as the reader and the writer see it."""

    name: str  # the attribute
    key: str  # its key in the document
    at: tuple[str, ...]  # the path of the object that holds it
    kind: str  # number, integer, flag, text, list, array, record, records, map, object, custom, inline
    item: str  # a list's or a map's entries' kind (number, integer, flag, text, object, record, number|null)
    optional: bool  # None allowed
    default: Any  # MISSING: the document must hold it
    factory: Any
    container: type  # tuple or list, for a list
    length: int | None  # a fixed-length tuple's
    record: Any  # the record type of record, records, map of records, inline
    entry: Entry

    @property
    def has_default(self) -> bool:
        """Whether a document may leave the field out."""
        return self.default is not MISSING or self.factory is not MISSING or self.entry.absent is not NOTHING

    @property
    def in_document(self) -> bool:
        """Whether a document must hold the field."""
        return self.entry.stored and (self.entry.required or not self.has_default) and self.kind != "inline"

    def fallback(self) -> Any:
        """What a document that leaves the field out reads as."""
        if self.entry.absent is not NOTHING:
            return self.entry.absent
        return self.factory() if self.factory is not MISSING else self.default

    def want(self) -> str:
        """What the field takes, in words: ``a number > 0``, ``a list of 3 strings``, ``null or an object``."""
        e = self.entry
        bounds = " and ".join(f"{op} {v:g}" for op, v in ((">=", e.ge), (">", e.gt), ("<=", e.le), ("<", e.lt))
                              if v is not None)
        if self.kind == "enum":
            text = "one of " + ", ".join(_values(self.record))
        elif self.kind in ("number", "integer", "flag", "text", "object"):
            text = ("one of " + ", ".join(e.choices)) if e.choices else _A[self.kind] + (f" {bounds}" if bounds else "")
        elif self.kind in ("list", "array"):
            size = e.size
            count = (f"{self.length} " if self.length else f"{size} " if isinstance(size, int)
                     else f"{size[0]} to {size[1]} " if isinstance(size, tuple) else "")
            per = f" (one per entry of '{size}')" if isinstance(size, str) else ""
            if self.kind == "array" and self.item == "rows":
                return f"a list of {count}rows, each a list of finite numbers" + per
            plural = {"rows": "rows", "bool": "0s and 1s"}.get(self.item, "finite numbers") if self.kind == "array" \
                else _PLURAL[self.item]
            text = f"a list of {count}{plural}"
            text += (f" {bounds}" if bounds else "") + (", strictly increasing" if e.increasing else "") + per
        elif self.kind == "records" or (self.kind == "custom" and e.each and self.container is not dict):
            text = f"a list of {e.takes or 'objects'}"
        elif self.kind == "map" or (self.kind == "custom" and e.each):
            text = "an object of " + (e.takes or _PLURAL.get(self.item, "objects"))
        elif self.kind in ("record", "via"):
            text = "an object"
        else:
            text = e.takes or "a valid value"
        return f"null or {text}" if self.optional else text


def _values(members: Any) -> tuple[str, ...]:
    """The values an enum's members are written as, in its order."""
    return tuple(str(m.value) for m in members)


def _member(members: Any, x: Any) -> Any:
    """The member of the enum ``members`` that ``x`` (a member, or its value as a document or a file writes it) names;
    None where it names none."""
    if isinstance(x, members):
        return x
    if isinstance(x, str) and x in _values(members):
        return members(x)
    return None


def _optional(hint: Any) -> tuple[bool, Any]:
    if get_origin(hint) in (Union, types.UnionType) and type(None) in get_args(hint):
        rest = tuple(a for a in get_args(hint) if a is not type(None))
        return True, (rest[0] if len(rest) == 1 else Union[rest])  # noqa: UP007 (a Union made at run time)
    return False, hint


def _item_kind(hint: Any) -> tuple[str, Any]:
    """The kind of a list's or a map's entries: a scalar, an object, a record, or a number that may be null."""
    optional, inner = _optional(hint)
    if inner in _SCALARS:
        kind = _SCALARS[inner]
        return (kind + "|null" if optional else kind), None
    if isinstance(inner, type) and issubclass(inner, Record):
        return "record", inner
    if inner is Any or get_origin(inner) is dict or inner is dict:
        return "object" if inner is not Any else "any", None
    raise TypeError(f"entries of {hint!r}")


def _spec(owner: type, f: Field[Any], hint: Any) -> _Spec:
    """The :class:`_Spec` of field ``f`` of ``owner`` from its annotation ``hint`` and its declaration."""
    e: Entry | None = f.metadata.get(ENTRY)
    if e is None:
        raise TypeError(f"{owner.__name__}.{f.name}: declare the field with records.entry(doc, ...)")
    optional, inner = _optional(hint)
    base = _Spec(name=f.name, key=e.name or f.name, at=tuple(p for p in e.at.split(".") if p), kind="custom", item="",
                 optional=optional, default=f.default, factory=f.default_factory, container=tuple, length=None,
                 record=None, entry=e)
    origin = get_origin(inner)
    is_record = isinstance(inner, type) and issubclass(inner, Record)
    if e.via is not None:
        return replace(base, kind="via", record=e.via)
    if not e.stored and e.read is None and inner in _SCALARS:  # set by the code, never the document: still checked
        return replace(base, kind=_SCALARS[inner])
    if e.read is not None or not e.stored:
        return replace(base, container=dict if origin is dict else tuple if origin is tuple else list) if e.each \
            else base
    if e.inline and not is_record:
        raise TypeError(f"{owner.__name__}.{f.name}: only a record is inline")
    if isinstance(inner, type) and issubclass(inner, Checked | enum.Enum) and not is_record:
        # a Checked type: its table or constructor reads it; an enum: one of its values, held as its member
        return replace(base, kind="enum" if issubclass(inner, enum.Enum) else base.kind, record=inner)
    if inner in _SCALARS or is_record:
        return replace(base, kind="inline" if e.inline else "record", record=inner) if is_record else \
            replace(base, kind=_SCALARS[inner])
    try:
        return _container_spec(base, inner)
    except TypeError:
        if not issubclass(owner, Record):  # a domain type's field of a type the declaration does not know: its own
            return base                    # constructor checks it
        raise TypeError(f"{owner.__name__}.{f.name}: a field holds float, int, bool, str, an array, a record, a tuple, "
                        f"list or dict of them, not {hint!r}; declare how to read it (entry(..., read=...))") from None


def _container_spec(base: _Spec, inner: Any) -> _Spec:
    """The spec of an array, a tuple, a list or a dict (a ``TypeError`` for any other type)."""
    origin, args = get_origin(inner), get_args(inner)
    if origin is np.ndarray:
        dtype = get_args(args[1])[0] if len(args) == 2 and get_args(args[1]) else np.float64
        item = "rows" if base.entry.rows else "bool" if dtype is np.bool_ else "number"
        return replace(base, kind="array", item=item)
    if origin in (tuple, list) and args:
        fixed = origin is tuple and not (len(args) == 2 and args[1] is Ellipsis)
        item, rec = _item_kind(args[0])
        if fixed and any(a != args[0] for a in args):
            raise TypeError("a tuple of mixed types")
        return replace(base, kind="records" if item == "record" else "list", item=item, record=rec,
                       container=origin, length=len(args) if fixed else None)
    if origin is dict and len(args) == 2 and args[0] is str:
        item, rec = _item_kind(args[1])
        return replace(base, kind="object") if item in ("any", "object") else \
            replace(base, kind="map", item=item, record=rec)
    if inner is dict:
        return replace(base, kind="object")
    raise TypeError(f"{inner!r}")


_SPECS: dict[type, tuple[_Spec, ...]] = {}


def _specs(cls: type) -> tuple[_Spec, ...]:
    if cls not in _SPECS:
        hints = get_type_hints(cls)
        _SPECS[cls] = tuple(_spec(cls, f, hints[f.name]) for f in fields(cls))
    return _SPECS[cls]


# --------------------------------------------------------------------------------------
# reading: one message format
# --------------------------------------------------------------------------------------
def object_without(key: str) -> Callable[[Any], dict[str, Any]]:
    """A field's reader (``entry(read=...)``) of a JSON object kept as written but for ``key``, which another field
    of the record reads (an artifact's ``inputs`` beside the one input it declares)."""
    def read(doc: Any) -> dict[str, Any]:
        if not isinstance(doc, dict):
            raise ValueError(f"expected an object, got {type(doc).__name__}")
        return {k: v for k, v in doc.items() if k != key}

    return read


class _Wrong(Exception):
    """A field that is missing or wrong, at ``path`` in the document (made an :class:`ArtifactError` at the top)."""

    def __init__(self, path: str, problem: str) -> None:
        super().__init__(path, problem)
        self.path, self.problem = path, problem


def _got(value: Any) -> str:
    """A document's value as a message shows it: JSON's words, a long list or an object by its size."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, list | tuple):
        if len(value) <= 4 and all(v is None or isinstance(v, bool | int | float) for v in value):
            return "[" + ", ".join(_got(v) for v in value) + "]"
        return f"a list of {len(value)} entries"
    if isinstance(value, dict):
        return "an object"
    return repr(value)


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _is(x: Any, kind: str) -> bool:
    if kind.endswith("|null") and x is None:
        return True
    kind = kind.removesuffix("|null")
    if kind == "flag":
        return isinstance(x, bool)
    if kind == "text":
        return isinstance(x, str)
    if kind == "object":
        return isinstance(x, dict)
    if kind == "any":
        return True
    if isinstance(x, bool) or not isinstance(x, int | float):
        return False
    if kind == "integer":
        return math.isfinite(x) and float(x).is_integer()
    return math.isfinite(x)


def _as(x: Any, kind: str) -> Any:
    if x is None or kind in ("flag", "text", "object", "any"):
        return dict(x) if kind == "object" else x
    return int(x) if kind.startswith("integer") else float(x)


def _in_range(e: Entry, x: Any) -> bool:
    if isinstance(x, str):
        return not e.choices or x in e.choices
    if x is None or isinstance(x, bool | dict):
        return True
    return ((e.ge is None or x >= e.ge) and (e.gt is None or x > e.gt) and (e.le is None or x <= e.le)
            and (e.lt is None or x < e.lt))


def _sized(spec: _Spec, n: int, values: dict[str, Any]) -> bool:
    """Whether a list of ``n`` entries has the length the field declares."""
    size = spec.entry.size
    if isinstance(size, str):
        first, *rest = size.split(".")
        other = values.get(first)
        for name in rest:
            other = getattr(other, name, None)
        return other is None or n == len(other)
    if isinstance(size, tuple):
        return size[0] <= n <= size[1]
    want = size if size is not None else spec.length
    return want is None or n == want


def _custom(spec: _Spec, x: Any, path: str) -> Any:
    """``read(x)``, its errors the field's "is not valid" (each entry's, for a field read entry by entry)."""
    read = spec.entry.read
    if read is None:
        return x

    def one(v: Any, where: str) -> Any:
        try:
            return read(v)
        except Invalid as exc:  # names a key inside the field's value
            raise _Wrong(_join(where, exc.path) if exc.path else where, exc.message) from None
        except (ValueError, TypeError, KeyError, OverflowError) as exc:
            why = str(exc).strip("'") if isinstance(exc, KeyError) else str(exc)
            raise _Wrong(where, f"is not valid: {why}") from None

    if not spec.entry.each:
        return one(x, path)
    if spec.container is dict:
        if not isinstance(x, dict):
            raise _Wrong(path, f"must be {spec.want()}, got {_got(x)}")
        return {str(k): one(v, _join(path, str(k))) for k, v in x.items()}
    if not isinstance(x, list | tuple):
        raise _Wrong(path, f"must be {spec.want()}, got {_got(x)}")
    return spec.container(one(v, _join(path, i)) for i, v in enumerate(x))


def _matrix(spec: _Spec, x: Any, path: str, values: dict[str, Any]) -> Any:
    """A 2-D array from a list of rows of finite numbers, all of one length (its rows ``size``)."""
    if not (isinstance(x, list) and _sized(spec, len(x), values) and all(isinstance(r, list) for r in x)):
        raise _Wrong(path, f"must be {spec.want()}, got {_got(x)}")
    width = len(x[0]) if x else 0
    for i, row in enumerate(x):
        if len(row) != width or not all(_is(v, "number") for v in row):
            raise _Wrong(_join(path, i), f"must be a list of {width} finite numbers (the first row's), got {_got(row)}")
    return np.asarray(x, dtype=np.float64).reshape(len(x), width)


def _read_value(spec: _Spec, x: Any, path: str, values: dict[str, Any]) -> Any:  # noqa: C901 (one branch per kind)
    """The field's value from the document's ``x``; :class:`_Wrong` names what was expected."""
    if x is None and (spec.optional or spec.entry.absent is not NOTHING):
        return None if spec.optional else spec.entry.absent
    kind, e = spec.kind, spec.entry

    def wrong() -> _Wrong:
        return _Wrong(path, f"must be {spec.want()}, got {_got(x)}")

    if kind == "custom":
        return _custom(spec, x, path)
    if kind == "enum":
        if not isinstance(x, str) or _member(spec.record, x) is None:
            raise wrong()
        return spec.record(x)
    if kind == "via":
        made = _read_record(spec.record, x, path)
        try:
            return made.to_value()
        except (ValueError, TypeError) as exc:
            raise _Wrong(path, f"is not valid: {exc}") from None
    if kind in ("number", "integer", "flag", "text", "object"):
        if not (_is(x, kind) and _in_range(e, x)):
            raise wrong()
        return _as(x, kind)
    if kind == "array" and spec.item == "rows":
        return _matrix(spec, x, path, values)
    if kind in ("list", "array"):
        item = "number" if kind == "array" else spec.item
        if not (isinstance(x, list | tuple) and all(_is(v, item) and _in_range(e, v) for v in x)
                and _sized(spec, len(x), values)
                and not (e.increasing and any(b <= a for a, b in zip(x, x[1:])))):
            raise wrong()
        if kind == "array":
            return np.asarray(x, dtype=np.float64) > 0.5 if spec.item == "bool" else np.asarray(x, dtype=np.float64)
        return spec.container(_as(v, item) for v in x)
    if kind == "record":
        return _read_record(spec.record, x, path)
    if kind == "records":
        if not isinstance(x, list | tuple):
            raise wrong()
        return spec.container(_read_record(spec.record, v, _join(path, i)) for i, v in enumerate(x))
    if kind == "map":
        if not isinstance(x, dict):
            raise wrong()
        if spec.item == "record":
            return {str(k): _read_record(spec.record, v, _join(path, str(k))) for k, v in x.items()}
        bad = next((k for k, v in x.items() if not (_is(v, spec.item) and _in_range(e, v))), None)
        if bad is not None:
            raise _Wrong(_join(path, str(bad)), f"must be {_A.get(spec.item, 'a finite number or null')}, got "
                                               f"{_got(x[bad])}")
        return {str(k): _as(v, spec.item) for k, v in x.items()}
    raise AssertionError(kind)  # pragma: no cover (every kind is handled above)


def _holder(obj: dict[str, Any], spec: _Spec, path: str) -> tuple[Any, str]:
    """The object that holds ``spec`` (``at`` followed from ``obj``) and its path; MISSING where it is absent."""
    holder: Any = obj
    for part in spec.at:
        here = _join(path, part)
        if not isinstance(holder, dict) or part not in holder or holder[part] is None:
            if spec.in_document:
                raise _Wrong(here, "is missing; expected an object")
            return MISSING, here
        holder, path = holder[part], here
        if not isinstance(holder, dict):
            raise _Wrong(path, f"must be an object, got {_got(holder)}")
    return holder, path


def _read_inline(spec: _Spec, holder: Any, path: str) -> Any:
    """An inline record from the object that holds its fields (None where they are all absent and it may be)."""
    if spec.optional or spec.has_default:
        keys = [s.key for s in _specs(spec.record) if s.in_document]
        if holder is MISSING or all(holder.get(k) is None for k in keys):
            return None if spec.optional and not spec.has_default else spec.fallback()
    if holder is MISSING:
        raise _Wrong(path, "is missing; expected an object")
    return _read_record(spec.record, holder, path)


def _renamed(cls: Any, obj: dict[str, Any]) -> dict[str, Any]:
    """``obj`` with the keys an older version wrote (``cls.RENAMED``) under their names now."""
    if not any(k in obj for k in cls.RENAMED):
        return obj
    return {cls.RENAMED.get(k, k): v for k, v in obj.items()}


def _read_field(spec: _Spec, obj: dict[str, Any], path: str, values: dict[str, Any]) -> Any:
    """The value of the field ``spec`` from the record's object ``obj`` at ``path`` (``values``: the fields read so
    far)."""
    holder, where = _holder(obj, spec, path)
    if spec.kind == "inline":
        return _read_inline(spec, holder, where)
    if spec.entry.spread:  # a dict whose entries sit beside the record's fields, under their own keys
        spread = {} if holder is MISSING else {k: v for k, v in holder.items() if k in spec.entry.spread}
        return _read_value(spec, spread, where, values)
    here = _join(where, spec.key)
    if holder is MISSING or spec.key not in holder:
        if spec.in_document or not spec.has_default:
            raise _Wrong(here, f"is missing; expected {spec.want()}")
        return spec.fallback()
    return _read_value(spec, holder[spec.key], here, values)


def _read_record(cls: Any, obj: Any, path: str) -> Any:
    """A record of ``cls`` from the document's object ``obj`` at ``path``."""
    if not isinstance(obj, dict):
        raise _Wrong(path, f"must be an object, got {_got(obj)}")
    obj = _renamed(cls, obj)
    if cls.CLOSED:
        known = {s.key for s in _specs(cls) if not s.at}
        unknown = sorted(k for k in obj if k not in known)
        if unknown:
            raise _Wrong(_join(path, unknown[0]), f"is not a field of {cls.NOUN or cls.__name__}; it has "
                                                  + ", ".join(sorted(known)))
    values: dict[str, Any] = {}
    for spec in _specs(cls):
        if spec.entry.stored:
            values[spec.name] = _read_field(spec, obj, path, values)
    try:
        made = cls(**values)
    except (ValueError, TypeError) as exc:
        raise _Wrong(path, f"is not valid: {exc}") from None
    cls._check_document(made, Raw(obj, path))  # the record class's own hook (overridden by the artifacts' records)
    return made


class Raw:
    """A document's object as it was read (``doc``, at ``path``): what a record's own checks of its document read.

    Parameters
    ----------
    doc : dict
        The object.
    path : str
        Its path in the document ("" for the document itself).
    """

    def __init__(self, doc: dict[str, Any], path: str = "") -> None:
        self.doc, self.path = doc, path

    def get(self, key: str, default: Any = None) -> Any:
        """The value at ``key`` (``default`` where there is none).

        Parameters
        ----------
        key : str
            The key in this object.
        default : object
            What an absent key gives.

        Returns
        -------
        object
            The value, as the document holds it.
        """
        return self.doc.get(key, default)

    def fail(self, key: str, problem: str) -> Exception:
        """The error for field ``key`` of this object (the reader adds the file and how to write it again).

        Parameters
        ----------
        key : str
            The field's key in this object ("": the object itself).
        problem : str
            What is wrong, as a sentence's predicate ("does not agree with its 'requirements'").

        Returns
        -------
        Exception
            The error to raise.
        """
        return _Wrong(_join(self.path, key) if key else self.path, problem)


# --------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------
def _plain(spec: _Spec, value: Any) -> Any:  # noqa: C901 (one branch per kind)
    """A field's value as its document holds it."""
    if value is None:
        return None
    e = spec.entry
    if e.write is not None and not e.each:
        return e.write(value)
    if spec.kind == "custom":
        if e.write is None:
            return value
        return {k: e.write(v) for k, v in value.items()} if spec.container is dict else [e.write(v) for v in value]
    if spec.kind == "enum":
        member = _member(spec.record, value)
        if member is None:
            raise ValueError(f"{spec.name} must be one of {', '.join(_values(spec.record))}, got {value!r}")
        return str(member.value)
    if spec.kind == "via":
        return spec.record.from_value(value).to_dict()
    if spec.kind in ("record", "inline"):
        return value.to_dict()
    if spec.kind == "records":
        return [v.to_dict() for v in value]
    if spec.kind == "array":
        return np.asarray(value).astype(int).tolist() if spec.item == "bool" else \
            np.asarray(value, dtype=np.float64).tolist()
    if spec.kind == "list":
        return [_as(v, spec.item) for v in value]
    if spec.kind == "map":
        if spec.item == "record":
            return {k: v.to_dict() for k, v in value.items()}
        return {k: _as(v, spec.item) for k, v in value.items()}
    if spec.kind == "object":
        return dict(value)
    return _as(value, spec.kind)


def _put(out: dict[str, Any], spec: _Spec, value: Any) -> None:
    """Put a field's document value where it sits: an inline record's fields into the object that holds them, a
    field under ``at`` into that object (made where it is not yet), an object beside another's keys merged."""
    for part in spec.at:
        out = out.setdefault(part, {})
    if spec.kind == "inline":
        out.update(value if value is not None else {s.key: None for s in _specs(spec.record) if s.entry.stored})
    elif spec.entry.spread:
        out.update(value or {})
    elif isinstance(out.get(spec.key), dict) and isinstance(value, dict):
        out[spec.key] = {**value, **out[spec.key]}
    else:
        out[spec.key] = value


# --------------------------------------------------------------------------------------
# the record
# --------------------------------------------------------------------------------------
class Record:
    """A frozen record whose fields are declared with :func:`entry` (made with :func:`record`).

    Class attributes: ``NOUN`` names the record in messages ("the gain set"); ``AGAIN`` says what
    writes its document again, the end of every message about it ("run the tune stage again");
    ``CLOSED`` refuses a key of its object that is no field (a table of settings, where a misspelt
    key would otherwise be lost); ``RENAMED`` maps a key an older version wrote to the field's key now
    (read under its old name, written under the new one only).
    """

    NOUN: ClassVar[str] = ""
    AGAIN: ClassVar[str] = ""
    CLOSED: ClassVar[bool] = False
    RENAMED: ClassVar[dict[str, str]] = {}

    @classmethod
    def from_dict(cls, doc: Any, shown: str = "", *, path: str = "") -> Self:
        """The record from its document; an :class:`ArtifactError` names the field that is missing or wrong.

        Parameters
        ----------
        doc : dict
            The document (or an object of one), as JSON gives it.
        shown : str
            What the messages call it (a file's path); default: :attr:`NOUN`, else the record's name.
        path : str
            Where ``doc`` sits in its document (``gains``), for the messages ("": it is the document).

        Returns
        -------
        Record
            The record, checked by its declaration and its own checks.
        """
        try:
            made: Self = _read_record(cls, doc, path)
        except _Wrong as exc:
            raise ArtifactError(field_message(shown or cls.NOUN or cls.__name__, exc.path, exc.problem, cls.AGAIN)) \
                from None
        return made

    def to_dict(self) -> dict[str, Any]:
        """The record as its document holds it (JSON's types: lists, objects, numbers, strings, null).

        Returns
        -------
        dict
            The document's object.
        """
        out: dict[str, Any] = {}
        for spec in _specs(type(self)):
            if not spec.entry.stored:
                continue
            value = getattr(self, spec.name)
            if spec.entry.omit and (value is None or (isinstance(value, tuple | list | dict) and not value
                                                      and spec.has_default and not spec.fallback())):
                continue
            _put(out, spec, _plain(spec, value))
        return out

    def _check_document(self, raw: Raw) -> None:
        """The record's checks of what its document says beside its fields (a verdict that must agree with them);
        raise ``raw.fail(key, problem)``."""

    @classmethod
    def required(cls) -> tuple[str, ...]:
        """The keys its object must hold (an inlined record's among them), in the order of the fields.

        Returns
        -------
        tuple of str
            The keys; for an :class:`Artifact`, what :data:`piezopreload.artifacts.registry.KINDS` lists for its kind.
        """
        out: list[str] = []
        for spec in _specs(cls):
            keys: tuple[str, ...]
            if spec.entry.spread:
                keys = ()
            elif spec.kind == "inline":
                inner = () if spec.optional or spec.has_default else spec.record.required()
                keys = ((spec.at[0],) if inner else ()) if spec.at else inner
            else:
                keys = ((spec.at or (spec.key,))[0],) if spec.in_document else ()
            out += [k for k in keys if k not in out]
        return tuple(out)


class Artifact(Record):
    """A record that is a whole artifact of kind ``KIND``: :meth:`load` is its one reader.

    A ``HASHED`` kind carries its content's hash, checked on every read.
    """

    KIND: ClassVar[str] = ""
    HASHED: ClassVar[bool] = False

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read the artifact at ``path``: its envelope (schema, kind, finite numbers, a hashed kind's hash), then
        every field by the declaration.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        Artifact
            The record.
        """
        return cls.from_dict(read_artifact(path, kind_of(cls), fields=False), str(path))

    def _write(self, path: str | Path) -> dict[str, Any]:
        """Write the artifact atomically at ``path``; returns the whole document (envelope and hash)."""
        return write_artifact(path, kind_of(type(self)), self.to_dict())


def kind_of(cls: type[Artifact]) -> ArtifactKind:
    """An artifact record's kind as its declaration makes it: the name, the required fields, the hash, what writes
    it again (listed with every other kind in :data:`piezopreload.artifacts.registry.KINDS`).

    Parameters
    ----------
    cls : type of Artifact
        The record.

    Returns
    -------
    ArtifactKind
        Its kind, which its reader and writer take.
    """
    return ArtifactKind(cls.KIND, cls.required, cls.HASHED, cls.AGAIN, f"{cls.__module__}.{cls.__qualname__}")


class SavedArtifact(Artifact):
    """An artifact whose :meth:`save` is the write and nothing more: it returns the file written.

    (A content-hashed record whose ``save`` returns itself with the hash, such as a gain set, defines its own on
    :meth:`Artifact._write`.)
    """

    def save(self, path: str | Path) -> Path:
        """Write the artifact atomically at ``path``: the envelope (``"schema": "piezopreload/<KIND>/1"``, the
        package version) around :meth:`~Record.to_dict`; a reader sees the previous file or this one, never a part.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        Path
            The file written.
        """
        self._write(path)
        return Path(path)


# --------------------------------------------------------------------------------------
# the decorator
# --------------------------------------------------------------------------------------
def _declared(base: type, name: str, cls: Any, eq: bool) -> Any:
    """What ``@record`` and ``@checked`` do alike: ``cls`` (a subclass of ``base``) as a frozen dataclass of its
    declared fields, its docstring's ``Parameters`` section made from the declarations; given ``eq`` alone (``cls``
    None), the decorator that does it."""
    def make(c: Any) -> Any:
        if not (isinstance(c, type) and issubclass(c, base)):
            raise TypeError(f"@{name} makes a {base.__name__}'s subclass, not {c!r}")
        made = dataclass(frozen=True, eq=eq)(c)
        made.__doc__ = _with_parameters(made)
        return made

    return make if cls is None else make(cls)


@overload
def record(cls: type[_R], /) -> type[_R]: ...


@overload
def record(*, eq: bool = True) -> Callable[[type[_R]], type[_R]]: ...


@dataclass_transform(frozen_default=True, field_specifiers=(entry,))
def record(cls: Any = None, /, *, eq: bool = True) -> Any:
    """Make ``cls`` (a :class:`Record`) a frozen dataclass of its declared fields.

    Its docstring gains a ``Parameters`` section from the declarations (an :class:`Artifact`'s kind is
    listed in :data:`piezopreload.artifacts.registry.KINDS`, not registered here).

    Parameters
    ----------
    cls : type
        The class (``@record``), or None for ``@record(eq=False)``.
    eq : bool
        Whether records compare equal field by field (False for records of arrays).

    Returns
    -------
    type
        The dataclass (or, given ``eq`` alone, the decorator that makes it).
    """
    return _declared(Record, "record", cls, eq)


def _words(annotation: str) -> str:
    """A field's annotation in numpydoc's words: ``float or None``, ``tuple of Front``, ``(float, float)``."""
    text = annotation.strip()
    optional = bool(re.search(r"\|\s*None$", text))
    text = re.sub(r"\s*\|\s*None$", "", text)
    pair = re.fullmatch(r"tuple\[(\w+)((?:, \1)+)\]", text)
    many = re.fullmatch(r"(tuple|list)\[(.+?)(?:, \.\.\.)?\]", text)
    if pair:
        text = "(" + ", ".join([pair.group(1)] * (1 + pair.group(2).count(","))) + ")"
    elif many:
        text = f"{many.group(1)} of {_words(many.group(2))}"
    elif text.startswith("dict["):
        text = "dict"
    elif text in ("Array", "BoolArray") or text.startswith(("NDArray", "np.ndarray")):
        text = "ndarray"
    return f"{text} or None" if optional else text


def _with_parameters(cls: type) -> str:
    """The class's docstring with a numpydoc ``Parameters`` section of its declared fields."""
    doc = (cls.__doc__ or "").rstrip()
    if re.search(r"^\s*Parameters\n\s*-{3,}", doc, flags=re.M):
        raise TypeError(f"{cls.__name__}: its Parameters section comes from its fields' declarations; "
                        "write each field's doc in its entry(...)")
    indent = "    "
    lines = ["", "", f"{indent}Parameters", f"{indent}----------"] if doc else ["Parameters", "----------"]
    annotations = {k: v for c in reversed(cls.__mro__) for k, v in getattr(c, "__annotations__", {}).items()}
    for f in fields(cls):
        e: Entry | None = f.metadata.get(ENTRY)
        if e is None or not f.init:
            continue
        hint = annotations.get(f.name, "")
        words = _words(hint if isinstance(hint, str) else getattr(hint, "__name__", str(hint)))
        if e.choices:
            words = "{" + ", ".join(f"'{c}'" for c in e.choices) + "}"
        default = f.default is not MISSING or f.default_factory is not MISSING
        lines.append(f"{indent if doc else ''}{f.name} : {words}{', optional' if default else ''}")
        text = e.doc + (f" Unit: {e.unit}." if e.unit else "")
        pad = indent * (2 if doc else 1)
        lines += textwrap.wrap(text, width=100, initial_indent=pad, subsequent_indent=pad)
    return doc + "\n".join(lines) + "\n"


_A1 = TypeVar("_A1", bound="Artifact")
_A2 = TypeVar("_A2", bound="Artifact")
_A3 = TypeVar("_A3", bound="Artifact")


@overload
def load_one_of(path: str | Path, a: type[_A1], /) -> _A1: ...


@overload
def load_one_of(path: str | Path, a: type[_A1], b: type[_A2], /) -> _A1 | _A2: ...


@overload
def load_one_of(path: str | Path, a: type[_A1], b: type[_A2], c: type[_A3], /) -> _A1 | _A2 | _A3: ...


def load_one_of(path: str | Path, *kinds: type[Artifact]) -> Artifact:
    """The artifact at ``path`` read by the one reader of its kind, among ``kinds``.

    Parameters
    ----------
    path : str or Path
        The file.
    *kinds : type of Artifact
        The records it may be.

    Returns
    -------
    Artifact
        The record of the kind its schema names.

    Raises
    ------
    ArtifactError
        Where the file is not an artifact of one of ``kinds``: the message names the file and the kinds.
    """
    from piezopreload.core.artifacts import artifact_kind, schema_name

    kind = artifact_kind(path)
    for k in kinds:
        if kind == k.KIND:
            return k.load(path)
    expected = " or ".join(f"{k.NOUN or k.__name__} ({schema_name(k.KIND)})" for k in kinds)
    raise ArtifactError(field_message(str(path), "schema", f"must be {expected}, got {schema_name(kind)!r} (a {kind} "
                                                           "artifact)"))


# --------------------------------------------------------------------------------------
# a type as a table of a configuration file: read, checked on construction, documented
# --------------------------------------------------------------------------------------
_TABLE_A = {"number": "a number", "integer": "an integer", "flag": "true or false", "text": "a string"}
_TABLE_PLURAL = {"number": "numbers", "integer": "integers", "flag": "booleans", "text": "strings"}
_LARGEST = 1.7976931348623157e308  # TOML integers are unbounded: one a float cannot hold is not a number
MANY = 1_000_000  # a size (least, most) whose most is this or more has no most


def takes(spec: _Spec) -> str:
    """What a field takes, in a table's words: ``a number > 0``, ``a list of 2 integers >= 1``, ``one of a, b``."""
    e = spec.entry
    bounds = " and ".join(f"{op} {v:g}" for op, v in ((">=", e.ge), (">", e.gt), ("<=", e.le), ("<", e.lt))
                          if v is not None)
    if spec.kind == "enum":
        return "one of " + ", ".join(_values(spec.record))
    if spec.kind in _TABLE_A:
        if e.choices:
            return "one of " + ", ".join(e.choices)
        return _TABLE_A[spec.kind] + (f" {bounds}" if bounds else "")
    if spec.kind == "list" and spec.item in _TABLE_PLURAL:
        size = e.size
        count = (f"{spec.length} " if spec.length else f"{size} " if isinstance(size, int)
                 else (f"{size[0]} or more " if size[1] >= MANY else f"{size[0]} to {size[1]} ")
                 if isinstance(size, tuple) else "")
        text = f"a list of {count}{_TABLE_PLURAL[spec.item]}" + (f" {bounds}" if bounds else "")
        if e.choices:
            text += " from " + ", ".join(e.choices)
        return text + (", increasing" if e.increasing else "")
    return e.takes or spec.want()


def _shown(value: Any) -> str:
    """A value as a table's message shows it."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, tuple):
        value = list(value)
    return f"{value!r}" if isinstance(value, int | float | str | list) and not isinstance(value, bool) else \
        f"{type(value).__name__} {value!r}"


def _all_in_range(e: Entry, x: Any) -> bool:
    """Whether a number, or every number of an array (a batch), lies in the declared range."""
    return bool((e.ge is None or np.all(x >= e.ge)) and (e.gt is None or np.all(x > e.gt))
                and (e.le is None or np.all(x <= e.le)) and (e.lt is None or np.all(x < e.lt)))


def _fits(spec: _Spec, value: Any) -> bool:  # noqa: C901 (one branch per kind)
    """Whether a value is what the field declares (a number field may hold an array of them: a batch)."""
    if value is None:
        return spec.optional
    e, kind = spec.entry, spec.kind
    if kind == "number":
        if isinstance(value, bool | str | dict):
            return False
        try:
            x = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            return False
        return bool(np.all(np.isfinite(x))) and _all_in_range(e, x)
    if kind == "integer":
        return isinstance(value, int | np.integer) and not isinstance(value, bool) and _all_in_range(e, value)
    if kind == "flag":
        return isinstance(value, bool | np.bool_)
    if kind == "text":
        return isinstance(value, str) and (not e.choices or value in e.choices)
    if kind == "enum":
        return isinstance(value, spec.record)
    if kind == "list":
        item = spec.item.removesuffix("|null")
        if isinstance(value, np.ndarray) and value.ndim == 1:
            value = value.tolist()
        if not isinstance(value, list | tuple):
            return False
        one = _Spec(spec.name, spec.key, (), item, "", spec.item.endswith("|null"), MISSING, MISSING, tuple, None,
                    None, e)
        sized = (spec.length is None or len(value) == spec.length) and (
            not isinstance(e.size, int | tuple) or _sized(spec, len(value), {}))
        return sized and all(_fits(one, v) for v in value) and \
            not (e.increasing and any(b < a for a, b in zip(value, value[1:])))
    if kind == "map":
        one = _Spec(spec.name, spec.key, (), spec.item, "", False, MISSING, MISSING, tuple, None, spec.record, e)
        return isinstance(value, dict) and all(_fits(one, v) for v in value.values())
    if kind in ("record", "inline"):
        return isinstance(value, spec.record)
    if isinstance(spec.record, type) and issubclass(spec.record, Checked):
        return isinstance(value, spec.record)
    return True  # a type the declaration does not know: its own constructor checks it


def as_members(obj: Any) -> None:
    """Hold each enum field of ``obj`` (a dataclass declared with :func:`entry`) that was given its value as a string
    (in code, or a copy) as the enum's member; a string that names no member is left for the checks to refuse.

    Parameters
    ----------
    obj : dataclass
        The object, as made (frozen: set in place, as its ``__post_init__`` may).
    """
    for spec in _specs(type(obj)):
        if spec.kind == "enum":
            value = getattr(obj, spec.name)
            member = _member(spec.record, value)
            if member is not None and member is not value:
                object.__setattr__(obj, spec.name, member)


def hold_members(obj: Any, error: type[Exception] = ValueError) -> None:
    """:func:`as_members`, then refuse an enum field whose value names no member of its enum (None passes where the
    field is optional): the one check a record made in code runs on its enum fields.

    Parameters
    ----------
    obj : dataclass
        The object, as made (frozen: set in place, as its ``__post_init__`` may).
    error : type of Exception
        What to raise (``ValueError``, or the record's own input error).

    Raises
    ------
    Exception
        ``error``: ``Owner.field must be one of A, B, got VALUE``.
    """
    as_members(obj)
    for spec in _specs(type(obj)):
        value = getattr(obj, spec.name)
        if spec.kind == "enum" and not isinstance(value, spec.record) and not (value is None and spec.optional):
            raise error(f"{type(obj).__name__}.{spec.name} must be one of {', '.join(spec.record)}, got {value!r}")


def check_entries(obj: Any) -> None:
    """Check every field of ``obj`` (a dataclass declared with :func:`entry`) against its declaration.

    Parameters
    ----------
    obj : dataclass
        The object, as made.

    Raises
    ------
    Invalid
        For the first field that is not what it declares: ``'Owner.field' must be WHAT, got VALUE``.
    """
    for spec in _specs(type(obj)):
        value = getattr(obj, spec.name)
        if not _fits(spec, value):  # by the field's name: a file's reader names its key (read_table)
            raise Invalid(spec.name, f"must be {takes(spec)}, got {_shown(value)}", type(obj).__name__)


class Checked:
    """A frozen dataclass whose fields are declared with :func:`entry`, each value checked against its declaration
    when it is made (:func:`check_entries`), then against the rules between its fields (:meth:`check`): each rule is
    stated once, on the type, whether the values come from code, a study's table or a document.

    Made with :func:`checked` (a frozen dataclass whose docstring gains its ``Parameters`` from the declarations).
    """

    def __post_init__(self) -> None:
        as_members(self)
        check_entries(self)
        self.check()

    def check(self) -> None:
        """The rules between fields (each field has been checked alone); raise :class:`Invalid` naming the field."""


@overload
def checked(cls: type[_R], /) -> type[_R]: ...


@overload
def checked(*, eq: bool = True) -> Callable[[type[_R]], type[_R]]: ...


@dataclass_transform(frozen_default=True, field_specifiers=(entry,))
def checked(cls: Any = None, /, *, eq: bool = True) -> Any:
    """Make ``cls`` (a :class:`Checked`) a frozen dataclass of its declared fields, its docstring's ``Parameters``
    section made from their declarations.

    Parameters
    ----------
    cls : type
        The class (``@checked``), or None for ``@checked(eq=False)``.
    eq : bool
        Whether values compare equal field by field (False for a type whose fields may be arrays).

    Returns
    -------
    type
        The dataclass (or, given ``eq`` alone, the decorator that makes it).
    """
    return _declared(Checked, "checked", cls, eq)


#: ``fail(path, message)``: the error for the key at ``path`` of a file (the caller adds the file and the line)
Fail = Callable[[str, str], Exception]


def _from_file(spec: _Spec, value: Any, at: str, fail: Fail) -> Any:  # noqa: C901 (one branch per kind)
    """A table's value as the field holds it (TOML's integer for a number as a float, a list as a tuple), checked."""
    def wrong() -> Exception:
        return fail(at, f"must be {takes(spec)}, got {_shown(value)}")

    kind = spec.kind
    if kind == "custom":
        if spec.entry.read is None:
            return value
        try:
            return spec.entry.read(value)
        except (ValueError, TypeError, KeyError):
            raise wrong() from None
    if kind == "number":
        if isinstance(value, bool) or not isinstance(value, int | float) or (isinstance(value, int)
                                                                             and abs(value) > _LARGEST):
            raise wrong()
        made: Any = float(value)
    elif kind == "integer":
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong()
        made = value
    elif kind == "enum":
        made = _member(spec.record, value) if isinstance(value, str) else None
        if made is None:
            raise wrong()
    elif kind == "list":
        if not isinstance(value, list) or not all(
                (isinstance(v, int | float) and not isinstance(v, bool)) if spec.item == "number"
                else _is(v, spec.item) and not isinstance(v, float) if spec.item == "integer"
                else _is(v, spec.item) for v in value):
            raise wrong()
        made = spec.container(float(v) if spec.item == "number" else v for v in value)
    else:
        made = value
    if not _fits(spec, made):
        raise wrong()
    return made


def table_keys(cls: type, keys: tuple[str, ...] | None = None) -> tuple[_Spec, ...]:
    """The declared fields of ``cls`` a table of a file gives (``keys``, by field name; None: every field)."""
    return tuple(s for s in _specs(cls) if keys is None or s.name in keys)


def read_table(cls: type[_R], data: Any, fail: Fail, path: str, *, keys: tuple[str, ...] | None = None,
               given: dict[str, Any] | None = None, nested: dict[str, TableOf] | None = None,
               unit: UnitKey | None = None) -> _R:
    """Make ``cls`` from a table of a file: each key checked against its field's declaration, then the type's own
    checks (:class:`Checked`); every error is ``fail(path of the key, message)``.

    Parameters
    ----------
    cls : type
        A dataclass declared with :func:`entry` (a :class:`Checked` one checks its rules when made).
    data : dict
        The table, as TOML gives it.
    fail : callable
        ``fail(key path, message)``: the error to raise (the caller adds the file and the key's line).
    path : str
        The table's path in the file (``tuning``).
    keys : tuple of str, optional
        The fields the table may give, by name (None: every field); the others take their defaults or ``given``.
    given : dict, optional
        Fields set from elsewhere (another table's value), by name.
    nested : dict of str to TableOf, optional
        The fields that are tables of their own (``[rig.stack]``), by name.
    unit : UnitKey, optional
        A key of the table that is no field: the unit some of its numbers are entered in, converted here.

    Returns
    -------
    object
        The value of ``cls``.
    """
    if not isinstance(data, dict):
        raise fail(path, f"must be a table ([{path}]), got {_shown(data)}")
    specs = {s.key: s for s in table_keys(cls, keys)}
    factor = 1.0 if unit is None else unit.factor(data.get(unit.key, unit.default), fail, f"{path}.{unit.key}")
    values: dict[str, Any] = dict(given or {})
    for key, value in data.items():
        if unit is not None and key == unit.key:
            continue
        spec = specs.get(key)
        if spec is None:
            known = [*specs, *([] if unit is None else [unit.key])]
            raise fail(f"{path}.{key}", f"is an unknown key; [{path}] has: {', '.join(known)}")
        inner = (nested or {}).get(spec.name)
        values[spec.name] = inner.parse(value, fail, f"{path}.{key}") if inner is not None else \
            _from_file(spec, value, f"{path}.{key}", fail)
        if unit is not None and spec.name in unit.fields:  # checked as entered, held in the field's unit
            values[spec.name] = factor * values[spec.name]
    for spec in specs.values():
        if spec.name not in values and ((spec.default is MISSING and spec.factory is MISSING)
                                        or spec.entry.required):
            raise fail(path, f"needs '{spec.key}' ({takes(spec)})")
    by_name = {s.name: s.key for s in _specs(cls)}
    try:
        return cls(**values)
    except Invalid as exc:
        name = next((n for n, k in by_name.items() if k == exc.path), exc.path)
        raise fail(f"{path}.{by_name.get(name, exc.path)}", exc.message) from None
    except (ValueError, TypeError) as exc:
        raise fail(path, f"is not valid: {exc}") from None


def table_values(obj: Any, keys: tuple[str, ...] | None = None) -> dict[str, Any]:
    """The keys of a table ``obj`` was read from, as the file would hold them (None left out, tuples as lists)."""
    out: dict[str, Any] = {}
    for spec in table_keys(type(obj), keys):
        value = getattr(obj, spec.name)
        if dataclasses.is_dataclass(value):  # a table of its own: its TableOf writes it
            continue
        if spec.entry.write is not None and value is not None:
            value = spec.entry.write(value)
        if isinstance(value, enum.Enum):
            value = value.value
        if value is not None:
            out[spec.key] = list(value) if isinstance(value, tuple) else value
    return out


@dataclass(frozen=True)
class UnitKey:
    """A key of a table that is no field of its type: the unit some of the table's numbers are entered in, each
    converted to its field's unit as the table is read (``[controller] units = "minutes"``: ``Ti`` and ``Td`` as
    LabVIEW enters them).

    Parameters
    ----------
    key : str
        The key (``units``).
    doc : str
        What it says, for the documentation's table of keys.
    factors : tuple of (str, float)
        Each unit the key may name and what a number entered in it is multiplied by; the first is the default.
    fields : tuple of str
        The fields, by name, entered in that unit.
    """

    key: str
    doc: str
    factors: tuple[tuple[str, float], ...]
    fields: tuple[str, ...]

    @property
    def default(self) -> str:
        """The unit where the table does not name one.

        Returns
        -------
        str
            The first of :attr:`factors`.
        """
        return self.factors[0][0]

    def takes(self) -> str:
        """What the key takes, in a table's words.

        Returns
        -------
        str
            ``one of seconds, minutes``.
        """
        return "one of " + ", ".join(name for name, _ in self.factors)

    def factor(self, value: Any, fail: Fail, at: str) -> float:
        """The factor of the unit ``value`` names.

        Parameters
        ----------
        value : object
            The key's value in the file.
        fail : callable
            ``fail(key path, message)``.
        at : str
            The key's path.

        Returns
        -------
        float
            What a number entered in that unit is multiplied by.
        """
        factors = dict(self.factors)
        if not isinstance(value, str) or value not in factors:
            raise fail(at, f"must be {self.takes()}, got {_shown(value)}")
        return factors[value]


@dataclass(frozen=True)
class TableOf:
    """A table of a configuration file read straight into a domain type: the type, the fields the file gives and the
    table's sentence for the documentation.

    Parameters
    ----------
    type : type
        The domain type (a dataclass declared with :func:`entry`).
    doc : str
        The table's sentence (``[tuning]: the PID tuning's specification``).
    keys : tuple of str or None
        The fields the file gives, by name (None: every field).
    nested : tuple of (str, TableOf)
        The fields that are tables of their own (``[rig.stack]``): each field's name and its table.
    unit : UnitKey or None
        A key naming the unit some of the table's numbers are entered in (None: each in its field's unit).
    """

    type: type
    doc: str
    keys: tuple[str, ...] | None = None
    nested: tuple[tuple[str, TableOf], ...] = ()
    unit: UnitKey | None = None

    def parse(self, data: Any, fail: Fail, path: str, given: dict[str, Any] | None = None) -> Any:
        """The type from the file's table (see :func:`read_table`).

        Parameters
        ----------
        data : dict
            The table.
        fail : callable
            ``fail(key path, message)``.
        path : str
            The table's path.
        given : dict, optional
            Fields set from elsewhere.

        Returns
        -------
        object
            The value.
        """
        return read_table(self.type, data, fail, path, keys=self.keys, given=given, nested=dict(self.nested),
                          unit=self.unit)

    def values(self, obj: Any) -> dict[str, Any]:
        """The table's keys of ``obj`` as a file holds them (:func:`table_values`).

        Parameters
        ----------
        obj : object
            A value of the type.

        Returns
        -------
        dict
            Key to value.
        """
        out = table_values(obj, self.keys)
        for name, table in self.nested:
            if getattr(obj, name) is not None:
                out[name] = table.values(getattr(obj, name))
        return out

    def rows(self) -> list[tuple[str, str, str, str, str]]:
        """The documentation's rows: each key, what it takes, its default, its unit and its doc.

        Returns
        -------
        list of (str, str, str, str, str)
            One row per key, in the order of the fields.
        """
        out = []
        inner = dict(self.nested)
        for spec in table_keys(self.type, self.keys):
            if spec.name in inner:
                out.append((spec.key, "the table", "", "", spec.entry.doc))
                continue
            default = spec.factory() if spec.factory is not MISSING else spec.default
            if spec.entry.write is not None and default is not None and default is not MISSING:
                default = spec.entry.write(default)
            shown = "required" if default is MISSING or spec.entry.required else _default_shown(default)
            out.append((spec.key, takes(spec), shown, spec.entry.unit, spec.entry.doc))
        if self.unit is not None:
            out.append((self.unit.key, self.unit.takes(), _default_shown(self.unit.default), "", self.unit.doc))
        return out


def _default_shown(value: Any) -> str:
    if value is None:
        return "not set"
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, tuple | list):
        return "`[" + ", ".join(_default_shown(v).strip("`") for v in value) + "]`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, float):
        return f"`{value:g}`"
    return f"`{value}`"
