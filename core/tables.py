"""Measured records and tables as CSV: read with errors that name the file, the line and the column; written atomically.

A CSV with a header names its columns with units (``time_s,voltage_V,force_N``); lines that
are blank or start with ``#`` are skipped. Every value must be a finite number.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.artifacts import atomic_write_text, read_bytes
from piezopreload.core.errors import InputError

__all__ = ["MeasuredRecord", "ColumnSpec", "parse_columns", "read_input", "read_record", "read_table", "write_csv"]


ROLES = ("time", "input", "output")
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)*$")


@dataclass(frozen=True)
class ColumnSpec:
    """Where one role (time, input, output) is found: a 0-based index or a header name, and its name."""

    role: str
    index: int | None
    header: str | None
    name: str | None


def parse_columns(text: str) -> dict[str, ColumnSpec]:
    """Parse ``time=1,input=3:voltage_V,output=2:displacement_um`` (indices 0-based, or header names).

    After ``:`` an optional name with its unit (``voltage_V``) labels a headerless column.
    """
    specs: dict[str, ColumnSpec] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        role, sep, where = part.partition("=")
        role = role.strip()
        if not sep or role not in ROLES:
            raise InputError(
                f"--columns: '{part}' is not ROLE=COLUMN with ROLE one of time, input, output "
                "(example: time=1,input=3:voltage_V,output=2:displacement_um)"
            )
        col, _, label = where.partition(":")
        col, name = col.strip(), label.strip() or None
        if name is not None and not _NAME.match(name):
            raise InputError(f"--columns: name '{name}' for {role} must look like quantity_unit, e.g. force_N")
        if col.isdigit():
            specs[role] = ColumnSpec(role, int(col), None, name)
        elif col:
            specs[role] = ColumnSpec(role, None, col, name or col)
        else:
            raise InputError(f"--columns: {role}= needs a column index or header name")
    missing = [r for r in ROLES if r not in specs]
    if missing:
        raise InputError(f"--columns: no column given for {', '.join(missing)} (need time, input and output)")
    return specs


def unit_of(name: str) -> str:
    """The unit in a column name: ``force_N`` -> ``N``; ``''`` when there is none."""
    return name.rsplit("_", 1)[1] if "_" in name else ""


@dataclass(frozen=True, eq=False)
class MeasuredRecord:
    """A measured record: strictly increasing time, one input and one output, all finite.

    Parameters
    ----------
    path : str
        The file it was read from.
    sha256 : str
        The SHA-256 of the file's bytes.
    time_s : ndarray
        The sample times, strictly increasing (s).
    input, output : ndarray
        The input (the stacks' voltage) and the output (the force) at each sample, in the units their
        names carry.
    input_name, output_name : str
        The columns' names (``voltage_V``, ``force_N``): their units follow the last underscore.
    """

    path: str
    sha256: str
    time_s: NDArray[np.float64]
    input: NDArray[np.float64]
    output: NDArray[np.float64]
    input_name: str
    output_name: str

    @property
    def input_unit(self) -> str:
        """The input's unit, read from its name (``voltage_V`` gives ``V``)."""
        return unit_of(self.input_name)

    @property
    def output_unit(self) -> str:
        """The output's unit, read from its name (``force_N`` gives ``N``)."""
        return unit_of(self.output_name)

    def window(self, t0: float, t1: float) -> NDArray[np.bool_]:
        """Samples with ``t0 <= t <= t1``.

        Parameters
        ----------
        t0, t1 : float
            The window's first and last time, in s (both included).

        Returns
        -------
        ndarray of bool
            True for each sample whose time lies in the window, one per sample of :attr:`time_s`.
        """
        return (self.time_s >= t0) & (self.time_s <= t1)


def _default_specs(header: list[str], path: str) -> dict[str, ColumnSpec]:
    names = [h.strip() for h in header]
    time = [i for i, h in enumerate(names) if h.lower().startswith("time")]
    inp = [i for i, h in enumerate(names) if h.lower().startswith(("voltage", "input"))]
    if len(time) != 1 or len(inp) != 1:
        raise InputError(
            f"{path}:1: cannot tell the time and input columns from the header {names}; expected one "
            "column named time_* and one named voltage_* (or give --columns time=...,input=...,output=...)"
        )
    rest = [i for i, h in enumerate(names) if i not in (time[0], inp[0]) and h]
    if len(rest) != 1:
        raise InputError(
            f"{path}:1: the header {names} has {len(rest)} candidate output columns; name the output "
            "with --columns time=time_s,input=voltage_V,output=force_N"
        )
    return {
        "time": ColumnSpec("time", time[0], None, names[time[0]]),
        "input": ColumnSpec("input", inp[0], None, names[inp[0]]),
        "output": ColumnSpec("output", rest[0], None, names[rest[0]]),
    }


def read_input(path: str | Path, what: str = "file", error: type[InputError] = InputError) -> bytes:
    """The bytes of an input file; a missing or unreadable file is ``error`` naming the path."""
    return read_bytes(path, what, error)


def _csv_lines(path: str | Path) -> tuple[bytes, list[tuple[int, str]]]:
    """The raw bytes and the numbered lines of a CSV that are neither blank nor ``#`` comments."""
    raw = read_input(path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a CSV") from None
    return raw, [(no, line) for no, line in enumerate(text.splitlines(), start=1)
                 if line.strip() and not line.lstrip().startswith("#")]


def _number(cell: str, shown: str, no: int, label: str, hint: str = "") -> float:
    """The finite number in ``cell``; else :class:`InputError` naming the line and ``label`` (the column)."""
    try:
        value = float(cell)
    except ValueError:
        raise InputError(f"{shown}:{no}: {label} holds '{cell}', which is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{shown}:{no}: {label} is {cell}; every value must be finite{hint}")
    return value


def _first_not_increasing(values: NDArray[np.float64]) -> int | None:
    """The index of the first value that is not above the one before it, or None."""
    bad = np.flatnonzero(np.diff(values) <= 0)
    return int(bad[0]) + 1 if bad.size else None


def _resolve_columns(columns: dict[str, ColumnSpec], names: list[str], header_no: int,
                     shown: str) -> dict[str, ColumnSpec]:
    """Each role's column found in the header ``names``: by header name or by index, with its name."""
    resolved = {}
    for role, spec in columns.items():
        if spec.header is not None:
            if spec.header not in names:
                raise InputError(
                    f"{shown}:{header_no}: no column named '{spec.header}' for {role}; the header has {names}"
                )
            resolved[role] = ColumnSpec(role, names.index(spec.header), None, spec.name)
        elif spec.index is not None:
            if spec.index >= len(names):
                raise InputError(
                    f"{shown}:{header_no}: column {spec.index} for {role} does not exist; the header has "
                    f"{len(names)} columns (indices are 0-based)"
                )
            resolved[role] = ColumnSpec(role, spec.index, None, spec.name or names[spec.index])
    return resolved


def _record_columns(lines: list[tuple[int, str]], columns: dict[str, ColumnSpec] | None, header: bool,
                    shown: str) -> tuple[list[tuple[int, str]], dict[str, ColumnSpec]]:
    """The data lines and the columns of the roles: from the header line, or as ``columns`` gives them."""
    if header:
        header_no, header_line = lines[0]
        names = [h.strip() for h in header_line.split(",")]
        if columns is None:
            columns = _default_specs(names, shown)
        return lines[1:], _resolve_columns(columns, names, header_no, shown)
    if columns is None:
        raise InputError(f"{shown}: a file without a header needs --columns time=I,input=J,output=K")
    for role, spec in columns.items():
        if spec.index is None:
            raise InputError(f"--columns: {role}={spec.header} names a header column, but --no-header was given")
    return lines, columns


def _record_rows(lines: list[tuple[int, str]], order: list[ColumnSpec], shown: str) -> NDArray[np.float64]:
    """The time, input and output of every data line, as the columns of an array."""
    index = [int(s.index) for s in order if s.index is not None]  # resolved: every role has its index
    width = max(index) + 1
    labels = [f"{spec.role} column '{spec.name or f'column {spec.index}'}'" for spec in order]
    data = np.empty((len(lines), 3))
    for row, (no, line) in enumerate(lines):
        cells = line.split(",")
        if len(cells) < width:
            raise InputError(
                f"{shown}:{no}: {len(cells)} columns, expected at least {width} "
                f"(time, input, output in columns {index})"
            )
        for j in range(len(order)):
            data[row, j] = _number(cells[index[j]].strip(), shown, no, labels[j],
                                   " (remove or interpolate the sample)")
    return data


def read_record(
    path: str | Path,
    columns: dict[str, ColumnSpec] | None = None,
    header: bool = True,
    min_samples: int = 2,
) -> MeasuredRecord:
    """Read a CSV record; every problem raises :class:`InputError` naming the file and line.

    Lines that are blank or start with ``#`` are skipped. With ``header=True`` the first other
    line names the columns (``time_s,voltage_V,force_N``); without one, ``columns`` must say
    where time, input and output are.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    columns : dict of ColumnSpec, optional
        Where the time, the input and the output are (``parse_columns("time=0,input=1,output=2")``); default:
        the columns the header names ``time_*``, ``voltage_*`` (or ``input_*``) and the one other.
    header : bool
        Whether the first line that is not blank or a comment names the columns.
    min_samples : int
        The fewest data rows the record may have.

    Returns
    -------
    MeasuredRecord
        The record, its file's SHA-256 with it.

    Raises
    ------
    InputError
        Naming the file and line of the first problem (a missing column, a number that is not one, time
        that does not increase).
    """
    path = Path(path)
    shown = str(path)
    raw, lines = _csv_lines(path)
    if not lines:
        raise InputError(f"{shown}: the file is empty (no data rows); expected a CSV of time, input and output")
    lines, columns = _record_columns(lines, columns, header, shown)
    if not lines:
        raise InputError(f"{shown}: the file has a header but no data rows")
    data = _record_rows(lines, [columns[r] for r in ROLES], shown)
    t = data[:, 0]
    k = _first_not_increasing(t)
    if k is not None:
        raise InputError(
            f"{shown}:{lines[k][0]}: time {float(t[k])!r} is not after the previous sample's {float(t[k - 1])!r}; "
            "time must be strictly increasing"
        )
    if len(t) < min_samples:
        raise InputError(f"{shown}: {len(t)} data rows, need at least {min_samples}")
    labels = {r: (columns[r].name or f"column{columns[r].index}") for r in ROLES}
    return MeasuredRecord(
        path=shown,
        sha256=hashlib.sha256(raw).hexdigest(),
        time_s=t.copy(),
        input=data[:, 1].copy(),
        output=data[:, 2].copy(),
        input_name=labels["input"],
        output_name=labels["output"],
    )


def _table_header(lines: list[tuple[int, str]], required: tuple[str, ...], optional: tuple[str, ...],
                  shown: str) -> list[str]:
    """The column names of a table's header line, which must hold every ``required`` one."""
    if not lines:
        raise InputError(f"{shown}: the file is empty; expected a CSV with the header {','.join(required)}")
    header_no, header = lines[0]
    names = [h.strip() for h in header.split(",")]
    for name in required:
        if name not in names:
            raise InputError(f"{shown}:{header_no}: no column named '{name}'; the header has {names}, "
                             f"expected {list(required) + [f'[{o}]' for o in optional]}")
    return names


def _table_rows(rows: list[tuple[int, str]], names: list[str], wanted: list[str],
                shown: str) -> dict[str, NDArray[np.float64]]:
    """The ``wanted`` columns of a table's data rows, each row as wide as the header ``names``."""
    out = {n: np.empty(len(rows)) for n in wanted}
    where = [(n, names.index(n), f"column '{n}'") for n in wanted]
    for row, (no, line) in enumerate(rows):
        cells = line.split(",")
        if len(cells) != len(names):
            raise InputError(f"{shown}:{no}: {len(cells)} columns, expected {len(names)} as in the header")
        for n, j, label in where:
            out[n][row] = _number(cells[j].strip(), shown, no, label)
    return out


def read_table(path: str | Path, required: tuple[str, ...], optional: tuple[str, ...] = (),
               increasing: str | None = None) -> dict[str, NDArray[np.float64]]:
    """Read a CSV with a header by column names; every problem names the file and line.

    Returns the ``required`` columns and those of ``optional`` that are present. Lines that
    are blank or start with ``#`` are skipped; every value must be a finite number; the
    column ``increasing`` (time, usually) must be strictly increasing.
    """
    shown = str(path)
    _, lines = _csv_lines(path)
    names = _table_header(lines, required, optional, shown)
    wanted = [n for n in required + optional if n in names]
    if len(lines) < 3:
        raise InputError(f"{shown}: {len(lines) - 1} data rows, need at least 2")
    out = _table_rows(lines[1:], names, wanted, shown)
    if increasing is not None:
        values = out[increasing]
        k = _first_not_increasing(values)
        if k is not None:
            raise InputError(f"{shown}:{lines[k + 1][0]}: {increasing} {values[k]!r} is not after the previous "
                             f"row's {values[k - 1]!r}; it must be strictly increasing")
    return out


def write_csv(path: str | Path, columns: Mapping[str, Any], comment: str) -> None:
    """Named columns as CSV (``#`` comment lines, one header line, 9 significant digits), written atomically."""
    buf = io.StringIO()
    for line in comment.splitlines():
        buf.write(f"# {line}\n")
    np.savetxt(buf, np.column_stack([np.asarray(c, float) for c in columns.values()]), delimiter=",",
               header=",".join(columns), comments="", fmt="%.9g")
    atomic_write_text(path, buf.getvalue())
