"""The PLC exports' IEC 61131-3 Structured Text: the controller's function block and program, the feedforward's block.

A gain set (:func:`controller_block`, :func:`loop_program`):

* ``PP_CONTROLLER``, the whole controller step as the simulation, the rig and the exported C run
  it (the PID in its form, trapezoidal integral, derivative on the measurement through its
  filter, setpoint weight, conditional-integration anti-windup, the output clamp; the
  feedforward and the gain schedule's interpolation where the gain set has them). Its body is the
  algorithm of the CasADi functions the C is generated from (:mod:`piezopreload.rig.controller_code`),
  statement for statement (:mod:`piezopreload.rig.casadi_st`), so the two cannot differ. It adds
  what a PLC needs around the step: ``enable`` (``FALSE``: ``u_V`` follows ``track_V``; its rising
  edge starts the step bumplessly from ``track_V``, as the rig starts it); the parameters are
  variables holding the gain set's numbers, by the names of
  :func:`~piezopreload.rig.controller_code.parameters`, which ``rig push --to`` writes;
* ``PP_LOOP``, a program that calls it once per task cycle with bumpless switching between
  manual and automatic.

A hysteresis model alone (:func:`function_block`) writes ``PP_FEEDFORWARD``: one call per
sample period, the desired force in (``target_N``), the command out (``command_V``); its
instance keeps the inverse step's state (the play operators' outputs, the creep carries and, for
the paper's direction-switched model, the last command). The model's numbers are ``VAR
CONSTANT`` arrays, the creep lags discretised at the loop's sample period. The code is the
algorithm of :class:`~piezopreload.models.hysteresis.InverseStep` written out statement by
statement (the steps of :data:`piezopreload.rig.export.INVERSE_STEP_ALGORITHM`), readable as the
algorithm's text.

Both use a small subset of the language: declarations of ``LREAL``, ``BOOL``, ``DINT`` and
one-based ``ARRAY [1..n] OF LREAL`` with their initial values; assignments; ``IF``/``ELSIF``/
``ELSE``; ``FOR ... TO ... DO``; the operators ``+ - * / < > <= >= = <> AND OR NOT``; ``MAX``,
``MIN``, ``ABS`` and ``SEL``; the program calls the block. Real literals always carry a decimal
point and 17 significant digits, so every number is the double the gain set holds.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.rig.casadi_st import real, statements
from piezopreload.rig.controller_code import DESCRIPTIONS, GAIN_NAMES, ControllerCode, read_elements, state_fields

if TYPE_CHECKING:
    from piezopreload.rig.export import InverseStepTable

__all__ = ["function_block", "controller_block", "loop_program", "real", "CONTROLLER_BLOCK", "LOOP_PROGRAM"]

#: the names of the gain set's function block and of the program that calls it
CONTROLLER_BLOCK, LOOP_PROGRAM = "PP_CONTROLLER", "PP_LOOP"

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


def _array(name: str, values: np.ndarray, what: str) -> list[str]:
    items = [real(v) for v in values]
    rows = [", ".join(items[i:i + 4]) for i in range(0, len(items), 4)]
    body = (",\n" + " " * 8).join(rows)
    return [f"    (* {what} *)", f"    {name} : ARRAY[1..{len(items)}] OF LREAL := [", f"        {body}];"]


def _constants(t: InverseStepTable) -> list[str]:
    lines = ["VAR CONSTANT", f"    OFFSET_N : LREAL := {real(t.scalar('offset_N'))};",
             f"    BIAS_N : LREAL := {real(t.scalar('bias'))};"]
    for key, name, what in _ARRAYS:
        if t.params[key].size:
            lines += _array(name, t.params[key], what)
    for d in t.directions:
        for key, name, what in _DIRECTION_ARRAYS:
            lines += _array(f"{name}_{d.upper()}", t.params[f"{key}_{d}"], f"{what}, {d}")
    return lines + ["END_VAR"]


def _variables(t: InverseStepTable) -> list[str]:
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


def _reset(t: InverseStepTable) -> list[str]:
    s = t.structure
    lines = ["IF reset THEN", f"    FOR k := 1 TO {s.n_operators} DO", "        y[k] := 0.0;", "    END_FOR;"]
    if s.n_lags:
        lines += [f"    FOR k := 1 TO {s.n_lags} DO", "        carry[k] := 0.0;", "    END_FOR;"]
    if s.asymmetric:
        lines.append("    v_prev := 0.0;")
    return lines + ["END_IF;"]


def _shaper_and_creep(t: InverseStepTable) -> list[str]:
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


def _direction(t: InverseStepTable, d: str, out: str) -> list[str]:
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


def _update(t: InverseStepTable) -> list[str]:
    s = t.structure
    lines = ["(* 6. the forward model's state moves with the command *)", f"FOR k := 1 TO {s.n_operators} DO",
             "    y[k] := MAX(v - THRESHOLD_V[k], MIN(v + THRESHOLD_V[k], y[k]));", "END_FOR;"]
    if s.n_lags:
        lines += [f"FOR k := 1 TO {s.n_lags} DO", "    carry[k] := CREEP_DECAY[k] * carry[k] + CREEP_INPUT[k] * v;",
                  "END_FOR;"]
    return lines + ["command_V := v;"]


def function_block(t: InverseStepTable, name: str = "PP_FEEDFORWARD") -> str:
    """The Structured Text source of the inverse step of ``t`` (a
    :class:`~piezopreload.rig.export.InverseStepTable`)."""
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


# --------------------------------------------------------------------------------------
# a gain set: the controller's block and the program that calls it
# --------------------------------------------------------------------------------------
_OUTPUTS = (("u_V", "the command, V, clamped to u_min_V..u_max_V"), ("p_V", "its proportional action, V"),
            ("i_V", "its integral action, V"), ("d_V", "its derivative action, V"),
            ("ff_V", "its feedforward, V"))


def _declaration(name: str, values: tuple[float, ...], array: bool, what: str) -> list[str]:
    """``name : LREAL`` or ``name : ARRAY[1..n] OF LREAL``, with its initial values."""
    if not array:
        return [f"    {name} : LREAL := {real(values[0])}; (* {what} *)"]
    n = len(values)
    items = [real(v) for v in values]
    rows = (",\n" + " " * 8).join(", ".join(items[i:i + 4]) for i in range(0, len(items), 4))
    return [f"    (* {what} *)", f"    {name} : ARRAY[1..{n}] OF LREAL := [", f"        {rows}];"]


def _state(code: ControllerCode) -> tuple[list[str], list[str | None], list[str]]:
    """The state's declarations, each element's ST variable, and the copy of ``state_next`` into the state: the fields
    the step reads (a field it only writes, the previous setpoint, is no variable of the block)."""
    decls: list[str] = []
    refs: list[str | None] = []
    copy: list[str] = []
    read = read_elements(code.step, "state")
    for name, start, size in state_fields(code.model):
        what = DESCRIPTIONS.get(name, name)
        if not any(start + j in read for j in range(size or 1)):
            refs += [None] * (size or 1)  # the start does not write it: the step does not read it
            continue
        if size is None or size == 1:
            decls.append(f"    {name} : LREAL; (* {what} *)")
            refs.append(name)
            copy.append(f"    {name} := state_next[{start + 1}];")
        else:
            decls.append(f"    {name} : ARRAY[1..{size}] OF LREAL; (* {what} *)")
            refs += [f"{name}[{j + 1}]" for j in range(size)]
            copy += [f"    FOR k := 1 TO {size} DO", f"        {name}[k] := state_next[{start} + k];", "    END_FOR;"]
    return decls, refs, copy


def _parameter_refs(code: ControllerCode) -> list[str]:
    refs: list[str] = []
    for p in code.parameters:
        refs += [f"{p.name}[{j + 1}]" for j in range(p.size)] if p.array else [p.name]
    return refs


def _comment(text: str) -> list[str]:
    """``text`` as an ST comment of lines of at most 110 characters."""
    lines = textwrap.wrap(text, 104)
    last = len(lines) - 1
    return [("(* " if i == 0 else "   ") + line + (" *)" if i == last else "") for i, line in enumerate(lines)]


def _names(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _numbers_to_change(code: ControllerCode) -> str:
    """The header's sentence on which of the block's numbers to change: the ones the step reads, by name (a scheduled
    set's gains are the schedule's arrays), and those not to change by hand."""
    read = [p.name for p in code.read]
    single = [n for n in read if n in GAIN_NAMES and not n.startswith("schedule_")]
    arrays = [n for n in read if n.startswith("schedule_")]
    what = f"the gains {_names(single)}" if not arrays else (
        f"the gain schedule's arrays {_names(arrays)} (one entry per setpoint level of schedule_levels_N, in N), "
        f"the single {_names(single)}")
    rng = [n for n in ("u_min_V", "u_max_V") if n in read]
    ff = (" The ff_ numbers are the feedforward's inverse step, derived from its model: export again to change "
          "them." if any(n.startswith("ff_") for n in read) else "")
    return (f"To retune, change {what}" + (f", and the output range {_names(rng)}" if rng else "")
            + " in the VAR section of the gain set's numbers below (or write them with 'piezopreload rig push --to'); "
            "dt_s must stay the "
            "task's cycle time." + ff)


def controller_block(code: ControllerCode, head: list[str] | tuple[str, ...] = ()) -> str:
    """``PP_CONTROLLER``: the controller step of ``code`` as a function block (see the module docstring)."""
    params = _parameter_refs(code)
    decls, state, copy = _state(code)
    n_state = code.model.state.size
    start = statements(code.start, [lambda k: "setpoint_N", lambda k: "pv_N", lambda k: "track_V",
                                    lambda k: params[k]], [lambda k: state[k]], prefix="s")

    def state_in(k: int) -> str:  # the step reads only the fields that are variables (_state)
        ref = state[k]
        if ref is None:
            raise InputError(f"the step reads element {k} of its state, which the block does not hold")
        return ref

    step = statements(code.step, [state_in, lambda k: "setpoint_N", lambda k: "pv_N", lambda k: params[k]],
                      [lambda k: "u_V", lambda k: "p_V", lambda k: "i_V", lambda k: "d_V", lambda k: "ff_V",
                       lambda k: f"state_next[{k + 1}]"], prefix="t")
    work = {**start.variables, **step.variables}
    dt = code.controller.dt_s
    lines = [f"FUNCTION_BLOCK {CONTROLLER_BLOCK}",
             *(["(* " + "\n   ".join(head) + " *)"] if head else []),
             *_comment(f"Call it once per sample period, {dt!r} s (a cyclic task of that period). Generated by "
                       "piezopreload from the controller step the gains were tuned and validated with, as its C export "
                       "is: do not edit the body. " + _numbers_to_change(code)),
             "VAR_INPUT",
             "    enable : BOOL; (* TRUE: the loop runs; when it rises the loop starts bumplessly from track_V *)",
             "    setpoint_N : LREAL; (* the force setpoint, N *)",
             "    pv_N : LREAL; (* the measured force, N *)",
             "    track_V : LREAL; (* the command the actuator holds (the last one written), V: u_V while enable is",
             "                        FALSE, and the first command when it rises *)",
             "END_VAR", "VAR_OUTPUT",
             *(f"    {name} : LREAL; (* {what} *)" for name, what in _OUTPUTS),
             "    active : BOOL; (* TRUE while the loop runs *)", "END_VAR",
             "VAR (* the gain set's numbers: those the step reads *)"]
    for p in code.read:
        lines += _declaration(p.name, p.values, p.array, p.description)
    lines += ["END_VAR", "VAR (* the step's state *)", *decls, "END_VAR",
              "VAR (* the algorithm's work variables *)",
              f"    state_next : ARRAY[1..{n_state}] OF LREAL;",
              *(["    k : DINT;"] if any("FOR" in c for c in copy) else []),
              *(f"    {name} : {work[name]};" for name in sorted(work, key=lambda x: (x[0], int(x[1:])))),
              "END_VAR",
              "IF enable AND NOT active THEN",
              "    (* the bumpless start: the state whose first command at this setpoint and measurement is track_V *)",
              *("    " + line for line in start.lines),
              "END_IF;",
              "IF enable THEN",
              "    (* one sample of the controller step *)",
              *("    " + line for line in step.lines),
              *copy,
              "ELSE",
              *(f"    {name} := {'track_V' if name == 'u_V' else '0.0'};" for name, _ in _OUTPUTS),
              "END_IF;",
              "active := enable;",
              "END_FUNCTION_BLOCK"]
    return "\n".join(lines) + "\n"


def loop_program(dt_s: float) -> str:
    """``PP_LOOP``: one instance of ``PP_CONTROLLER`` called every task cycle, switched bumplessly between manual
    and automatic."""
    return "\n".join([
        f"PROGRAM {LOOP_PROGRAM}",
        f"(* Run it in a cyclic task of {dt_s!r} s. Connect force_N to the force sensor's reading and command_V to",
        "   the amplifier's input (in N and V: scale the raw channels first). automatic switches the loop in and",
        "   out bumplessly: in manual, command_V is manual_V, which follows the loop's command while the loop runs, so",
        "   switching to manual holds the last command and switching back starts from the command held. *)",
        "VAR",
        f"    ctrl : {CONTROLLER_BLOCK};",
        "    automatic : BOOL; (* TRUE: the loop runs; FALSE: manual *)",
        "    setpoint_N : LREAL; (* the force setpoint, N *)",
        "    force_N : LREAL; (* the measured force, N *)",
        "    manual_V : LREAL; (* the command in manual, V *)",
        "    command_V : LREAL; (* the command to the amplifier, V *)",
        "END_VAR",
        "ctrl(enable := automatic, setpoint_N := setpoint_N, pv_N := force_N, track_V := command_V);",
        "IF automatic THEN",
        "    command_V := ctrl.u_V;",
        "    manual_V := command_V;",
        "ELSE",
        "    command_V := manual_V;",
        "END_IF;",
        "END_PROGRAM"]) + "\n"
