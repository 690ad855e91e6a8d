"""Compiled model code: CasADi's code generator, the system C compiler, and a build cache on disk.

A model step written over CasADi expressions becomes C (``casadi.CodeGenerator``), is compiled
by the system's C compiler into a shared library, and is loaded with :mod:`ctypes` (or
``casadi.external``). A library is built once and kept in the build cache
(``$XDG_CACHE_HOME/piezopreload``, else ``~/.cache/piezopreload``) under the hash of its source,
the compiler and the flags: a changed definition is a new source, so a new library; an
unchanged one is loaded as it is. Two processes building the same library at once each compile
into a private folder and rename the result into place (an atomic rename), so neither reads a
half-written file.

:class:`StepRunner` wraps the common case: one step function ``(x, p, s_1..s_k) -> (x_next, y)``
called by a small generated C loop over time and over a batch of plants (parameters per plant,
the ``k`` scalar input series with any strides), writing every output sample.

Where no C compiler works, or ``PIEZOPRELOAD_ENGINE=numpy`` is set, :func:`enabled` is False
and callers take their numpy path, which gives the same numbers. ``PIEZOPRELOAD_ENGINE=c``
makes a failed build an error instead of a fall-back. Every build is logged (seconds, name,
hash) in ``builds.jsonl`` in the cache and counted in :func:`build_stats`.

This module imports casadi and nothing of the package's own.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.core.errors import InputError, InternalError

__all__ = ["ENGINE_ENV", "FLAGS", "FLAGS_LARGE", "prelude", "NativeBuildError", "cache_dir", "compiler", "engine",
           "enabled", "generate", "build", "build_from", "load", "library", "StepRunner", "step_runner",
           "build_stats", "reset_failures"]

#: ``numpy`` forces the numpy path; ``c`` makes a failed build an error; anything else: C where it works
ENGINE_ENV = "PIEZOPRELOAD_ENGINE"
#: the compiler flags (part of every library's hash): no fused multiply-add, so the C code rounds
#: as numpy does; calls inside the library bound locally, so the compiler inlines CasADi's helpers
FLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-semantic-interposition", "-fno-math-errno")

#: for a large unit (a step with its second derivatives): -O1 compiles in about half -O2's time
#: and runs as fast on it
FLAGS_LARGE = ("-O1",) + FLAGS[1:]

#: put before CasADi's code: max and min of two numbers as comparisons (libm's fmax and fmin are
#: calls the compiler does not inline, and they are most of a step's operations; the values are
#: the same for numbers, and both return the other argument for a NaN)
_PRELUDE = """#include <math.h>
#define fmax(x, y) ((x) > (y) ? (x) : (y))
#define fmin(x, y) ((x) < (y) ? (x) : (y))
"""

_LOCK = threading.Lock()
_LOADED: dict[str, ctypes.CDLL] = {}
_RUNNERS: dict[Any, StepRunner] = {}
_FAILED: dict[str, str] = {}
_STATS = {"builds": 0, "compile_s": 0.0, "cache_hits": 0}


class NativeBuildError(InternalError):
    """A library could not be generated, compiled or loaded (the caller falls back to numpy)."""


def cache_dir() -> Path:
    """Where compiled libraries are kept: ``$XDG_CACHE_HOME/piezopreload`` or ``~/.cache/piezopreload``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "piezopreload"


def engine() -> str:
    """``numpy``, ``c`` or ``auto``, from ``$PIEZOPRELOAD_ENGINE``."""
    value = os.environ.get(ENGINE_ENV, "auto").strip().lower()
    return value if value in ("numpy", "c") else "auto"


@lru_cache(maxsize=4)
def _identify(cc: str) -> str | None:
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    first = (out.stdout or out.stderr).strip().splitlines()
    return f"{cc} | {first[0] if first else ''}"


def compiler() -> tuple[str, str] | None:
    """The C compiler (``$CC``, else cc, gcc or clang on the PATH) and its identity (``--version``)."""
    for name in ([os.environ["CC"]] if os.environ.get("CC") else []) + ["cc", "gcc", "clang"]:
        path = shutil.which(name)
        if path is None:
            continue
        ident = _identify(path)
        if ident is not None:
            return path, ident
    return None


def enabled() -> bool:
    """Whether compiled code may run here: not forced off, and a C compiler answers."""
    return engine() != "numpy" and compiler() is not None


def reset_failures() -> None:
    """Forget builds that failed in this process (they are tried again)."""
    with _LOCK:
        _FAILED.clear()


def build_stats() -> dict[str, float]:
    """Builds and cache hits in this process, and the seconds spent compiling."""
    with _LOCK:
        return dict(_STATS)


def prelude() -> str:
    """What :func:`generate` puts before CasADi's code (the max and min as comparisons)."""
    return _PRELUDE


def generate(functions: Sequence[ca.Function], name: str, *, inline_minmax: bool = True) -> str:
    """C source of CasADi ``functions`` (plain C99, ``double``), as text.

    ``inline_minmax`` puts the comparisons for max and min in front (see ``_PRELUDE``); code
    for others to build (an export) goes without.
    """
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator(f"{name}.c", {"with_header": False, "casadi_real": "double"})
        for fn in functions:
            gen.add(fn)
        gen.generate(tmp + os.sep)
        return (_PRELUDE if inline_minmax else "") + Path(tmp, f"{name}.c").read_text()


def _log_build(folder: Path, record: dict[str, Any]) -> None:
    try:
        with open(folder / "builds.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(record) + "\n")
    except OSError:
        pass  # the log is a courtesy; the library is what counts


def build(name: str, source: str, flags: Sequence[str] = FLAGS) -> Path:
    """The shared library of ``source``, compiled once and cached by the hash of source, compiler and flags."""
    return build_from(name, source, lambda: source, flags)


def build_from(name: str, key: str, make_source: Callable[[], str], flags: Sequence[str] = FLAGS) -> Path:
    """:func:`build` for a source that is costly to generate: cached by the hash of ``key`` (a text
    that determines the source, such as a serialised CasADi function and the CasADi version),
    compiler and flags; ``make_source()`` runs only when the library is not in the cache."""
    found = compiler()
    if found is None:
        raise NativeBuildError("no C compiler found (set CC, or install cc, gcc or clang)")
    cc, ident = found
    digest = hashlib.sha256("\0".join([key, ident, *flags]).encode()).hexdigest()[:20]
    folder = cache_dir()
    lib = folder / f"{name}-{digest}.so"
    with _LOCK:
        if digest in _FAILED:
            raise NativeBuildError(_FAILED[digest])
    if lib.exists():
        with _LOCK:
            _STATS["cache_hits"] += 1
        return lib
    t0 = time.perf_counter()
    try:
        source = make_source()
        t_generated = time.perf_counter()
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder, prefix=f".build-{name}-") as tmp:
            src, out = Path(tmp, f"{name}.c"), Path(tmp, f"{name}.so")
            src.write_text(source)
            done = subprocess.run([cc, *flags, "-o", str(out), str(src), "-lm"], capture_output=True, text=True,
                                  check=False)
            if done.returncode != 0:
                raise NativeBuildError(f"{cc} failed on {name} ({done.returncode}): {done.stderr.strip()[-2000:]}")
            os.replace(src, folder / f"{name}-{digest}.c")  # beside the library, for reading
            os.replace(out, lib)  # atomic: a concurrent build of the same source writes the same file
    except (OSError, subprocess.SubprocessError, RuntimeError, NativeBuildError) as exc:
        message = str(exc) if isinstance(exc, NativeBuildError) else f"building {name} failed: {exc}"
        with _LOCK:
            _FAILED[digest] = message
        raise NativeBuildError(message) from exc
    seconds = time.perf_counter() - t0
    with _LOCK:
        _STATS["builds"] += 1
        _STATS["compile_s"] += seconds
    _log_build(folder, {"name": name, "digest": digest, "seconds": round(seconds, 4),
                        "generate_s": round(t_generated - t0, 4), "pid": os.getpid(),
                        "time_unix": round(time.time(), 3), "bytes": len(source), "flags": list(flags)})
    return lib


def load(path: Path) -> ctypes.CDLL:
    """The library at ``path``, loaded once per process."""
    key = str(path)
    with _LOCK:
        if key not in _LOADED:
            try:
                _LOADED[key] = ctypes.CDLL(key)
            except OSError as exc:
                raise NativeBuildError(f"cannot load {key}: {exc}") from exc
        return _LOADED[key]


def library(name: str, source: str) -> ctypes.CDLL:
    """:func:`build` then :func:`load`."""
    return load(build(name, source))


_DRIVER = """
/* piezopreload: the step above over n_steps samples for each of n_plants plants.
   params: n_plants rows of NP (row stride params_stride, 0 to share one row); x0 likewise (NX);
   series[i][k * sk[i] + p * sp[i]]: input i at sample k of plant p (strides in elements, 0 to share);
   out[(p * NY + j) * n_steps + k]: output j; x_end[p * NX + i]: the state after the last sample. */
int {entry}(long long n_plants, long long n_steps, const double* params, long long params_stride,
            const double* x0, long long x0_stride, const double* const* series, const long long* sk,
            const long long* sp, double* out, double* x_end) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real x[{nx}], x_next[{nx}], y[{ny}], u[{nin}];
  long long p, k;
  int i, j, flag;
  for (p = 0; p < n_plants; ++p) {{
    for (i = 0; i < {nx}; ++i) x[i] = x0[p * x0_stride + i];
    for (k = 0; k < n_steps; ++k) {{
      for (i = 0; i < {nin}; ++i) u[i] = series[i][k * sk[i] + p * sp[i]];
      arg[0] = x; arg[1] = params + p * params_stride;
      for (i = 0; i < {nin}; ++i) arg[2 + i] = u + i;
      res[0] = x_next; res[1] = y;
      flag = {fn}(arg, res, iw, w, 0);
      if (flag) return flag;
      for (j = 0; j < {ny}; ++j) out[(p * {ny} + j) * n_steps + k] = y[j];
      for (i = 0; i < {nx}; ++i) x[i] = x_next[i];
    }}
    for (i = 0; i < {nx}; ++i) x_end[p * {nx} + i] = x[i];
  }}
  return 0;
}}
"""


class StepRunner:
    """A step function ``(x, p, s_1..s_k) -> (x_next, y)`` compiled with a C loop over time and plants.

    ``step`` has a dense column ``x`` (``nx``), a column ``p`` (``np``), ``k`` scalars and two
    outputs, ``x_next`` (``nx``) and ``y`` (``ny``). Building may raise :class:`NativeBuildError`.
    """

    def __init__(self, step: ca.Function, name: str, flags: Sequence[str] = FLAGS) -> None:
        n_in = step.n_in()
        if step.n_out() != 2 or n_in < 2:
            raise InputError(f"a step takes (x, p, inputs...) and returns (x_next, y); {step.name()} has "
                             f"{n_in} inputs and {step.n_out()} outputs.")
        self.nx, self.np, self.ny = step.numel_in(0), step.numel_in(1), step.numel_out(1)
        self.n_series = n_in - 2
        if step.numel_out(0) != self.nx or any(step.numel_in(i) != 1 for i in range(2, n_in)):
            raise InputError(f"{step.name()}: x_next must match x, and each input after p must be a scalar.")
        entry = f"{name}_run"
        driver = _DRIVER.format(entry=entry, fn=step.name(), sz_arg=max(step.sz_arg(), n_in),
                                sz_res=max(step.sz_res(), 2), sz_iw=max(step.sz_iw(), 1), sz_w=max(step.sz_w(), 1),
                                nx=max(self.nx, 1), ny=max(self.ny, 1), nin=max(self.n_series, 1))
        self.source = generate([step], name) + driver
        self.name = name
        self._lib = load(build(name, self.source, flags))
        fn = getattr(self._lib, entry)
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_longlong, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p,
                       ctypes.c_longlong, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                       ctypes.c_void_p]
        self._fn = fn

    def __call__(self, params: np.ndarray, x0: np.ndarray, series: Sequence[np.ndarray],
                 n_plants: int) -> tuple[np.ndarray, np.ndarray]:
        """Run ``n_plants`` plants over the series; returns ``y`` ``(n_plants, ny, n_steps)`` and the final states.

        ``params`` and ``x0`` are ``(n_plants, n)`` or ``(n,)`` (shared); each series is
        ``(n_steps, n_plants)`` or ``(n_steps,)`` (shared), any strides (a broadcast view is fine).
        """
        if len(series) != self.n_series:
            raise InputError(f"{self.name} takes {self.n_series} input series, got {len(series)}.")
        params = np.ascontiguousarray(params, dtype=float)
        x0 = np.ascontiguousarray(x0, dtype=float)
        n_steps = int(np.shape(series[0])[0]) if series else 0
        arrays, sk, sp = [], [], []
        for s in series:
            a = np.asarray(s, dtype=float)
            if a.ndim == 1:
                a = a[:, None]
            if a.ndim != 2 or a.shape[0] != n_steps or a.shape[1] not in (1, n_plants):
                raise InputError(f"each input series must be (n_steps,) or (n_steps, {n_plants}), got {np.shape(s)}.")
            if a.strides[0] % 8 or a.strides[1] % 8:
                a = a.copy()
            arrays.append(a)
            sk.append(a.strides[0] // 8)
            sp.append(a.strides[1] // 8 if a.shape[1] > 1 else 0)
        for arr, n, what in ((params, self.np, "params"), (x0, self.nx, "x0")):
            if arr.shape[-1:] != (n,) or arr.ndim > 2 or (arr.ndim == 2 and arr.shape[0] != n_plants):
                raise InputError(f"{what} must be ({n},) or ({n_plants}, {n}), got {arr.shape}.")
        out = np.empty((n_plants, self.ny, n_steps))
        x_end = np.empty((n_plants, self.nx))
        ptrs = (ctypes.c_void_p * max(len(arrays), 1))(*[a.ctypes.data for a in arrays])
        sk_arr = np.array(sk or [0], dtype=np.int64)
        sp_arr = np.array(sp or [0], dtype=np.int64)
        flag = self._fn(n_plants, n_steps, params.ctypes.data, self.np if params.ndim == 2 else 0, x0.ctypes.data,
                        self.nx if x0.ndim == 2 else 0, ctypes.cast(ptrs, ctypes.c_void_p), sk_arr.ctypes.data,
                        sp_arr.ctypes.data, out.ctypes.data, x_end.ctypes.data)
        if flag:
            raise InternalError(f"the compiled {self.name} returned {flag}")
        return out, x_end


def step_runner(key: Any, make_step: Callable[[], ca.Function], name: str,
                flags: Sequence[str] = FLAGS) -> StepRunner:
    """The :class:`StepRunner` of ``make_step()``, built once per process for each hashable ``key``
    (a model's structure); the library itself comes from the cache on disk when it is there."""
    with _LOCK:
        runner = _RUNNERS.get(key)
    if runner is None:
        runner = StepRunner(make_step(), name, flags)
        with _LOCK:
            _RUNNERS[key] = runner
    return runner
