"""The operations the model steps are written over, and the named layouts of their vectors.

A model step (the plant's, the controller's, the closed loop's, the ball screw's formulas) is written once as a function
of an *ops table* and runs on numpy arrays or on CasADi expressions:

* :data:`NUMPY`: arrays whose last axis is the vector's and whose leading axes are a batch (one
  plant or thousands at once), for the reference simulation;
* :data:`CASADI`: ``SX``/``MX`` column vectors, for the graph the tuning differentiates and
  for the C code CasADi's code generator writes (the compiled simulation, the rig executor's
  step, the exported controller).

A :class:`Layout` names the entries of a parameter or state vector (``p.keff_N_per_um``, not
``theta[1]``); it unpacks a vector into named parts and packs them back, for either table.

Corners (``|x|``, a clip) may be *smoothed* for a gradient-based optimiser: ``smoothing = 0``
is the exact function, as the rig runs it; ``smoothing > 0`` rounds the corner (see
:func:`clip` and :func:`absolute`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError

__all__ = ["Ops", "NUMPY", "CASADI", "Layout", "clip", "absolute", "softplus"]


def _np_dot(z: Any, w: Any) -> Any:
    w = np.asarray(w)
    return z @ w if w.ndim == 1 else np.sum(z * w, axis=-1)


def _ca_dot(z: Any, w: Any) -> Any:
    return ca.dot(w, z)


def _np_shift_in(line: Any, s: Any) -> Any:
    line, s = np.asarray(line), np.asarray(s)
    batch = np.broadcast_shapes(line.shape[:-1], s.shape)
    return np.concatenate([np.broadcast_to(line[..., 1:], batch + (line.shape[-1] - 1,)),
                           np.broadcast_to(s, batch)[..., None]], axis=-1)


def _ca_shift_in(line: Any, s: Any) -> Any:
    return ca.vertcat(line[1:], s) if line.numel() > 1 else s + 0 * line


@dataclass(frozen=True)
class Ops:
    """What differs between numpy arrays and CasADi expressions, by name.

    ``expand(s)`` lets a scalar field meet a vector field (numpy: a trailing axis; CasADi: as
    is); ``dot(z, w)`` and ``sum(z)`` reduce a vector field, ``cumsum(z)`` its partial sums; ``repeat(s, n)`` makes one
    of ``n`` copies of a scalar; ``first(line)`` and ``shift_in(line, s)`` read and advance a delay line (drop the
    oldest entry, append ``s``). ``cbrt`` on CasADi is ``x ** (1/3)``: positive arguments only (the ball-screw formulas'
    forces), where numpy's also takes negative ones.
    """

    name: str
    symbolic: bool
    where: Callable[..., Any]
    minimum: Callable[..., Any]
    maximum: Callable[..., Any]
    logical_and: Callable[..., Any]
    logical_or: Callable[..., Any]
    exp: Callable[..., Any]
    expm1: Callable[..., Any]
    log1p: Callable[..., Any]
    sqrt: Callable[..., Any]
    fabs: Callable[..., Any]
    floor: Callable[..., Any]
    sin: Callable[..., Any]
    cos: Callable[..., Any]
    tan: Callable[..., Any]
    log: Callable[..., Any]
    cbrt: Callable[..., Any]
    dot: Callable[..., Any]
    sum: Callable[..., Any]
    expand: Callable[..., Any]
    repeat: Callable[..., Any]
    first: Callable[..., Any]
    shift_in: Callable[..., Any]
    cumsum: Callable[..., Any]


NUMPY = Ops(name="numpy", symbolic=False, where=np.where, minimum=np.minimum, maximum=np.maximum,
            logical_and=np.logical_and, logical_or=np.logical_or, exp=np.exp, expm1=np.expm1, log1p=np.log1p,
            sqrt=np.sqrt, fabs=np.abs, floor=np.floor, sin=np.sin, cos=np.cos, tan=np.tan, log=np.log, cbrt=np.cbrt,
            dot=_np_dot, sum=lambda z: np.sum(z, axis=-1), expand=lambda s: np.asarray(s)[..., None],
            repeat=lambda s, n: np.repeat(np.asarray(s, float)[..., None], n, axis=-1),
            first=lambda line: line[..., 0], shift_in=_np_shift_in, cumsum=lambda z: np.cumsum(z, axis=-1))
CASADI = Ops(name="casadi", symbolic=True, where=ca.if_else, minimum=ca.fmin, maximum=ca.fmax,
             logical_and=ca.logic_and, logical_or=ca.logic_or, exp=ca.exp, expm1=ca.expm1, log1p=ca.log1p,
             sqrt=ca.sqrt, fabs=ca.fabs, floor=ca.floor, sin=ca.sin, cos=ca.cos, tan=ca.tan, log=ca.log,
             cbrt=lambda x: x ** (1.0 / 3.0), dot=_ca_dot, sum=ca.sum1, expand=lambda s: s,
             repeat=lambda s, n: ca.repmat(s, n, 1) if n else ca.DM(0, 1), first=lambda line: line[0],
             shift_in=_ca_shift_in, cumsum=ca.cumsum)


def softplus(ops: Ops, y: Any, k: Any) -> Any:
    """``log(1 + exp(k y)) / k`` without overflow."""
    return ops.maximum(y, 0.0) + ops.log1p(ops.exp(-k * ops.fabs(y))) / k


def clip(ops: Ops, x: Any, lo: Any, hi: Any, smoothing: float = 0.0) -> Any:
    """``min(max(x, lo), hi)``; with ``smoothing > 0`` its corners rounded by softplus.

    The rounding spans ``smoothing`` of the half-range ``(hi - lo) / 2`` (the softplus'
    sharpness is its inverse): exact away from the corners, at most ``log(2)`` of that span off
    at them (a tanh would be a quarter of the range off at ``x = hi``).
    """
    if smoothing == 0.0:
        return ops.minimum(ops.maximum(x, lo), hi)
    k = 1.0 / (smoothing * 0.5 * (hi - lo))
    return x - softplus(ops, x - hi, k) + softplus(ops, lo - x, k)


def absolute(ops: Ops, x: Any, eps: float = 0.0) -> Any:
    """``|x|``; with ``eps > 0`` rounded as ``sqrt(x^2 + eps^2)``."""
    return ops.fabs(x) if eps == 0.0 else ops.sqrt(x * x + eps * eps)


class Layout:
    """Named fields of a flat vector: scalars (size ``None``) and sub-vectors (a length, maybe 0).

    >>> lay = Layout("state", [("v", None), ("creep", 4)])
    >>> lay.size, lay.slice("creep")
    (5, slice(1, 5, None))

    On numpy the vector is the last axis of an array (leading axes a batch); on CasADi a column.
    """

    def __init__(self, name: str, fields: Iterable[tuple[str, int | None]]) -> None:
        self.name = name
        self._fields: dict[str, tuple[int, int | None]] = {}
        start = 0
        for field_name, size in fields:
            if field_name in self._fields:
                raise InputError(f"layout {name!r} names {field_name!r} twice.")
            if size is not None and (int(size) != size or size < 0):
                raise InputError(f"layout {name!r}: field {field_name!r} needs a size >= 0 or None, got {size!r}.")
            self._fields[field_name] = (start, None if size is None else int(size))
            start += 1 if size is None else int(size)
        self.size = start
        self._numpy_keys = [(n, (Ellipsis, start) if size is None else (Ellipsis, slice(start, start + size)))
                            for n, (start, size) in self._fields.items()]

    def __repr__(self) -> str:
        inner = ", ".join(f"{n}" + ("" if s is None else f"[{s}]") for n, (_, s) in self._fields.items())
        return f"Layout({self.name!r}: {inner})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Layout) and list(self._fields.items()) == list(other._fields.items())

    def __hash__(self) -> int:
        return hash(tuple(self._fields.items()))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._fields)

    def field_size(self, name: str) -> int | None:
        return self._fields[name][1]

    def slice(self, name: str) -> slice:
        """Where field ``name`` sits in the vector (a scalar's slice has length 1)."""
        start, size = self._fields[name]
        return slice(start, start + (1 if size is None else size))

    def index(self, name: str) -> int:
        """Where scalar field ``name`` sits."""
        start, size = self._fields[name]
        if size is not None:
            raise InputError(f"{self.name}.{name} is a vector of {size}; take its slice().")
        return start

    def get(self, x: Any, name: str) -> Any:
        start, size = self._fields[name]
        if isinstance(x, ca.SX | ca.MX | ca.DM):
            return x[start] if size is None else x[start:start + size]
        return x[..., start] if size is None else x[..., start:start + size]

    def unpack(self, x: Any) -> SimpleNamespace:
        """Every field of ``x`` by name (views on numpy)."""
        if isinstance(x, ca.SX | ca.MX | ca.DM):
            return SimpleNamespace(**{n: self.get(x, n) for n in self._fields})
        if np.shape(x)[-1:] != (self.size,):
            raise InputError(f"{self.name} vector must end in an axis of {self.size}, got shape {np.shape(x)}.")
        return SimpleNamespace(**{n: x[key] for n, key in self._numpy_keys})

    def pack(self, ops: Ops, **parts: Any) -> Any:
        """The vector from its named parts (every field given; numpy parts broadcast over the batch)."""
        missing = [n for n in self._fields if n not in parts]
        extra = sorted(set(parts) - set(self._fields))
        if missing or extra:
            raise InputError(f"{self.name}: missing fields {missing}, unknown {extra}.")
        if ops.symbolic:
            return ca.vertcat(*[parts[n] for n, (_, size) in self._fields.items() if size != 0])
        arrays = [(np.asarray(parts[n], float), key) for n, key in self._numpy_keys]
        shapes = [a.shape if isinstance(key[1], int) else a.shape[:-1] for a, key in arrays]
        if not any(shapes):  # one loop: no batch to broadcast over
            return np.concatenate([a.reshape(-1) for a, _ in arrays])
        batch = np.broadcast_shapes(*shapes)
        out = np.empty(batch + (self.size,))
        for a, key in arrays:
            out[key] = a
        return out

    def numbers(self, **values: Any) -> Array:
        """A numeric vector (numpy, batched) from named values: :meth:`pack` on :data:`NUMPY`."""
        return np.asarray(self.pack(NUMPY, **values), dtype=np.float64)  # numpy's pack fills a float array
