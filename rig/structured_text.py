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
CONSTANT``, named as ``PP_CONTROLLER`` names a feedforward's (``ff_thresholds``, ...), the creep
lags discretised at the loop's sample period. Its body is the algorithm of the CasADi function of
:class:`~piezopreload.models.hysteresis.InverseStep` that the model's C is generated from
(:func:`~piezopreload.rig.controller_code.feedforward_code`), operation for operation, as
``PP_CONTROLLER``'s is: the inverse step is written once, and its text
(:data:`piezopreload.rig.export.INVERSE_STEP_ALGORITHM`) is for the LabVIEW table, which has no
generator.

Each block declares only what its body reads.

Both use a small subset of the language: declarations of ``LREAL``, ``BOOL``, ``DINT`` and
one-based ``ARRAY [1..n] OF LREAL`` with their initial values; assignments; ``IF``/``ELSIF``/
``ELSE``; ``FOR ... TO ... DO``; the operators ``+ - * / < > <= >= = <> AND OR NOT``; ``MAX``,
``MIN``, ``ABS`` and ``SEL``; the program calls the block. Real literals always carry a decimal
point and 17 significant digits, so every number is the double the gain set holds.
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import casadi as ca

from piezopreload.core.errors import InputError
from piezopreload.rig.casadi_st import real, statements
from piezopreload.rig.controller_code import (
    DESCRIPTIONS,
    GAIN_NAMES,
    ControllerCode,
    Parameter,
    feedforward_code,
    read_elements,
    state_fields,
)

if TYPE_CHECKING:
    from piezopreload.rig.export import InverseStepTable

__all__ = ["function_block", "controller_block", "loop_program", "real", "CONTROLLER_BLOCK", "LOOP_PROGRAM"]

#: the names of the gain set's function block and of the program that calls it
CONTROLLER_BLOCK, LOOP_PROGRAM = "PP_CONTROLLER", "PP_LOOP"


def function_block(t: InverseStepTable, name: str = "PP_FEEDFORWARD") -> str:
    """The Structured Text source of the inverse step of ``t`` (a :class:`~piezopreload.rig.export.InverseStepTable`):
    the algorithm of the CasADi function its C is generated from (:func:`~piezopreload.rig.controller_code.
    feedforward_code`), written out operation for operation as ``PP_CONTROLLER``'s is."""
    code = feedforward_code(t.structure, t.vector)
    params = _parameter_refs(code.parameters)
    decls, state, copy = _state(code.state, code.step)
    rest = statements(code.rest, [lambda k: params[k]], [lambda k: state[k]], prefix="s")
    step = statements(code.step, [_reader(state), lambda k: "target_N", lambda k: params[k]],
                      [lambda k: "command_V", lambda k: f"state_next[{k + 1}]"], prefix="t")
    work = {**rest.variables, **step.variables}
    period = "any period (no creep)" if t.sample_period_s is None else f"a sample period of {t.sample_period_s!r} s"
    lines = [f"FUNCTION_BLOCK {name}",
             *_comment(f"The inverse P-I step of a {t.kind} model at {period} (piezopreload; docs/exports.md): call "
                       "it once per sample with the desired force; add command_V to the PID's output before the clamp. "
                       "Generated from the CasADi function the model's C export is generated from (the algorithm "
                       "docs/exports.md states), operation for operation: do not edit the body. Its numbers are the "
                       "model's inverse step at this period, derived from the model: export it again to change them."),
             "VAR_INPUT", "    target_N : LREAL; (* the desired force, N *)",
             "    reset : BOOL; (* TRUE: the step starts from rest at 0 V this sample *)", "END_VAR",
             "VAR_OUTPUT", "    command_V : LREAL; (* the feedforward's command, V *)", "END_VAR",
             "VAR CONSTANT (* the model's inverse step's numbers: those the step reads *)"]
    for p in code.read:
        lines += _declaration(p.name, p.values, p.array, p.description)
    lines += ["END_VAR", "VAR (* the step's state: the forward model's *)", *decls, "END_VAR",
              "VAR (* the algorithm's work variables *)",
              f"    state_next : ARRAY[1..{code.structure.n_states}] OF LREAL;",
              *(["    k : DINT;"] if any("FOR" in c for c in copy) else []),
              *(f"    {n} : {work[n]};" for n in sorted(work, key=lambda x: (x[0], int(x[1:])))), "END_VAR",
              "IF reset THEN", "    (* at rest at 0 V *)", *("    " + line for line in rest.lines), "END_IF;",
              "(* one sample of the inverse step *)", *step.lines, *(line[4:] for line in copy), "END_FUNCTION_BLOCK"]
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


def _state(fields: tuple[tuple[str, int, int | None], ...] | list[tuple[str, int, int | None]],
           step: ca.Function) -> tuple[list[str], list[str | None], list[str]]:
    """The state's declarations, each element's ST variable, and the copy of ``state_next`` into the state: the fields
    ``step`` reads (a field it only writes, the controller's previous setpoint, is no variable of the block)."""
    decls: list[str] = []
    refs: list[str | None] = []
    copy: list[str] = []
    read = read_elements(step, "state")
    for name, start, size in fields:
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


def _reader(state: list[str | None]) -> Callable[[int], str]:
    """The ST variable of each state element the step reads (the others are no variables: :func:`_state`)."""
    def read(k: int) -> str:
        ref = state[k]
        if ref is None:
            raise InputError(f"the step reads element {k} of its state, which the block does not hold")
        return ref
    return read


def _parameter_refs(parameters: tuple[Parameter, ...]) -> list[str]:
    refs: list[str] = []
    for p in parameters:
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
    params = _parameter_refs(code.parameters)
    decls, state, copy = _state(state_fields(code.model), code.step)
    n_state = code.model.state.size
    start = statements(code.start, [lambda k: "setpoint_N", lambda k: "pv_N", lambda k: "track_V",
                                    lambda k: params[k]], [lambda k: state[k]], prefix="s")
    step = statements(code.step, [_reader(state), lambda k: "setpoint_N", lambda k: "pv_N", lambda k: params[k]],
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
