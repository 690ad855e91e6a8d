"""Configuration files (TOML): their text read with the lines of its keys, and their tables, typed.

A table of a file is a frozen dataclass deriving from :class:`Table`, its keys declared with :func:`key`: a
record's :func:`~piezopreload.core.records.entry` (its default, its documentation, its unit and its range; its type
the field's annotation), so the study's tables and the artifacts speak one schema dialect, that of
:mod:`piezopreload.core.records`. A table that is a domain type's (``[rig]`` is a
:class:`~piezopreload.models.actuator.Plant`) is read straight into that type
(:class:`~piezopreload.core.records.TableOf`). From the one declaration come

* the checks (:meth:`Table.parse` on a file's values, and every construction in code): unknown keys, types,
  finite numbers, ranges, choices and list lengths, then the type's own rules between its keys (``check``);
* the error messages, in one format: ``FILE:LINE: 'table.key' must be WHAT, got VALUE``: each names the key's path,
  the value and what was expected, and the caller's ``fail(path, message)`` adds the file and the key's line
  (:class:`Lines`);
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

import re
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from piezopreload.core.artifacts import read_bytes
from piezopreload.core.errors import InputError
from piezopreload.core.records import MANY, Checked, Invalid, TableOf, entry, table_keys

__all__ = ["Invalid", "Lines", "Table", "key", "keys_markdown", "read_toml", "toml_text"]

#: ``fail(path, message)``: the error for the key at ``path`` (the caller adds its file and line)
Fail = Callable[[str, str], Exception]


# --------------------------------------------------------------------------------------
# a table's key: a record's entry
# --------------------------------------------------------------------------------------
def key(default: Any, doc: str, *, unit: str = "", ge: float | None = None, gt: float | None = None,
        le: float | None = None, lt: float | None = None, choices: tuple[str, ...] | list[str] = (),
        increasing: bool = False, min_length: int = 0, required: bool = False) -> Any:
    """Declare a key of a :class:`Table`: a record's :func:`~piezopreload.core.records.entry` in a table's order of
    arguments (its default first; ignored where ``required``); ``min_length`` the fewest entries of a list.

    Parameters
    ----------
    default : object
        The key's value where the file gives none.
    doc : str
        What the key holds (the docs' table of keys shows it).
    unit, ge, gt, le, lt, choices, increasing
        As :class:`~piezopreload.core.records.Entry` has them.
    min_length : int
        The fewest entries of a list (0: any).
    required : bool
        Whether the file must give it.

    Returns
    -------
    dataclasses.Field
        The field, its declaration in its metadata.
    """
    size = (min_length, MANY) if min_length else None
    if required:
        return entry(doc, unit=unit, ge=ge, gt=gt, le=le, lt=lt, choices=choices, increasing=increasing, size=size)
    return entry(doc, default=default, unit=unit, ge=ge, gt=gt, le=le, lt=lt, choices=choices, increasing=increasing,
                 size=size)


# --------------------------------------------------------------------------------------
# the table
# --------------------------------------------------------------------------------------
class Table(Checked):
    """A table of a configuration file as a frozen dataclass, its keys as fields declared with :func:`key` (a record's
    entries): the one schema dialect of the study's tables and the artifacts.

    A table checks itself on construction (every key against its declaration, then :meth:`check`, as every
    :class:`~piezopreload.core.records.Checked` type); :meth:`parse` makes one from a file's values with errors naming
    the key's path; None stands for a key not given where the domain's default applies.
    """

    @classmethod
    def table(cls) -> TableOf:
        """The table as the study's schema holds it: its type, its doc and its nested tables.

        Returns
        -------
        TableOf
            The table's schema (:class:`~piezopreload.core.records.TableOf`).
        """
        nested = tuple((s.name, s.record.table()) for s in table_keys(cls)
                       if isinstance(s.record, type) and issubclass(s.record, Table))
        return TableOf(cls, cls.__doc__ or "", nested=nested)

    @classmethod
    def parse(cls, data: Any, fail: Fail, path: str) -> Any:
        """The table from a file's values ``data`` at ``path`` (``design``, ``reference.step``).

        Parameters
        ----------
        data : dict
            The table, as TOML gives it.
        fail : callable
            ``fail(path of the key, message)``: the error to raise.
        path : str
            The table's path in the file.

        Returns
        -------
        Table
            The table.
        """
        return cls.table().parse(data, fail, path)

    def to_dict(self) -> dict[str, Any]:
        """The keys with a value (nested tables as dicts, tuples as lists), as a file would hold them.

        Returns
        -------
        dict
            Key to value.
        """
        return type(self).table().values(self)


# --------------------------------------------------------------------------------------
# the documentation's table of keys
# --------------------------------------------------------------------------------------
def keys_markdown(tables: Mapping[str, Any], notes: Mapping[str, str] | None = None) -> str:
    """The keys of ``tables`` (a file's table names and their :class:`Table` types or
    :class:`~piezopreload.core.records.TableOf`) as Markdown: one section per table (its doc's first paragraph), one
    row per key: what it takes, its default, its unit and its doc.

    Parameters
    ----------
    tables : mapping of str to Table type or TableOf
        The tables, by name, in the file's order.
    notes : mapping of str to str, optional
        A sentence added to a key's row, by its path (``rig.bolt_preload_N``).

    Returns
    -------
    str
        The Markdown.
    """
    out: list[str] = []
    for name, cls in tables.items():
        out += _table_markdown(name, cls if isinstance(cls, TableOf) else cls.table(), notes or {})
    return "\n".join(out).rstrip() + "\n"


def _table_markdown(name: str, table: TableOf, notes: Mapping[str, str]) -> list[str]:
    doc = " ".join(table.doc.strip().split("\n\n")[0].split()).removeprefix(f"[{name}]: ")
    lines = [f"### `[{name}]`", "", _cell(doc[:1].upper() + doc[1:]), "",
             "| key | takes | default | unit | description |", "|---|---|---|---|---|"]
    for key_name, want, default, unit, about in table.rows():
        note = notes.get(f"{name}.{key_name}")
        about = about.rstrip(".") + f"; {note}." if note and about.endswith(".") else \
            about + (f"; {note}" if note else "")
        if want == "the table":
            want = f"the table `[{name}.{key_name}]`"
        lines.append(f"| `{key_name}` | {_cell(want)} | {_cell(default)} | {_cell(unit)} | {_cell(about)} |")
    lines.append("")
    for sub, inner in table.nested:
        lines += _table_markdown(f"{name}.{sub}", inner, notes)
    return lines


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
