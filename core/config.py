"""Configuration files (TOML) checked against a schema, with errors that name the file, the line and the key.

A schema is a nested dict: a key maps to a type (``str``, ``int``, ``bool``, ``list``,
:data:`NUMBER`) or to a nested schema (a table). :func:`read_config` reads a file and checks
every key and type; :class:`Lines` finds the line of a key for later messages;
:func:`toml_text` writes such a tree back as TOML; :class:`Table` is the base of a file's typed tables.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from piezopreload.core.artifacts import read_bytes
from piezopreload.core.errors import InputError

__all__ = ["NUMBER", "Lines", "Table", "check_tree", "read_config", "toml_text"]

#: the type of a key that takes any number (an integer or a float, not a bool)
NUMBER = (int, float)
_WANT = {str: "a string", list: "a list", int: "an integer", NUMBER: "a number", bool: "true or false"}


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


def check_tree(data: dict[str, Any], schema: dict[str, Any], where: Lines, shown: str, prefix: str = "",
               string_lists: frozenset[str] | set[str] = frozenset()) -> None:
    """Check every key of ``data`` against ``schema``: unknown keys, types, finite numbers.

    Lists hold finite numbers, or strings for the key paths in ``string_lists``.
    """
    for key, value in data.items():
        path = f"{prefix}{key}"
        line = where.of(path)
        at = f"{shown}:{line}" if line else shown
        if key not in schema:
            raise InputError(f"{at}: unknown key '{path}'; expected one of: {', '.join(sorted(schema))}")
        expected = schema[key]
        if isinstance(expected, dict):
            if not isinstance(value, dict):
                raise InputError(f"{at}: '{path}' must be a table ([{path}])")
            check_tree(value, expected, where, shown, f"{path}.", string_lists)
            continue
        ok = isinstance(value, bool) if expected is bool else isinstance(value, expected) and not isinstance(value, bool)
        if not ok:
            raise InputError(f"{at}: '{path}' must be {_WANT.get(expected, str(expected))}, "
                             f"got {type(value).__name__} {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{at}: '{path}' must be finite, got {value!r}")
        if isinstance(value, list) and path in string_lists:
            if not all(isinstance(x, str) for x in value):
                raise InputError(f"{at}: '{path}' must be a list of strings, got {value!r}")
        elif isinstance(value, list) and not all(isinstance(x, NUMBER) and not isinstance(x, bool) and math.isfinite(x)
                                                 for x in value):
            raise InputError(f"{at}: '{path}' must be a list of finite numbers, got {value!r}")


def read_config(path: str | Path, schema: dict[str, Any], what: str = "file",
                string_lists: frozenset[str] | set[str] = frozenset()) -> tuple[dict[str, Any], Lines, bytes]:
    """Read a TOML file and check it against ``schema``: its tables, their lines and its bytes."""
    shown = str(path)
    raw = read_bytes(path, what, InputError)
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise InputError(f"{shown}: not UTF-8 text") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{shown}: not valid TOML ({exc})") from exc
    lines = Lines(text)
    check_tree(data, schema, lines, shown, string_lists=string_lists)
    return data, lines, raw


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
        lines = [f"[{name}]"] + [f"{k} = {value(v)}" for k, v in body.items() if not isinstance(v, dict) and v is not None]
        for k, v in body.items():
            if isinstance(v, dict):
                lines += ["", *table(f"{name}.{k}", v)]
        return lines

    out: list[str] = []
    for name, body in data.items():
        out += [*table(name, body), ""]
    return "\n".join(out)


@dataclass(frozen=True)
class Table:
    """A table of a configuration file as a frozen record, its keys as fields; None stands for a key not given
    (the domain's default applies)."""

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None}


def _plain(x: Any) -> Any:
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    return x.to_dict() if isinstance(x, Table) else x
