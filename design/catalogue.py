"""Ball-screw catalogue rows and the rigidity model evaluated on them.

A catalogue table is a CSV with a header, one row per printed rigidity of a preloaded double
nut; the columns the reader uses are ``designation``, ``source`` (``<vendor>_<catalogue>``),
the screw (``nominal_diameter_mm``, ``lead_mm``, ``ball_mm``, ``pitch_diameter_mm``, ``turns``,
``nut_outer_diameter_mm``), its ratings ``c_dyn_N`` and ``c0_N``, the preload the figure is
stated at (``preload_fraction`` of C_dyn), the figure ``rigidity_N_per_um``, its ``basis``
(``theoretical``, or ``accuracy_p5``: corrected for tolerance class P5) and ``check`` (``yes``,
or ``no`` for a row the vendor's own tables contradict); other columns (the figure as printed, a
note) are kept in the file and not read. The repository's table of HIWIN, THK and Rexroth ground
double nuts, 16-63 mm, is ``tests/data/ballscrew_rigidity.csv`` (its sources in
``tests/data/ballscrew_rigidity_sources.toml``); the tests and ``benchmarks/ballscrew_rigidity.py``
read it through :func:`load_rows`.

Each row becomes the screw the vendor tabulates (:meth:`BallScrew.from_catalogue`: the groove
conformity from the printed C_0), evaluated at the row's preload; the model's two calibrated
constants (:data:`EFFECTIVE_BALL_SHARE`, :data:`ACCURACY_FACTOR_P5`) can be fitted again on any
subset of rows (the leave-out checks).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from piezopreload.core.artifacts import read_bytes
from piezopreload.core.errors import InputError
from piezopreload.models.ballscrew import ACCURACY_FACTOR_P5, EFFECTIVE_BALL_SHARE, BallScrew

__all__ = ["CatalogueRow", "BASES", "load_rows", "checked", "error_stats", "fit_share", "fit_accuracy",
           "largest_lambda_L", "first_order_body_error"]

#: what a row's figure is: calculated for the nominal geometry, or corrected for tolerance class P5
BASES = ("theoretical", "accuracy_p5")
_NUMBERS = ("nominal_diameter_mm", "lead_mm", "ball_mm", "pitch_diameter_mm", "turns", "nut_outer_diameter_mm",
            "c_dyn_N", "c0_N", "preload_fraction", "rigidity_N_per_um")
_COLUMNS = ("designation", "source", *_NUMBERS, "basis", "check")


@dataclass(frozen=True)
class CatalogueRow:
    """One printed rigidity: the screw, the preload it is stated at, what kind of figure it is."""

    designation: str
    source: str
    nominal_diameter_mm: float
    lead_mm: float
    ball_mm: float
    pitch_diameter_mm: float
    turns: float
    nut_outer_diameter_mm: float
    c_dyn_N: float
    c0_N: float
    preload_fraction: float
    rigidity_N_per_um: float
    basis: str
    check: bool

    @property
    def preload_N(self) -> float:
        return self.preload_fraction * self.c_dyn_N

    @property
    def vendor(self) -> str:
        return self.source.split("_")[0]

    @cached_property
    def screw(self) -> BallScrew:
        """The row's screw with the model's constants (eta, and f_ar by the row's basis)."""
        return BallScrew.from_catalogue(
            self.nominal_diameter_mm, self.lead_mm, self.ball_mm, self.turns, c_dyn_N=self.c_dyn_N, c0_N=self.c0_N,
            pitch_diameter_mm=self.pitch_diameter_mm, nut_outer_diameter_mm=self.nut_outer_diameter_mm,
            accuracy_factor=ACCURACY_FACTOR_P5 if self.basis == "accuracy_p5" else 1.0)

    def predicted_N_per_um(self, share: float = EFFECTIVE_BALL_SHARE, accuracy_p5: float = ACCURACY_FACTOR_P5
                           ) -> float:
        """The model's rigidity at the row's preload with the given constants."""
        screw = replace(self.screw, load_sharing=share,
                        accuracy_factor=accuracy_p5 if self.basis == "accuracy_p5" else 1.0)
        return float(screw.rigidity_N_per_um(self.preload_N))

    def error(self, share: float = EFFECTIVE_BALL_SHARE, accuracy_p5: float = ACCURACY_FACTOR_P5) -> float:
        """Model over catalogue, minus one."""
        return self.predicted_N_per_um(share, accuracy_p5) / self.rigidity_N_per_um - 1.0

    def eq13_error(self) -> float:
        """The paper's eq. (13) (Hertz only, all balls, rigid nut and screw) over catalogue, minus one."""
        return float(self.screw.hertz_rigidity_N_per_um(self.preload_N)) / self.rigidity_N_per_um - 1.0


def _row(record: dict[str, str], where: str) -> CatalogueRow:
    """One CSV record as a row; ``where`` (``file:line``) names it in errors."""
    numbers = {}
    for name in _NUMBERS:
        try:
            numbers[name] = float(record[name])
        except ValueError:
            raise InputError(f"{where}: column '{name}' holds {record[name]!r}, which is not a number") from None
        if not (math.isfinite(numbers[name]) and numbers[name] > 0):
            raise InputError(f"{where}: column '{name}' is {record[name]}; it must be a finite number > 0")
    if record["basis"] not in BASES or record["check"] not in ("yes", "no"):
        raise InputError(f"{where}: row {record['designation']!r} has basis {record['basis']!r} and check "
                         f"{record['check']!r}; expected one of {BASES} and yes/no")
    return CatalogueRow(designation=record["designation"], source=record["source"], basis=record["basis"],
                        check=record["check"] == "yes", **numbers)


def load_rows(path: str | Path) -> list[CatalogueRow]:
    """Every row of a catalogue table (the layout of the module docstring), in its order.

    Parameters
    ----------
    path : str or Path
        The CSV file.

    Returns
    -------
    list of CatalogueRow
        The rows, flagged ones (``check = no``) included.

    Raises
    ------
    InputError
        The file cannot be read, a column is missing, or a row holds a value that is not
        what its column needs; the message names the file, the line and the column.
    """
    shown = str(path)
    try:
        text = read_bytes(path, "catalogue table", InputError).decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{shown}: not a UTF-8 text file (byte {exc.start}); expected a CSV") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    missing = [c for c in _COLUMNS if c not in (reader.fieldnames or ())]
    if missing:
        raise InputError(f"{shown}:1: no column named '{missing[0]}'; a catalogue table needs {list(_COLUMNS)}")
    rows = []
    for record in reader:
        if None in record or None in record.values():  # csv's marks of a row longer or shorter than the header
            cells = sum(v is not None for k, v in record.items() if k is not None) + len(record.get(None) or ())
            raise InputError(f"{shown}:{reader.line_num}: {cells} columns, expected {len(reader.fieldnames or ())} "
                             "as in the header")
        rows.append(_row(record, f"{shown}:{reader.line_num}"))
    return rows


def checked(rows: Iterable[CatalogueRow]) -> list[CatalogueRow]:
    """The rows the acceptance checks use: those the vendor's own tables do not contradict."""
    return [r for r in rows if r.check]


def error_stats(errors: Sequence[float]) -> dict[str, float]:
    """Largest absolute and root-mean-square relative error."""
    e = np.asarray(errors, float)
    return {"max": float(np.max(np.abs(e))), "rms": float(np.sqrt(np.mean(e ** 2))), "n": int(e.size)}


def fit_share(rows: Sequence[CatalogueRow]) -> float:
    """eta that minimises the RMS relative error over theoretical rows."""
    rows = [r for r in rows if r.basis == "theoretical"]
    if not rows:
        raise ValueError("fit_share needs theoretical rows")
    res = minimize_scalar(lambda eta: sum(r.error(eta) ** 2 for r in rows), bounds=(0.3, 1.0), method="bounded",
                          options={"xatol": 1e-6})
    return float(res.x)


def fit_accuracy(rows: Sequence[CatalogueRow], share: float = EFFECTIVE_BALL_SHARE) -> float:
    """f_ar (P5) that minimises the RMS relative error over accuracy-corrected rows, eta given."""
    rows = [r for r in rows if r.basis == "accuracy_p5"]
    if not rows:
        raise ValueError("fit_accuracy needs accuracy_p5 rows")
    # the rigidity is f_ar times the theoretical one: the least-squares f_ar is a closed form
    k = np.array([r.predicted_N_per_um(share, 1.0) / r.rigidity_N_per_um for r in rows])
    return float(np.sum(k) / np.sum(k ** 2))


def largest_lambda_L(rows: Iterable[CatalogueRow]) -> float:
    """The largest lambda L of the elastic load distribution over the rows, each nut at its preload."""
    return max(r.screw.load_distribution_lambda_per_mm(r.preload_N) * r.screw.nut_length_mm for r in rows)


def first_order_body_error(row: CatalogueRow) -> float:
    """How far the nut law's first-order body term is from the exact shear-lag stiffness of one
    nut at the row's preload: (exact compliance) / (first-order compliance) - 1."""
    s = row.screw
    lam_L = s.load_distribution_lambda_per_mm(row.preload_N) * s.nut_length_mm
    # exact: 1/k = (1/(k' L)) lam L coth(lam L); first order: 1/(k' L) (1 + (lam L)^2 / 3)
    exact = lam_L / math.tanh(lam_L)
    return exact / (1.0 + lam_L ** 2 / 3.0) - 1.0
