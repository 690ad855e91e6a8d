"""Configuration files (TOML) read into typed tables whose keys are declared once.

A table of a file is a frozen dataclass deriving from :class:`Table`. Each of its keys is a
field declared with :func:`key`: its default, its documentation, its unit and its range; its
type is the field's annotation (``float``, ``int``, ``bool``, ``str``, a tuple of them, another
:class:`Table` for a nested table, ``| None`` where a key may be left out). From that one
declaration come

* the checks (:meth:`Table.parse` on a file's values, and every construction in code:
  :class:`Table` validates itself): unknown keys, types, finite numbers, ranges, choices and
  list lengths, then the table's own rules between its keys (:meth:`Table.check`);
* the error messages: each names the key's path (``rig.bolt_preload_N``), and the caller's
  ``fail(path, message)`` adds the file and the key's line (:class:`Lines`);
* the documentation's table of keys (:func:`keys_markdown`).

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Axis(Table):
...     '''[axis]: an example table.'''
...     mass_kg: float = key(350.0, "the table's mass", unit="kg", gt=0)
>>> Axis.parse({"mass_kg": 400}, lambda path, message: ValueError(f"{path} {message}"), "axis").mass_kg
400.0
>>> Axis.parse({"mass_kg": -1.0}, lambda path, message: ValueError(f"'{path}' {message}"), "axis")
Traceback (most recent call last):
...
ValueError: 'axis.mass_kg' must be a number > 0, got -1.0
"""

from __future__ import annotations

import math
import re
import tomllib
import types
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any, Union, get_args, get_origin, get_type_hints

from piezopreload.core.artifacts import read_bytes
from piezopreload.core.errors import InputError

__all__ = ["Key", "KeySpec", "Invalid", "Lines", "Table", "key", "keys_markdown", "read_toml", "toml_text"]

#: the metadata entry of a field declared with :func:`key`
KEY = "piezopreload.key"

#: ``fail(path, message)``: the error for the key at ``path`` (the caller adds its file and line)
Fail = Callable[[str, str], Exception]


class Invalid(ValueError):
    """A value of a table that is not valid, with the path of its key inside the table (``ball_mm``)."""

    def __init__(self, path: str, message: str, owner: str = "") -> None:
        super().__init__(f"'{owner}.{path}' {message}" if owner else f"'{path}' {message}")
        self.path = path
        self.message = message


# --------------------------------------------------------------------------------------
# the declaration of a key
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Key:
    """What a key declares beside its type and default: its documentation, unit and range.

    ``ge``/``gt``/``le``/``lt`` bound a number (or each number of a list); ``choices`` the strings
    a string (or each string of a list) may be; ``increasing`` asks a list's entries in
    non-decreasing order (a ``(low, high)`` pair); ``min_length`` the fewest entries of a list.
    """

    doc: str
    unit: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[str, ...] = ()
    increasing: bool = False
    min_length: int = 0


def key(default: Any, doc: str, *, unit: str = "", ge: float | None = None, gt: float | None = None,
        le: float | None = None, lt: float | None = None, choices: tuple[str, ...] | list[str] = (),
        increasing: bool = False, min_length: int = 0, required: bool = False) -> Any:
    """Declare a key of a :class:`Table`: its default (ignored where ``required``), documentation, unit and range."""
    meta = {KEY: Key(doc, unit, ge, gt, le, lt, tuple(choices), increasing, min_length)}
    return field(metadata=meta) if required else field(default=default, metadata=meta)


_SCALARS = {float: "number", int: "integer", bool: "bool", str: "string"}
_A = {"number": "a number", "integer": "an integer", "bool": "true or false", "string": "a string"}
_PLURAL = {"number": "numbers", "integer": "integers", "string": "strings"}


@dataclass(frozen=True)
class KeySpec:
    """A declared key as the schema holds it: its name, what it holds (``kind``: number, integer, bool,
    string, a list of one of them, or table), a list's fixed ``length``, whether it may be left out
    (``optional``), its ``default`` (``MISSING`` where required) and its declaration."""

    name: str
    kind: str
    item: str  # a list's entries' kind ("" for a scalar or a table)
    length: int | None
    optional: bool
    default: Any
    key: Key
    table: type[Table] | None = None

    @property
    def required(self) -> bool:
        return self.default is MISSING

    def want(self) -> str:
        """What the key takes, in words: ``a number > 0``, ``a list of 2 integers >= 1, increasing``."""
        k = self.key
        bounds = " and ".join(f"{op} {_num(v)}" for op, v in ((">=", k.ge), (">", k.gt), ("<=", k.le), ("<", k.lt))
                              if v is not None)
        if self.kind == "table":
            return "a table"
        if self.kind != "list":
            if k.choices:
                return "one of " + ", ".join(k.choices)
            return _A[self.kind] + (f" {bounds}" if bounds else "")
        count = f"{self.length} " if self.length else (f"{k.min_length} or more " if k.min_length else "")
        text = f"a list of {count}{_PLURAL[self.item]}" + (f" {bounds}" if bounds else "")
        if k.choices:
            text += " from " + ", ".join(k.choices)
        return text + (", increasing" if k.increasing else "")

    def convert(self, value: Any) -> Any:
        """A file's value as the table holds it (lists as tuples, integers given for a number as floats),
        checked; :class:`Invalid` (this key's name) where it is not what the key takes."""
        if self.kind == "list":
            if not isinstance(value, list | tuple):
                raise Invalid(self.name, f"must be {self.want()}, got {_shown(value)}")
            value = tuple(float(x) if self.item == "number" and _is(x, "number") else x for x in value)
        elif self.kind == "number" and _is(value, "number"):
            value = float(value)
        self.validate(value)
        return value

    def validate(self, value: Any) -> None:
        """Check a value against the declaration: :class:`Invalid` (this key's name) naming what was expected."""
        if value is None and self.optional:
            return
        if self.kind == "list":
            ok = (isinstance(value, list | tuple) and all(_is(x, self.item) for x in value)
                  and (self.length is None or len(value) == self.length) and len(value) >= self.key.min_length
                  and all(self._in_range(x) for x in value)
                  and not (self.key.increasing and any(b < a for a, b in zip(value, value[1:]))))
        else:
            ok = _is(value, self.kind) and self._in_range(value)
        if not ok:
            raise Invalid(self.name, f"must be {self.want()}, got {_shown(value)}")

    def _in_range(self, x: Any) -> bool:
        k = self.key
        if isinstance(x, str):
            return not k.choices or x in k.choices
        if isinstance(x, bool):
            return True
        return ((k.ge is None or x >= k.ge) and (k.gt is None or x > k.gt) and (k.le is None or x <= k.le)
                and (k.lt is None or x < k.lt))


def _is(x: Any, kind: str) -> bool:
    if kind == "bool":
        return isinstance(x, bool)
    if kind == "string":
        return isinstance(x, str)
    if kind == "integer":
        return isinstance(x, int) and not isinstance(x, bool)
    if isinstance(x, int) and not isinstance(x, bool):
        return abs(x) <= _LARGEST  # TOML integers are unbounded here: one a float cannot hold is not a number
    return isinstance(x, float) and math.isfinite(x)


_LARGEST = 1.7976931348623157e308


def _num(x: float) -> str:
    return f"{x:g}"


def _shown(value: Any) -> str:
    if isinstance(value, tuple):
        value = list(value)
    return f"{value!r}" if isinstance(value, int | float | str | list) and not isinstance(value, bool) else \
        f"{type(value).__name__} {value!r}"


def _spec(owner: type, name: str, hint: Any, f: Any) -> KeySpec:
    """The :class:`KeySpec` of field ``name`` of ``owner`` from its annotation ``hint`` and declaration."""
    declared = f.metadata.get(KEY)
    if declared is None:
        raise TypeError(f"{owner.__name__}.{name}: declare the key with config.key(default, doc, ...)")
    optional = False
    if get_origin(hint) in (Union, types.UnionType) and type(None) in get_args(hint):
        optional, hint = True, next(a for a in get_args(hint) if a is not type(None))
    default = f.default
    if isinstance(hint, type) and issubclass(hint, Table):
        return KeySpec(name, "table", "", None, optional, default, declared, hint)
    if hint in _SCALARS:
        return KeySpec(name, _SCALARS[hint], "", None, optional, default, declared)
    args = get_args(hint)
    if get_origin(hint) is tuple and args and args[0] in _SCALARS:
        length = None if len(args) == 2 and args[1] is Ellipsis else len(args)
        return KeySpec(name, "list", _SCALARS[args[0]], length, optional, default, declared)
    raise TypeError(f"{owner.__name__}.{name}: a key holds float, int, bool, str, a tuple of one of them or a Table, "
                    f"not {hint!r}")


_SPECS: dict[type, tuple[KeySpec, ...]] = {}  # each table class's keys, resolved once


def _specs(cls: type[Table]) -> tuple[KeySpec, ...]:
    if cls not in _SPECS:
        hints = get_type_hints(cls)
        _SPECS[cls] = tuple(_spec(cls, f.name, hints[f.name], f) for f in fields(cls))
    return _SPECS[cls]


# --------------------------------------------------------------------------------------
# the table
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Table:
    """A table of a configuration file as a frozen record, its keys as fields declared with :func:`key`.

    A table checks itself on construction (every key against its declaration, then :meth:`check`);
    :meth:`parse` makes one from a file's values with errors naming the key's path; None stands for a
    key not given where the domain's default applies.
    """

    def __post_init__(self) -> None:
        for spec in _specs(type(self)):
            if spec.kind == "table":
                value = getattr(self, spec.name)
                if not (isinstance(value, spec.table or Table) or (value is None and spec.optional)):
                    raise Invalid(spec.name, f"must be a {spec.table.__name__ if spec.table else 'table'}, got "
                                             f"{_shown(value)}")
            else:
                spec.validate(getattr(self, spec.name))
        self.check()

    def check(self) -> None:
        """The table's rules between its keys (each key has been checked alone); raise :class:`Invalid`."""

    @classmethod
    def declared(cls) -> tuple[KeySpec, ...]:
        """The table's keys as declared, in the order of the fields."""
        return _specs(cls)

    @classmethod
    def parse(cls, data: Any, fail: Fail, path: str) -> Any:
        """The table from a file's values ``data`` at ``path`` (``rig``, ``reference.step``); every error is
        ``fail(path of the key, message)``."""
        if not isinstance(data, Mapping):
            raise fail(path, f"must be a table ([{path}]), got {_shown(data)}")
        specs = {s.name: s for s in cls.declared()}
        values: dict[str, Any] = {}
        for name, value in data.items():
            at = f"{path}.{name}"
            spec = specs.get(name)
            if spec is None:
                raise fail(at, f"is an unknown key; [{path}] has: {', '.join(specs)}")
            if spec.kind == "table" and spec.table is not None:
                values[name] = spec.table.parse(value, fail, at)
                continue
            try:
                values[name] = spec.convert(value)
            except Invalid as exc:
                raise fail(at, exc.message) from None
        for spec in specs.values():
            if spec.required and spec.name not in values:
                raise fail(path, f"needs '{spec.name}' ({spec.want()})")
        try:
            return cls(**values)
        except Invalid as exc:
            raise fail(f"{path}.{exc.path}", exc.message) from None

    def to_dict(self) -> dict[str, Any]:
        """The keys with a value (nested tables as dicts, tuples as lists), as a file would hold them."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None}


def _plain(x: Any) -> Any:
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    return x.to_dict() if isinstance(x, Table) else x


# --------------------------------------------------------------------------------------
# the documentation's table of keys
# --------------------------------------------------------------------------------------
def keys_markdown(tables: Mapping[str, Any], notes: Mapping[str, str] | None = None) -> str:
    """The keys of ``tables`` (a file's table names and their types) as Markdown: one section per table (its
    docstring's first paragraph), one row per key: type, default, unit, what it takes and its doc.

    ``notes`` adds a sentence to a key's row, by its path (``rig.bolt_preload_N``).
    """
    out: list[str] = []
    for name, cls in tables.items():
        out += _table_markdown(name, cls, notes or {})
    return "\n".join(out).rstrip() + "\n"


def _table_markdown(name: str, cls: Any, notes: Mapping[str, str]) -> list[str]:
    text = cls.doc if hasattr(cls, "rows") else (cls.__doc__ or "")
    doc = " ".join(text.strip().split("\n\n")[0].split()).removeprefix(f"[{name}]: ")
    lines = [f"### `[{name}]`", "", _cell(doc[:1].upper() + doc[1:]), "",
             "| key | takes | default | unit | description |", "|---|---|---|---|---|"]
    if hasattr(cls, "rows"):  # a domain type read straight from the table (piezopreload.core.records.TableOf)
        for key_name, want, default, unit, about in cls.rows():
            note = notes.get(f"{name}.{key_name}")
            about = about.rstrip(".") + f"; {note}." if note else about
            if want == "the table":
                want = f"the table `[{name}.{key_name}]`"
            lines.append(f"| `{key_name}` | {_cell(want)} | {_cell(default)} | {_cell(unit)} | {_cell(about)} |")
        lines.append("")
        for sub, table in cls.nested:
            lines += _table_markdown(f"{name}.{sub}", table, notes)
        return lines
    nested = []
    for spec in cls.declared():
        if spec.kind == "table" and spec.table is not None:
            nested.append((f"{name}.{spec.name}", spec.table))
            note = notes.get(f"{name}.{spec.name}")
            text = spec.key.doc + (f"; {note}" if note else "")
            lines.append(f"| `{spec.name}` | the table `[{name}.{spec.name}]` | | | {_cell(text)} |")
            continue
        default = "required" if spec.required else _cell(_default(spec.default))
        note = notes.get(f"{name}.{spec.name}")
        text = spec.key.doc + (f"; {note}" if note else "")
        lines.append(f"| `{spec.name}` | {_cell(spec.want())} | {default} | {_cell(spec.key.unit)} | {_cell(text)} |")
    lines.append("")
    for sub, table in nested:
        lines += _table_markdown(sub, table, notes)
    return lines


def _default(value: Any) -> str:
    if value is None:
        return "not set"
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, tuple):
        return "`[" + ", ".join(_default(v).strip("`") for v in value) + "]`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, float):
        return f"`{value:g}`"
    return f"`{value}`"


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("``", "`").replace("|", "\\|")


# --------------------------------------------------------------------------------------
# the file
# --------------------------------------------------------------------------------------
class Lines:
    """Line numbers of the tables and keys of a TOML text, for messages (``a.b.key -> line``)."""

    _table = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\- ]+?)\s*\]\s*(#.*)?$")
    _key = re.compile(r"^\s*([A-Za-z0-9_\-]+)\s*=")

    def __init__(self, text: str) -> None:
        self.lines: dict[str, int] = {}
        table = ""
        for no, line in enumerate(text.splitlines(), start=1):
            m = self._table.match(line)
            if m:
                table = m.group(1).replace(" ", "")
                self.lines.setdefault(table, no)
                continue
            m = self._key.match(line)
            if m:
                self.lines.setdefault(f"{table}.{m.group(1)}" if table else m.group(1), no)

    def of(self, key_path: str) -> int | None:
        """The line of ``key_path``, or of the nearest table that holds it."""
        while key_path:
            if key_path in self.lines:
                return self.lines[key_path]
            key_path = key_path.rpartition(".")[0]
        return None


def read_toml(path: str | Path, what: str = "file") -> tuple[dict[str, Any], Lines, bytes]:
    """A TOML file's tables, the lines of its keys and its bytes; :class:`InputError` naming the file when it
    cannot be read or is not TOML."""
    shown = str(path)
    raw = read_bytes(path, what, InputError)
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise InputError(f"{shown}: not UTF-8 text") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{shown}: not valid TOML ({exc})") from exc
    return data, Lines(text), raw


def toml_text(data: dict[str, Any]) -> str:
    """A tree of tables (scalars, lists of scalars, nested tables; None left out) as TOML."""
    def value(x: Any) -> str:
        if isinstance(x, bool):
            return "true" if x else "false"
        if isinstance(x, str):
            return '"' + x.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
        if isinstance(x, list | tuple):
            return "[" + ", ".join(value(v) for v in x) + "]"
        return repr(float(x)) if isinstance(x, float) else str(x)

    def table(name: str, body: dict[str, Any]) -> list[str]:
        lines = [f"[{name}]"] + [f"{k} = {value(v)}"
                                 for k, v in body.items() if not isinstance(v, dict) and v is not None]
        for k, v in body.items():
            if isinstance(v, dict):
                lines += ["", *table(f"{name}.{k}", v)]
        return lines

    out: list[str] = []
    for name, body in data.items():
        out += [*table(name, body), ""]
    return "\n".join(out)
