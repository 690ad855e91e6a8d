"""A CasADi SX function's algorithm written as IEC 61131-3 Structured Text statements.

CasADi's code generator writes C from an SX function's *algorithm*: a list of elementary
instructions over a work vector (read an element of an input, load a constant, one arithmetic,
comparison or logical operation, write an element of an output). :func:`statements` writes the
same list as ST assignments, one per instruction, in the same order and on the same operands, so
the Structured Text and the C compute the same IEEE 754 doubles (``LREAL``) step for step: the
exported PLC block and the exported C come from one expression tree, the controller step of
:mod:`piezopreload.models.controller`.

What differs is only how each language spells an instruction:

* the work vector's slots become variables ``w<slot>`` (``LREAL``) and, for the results of a
  comparison or a logical operation, ``q<slot>`` (``BOOL``): ST has a Boolean type where C keeps
  0 and 1 in a double;
* ``c ? x : 0`` (``OP_IF_ELSE_ZERO``) is ``SEL(c, 0.0, x)``; ``fmin``/``fmax``/``fabs`` are
  ``MIN``/``MAX``/``ABS``; ``x*x`` and ``2*x`` (``OP_SQ``, ``OP_TWICE``) are written out;
* a Boolean read as a number is ``SEL(q, 0.0, 1.0)``, a number read as a Boolean ``w <> 0.0``,
  as C's conversions have it;
* a constant is an ``LREAL`` literal that reads back as the same double.

An instruction outside this set (a trigonometric function, say) is refused with its name: the
controller step uses none, and a PLC's library of such functions is not the C library's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from piezopreload.core.errors import InputError

__all__ = ["Translation", "statements", "real", "INLINE_MAX"]

#: two operands, an LREAL result: the ST operator between them
_ARITHMETIC = {ca.OP_ADD: "+", ca.OP_SUB: "-", ca.OP_MUL: "*", ca.OP_DIV: "/"}
#: two LREAL operands, a BOOL result
_COMPARISON = {ca.OP_LT: "<", ca.OP_LE: "<=", ca.OP_EQ: "=", ca.OP_NE: "<>"}
#: two BOOL operands, a BOOL result
_LOGICAL = {ca.OP_AND: "AND", ca.OP_OR: "OR"}
#: one or two LREAL operands, an LREAL result: the standard function
_FUNCTIONS = {ca.OP_FMIN: "MIN", ca.OP_FMAX: "MAX", ca.OP_FABS: "ABS", ca.OP_SQRT: "SQRT", ca.OP_EXP: "EXP",
              ca.OP_LOG: "LN"}
_NAMES = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_")}


def real(x: float) -> str:
    """An LREAL literal that reads back as the double ``x``: the shortest decimal that does (Python's ``repr``), with
    a decimal point always (``1.0E-05``, not ``1e-05``, which ST reads as no real)."""
    x = float(x)
    if not np.isfinite(x):
        raise InputError(f"a Structured Text literal must be finite, got {x!r}")
    mantissa, e, exponent = repr(x).partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + ("E" + exponent if e else "")


#: ST's operator precedence (IEC 61131-3): a higher level binds tighter; 9: a name, a literal, a function call
_OR, _AND, _EQUALITY, _RELATION, _ADDITIVE, _MULTIPLICATIVE, _UNARY, _ATOM = 1, 3, 4, 5, 6, 7, 8, 9
_LEVELS = {"OR": _OR, "AND": _AND, "=": _EQUALITY, "<>": _EQUALITY, "<": _RELATION, "<=": _RELATION,
           "+": _ADDITIVE, "-": _ADDITIVE, "*": _MULTIPLICATIVE, "/": _MULTIPLICATIVE}
#: an expression longer than this gets a variable of its own, though it is used once
INLINE_MAX = 72


@dataclass
class Translation:
    """The statements of one function's algorithm and the variables they use (name -> ``LREAL``/``BOOL``)."""

    lines: list[str] = field(default_factory=list)
    variables: dict[str, str] = field(default_factory=dict)


@dataclass
class _Value:
    """One value of the algorithm: its expression, the precedence of its outermost operator, its type."""

    text: str
    level: int
    type: str
    uses: int = 0


def _operand(v: _Value, want: str, level: int, right: bool = False) -> str:
    """``v`` as an operand of an operator of precedence ``level`` (right: its right-hand operand), as ``want``.

    Parentheses where the precedence needs them, around the right operand of an operator of its own
    level (``a - (b - c)``, and ``a + (b + c)``: the order of a floating-point sum is kept) and around a
    negation inside another operator (``a * (-b)``, as some compilers require)."""
    text, lv = v.text, v.level
    if v.type != want and want == "LREAL":
        text, lv = f"SEL({text}, 0.0, 1.0)", _ATOM
    elif v.type != want:
        text, lv = f"{f'({text})' if lv <= _EQUALITY else text} <> 0.0", _EQUALITY
    if lv < level or (right and lv == level) or (lv == _UNARY and 0 < level < _UNARY):
        return f"({text})"
    return text


#: one operand: the text around it, the operand's context (precedence, whether it is a right operand), the result's
#: precedence, the operand's and the result's type
_ONE_OPERAND = {
    ca.OP_NEG: ("-{0}", _ATOM, False, _UNARY, "LREAL", "LREAL"),
    ca.OP_NOT: ("NOT {0}", _ATOM, False, _UNARY, "BOOL", "BOOL"),
    ca.OP_SQ: ("{0} * {0}", _MULTIPLICATIVE, True, _MULTIPLICATIVE, "LREAL", "LREAL"),
    ca.OP_TWICE: ("2.0 * {0}", _MULTIPLICATIVE, True, _MULTIPLICATIVE, "LREAL", "LREAL"),
    ca.OP_INV: ("1.0 / {0}", _MULTIPLICATIVE, True, _MULTIPLICATIVE, "LREAL", "LREAL"),
}


def _operation(op: int, a: list[_Value]) -> _Value:
    """The expression of one operation on its operands' values."""
    for table, want, out in ((_ARITHMETIC, "LREAL", "LREAL"), (_COMPARISON, "LREAL", "BOOL"),
                             (_LOGICAL, "BOOL", "BOOL")):
        if op in table:
            sym = table[op]
            lv = _LEVELS[sym]
            return _Value(f"{_operand(a[0], want, lv)} {sym} {_operand(a[1], want, lv, True)}", lv, out)
    if op in _FUNCTIONS:
        return _Value(f"{_FUNCTIONS[op]}({', '.join(_operand(x, 'LREAL', 0) for x in a)})", _ATOM, "LREAL")
    if op == ca.OP_IF_ELSE_ZERO:
        return _Value(f"SEL({_operand(a[0], 'BOOL', 0)}, 0.0, {_operand(a[1], 'LREAL', 0)})", _ATOM, "LREAL")
    if op in _ONE_OPERAND:
        text, context, right, level, want, out = _ONE_OPERAND[op]
        return _Value(text.format(_operand(a[0], want, context, right)), level, out)
    if op == ca.OP_ASSIGN:
        return _Value(a[0].text, a[0].level, a[0].type)
    raise InputError(f"the controller's algorithm uses {_NAMES.get(op, op)}, which the Structured Text export does "
                     "not write")


@dataclass
class _Make:
    """An operation: its code, its operands, and the value it makes."""

    op: int
    operands: list[_Value]
    value: _Value


@dataclass
class _Write:
    """An element of an output written with a value."""

    output: int
    element: int
    value: _Value


def _algorithm(fn: ca.Function, inputs: Sequence[Callable[[int], str] | None]) -> list[_Make | _Write]:
    """The algorithm over values in single assignment (the work vector's slots are reused, the values are not),
    each value's uses counted; inputs and constants are values whose text is known already."""
    slots: dict[int, _Value] = {}
    steps: list[_Make | _Write] = []
    for k in range(fn.n_instructions()):
        op, a, r = fn.instruction_id(k), list(fn.instruction_input(k)), list(fn.instruction_output(k))
        if op == ca.OP_OUTPUT:
            slots[a[0]].uses += 1
            steps.append(_Write(r[0], r[1], slots[a[0]]))
            continue
        if op == ca.OP_INPUT:
            source = inputs[a[0]]
            if source is None:
                raise InputError(f"the algorithm of {fn.name()} reads its input {fn.name_in(a[0])}, which has no "
                                 "Structured Text variable")
            v = _Value(source(a[1]), _ATOM, "LREAL")
        elif op == ca.OP_CONST:
            text = real(fn.instruction_constant(k))
            v = _Value(text, _UNARY if text.startswith("-") else _ATOM, "LREAL")
        else:
            operands = [slots[x] for x in a]
            for x in operands:
                x.uses += 1
            v = _Value("", 0, "")
            steps.append(_Make(op, operands, v))
        slots[r[0]] = v
    return steps


def statements(fn: ca.Function, inputs: Sequence[Callable[[int], str] | None],
               outputs: Sequence[Callable[[int], str | None] | None], prefix: str = "t") -> Translation:
    """``fn``'s algorithm as ST assignments.

    ``inputs[i](k)`` is the ST expression (``LREAL``) of element ``k`` of input ``i``;
    ``outputs[j](k)`` the variable element ``k`` of output ``j`` is written to (None, for the output
    or for the element: not needed). A value used more than once, or longer than :data:`INLINE_MAX` characters,
    gets a variable ``<prefix><n>`` of its own; the others are written where they are used.
    Reading a value later than the instruction that made it computes the same number: the
    algorithm's inputs are variables that it does not write.
    """
    if not isinstance(fn, ca.Function) or not fn.is_a("SXFunction"):
        raise InputError("statements() translates a CasADi SX function")
    out = Translation()
    for step in _algorithm(fn, inputs):
        if isinstance(step, _Write):
            target = outputs[step.output]
            name = None if target is None else target(step.element)
            if name is not None:
                out.lines.append(f"{name} := {_operand(step.value, 'LREAL', 0)};")
            continue
        v = step.value
        made = _operation(step.op, step.operands)
        v.text, v.level, v.type = made.text, made.level, made.type
        if v.uses > 1 or len(v.text) > INLINE_MAX:
            name = f"{prefix}{len(out.variables) + 1}"
            out.variables[name] = v.type
            out.lines.append(f"{name} := {v.text};")
            v.text, v.level = name, _ATOM
    return out
