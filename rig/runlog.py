"""The rig's run log: samples as CSV, a JSON sidecar (:class:`~piezopreload.artifacts.rigrun.RigRunRecord`) with what
ran and what happened.

Both files of a run share a name that no earlier run has (``run-<UTC time>-<gain set hash>``,
with ``-2``, ``-3`` ... on a clash); the CSV is created exclusively, so a run never
overwrites another. Samples are buffered and written at least every ``flush_s`` (50 ms by
default) and the sidecar is rewritten atomically at the start, at every event and at the end,
so a process killed outright leaves a CSV readable up to its last flush and a sidecar that
says the run was still ``running`` with every event until then.

The files are flushed to the operating system, not fsynced per flush: they survive the
process, not the power going down mid-run. The log also keeps its samples in memory (the first
``keep_rows``, all by default): a run is scored from :meth:`RunLog.columns`, not by reading
its CSV back. ``measured_N`` is the force the sensor read (what the controller saw).

An event may be logged without rewriting the sidecar at once (``write=False``: a stall, which the
Python loop logs inside its cycle); the next event or the end writes it with the rest.
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from array import array
from dataclasses import replace
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from piezopreload.artifacts.rigrun import RigRunRecord, RunMetrics, RunOutcome
from piezopreload.core.errors import InputError

__all__ = ["RunLog", "COLUMNS", "read_run_log", "LearnedFigures"]


class LearnedFigures(TypedDict, total=False):
    """A learned run's figures, added to the record of the signal it played: its RMS error against the reference the
    signal was learned on and against the plan (the setpoint) it played."""

    tracking_rms_measured_N: float
    plan_rms_measured_N: float

#: the CSV's columns, in order
COLUMNS = ("time_s", "reference_N", "measured_N", "command_V", "voltage_V", "feedforward_V", "p_V", "i_V", "d_V",
           "period_s", "lateness_s", "compute_s", "missed", "mode")
_ROW = ",".join(["%.6f"] + ["%.9g"] * (len(COLUMNS) - 3) + ["%d", "%d"]) + "\n"
#: the columns' units as the sidecar states them
UNITS = {"time_s": "s on the run's timeline (sample k at k / rate)",
         "mode": "0 control, 1 ramp-down, 2 the sample that stopped the run"}


def utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


class RunLog:
    """One run's CSV and JSON sidecar in ``folder``; ``record`` is what ran (the sidecar's fields before the run)."""

    def __init__(self, folder: str | Path, tag: str, record: RigRunRecord | None = None, *, flush_s: float = 0.05,
                 keep_rows: int | None = None) -> None:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        base = f"run-{stamp}-{tag}" if tag else f"run-{stamp}"
        for n in range(1, 10_000):
            stem = base if n == 1 else f"{base}-{n}"
            csv, sidecar = folder / f"{stem}.csv", folder / f"{stem}.json"
            if sidecar.exists():
                continue
            try:
                self._fh = open(csv, "x", encoding="utf-8", newline="")  # noqa: SIM115 - closed in close()
            except FileExistsError:
                continue
            break
        else:  # pragma: no cover - ten thousand runs in one second
            raise FileExistsError(f"no free run name for {base} in {folder}")
        self.csv_path, self.json_path = csv, sidecar
        self.flush_s = float(flush_s)
        self._rows: list[tuple] = []
        self._kept = [array("d") for _ in COLUMNS]
        self._keep = keep_rows
        self._lock = threading.Lock()
        self._last_flush = time.monotonic()
        self._fh.write(",".join(COLUMNS) + "\n")
        self._fh.flush()
        self.record = replace(record or RigRunRecord(), status="running", created_utc=utc_now(), csv=csv.name,
                              columns=COLUMNS, units=dict(UNITS), events=(), summary=None, reason=None,
                              finished_utc=None)
        self._write_sidecar()

    def sample(self, row: tuple, now: float) -> None:
        """Add one sample (in :data:`COLUMNS` order); written out when ``flush_s`` has passed."""
        self._rows.append(row)
        if self._keep is None or len(self._kept[0]) < self._keep:
            for column, x in zip(self._kept, row):
                column.append(x)
        if now - self._last_flush >= self.flush_s:
            self.flush(now)

    def flush(self, now: float | None = None) -> None:
        if self._rows:
            self._fh.write("".join(_ROW % r for r in self._rows))
            self._rows.clear()
        self._fh.flush()
        self._last_flush = time.monotonic() if now is None else now

    def columns(self) -> dict[str, np.ndarray]:
        """The samples kept in memory, as named columns (:data:`COLUMNS`)."""
        return {name: np.frombuffer(column, dtype=float).copy() for name, column in zip(COLUMNS, self._kept)}

    def event(self, event: dict[str, Any], write: bool = True) -> None:
        """Record an event (interlock, gain switch, ...) with its UTC time; the sidecar is rewritten (``write``).

        Safe from another thread than the loop's: only the loop writes the CSV, which it
        flushes within ``flush_s``.
        """
        with self._lock:
            self.record = self.record.event({"utc": utc_now(), **event})
            if write:
                self._write_sidecar()

    def save(self) -> None:
        """Rewrite the sidecar with every event recorded so far (those recorded with ``write=False`` too)."""
        with self._lock:
            self._write_sidecar()

    def close(self, status: str, outcome: RunOutcome) -> None:
        """The run has ended: the CSV closed, the sidecar's status and outcome written."""
        self._close(status=status, summary=outcome)

    def not_started(self, reason: str) -> None:
        """The run was refused after the log was opened (before arming): closed with the reason."""
        self._close(status="not started", reason=reason)

    def record_metrics(self, metrics: RunMetrics, learned: LearnedFigures | None = None) -> None:
        """A completed run's step and tracking figures, added to its outcome (a tripped run has none), and a
        learned signal's figures (``learned``) to the record of the signal."""
        with self._lock:
            summary = self.record.summary
            if summary is None or summary.trip is not None:
                raise ValueError("only a completed run's outcome takes metrics")
            changes: dict[str, Any] = {"summary": replace(summary, metrics=metrics)}
            if learned:
                changes["learned"] = {**(self.record.learned or {}), **learned}
            self.record = replace(self.record, **changes)
            self._write_sidecar()

    def _close(self, **fields: Any) -> None:
        self.flush()
        self._fh.close()
        with self._lock:
            self.record = replace(self.record, finished_utc=utc_now(), **fields)
            self._write_sidecar()

    def _write_sidecar(self) -> None:
        self.record.save(self.json_path)


def read_run_log(csv_path: str | Path) -> dict[str, np.ndarray]:
    """A run log's CSV as named columns: whatever was flushed, also after a kill (a line cut short is left out)."""
    with open(csv_path, encoding="utf-8") as fh:
        header = fh.readline().strip().split(",")
        if tuple(header) != COLUMNS:
            raise InputError(f"{csv_path}:1: not a run log; expected the header {','.join(COLUMNS)}")
        rows = [line for line in fh if line.endswith("\n")]
    try:
        data = np.loadtxt(rows, delimiter=",", ndmin=2) if rows else np.empty((0, len(COLUMNS)))
    except ValueError as exc:  # a row that is not numbers, or the wrong count of them (the header is line 1)
        raise InputError(f"{csv_path}: not a run log's samples ({exc}; row 0 is line 2)") from None
    if data.shape[1] != len(COLUMNS):
        raise InputError(f"{csv_path}: {data.shape[1]} columns in the samples, the header names {len(COLUMNS)}")
    return {name: data[:, j] for j, name in enumerate(COLUMNS)}
