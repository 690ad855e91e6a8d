"""The feedforward as an IEC 61131-3 Structured Text function block, for a PLC to run.

:func:`function_block` writes ``PP_FEEDFORWARD``: one call per sample period, the desired force
in (``target_N``), the command out (``command_V``); its instance keeps the inverse step's state
(the play operators' outputs, the creep carries and, for the paper's direction-switched model,
the last command). The model's numbers are ``VAR CONSTANT`` arrays, the creep lags discretised at
the loop's sample period. The code is the algorithm of
:class:`~piezopreload.models.hysteresis.InverseStep` written out statement by statement (the
steps of :data:`piezopreload.rig.export.INVERSE_STEP_ALGORITHM`), in a small subset of the
language: declarations of ``LREAL``, ``BOOL``, ``DINT`` and one-based ``ARRAY [1..n] OF LREAL``
with their initial values; assignments; ``IF``/``ELSIF``/``ELSE``; ``FOR ... TO ... DO``; the
operators ``+ - * / < > <= >= AND NOT``; ``MAX``, ``MIN`` and ``ABS``. Real literals always
carry a decimal point and 17 significant digits, so every number is the double the model holds.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from piezopreload.rig.export import FeedforwardTable

__all__ = ["function_block", "real"]

#: the array constants: the table's parameter, its name in the block, its unit
_ARRAYS = (("thresholds", "THRESHOLD_V", "play operator thresholds r, V"),
           ("shaper_thresholds", "DZ_THRESHOLD_N", "inverse dead-zone thresholds, N"),
           ("shaper_weights", "DZ_WEIGHT", "inverse dead-zone weights"),
           ("creep_weights", "CREEP_WEIGHT", "creep weights c, N/V"),
           ("creep_decay", "CREEP_DECAY", "creep carries' decay a per sample"),
           ("creep_input", "CREEP_INPUT", "creep carries' input gain e per sample"))
_DIRECTION_ARRAYS = (("weights", "WEIGHT", "weights w, N/V"), ("partial", "PARTIAL", "partial sums W, N/V"),
                     ("inverse_thresholds", "INV_THRESHOLD", "inverse thresholds, N"),
                     ("inverse_weights", "INV_WEIGHT", "inverse weights, V/N"))


def real(x: float) -> str:
    """An LREAL literal that reads back as the double ``x`` (always a decimal point, 17 significant digits)."""
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"a Structured Text literal must be finite, got {x!r}")
    return format(x, ".16E")


def _array(name: str, values: np.ndarray, what: str) -> list[str]:
    items = [real(v) for v in values]
    rows = [", ".join(items[i:i + 4]) for i in range(0, len(items), 4)]
    body = (",\n" + " " * 8).join(rows)
    return [f"    (* {what} *)", f"    {name} : ARRAY[1..{len(items)}] OF LREAL := [", f"        {body}];"]


def _constants(t: FeedforwardTable) -> list[str]:
    lines = ["VAR CONSTANT", f"    OFFSET_N : LREAL := {real(t.scalar('offset_N'))};",
             f"    BIAS_N : LREAL := {real(t.scalar('bias'))};"]
    for key, name, what in _ARRAYS:
        if t.params[key].size:
            lines += _array(name, t.params[key], what)
    for d in t.directions:
        for key, name, what in _DIRECTION_ARRAYS:
            lines += _array(f"{name}_{d.upper()}", t.params[f"{key}_{d}"], f"{what}, {d}")
    return lines + ["END_VAR"]


def _variables(t: FeedforwardTable) -> list[str]:
    s = t.structure
    lines = ["VAR_INPUT", "    target_N : LREAL; (* the desired force, N *)",
             "    reset : BOOL; (* TRUE: the step starts from rest at 0 V this sample *)", "END_VAR",
             "VAR_OUTPUT", "    command_V : LREAL; (* the feedforward's command, V *)", "END_VAR", "VAR",
             f"    y : ARRAY[1..{s.n_operators}] OF LREAL; (* the play operators' outputs, V *)"]
    if s.n_lags:
        lines.append(f"    carry : ARRAY[1..{s.n_lags}] OF LREAL; (* the creep carries, V *)")
    if s.asymmetric:
        lines += ["    v_prev : LREAL; (* the last command, V *)", "    v_fall : LREAL;", "    tol : LREAL;",
                  "    rise_ok : BOOL;", "    fall_ok : BOOL;"]
    lines += [f"    {n} : LREAL;" for n in ("x", "shaped", "g", "v", "total", "cum", "z")]
    return lines + ["    k : DINT;", "END_VAR"]


def _reset(t: FeedforwardTable) -> list[str]:
    s = t.structure
    lines = ["IF reset THEN", f"    FOR k := 1 TO {s.n_operators} DO", "        y[k] := 0.0;", "    END_FOR;"]
    if s.n_lags:
        lines += [f"    FOR k := 1 TO {s.n_lags} DO", "        carry[k] := 0.0;", "    END_FOR;"]
    if s.asymmetric:
        lines.append("    v_prev := 0.0;")
    return lines + ["END_IF;"]


def _shaper_and_creep(t: FeedforwardTable) -> list[str]:
    s = t.structure
    lines = ["(* 1. the target less the offset *)", "x := target_N - OFFSET_N;"]
    if s.n_shaper:
        lines += ["(* 2. the inverse dead-zone superposition *)", "shaped := 0.0;", f"FOR k := 1 TO {s.n_shaper} DO",
                  "    IF DZ_THRESHOLD_N[k] > 0.0 THEN",
                  "        shaped := shaped + DZ_WEIGHT[k] * MAX(x - DZ_THRESHOLD_N[k], 0.0);",
                  "    ELSIF DZ_THRESHOLD_N[k] < 0.0 THEN",
                  "        shaped := shaped + DZ_WEIGHT[k] * MIN(x - DZ_THRESHOLD_N[k], 0.0);", "    ELSE",
                  "        shaped := shaped + DZ_WEIGHT[k] * x;", "    END_IF;", "END_FOR;", "x := shaped;"]
    lines += ["(* 3. what the one-sample P-I map must give, the creep's known part taken off *)", "g := x - BIAS_N;"]
    if s.n_lags:
        lines += [f"FOR k := 1 TO {s.n_lags} DO", "    g := g - CREEP_WEIGHT[k] * carry[k];", "END_FOR;"]
    return lines


def _direction(t: FeedforwardTable, d: str, out: str) -> list[str]:
    n, D = t.structure.n_operators, d.upper()
    return [f"(* 4. the inverse operators on the {d} weights, eqs. (19)-(20) *)", "total := 0.0;",
            f"FOR k := 1 TO {n} DO", f"    total := total + WEIGHT_{D}[k] * y[k];", "END_FOR;",
            "cum := 0.0;", f"{out} := 0.0;", f"FOR k := 1 TO {n} DO", f"    cum := cum + WEIGHT_{D}[k] * y[k];",
            f"    z := PARTIAL_{D}[k] * y[k] + total - cum;",
            f"    z := MAX(g - INV_THRESHOLD_{D}[k], MIN(g + INV_THRESHOLD_{D}[k], z));",
            f"    {out} := {out} + INV_WEIGHT_{D}[k] * z;", "END_FOR;"]


_SWITCH = ["(* 5. the direction the weights used agree with; the one nearer the last command where both do *)",
           "tol := 1.0E-9 * (1.0 + ABS(v_prev));", "rise_ok := v >= v_prev - tol;", "fall_ok := v_fall < v_prev + tol;",
           "v := MAX(v, v_prev);", "v_fall := MIN(v_fall, v_prev - tol);", "IF rise_ok AND fall_ok THEN",
           "    IF v - v_prev > v_prev - v_fall THEN", "        v := v_fall;", "    END_IF;", "ELSIF fall_ok THEN",
           "    v := v_fall;", "ELSIF NOT rise_ok THEN", "    v := v_prev;", "END_IF;", "v_prev := v;"]


def _update(t: FeedforwardTable) -> list[str]:
    s = t.structure
    lines = ["(* 6. the forward model's state moves with the command *)", f"FOR k := 1 TO {s.n_operators} DO",
             "    y[k] := MAX(v - THRESHOLD_V[k], MIN(v + THRESHOLD_V[k], y[k]));", "END_FOR;"]
    if s.n_lags:
        lines += [f"FOR k := 1 TO {s.n_lags} DO", "    carry[k] := CREEP_DECAY[k] * carry[k] + CREEP_INPUT[k] * v;",
                  "END_FOR;"]
    return lines + ["command_V := v;"]


def function_block(t: FeedforwardTable, name: str = "PP_FEEDFORWARD") -> str:
    """The Structured Text source of the inverse step of ``t`` (a
    :class:`~piezopreload.rig.export.FeedforwardTable`)."""
    period = "any period (no creep)" if t.sample_period_s is None else f"a sample period of {t.sample_period_s!r} s"
    body = _reset(t) + _shaper_and_creep(t) + _direction(t, "rising", "v")
    if t.structure.asymmetric:
        body += _direction(t, "falling", "v_fall") + _SWITCH
    lines = [f"FUNCTION_BLOCK {name}",
             f"(* The inverse P-I step of a {t.kind} model at {period} (piezopreload; docs/exports.md):",
             "   call it once per sample with the desired force; "
             "add command_V to the PID's output before the clamp. *)",
             *_variables(t), *_constants(t), *body, *_update(t), "END_FUNCTION_BLOCK"]
    return "\n".join(lines) + "\n"
