"""A validated gain set written to a PLC's own OPC UA server: the nodes a map names, checked, written, read back.

``piezopreload rig push GAINS --to opc.tcp://HOST:PORT --map NODES.toml`` (:func:`push`) writes the
numbers of the gain set's controller that its step reads
(:attr:`~piezopreload.rig.controller_code.ControllerCode.read`: the gains, or a scheduled set's
schedule arrays, the output range, the sample period and the feedforward's table, by the names
of the PLC export's ``PP_CONTROLLER``, which declares those and no others) to the nodes the map names, on any OPC UA
server, in the user's session (user name and password, a secure channel of the policy and mode
asked for). In order:

1. the gain set: its status (:func:`~piezopreload.rig.export.require_validated`), its controller;
2. the map (:class:`NodeMap`): a node for every number the controller reads (a feedforward's and
   a schedule's too), no name it does not know or does not read (a scheduled set's single ``Kc``,
   ``Ti_s``, ``Td_s`` and ``b``);
3. every node, read before anything is written: it exists, it is a variable of a type the number
   fits (``Float``, a PLC's ``REAL``, or ``Double``, ``LREAL``; ``String`` for ``gain_set_sha256``),
   of the shape the server states by its ``ValueRank`` and ``ArrayDimensions`` (a table: a node that
   may hold a one-dimensional array, ValueRank 1, or 0, -2, -3, of the table's length; a number: a
   node that may hold a scalar, ValueRank -1, -2 or -3), and this user may write it. Anything wrong
   is refused by its name, saying what the server states and what the number needs, and nothing is
   written;
4. one write request for every node, then every node read back: the report holds each number
   before, as written and as read back, and the difference (a ``REAL`` holds the number rounded
   to single precision; anything more is refused after the write, naming the nodes).

A node is named by its node id, ``ns=<index>;...`` or, steadier across a PLC's restarts,
``nsu=<namespace URI>;...`` (resolved through the server's namespace array).
"""

from __future__ import annotations

import asyncio
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from asyncua import Client, ua

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.requirements import Requirement
from piezopreload.core.errors import InputError
from piezopreload.rig.controller_code import Parameter, controller_code
from piezopreload.rig.export import controller_from_gain_set, require_validated
from piezopreload.rig.opcua import Credentials, PushRefused, connect, lost

__all__ = ["NodeMap", "NodeWritten", "PlcPush", "push", "push_to_server", "SHA_NODE", "NUMBER_TYPES"]

#: the one node a map may name besides the numbers: a String node the push writes the gain set's hash to
SHA_NODE = "gain_set_sha256"
#: the OPC UA data types (their ids in namespace 0) a number may be written to, as PLCs name them
NUMBER_TYPES = {ua.ObjectIds.Float: "Float (REAL)", ua.ObjectIds.Double: "Double (LREAL)"}
_VARIANTS = {ua.ObjectIds.Float: ua.VariantType.Float, ua.ObjectIds.Double: ua.VariantType.Double,
             ua.ObjectIds.String: ua.VariantType.String}
_ATTRIBUTES = (ua.AttributeIds.NodeClass, ua.AttributeIds.DataType, ua.AttributeIds.ValueRank,
               ua.AttributeIds.ArrayDimensions, ua.AttributeIds.UserAccessLevel, ua.AttributeIds.Value)


@dataclass(frozen=True)
class NodeMap:
    """Which node holds which number: ``nodes`` (name -> node id) and ``prefix`` (a name the table does not give is
    ``prefix + name``); ``path`` is the file's, for messages."""

    path: str
    nodes: dict[str, str]
    prefix: str | None = None

    @classmethod
    def load(cls, path: str | Path) -> NodeMap:
        """Read a map: ``prefix = "..."`` (optional) and a table ``[nodes]`` of ``name = "node id"``."""
        shown = str(path)
        try:
            doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except OSError as exc:
            raise InputError(f"{shown}: cannot read the node map ({exc.strerror or exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{shown}: not a TOML file: {exc}") from None
        unknown = sorted(set(doc) - {"prefix", "nodes"})
        if unknown:
            raise InputError(f"{shown}: key '{unknown[0]}' is not a node map's; expected 'prefix' and a table [nodes]")
        prefix, nodes = doc.get("prefix"), doc.get("nodes", {})
        if prefix is not None and not isinstance(prefix, str):
            raise InputError(f"{shown}: field 'prefix' must be a string (the node id every name is appended to)")
        if not isinstance(nodes, dict):
            raise InputError(f"{shown}: field 'nodes' must be a table of name = \"node id\"")
        bad = next((k for k, v in nodes.items() if not isinstance(v, str) or not v.strip()), None)
        if bad is not None:
            raise InputError(f"{shown}: field 'nodes.{bad}' must be a node id such as \"ns=4;s=PLC.Kc\"")
        return cls(shown, dict(nodes), prefix)

    def node_ids(self, names: list[str], unread: dict[str, str] | None = None) -> dict[str, str]:
        """The node id of every name of ``names`` (and of :data:`SHA_NODE` where the map names it); a name the map
        cannot place, or one it names that the gain set does not have, is refused. ``unread`` maps the names of the
        controller's parameters that its step does not read to the reason (a scheduled set's single gains): a map that
        names one is refused with that reason."""
        extra = sorted(set(self.nodes) - set(names) - {SHA_NODE})
        dead = [n for n in extra if n in (unread or {})]
        if dead:
            raise InputError(f"{self.path}: field 'nodes.{dead[0]}' names a number this gain set's controller does not "
                             f"read ({(unread or {})[dead[0]]}); remove it: the push writes {', '.join(names)}")
        if extra:
            raise InputError(f"{self.path}: field 'nodes.{extra[0]}' names no number of this gain set's controller; "
                             f"it has {', '.join(names)}")
        missing = [n for n in names if n not in self.nodes and self.prefix is None]
        if missing:
            raise InputError(f"{self.path}: no node for {', '.join(missing)} (this gain set's controller has them); "
                             "name each under [nodes], or give a prefix")
        out = {n: self.nodes.get(n) or f"{self.prefix}{n}" for n in names}
        if SHA_NODE in self.nodes:
            out[SHA_NODE] = self.nodes[SHA_NODE]
        return out


@dataclass
class _Target:
    """One node to write: the name, the node id as the map gives it, the value (numbers, or the hash)."""

    name: str
    node_id: str
    value: tuple[float, ...] | str
    array: bool
    node: Any = None
    type_id: int = 0
    before: Any = None


async def _resolve(client: Client, text: str) -> ua.NodeId:
    """A node id from its text; ``nsu=URI;...`` through the server's namespace array."""
    if text.startswith("nsu="):
        uri, sep, rest = text[4:].partition(";")
        if not sep:
            raise ValueError("nsu=<namespace URI>; must be followed by the identifier")
        try:
            index = await client.get_namespace_index(uri)
        except ValueError:
            raise ValueError(f"the server has no namespace '{uri}'") from None
        text = f"ns={index};{rest}"
    return ua.NodeId.from_string(text)


def _good(dv: ua.DataValue) -> bool:
    return dv.StatusCode is None or dv.StatusCode.is_good()


def _value(dv: ua.DataValue) -> Any:
    """A read attribute's value; None where the read failed."""
    return dv.Value.Value if _good(dv) and dv.Value is not None else None


#: what each ValueRank states (OPC UA Part 3, the VariableType's ValueRank attribute); n > 1: n dimensions
_RANKS = {-3: "a scalar or a one-dimensional array", -2: "any value, scalar or array", -1: "a scalar",
          0: "an array of one or more dimensions", 1: "a one-dimensional array"}


def _rank_words(rank: Any, dims: Any) -> str:
    """What the server states of a node's shape: its ValueRank in words, and its ArrayDimensions where it gives them."""
    if not isinstance(rank, int):
        return "no ValueRank this session can read"
    words = _RANKS.get(rank, f"an array of {rank} dimensions")
    given = [int(d) for d in dims or []]
    return f"ValueRank {rank} ({words}" + (f", ArrayDimensions {given}" if any(given) else "") + ")"


def _shape_problem(t: _Target, rank: Any, dims: Any, value: Any) -> str | None:
    """What differs between the shape the server states for ``t``'s node (its ValueRank and ArrayDimensions; the
    length of its value where it states none) and the number's, or None: a table needs a node that may hold a
    one-dimensional array (ValueRank 1, or 0, -2 or -3, which allow one) of its length, a scalar a node that may hold
    a scalar (ValueRank -1, -2 or -3)."""
    stated = f"has {_rank_words(rank, dims)} on the server"
    n = len(t.value)
    if not t.array:
        if rank in (-1, -2, -3, None):
            return None
        return f"{stated}; the gain set's {t.name} is a scalar (ValueRank -1)"
    need = f"the gain set's {t.name} needs a one-dimensional array (ValueRank 1) of {n}"
    if rank not in (1, 0, -2, -3):
        return f"{stated}; {need}"
    given = [int(d) for d in dims or []]
    if len(given) > 1 and rank != 1:
        return f"{stated}: {len(given)} dimensions; {need}"
    if given and given[0]:
        length, held = given[0], ""
    elif isinstance(value, list):
        length, held = len(value), f" and its value holds {len(value)}"
    else:
        return f"{stated}, and neither its ArrayDimensions nor its value give a length; {need}"
    return None if length == n else f"{stated}{held}; {need}"


def _type_id(dtype: Any) -> int | None:
    """The id of a data type of namespace 0 (the standard's), else None."""
    if isinstance(dtype, ua.NodeId) and dtype.NamespaceIndex == 0 and isinstance(dtype.Identifier, int):
        return int(dtype.Identifier)
    return None


def _problem(t: _Target, values: list[ua.DataValue], user: str) -> str | None:
    """What is wrong with writing ``t`` to the node whose attributes are ``values``, or None."""
    where = f"node '{t.node_id}' for {t.name}"
    if not _good(values[0]):
        status = values[0].StatusCode
        return f"{where} does not exist on the server ({'' if status is None else status.name})"
    if _value(values[0]) != ua.NodeClass.Variable:
        return f"{where} is not a variable"
    dtype = _value(values[1])
    type_id = _type_id(dtype)
    want = {ua.ObjectIds.String: "String"} if t.name == SHA_NODE else NUMBER_TYPES
    if type_id not in want:
        name = str(dtype) if type_id is None else ua.ObjectIdNames.get(type_id, str(dtype))
        return f"{where} is of type {name}; expected {' or '.join(want.values())}"
    shape = _shape_problem(t, _value(values[2]), _value(values[3]), _value(values[5]))
    if shape is not None:
        return f"{where} {shape}"
    if not int(_value(values[4]) or 0) & ua.AccessLevel.CurrentWrite.mask:
        return f"{where} is not writable for {user}"
    t.type_id = int(type_id)
    t.before = _value(values[5])
    return None


async def _check(client: Client, targets: list[_Target], user: str) -> None:
    """Every node read before anything is written; :class:`PushRefused` names everything wrong."""
    problems = []
    for t in targets:
        try:
            t.node = client.get_node(await _resolve(client, t.node_id))
        except (ValueError, ua.UaError) as exc:
            problems.append(f"node id '{t.node_id}' for {t.name} is not valid: {exc}")
            continue
        values = await t.node.read_attributes(list(_ATTRIBUTES))
        problem = _problem(t, values, user)
        if problem is not None:
            problems.append(problem)
    if problems:
        raise PushRefused("nothing was written: " + "; ".join(problems))


def _as_written(t: _Target) -> Any:
    """The value as the node holds it: single precision for a REAL."""
    if isinstance(t.value, str):
        return t.value
    x = np.asarray(t.value, np.float32 if t.type_id == ua.ObjectIds.Float else np.float64).astype(float)
    return x.tolist() if t.array else float(x[0])


@dataclass(frozen=True)
class NodeWritten:
    """One node of a push: its name and node id, its type, its value before, the value written and read back, the
    largest difference between them (absolute and relative; None for a string) and whether it reads as written."""

    name: str
    node: str
    type: str
    before: Any
    written: Any
    read_back: Any
    difference: float | None
    relative_difference: float | None
    as_written: bool

    def to_dict(self) -> dict[str, Any]:
        out = {"name": self.name, "node": self.node, "type": self.type, "before": self.before,
               "written": self.written, "read_back": self.read_back, "difference": self.difference}
        if self.relative_difference is not None:
            out["relative_difference"] = self.relative_difference
        return {**out, "as_written": self.as_written}


def _report(t: _Target, read: Any) -> NodeWritten:
    kind = NUMBER_TYPES.get(t.type_id, "String")
    if isinstance(t.value, str):
        return NodeWritten(t.name, t.node_id, kind, t.before, t.value, read, None, None, read == t.value)
    got, want = np.atleast_1d(np.asarray(read, float)), np.asarray(t.value, float)
    diff = float(np.max(np.abs(got - want))) if got.shape == want.shape else float("inf")
    return NodeWritten(t.name, t.node_id, kind, t.before, list(t.value) if t.array else t.value[0], read, diff,
                       float(diff / max(float(np.max(np.abs(want))), 1e-300)),
                       got.shape == want.shape and bool(np.array_equal(got, np.atleast_1d(_as_written(t)))))


@dataclass(frozen=True)
class PlcPush:
    """``rig push --to URL --map NODES.toml``'s report: the gain set (file, content hash), the server and the map,
    each node written, the largest relative difference read back, whether every number read back exactly, and the
    requirements a candidate missed that the pusher accepted."""

    gain_set: str
    gain_set_sha256: str | None
    to: str
    map: str
    nodes: tuple[NodeWritten, ...]
    max_relative_difference: float
    exact: bool
    accepted_missed: tuple[Requirement, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"gain_set": self.gain_set, "gain_set_sha256": self.gain_set_sha256, "to": self.to, "map": self.map,
                "nodes": [n.to_dict() for n in self.nodes], "max_relative_difference": self.max_relative_difference,
                "exact": self.exact, "accepted_missed": [r.to_dict() for r in self.accepted_missed]}


async def _write_and_read(client: Client, targets: list[_Target]) -> list[NodeWritten]:
    """One write request for every node, then each read back."""
    values = [ua.DataValue(ua.Variant(_as_written(t), _VARIANTS[t.type_id or ua.ObjectIds.String])) for t in targets]
    codes = await client.write_values([t.node for t in targets], values, raise_on_partial_error=False)
    failed = [f"{t.name} ({c.name})" for t, c in zip(targets, codes) if not c.is_good()]
    if failed:
        raise PushRefused(f"the server refused writing {', '.join(failed)}; the other nodes were written")
    read = await client.read_values([t.node for t in targets])
    return [_report(t, r) for t, r in zip(targets, read)]


def _targets(gain_set: GainSet, node_map: NodeMap, accepted: tuple[str, ...] = ()) -> list[_Target]:
    """The nodes to write: the numbers the exported ``PP_CONTROLLER`` declares (those its step reads), and the hash."""
    code = controller_code(controller_from_gain_set(gain_set, accepted))
    params: tuple[Parameter, ...] = code.read
    why = ("a scheduled set's step runs on the schedule's arrays" if code.model.scheduled else
           "its step does not use it")
    unread = {p.name: why for p in code.parameters if p not in params}
    ids = node_map.node_ids([p.name for p in params], unread)
    out = [_Target(p.name, ids[p.name], p.values, p.array) for p in params]
    if SHA_NODE in ids:
        out.append(_Target(SHA_NODE, ids[SHA_NODE], gain_set.content_sha256 or "", False))
    return out


async def push_to_server(gain_set: GainSet, endpoint: str, node_map: NodeMap, who: Credentials,
                         timeout_s: float = 10.0, accepted: tuple[str, ...] = ()) -> list[NodeWritten]:
    """Write ``gain_set``'s numbers to the nodes of ``node_map`` on ``endpoint`` (see the module docstring); the rows of
    the report, one per node. :class:`PushRefused` says why nothing (or not everything) was written."""
    targets = _targets(gain_set, node_map, accepted)
    client = await connect(endpoint, who, timeout_s)
    try:
        await _check(client, targets, who.username or "an anonymous session")
        return await _write_and_read(client, targets)
    except (ConnectionError, TimeoutError) as exc:
        raise PushRefused(lost(endpoint, exc)) from None
    finally:
        await client.disconnect()


def push(gains_path: str | Path, *, to: str, map_path: str | Path, who: Credentials,
         timeout_s: float = 10.0, accepted: tuple[str, ...] = ()) -> PlcPush:
    """``rig push GAINS --to URL --map NODES.toml``: the report of :func:`push_to_server`, with what it wrote where.

    Refusals (the gain set's status, the map, a node missing, of another type or not writable, the session) are bad
    input: :class:`InputError` with the reason, nothing written. A number read back otherwise than written (beyond
    a ``REAL``'s rounding) is refused after the write, naming the nodes. A gain set that is not validated is pushed
    only where each requirement it missed is ``accepted`` by name (the report lists them)."""
    gain_set = require_validated(GainSet.load(gains_path), "pushed", str(gains_path), accepted)
    node_map = NodeMap.load(map_path)
    try:
        rows = asyncio.run(push_to_server(gain_set, to, node_map, who, timeout_s, accepted))
    except PushRefused as exc:
        raise InputError(f"{to}: {exc}") from None
    off = [r.name for r in rows if not r.as_written]
    if off:
        raise InputError(f"{to}: written, but {', '.join(off)} read back otherwise than written (see the node's "
                         "scaling or limits on the PLC)")
    numbers = [r for r in rows if r.difference is not None]
    return PlcPush(str(gains_path), gain_set.content_sha256, to, node_map.path, tuple(rows),
                   max((r.relative_difference or 0.0 for r in numbers), default=0.0),
                   all(r.difference == 0.0 for r in numbers), () if gain_set.validated else gain_set.missed)
