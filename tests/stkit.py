"""A translator of the Structured Text subset the PLC export writes, into Python the tests execute.

Why a translation and why it is faithful. No IEC 61131-3 runtime installs from the package
registries this project uses, so the test parses the exported source with a grammar of the
subset (IEC 61131-3, 3rd edition: function blocks, ``VAR_INPUT``/``VAR_OUTPUT``/``VAR``/``VAR
CONSTANT`` declarations of ``LREAL``, ``BOOL``, ``DINT`` and ``ARRAY[a..b] OF LREAL`` with their
initial values, ``:=``, ``IF``/``ELSIF``/``ELSE``/``END_IF``, ``FOR ... TO ... DO``/``END_FOR``,
``MAX``, ``MIN``, ``ABS``, ``SEL``, comments; a program that declares instances of the source's
function blocks, calls them with named inputs and reads their outputs) and refuses anything outside
it. Each construct maps to the Python one with the same meaning:

* the operator precedence is the standard's (table 71: unary ``-`` and ``NOT``; ``*`` ``/``;
  ``+`` ``-``; ``< > <= >=``; ``= <>``; ``AND``; ``XOR``; ``OR``), applied by this parser, and the
  Python is fully parenthesised, so Python's own precedence never decides;
* ``LREAL`` is an IEC 60559 double, as Python's float; real literals are read by ``float``;
* types are checked as a strict compiler does: arithmetic and comparisons on operands of one
  type (``LREAL`` with ``LREAL``, ``DINT`` with ``DINT``), ``AND``/``OR``/``NOT`` and conditions
  on ``BOOL``, array indices ``DINT``, assignments to a variable of the expression's type, none
  to a ``CONSTANT`` or an input;
* arrays keep their declared bounds: an index outside them raises (a Python list would wrap a
  negative index silently);
* identifiers are case-insensitive, as in ST, and a name declared twice is refused;
* ``FOR i := a TO b`` runs ``i = a, a+1, ..., b`` (none when ``a > b``);
* ``SEL(g, in0, in1)`` is ``in1`` when ``g`` is TRUE, else ``in0`` (table 23 of the standard), ``g``
  BOOL and the two inputs of one type;
* a call ``inst(a := x, ...)`` sets the instance's inputs it names (the others keep theirs) and runs
  its body once; ``inst.out`` reads an output (or an input) of the instance;
* the instance's variables keep their values between calls (a function block's memory), and
  start at their initial values (0.0, FALSE, 0 where none is given).

:attr:`FunctionBlock.read` holds the names the body reads (in an expression, an index or a call's
argument; the target of an assignment is not a read), so a test can tell a declared variable the
body never reads.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

__all__ = ["STError", "FunctionBlock", "translate"]


class STError(Exception):
    """Source outside the subset, or a type error a compiler would report."""


_TOKEN = re.compile(r"""
    (?P<comment>\(\*.*?\*\))
  | (?P<real>\d+\.\d+(?:[eE][+-]?\d+)?)
  | (?P<int>\d+)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>:=|<=|>=|<>|\.\.|[-+*/<>=()\[\],;:.])
  | (?P<space>\s+)
""", re.VERBOSE | re.DOTALL)
_KEYWORDS = {"FUNCTION_BLOCK", "END_FUNCTION_BLOCK", "VAR_INPUT", "VAR_OUTPUT", "VAR", "CONSTANT", "END_VAR",
             "ARRAY", "OF", "LREAL", "BOOL", "DINT", "IF", "THEN", "ELSIF", "ELSE", "END_IF", "FOR", "TO", "DO",
             "END_FOR", "AND", "OR", "XOR", "NOT", "TRUE", "FALSE", "MAX", "MIN", "ABS", "SEL", "PROGRAM",
             "END_PROGRAM"}
_SCALARS = {"LREAL": 0.0, "BOOL": False, "DINT": 0}


def _tokens(text: str) -> list[tuple[str, str]]:
    out, pos = [], 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            raise STError(f"unexpected character {text[pos]!r} at offset {pos}")
        pos = m.end()
        kind = m.lastgroup or ""
        if kind in ("comment", "space"):
            continue
        value = m.group()
        if kind == "name" and value.upper() in _KEYWORDS:
            kind, value = "kw", value.upper()
        out.append((kind, value))
    return out + [("end", "")]


@dataclass
class _Var:
    type: str  # LREAL, BOOL, DINT, ARRAY, or a function block's name
    section: str  # VAR_INPUT, VAR_OUTPUT, VAR, CONSTANT
    bounds: tuple[int, int] | None = None
    init: Any = None


@dataclass
class _Pou:
    """A translated function block or program: its variables and the Python of its body."""

    name: str
    kind: str
    variables: dict[str, _Var]
    body: str
    read: frozenset[str] = frozenset()


class _Parser:
    def __init__(self, text: str) -> None:
        self.toks, self.i = _tokens(text), 0
        self.vars: dict[str, _Var] = {}
        self.lines: list[str] = []
        self.blocks: dict[str, _Pou] = {}
        self.read: set[str] = set()

    # ---- tokens ----------------------------------------------------------------------------------
    def peek(self) -> tuple[str, str]:
        return self.toks[self.i]

    def take(self, value: str | None = None, kind: str | None = None) -> str:
        k, v = self.toks[self.i]
        if (value is not None and v != value) or (kind is not None and k != kind):
            raise STError(f"expected {value or kind}, got {v!r} (token {self.i})")
        self.i += 1
        return v

    def accept(self, value: str) -> bool:
        if self.toks[self.i][1] == value:
            self.i += 1
            return True
        return False

    # ---- declarations ----------------------------------------------------------------------------
    def declarations(self) -> None:
        while self.peek()[1] in ("VAR_INPUT", "VAR_OUTPUT", "VAR"):
            section = self.take()
            if section == "VAR" and self.accept("CONSTANT"):
                section = "CONSTANT"
            while not self.accept("END_VAR"):
                self.declaration(section)

    def declaration(self, section: str) -> None:
        name = self.take(kind="name").lower()
        if name in self.vars:
            raise STError(f"'{name}' is declared twice (identifiers are case-insensitive)")
        self.take(":")
        if self.accept("ARRAY"):
            self.take("[")
            lo, _, hi = int(self.take(kind="int")), self.take(".."), int(self.take(kind="int"))
            self.take("]")
            self.take("OF")
            self.take("LREAL")
            var = _Var("ARRAY", section, (lo, hi), [0.0] * (hi - lo + 1))
        elif self.peek()[0] == "name" and self.peek()[1].upper() in self.blocks and section == "VAR":
            var = _Var(self.take().upper(), section)
        else:
            t = self.take(kind="kw")
            if t not in _SCALARS:
                raise STError(f"type {t} is outside the subset")
            var = _Var(t, section, None, _SCALARS[t])
        if self.accept(":="):
            var.init = self.initial(var)
        elif section == "CONSTANT":
            raise STError(f"constant '{name}' has no value")
        self.take(";")
        self.vars[name] = var

    def literal(self, type_: str) -> Any:
        sign = -1.0 if self.accept("-") else 1.0
        k, v = self.peek()
        if type_ == "LREAL" and k == "real":
            return sign * float(self.take())
        if type_ == "DINT" and k == "int":
            return int(sign) * int(self.take())
        if type_ == "BOOL" and v in ("TRUE", "FALSE"):
            return self.take() == "TRUE"
        raise STError(f"an initial value of type {type_} expected, got {v!r}")

    def initial(self, var: _Var) -> Any:
        if var.type != "ARRAY":
            return self.literal(var.type)
        self.take("[")
        values = [self.literal("LREAL")]
        while self.accept(","):
            values.append(self.literal("LREAL"))
        self.take("]")
        lo, hi = var.bounds or (0, -1)
        if len(values) != hi - lo + 1:
            raise STError(f"an ARRAY[{lo}..{hi}] initialised with {len(values)} values")
        return values

    # ---- expressions: (python code, type), by the standard's precedence ----------------------------
    _LEVELS = (("OR",), ("XOR",), ("AND",), ("=", "<>"), ("<", ">", "<=", ">="), ("+", "-"), ("*", "/"))
    _PY = {"OR": "or", "XOR": "!=", "AND": "and", "=": "==", "<>": "!="}

    def expr(self, level: int = 0) -> tuple[str, str]:
        if level == len(self._LEVELS):
            return self.unary()
        left, lt = self.expr(level + 1)
        while self.peek()[1] in self._LEVELS[level]:
            op = self.take()
            right, rt = self.expr(level + 1)
            left, lt = self.binary(op, left, lt, right, rt)
        return left, lt

    def binary(self, op: str, left: str, lt: str, right: str, rt: str) -> tuple[str, str]:
        if op in ("OR", "XOR", "AND"):
            if lt != "BOOL" or rt != "BOOL":
                raise STError(f"{op} needs BOOL operands, got {lt} and {rt}")
            return f"({left} {self._PY[op]} {right})", "BOOL"
        if lt != rt or lt == "BOOL" and op not in ("=", "<>"):
            raise STError(f"'{op}' on {lt} and {rt}: the operands must be numbers of one type")
        if op in ("=", "<>", "<", ">", "<=", ">="):
            return f"({left} {self._PY.get(op, op)} {right})", "BOOL"
        if op == "/" and lt == "DINT":
            return f"_idiv({left}, {right})", "DINT"
        return f"({left} {op} {right})", lt

    def unary(self) -> tuple[str, str]:
        if self.accept("-"):
            code, t = self.unary()
            if t == "BOOL":
                raise STError("unary minus on a BOOL")
            return f"(-{code})", t
        if self.accept("NOT"):
            code, t = self.unary()
            if t != "BOOL":
                raise STError(f"NOT on a {t}")
            return f"(not {code})", "BOOL"
        return self.primary()

    def primary(self) -> tuple[str, str]:
        k, v = self.peek()
        if v == "(":
            self.take()
            code, t = self.expr()
            self.take(")")
            return code, t
        if k in ("real", "int"):
            self.take()
            return (repr(float(v)), "LREAL") if k == "real" else (str(int(v)), "DINT")
        if v in ("TRUE", "FALSE"):
            self.take()
            return str(v == "TRUE"), "BOOL"
        if v in ("MAX", "MIN", "ABS"):
            return self.call(self.take())
        if v == "SEL":
            return self.select()
        return self.reference()

    def call(self, fn: str) -> tuple[str, str]:
        self.take("(")
        args = [self.expr()]
        while self.accept(","):
            args.append(self.expr())
        self.take(")")
        types = {t for _, t in args}
        if len(args) != (1 if fn == "ABS" else 2) or len(types) != 1 or types == {"BOOL"}:
            raise STError(f"{fn} takes {'one' if fn == 'ABS' else 'two'} numbers of one type, "
                          f"got {[t for _, t in args]}")
        return f"{fn.lower()}({', '.join(c for c, _ in args)})", types.pop()

    def select(self) -> tuple[str, str]:
        self.take("SEL")
        self.take("(")
        g, gt = self.expr()
        self.take(",")
        in0, t0 = self.expr()
        self.take(",")
        in1, t1 = self.expr()
        self.take(")")
        if gt != "BOOL" or t0 != t1:
            raise STError(f"SEL takes a BOOL and two inputs of one type, got {gt}, {t0} and {t1}")
        return f"({in1} if {g} else {in0})", t0

    def reference(self, read: bool = True) -> tuple[str, str]:
        name = self.take(kind="name").lower()
        var = self.vars.get(name)
        if var is None:
            raise STError(f"'{name}' is not declared")
        if read:
            self.read.add(name)
        if var.type in self.blocks:
            self.take(".")
            field = self.take(kind="name").lower()
            inner = self.blocks[var.type].variables.get(field)
            if inner is None or inner.section not in ("VAR_INPUT", "VAR_OUTPUT") or inner.type == "ARRAY":
                raise STError(f"{var.type} has no input or output '{field}'")
            return f"m[{name!r}].memory[{field!r}]", inner.type
        if var.type != "ARRAY":
            return f"m[{name!r}]", var.type
        self.take("[")
        index, t = self.expr()
        self.take("]")
        if t != "DINT":
            raise STError(f"index of '{name}' must be DINT, got {t}")
        lo, hi = var.bounds or (0, -1)
        return f"m[{name!r}][_ix({index}, {lo}, {hi}, {name!r})]", "LREAL"

    # ---- statements ------------------------------------------------------------------------------
    def statements(self, depth: int, until: tuple[str, ...]) -> None:
        start = len(self.lines)
        while self.peek()[1] not in until:
            self.statement(depth)
        if len(self.lines) == start:
            self.lines.append("    " * depth + "pass")

    def statement(self, depth: int) -> None:
        pad = "    " * depth
        v = self.peek()[1]
        if v == "IF":
            self.take()
            self.branch(depth, "if")
            while self.accept("ELSIF"):
                self.branch(depth, "elif")
            if self.accept("ELSE"):
                self.lines.append(pad + "else:")
                self.statements(depth + 1, ("END_IF",))
            self.take("END_IF")
        elif v == "FOR":
            self.take()
            name = self.take(kind="name").lower()
            if self.vars.get(name, _Var("", "")).type != "DINT" or self.vars[name].section != "VAR":
                raise STError(f"the FOR variable '{name}' must be a DINT of VAR")
            self.take(":=")
            lo, lt = self.expr()
            self.take("TO")
            hi, ht = self.expr()
            if lt != "DINT" or ht != "DINT":
                raise STError("FOR bounds must be DINT")
            self.take("DO")
            self.lines.append(pad + f"for m[{name!r}] in range({lo}, ({hi}) + 1):")
            self.statements(depth + 1, ("END_FOR",))
            self.take("END_FOR")
        elif self.vars.get(self.peek()[1].lower(), _Var("", "")).type in self.blocks:
            self.instance_call(pad)
        else:
            self.assignment(pad)
        self.take(";")

    def instance_call(self, pad: str) -> None:
        name = self.take(kind="name").lower()
        block = self.blocks[self.vars[name].type]
        self.take("(")
        args = []
        while not self.accept(")"):
            if args:
                self.take(",")
            field = self.take(kind="name").lower()
            inner = block.variables.get(field)
            if inner is None or inner.section != "VAR_INPUT":
                raise STError(f"{block.name} has no input '{field}'")
            self.take(":=")
            code, t = self.expr()
            if t != inner.type:
                raise STError(f"{block.name}.{field} is {inner.type}, given a {t}")
            args.append(f"{field!r}: {code}")
        self.lines.append(pad + f"m[{name!r}].call({{{', '.join(args)}}})")

    def branch(self, depth: int, word: str) -> None:
        cond, t = self.expr()
        if t != "BOOL":
            raise STError(f"an IF condition must be BOOL, got {t}")
        self.take("THEN")
        self.lines.append("    " * depth + f"{word} {cond}:")
        self.statements(depth + 1, ("ELSIF", "ELSE", "END_IF"))

    def assignment(self, pad: str) -> None:
        name = self.peek()[1].lower()
        var = self.vars.get(name)
        if var is not None and var.section in ("CONSTANT", "VAR_INPUT"):
            raise STError(f"assignment to {var.section} '{name}'")
        target, t = self.reference(read=False)
        self.take(":=")
        code, et = self.expr()
        if et != t:
            raise STError(f"assigning a {et} to '{name}' ({t})")
        self.lines.append(pad + f"{target} = {code}")

    def pou(self) -> _Pou:
        kind = self.take()
        if kind not in ("FUNCTION_BLOCK", "PROGRAM"):
            raise STError(f"expected FUNCTION_BLOCK or PROGRAM, got {kind!r}")
        name = self.take(kind="name").upper()
        self.vars, self.lines, self.read = {}, [], set()
        self.declarations()
        self.statements(1, (f"END_{kind}",))
        self.take(f"END_{kind}")
        pou = _Pou(name, kind, self.vars, "def _step(m):\n" + "\n".join(self.lines) + "\n", frozenset(self.read))
        if name in self.blocks:
            raise STError(f"'{name}' is declared twice")
        self.blocks[name] = pou
        return pou

    def source(self) -> list[_Pou]:
        pous = [self.pou()]
        while self.peek()[0] != "end":
            pous.append(self.pou())
        return pous


def _ix(i: int, lo: int, hi: int, name: str) -> int:
    if not lo <= i <= hi:
        raise IndexError(f"{name}[{i}] is outside [{lo}..{hi}]")
    return i - lo


def _idiv(a: int, b: int) -> int:
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q  # ST integer division truncates towards zero


class FunctionBlock:
    """An instance of a translated function block or program: call it with its inputs by name (a program has
    none: set its variables in :attr:`memory`), read its outputs."""

    def __init__(self, pou: _Pou, pous: dict[str, _Pou]) -> None:
        self.name, self.variables, self.read = pou.name, pou.variables, pou.read
        self.memory: dict[str, Any] = {}
        for n, v in pou.variables.items():
            if v.type in pous:
                self.memory[n] = FunctionBlock(pous[v.type], pous)
            else:
                self.memory[n] = list(v.init) if v.type == "ARRAY" else v.init
        scope = {"_ix": _ix, "_idiv": _idiv, "max": max, "min": min, "abs": abs}
        exec(compile(pou.body, f"<{pou.name}>", "exec"), scope)
        self._run = scope["_step"]

    def call(self, inputs: dict[str, Any]) -> None:
        """A call from a translated program: the inputs it names set (types checked when translated), one run."""
        self.memory.update(inputs)
        self._run(self.memory)

    def __call__(self, **inputs: Any) -> dict[str, Any]:
        for key, value in inputs.items():
            var = self.variables.get(key.lower())
            if var is None or var.section != "VAR_INPUT":
                raise STError(f"{self.name} has no input '{key}'")
            self.memory[key.lower()] = float(value) if var.type == "LREAL" else bool(value)
        self._run(self.memory)
        return {n: self.memory[n] for n, v in self.variables.items() if v.section == "VAR_OUTPUT"}


def translate(source: str, name: str | None = None) -> FunctionBlock:
    """An instance of the function block or program ``name`` in ``source`` (default: the first), as a callable.

    Anything before the first declaration must be comments; a program may use the function blocks declared
    before it."""
    pous = _Parser(source).source()
    table = {p.name: p for p in pous}
    pou = pous[0] if name is None else table.get(name.upper())
    if pou is None:
        raise STError(f"'{name}' is not in the source")
    return FunctionBlock(pou, table)
