"""The rig executor as an OPC UA server, and the client that pushes gain sets to it (asyncua).

Address space (namespace ``urn:piezopreload:rig``), under ``Objects/PreloadRig``:

* ``ControllerParameters``: ``CtrlP`` (V/N), ``CtrlTi`` (s) and ``CtrlTd`` (s), named as the
  OPC UA LADS companion specification's ``PidControllerParameterType`` names them, and
  ``CtrlTf`` (s, the derivative filter) and ``CtrlB`` (the setpoint weight);
* ``GainSetSha256`` and ``FeedforwardSha256``: which gain set runs, and which hysteresis model
  its feedforward inverts (the hash of the model's JSON);
* ``SetPoint`` (N), ``MeasuredForce`` (N), ``CommandVoltage`` (V), ``State`` and ``LastEvent``;
* the method ``PushGainSetWithNote(GainSetDocument: String, Note: String, AcceptedMisses: String) ->
  (Accepted: Boolean, Message: String)`` (:data:`PUSH_METHOD`, :data:`PUSH_INPUTS`, :data:`PUSH_OUTPUTS`), and
  beside it ``PushGainSet(GainSetDocument: String) -> (Accepted, Message)``, the method's first form
  (:data:`PUSH_METHOD_V1`), kept so that a client written against it goes on working: a method's
  arguments are its contract with the clients that call it, so the form with more arguments got a
  name of its own. ``PushGainSet`` also takes the Note and AcceptedMisses after the document, as
  it did between the two forms, for the clients written then.

Every variable is read-only to clients; the one way to change the controller is the method,
which checks the document again (its hash, its status, the rig's plant, the limits it would be
armed with against those it was armed with, a controller of another structure compiled:
:func:`piezopreload.rig.session.check_pushed`), hands it to the executor to switch bumplessly
between two cycles, and records who pushed what, why and when. ``docs/targets/rig-opcua.md``
lists the address space and the security.

Security: sessions authenticate with a user name and password (``users``); anonymous
sessions are refused.
With ``certificate`` and ``private_key`` the server offers only the Basic256Sha256
SignAndEncrypt policy; without, it offers no encryption, which is for loopback use only (the
default endpoint binds 127.0.0.1).

The pushing user's name comes from the permission check that asyncua runs on each request,
right before it dispatches the call (no other request can run between the two).

The server runs in a process of its own (:class:`RigServer`), out of the loop's way: the
sessions, the password hashing (PBKDF2), the secure channel's cryptography and the pushed
document's JSON, hash and status checks all run there, at a lower priority (``nice``
+:data:`SERVER_NICE`), and cost the loop's process nothing. The two talk over a pipe:

* the server process sends a gain set it has checked (the :class:`Controller` built from it
  and its identity), or tells the supervisor of a refusal it has already answered;
* the supervisor switches (the loop's buffer flip, :meth:`Executor.request_switch`), answers
  the server process (accepted, or refused with the reason) and publishes the nodes' values
  (what changed, every ``update_s``, and every millisecond after a push until the loop runs
  it, so the new hash shows within a few ms of the switch).

The process is a fresh interpreter (``sys.executable``, the pipe's other end passed as a file
descriptor), started before the loop starts: it inherits no thread, lock or locked memory of
the supervisor. A ``fork`` would copy a process that may hold other threads' locks (an
asyncio or logging lock held at that instant stays held in the child for good), and forking
while the loop runs would make the supervisor's pages copy-on-write, so the loop's next writes
to its ring and state would fault in the real-time thread. ``multiprocessing``'s ``spawn``
gives the same fresh interpreter but imports the caller's main script again in it, which would
run a study script without a ``__main__`` guard a second time; the server's own entry point
imports this module alone. The server process ends when the supervisor asks, when
its pipe closes, or within :data:`PARENT_CHECK_S` of the supervisor's death (its parent
changes), so a killed supervisor leaves no server behind.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import hmac
import json
import logging
import multiprocessing
import multiprocessing.connection
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Protocol

from asyncua import Client, Server, ua
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole
from asyncua.crypto.security_policies import (
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyAes256Sha256RsaPss,
    SecurityPolicyBasic256Sha256,
)
from asyncua.server.user_managers import UserManager

from piezopreload.core.errors import PiezopreloadError
from piezopreload.core.records import Record, entry, record
from piezopreload.models.controller import Controller
from piezopreload.rig import DEFAULT_ENDPOINT
from piezopreload.rig import SECURITY_MODES as MODE_NAMES
from piezopreload.rig import SECURITY_POLICIES as POLICY_NAMES
from piezopreload.rig.executor import Executor, RunResult

__all__ = ["RigServer", "push_gain_set", "PushReply", "PushRefused", "NAMESPACE", "DEFAULT_ENDPOINT", "ROOT",
           "PUSH_METHOD", "PUSH_METHOD_V1", "PUSH_INPUTS", "PUSH_INPUTS_V1", "PUSH_OUTPUTS", "Credentials", "connect",
           "SECURITY_POLICIES", "SECURITY_MODES", "PushTaken"]

NAMESPACE = "urn:piezopreload:rig"
ROOT = "PreloadRig"

#: check_gain_set(document text) -> (controller, {"gain_set_sha256": ..., "feedforward_sha256": ...});
#: raises ValueError with the reason when the document cannot run
class GainSetCheck(Protocol):
    """The served rig's check of a pushed document (``session.check_pushed`` with the rig bound): the controller it
    switches to and what the push records; ``accepted``: the keys of the requirements a candidate missed that the
    pusher accepts."""

    def __call__(self, text: str, *, accepted: tuple[str, ...] = ()) -> tuple[Controller, dict[str, Any]]: ...


class PushRefused(PiezopreloadError, RuntimeError):
    """The server refused the push (or the session); the message says why."""


def _hash_password(password: str, salt: bytes) -> bytes:
    return hashlib.pbkdf2_hmac("sha256", password.encode(), salt, 200_000)


class _Users(UserManager):
    """User names with salted password hashes."""

    def __init__(self, passwords: dict[str, str]) -> None:
        self._salt = os.urandom(16)
        self._hashes = {name: _hash_password(pw, self._salt) for name, pw in passwords.items()}

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if username is not None:
            known = self._hashes.get(username)
            if (known is not None and password is not None
                    and hmac.compare_digest(known, _hash_password(password, self._salt))):
                return User(role=UserRole.User, name=username)
        return None


class _Ruleset(SimpleRoleRuleset):
    """asyncua's role rules, remembering who makes each method call (see the module docstring)."""

    caller: str | None = None

    def check_validity(self, user: User, action_type_id: Any, body: Any) -> bool:
        ok = super().check_validity(user, action_type_id, body)
        if ok and action_type_id == ua.NodeId(ua.Int32(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)):
            self.caller = user.name
        return ok


def feedforward_hash(model: dict[str, Any] | None) -> str:
    if model is None:
        return ""
    return hashlib.sha256(json.dumps(model, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@dataclass
class _Nodes:
    p: Any
    ti: Any
    td: Any
    tf: Any
    b: Any
    gain_sha: Any
    ff_sha: Any
    setpoint: Any
    force: Any
    voltage: Any
    state: Any
    last_event: Any


#: the variable nodes by the keys the supervisor publishes them under
_NODE_KEYS = {"CtrlP": "p", "CtrlTi": "ti", "CtrlTd": "td", "CtrlTf": "tf", "CtrlB": "b", "GainSetSha256": "gain_sha",
              "FeedforwardSha256": "ff_sha", "SetPoint": "setpoint", "MeasuredForce": "force",
              "CommandVoltage": "voltage", "State": "state", "LastEvent": "last_event"}

#: how long the server process waits for the supervisor's answer to a push before refusing it
ANSWER_TIMEOUT_S = 10.0
#: how long a client waits for a push's answer: the served rig's check derives the limits on a simulation and may
#: compile a controller of another structure first (well under a second on a quiet machine, seconds on a loaded one)
PUSH_TIMEOUT_S = 60.0
#: how often the server process checks that its supervisor is alive
PARENT_CHECK_S = 0.2
#: the server process's niceness increment: it yields the CPU to the loop's process
SERVER_NICE = 10


@dataclass(frozen=True)
class _Config:
    """What the server process is started with (pickled to it)."""

    check: GainSetCheck
    passwords: dict[str, str]
    endpoint: str
    certificate: str | None
    private_key: str | None
    values: dict[str, Any]  # every node's first value
    parent_pid: int
    nice: int
    log_level: int  # the supervisor's level for asyncua's logger (the CLI quiets it)


@record
class PushTaken(Record):
    """A push a served rig took or refused, as its run records it (``rig serve --json``'s ``pushes``): who pushed,
    the gain set's identity where the push got as far as its check, whether it was accepted and why not, and how long
    the supervisor took to show an accepted one running."""

    CLOSED: ClassVar[bool] = True  # an identity key it does not declare is refused, not dropped
    user: str = entry("Who pushed.")
    gain_set_sha256: str | None = entry("The pushed gain set's content hash.", default=None, omit=True)
    feedforward_sha256: str | None = entry("Its feedforward's hash.", default=None, omit=True)
    controller: str | None = entry("Its controller, in words.", default=None, omit=True)
    interlocks_kept: tuple[str, ...] | None = entry("The running rig's limits it keeps that are stricter than its "
                                                    "own.", default=None, omit=True)
    accepted_missed: tuple[dict[str, Any], ...] | None = entry("The requirements it missed and the pusher accepted by "
                                                               "name.", default=None, omit=True)
    note: str | None = entry("The pusher's note.", default=None, omit=True)
    accepted: bool = entry("Whether the rig took it.", default=False)
    reason: str | None = entry("Why it was refused.", default=None, omit=True)
    switch_shown_ms: float | None = entry("From the push to the supervisor showing it running.", unit="ms",
                                          default=None, omit=True)

    @classmethod
    def of(cls, user: str, identity: dict[str, Any], *, accepted: bool, reason: str | None = None) -> PushTaken:
        """The record of a push from its identity (as the check gives it).

        Parameters
        ----------
        user : str
            Who pushed.
        identity : dict
            The gain set's identity as the check gives it (its hashes, its controller, the limits kept, the
            requirements accepted, the note).
        accepted : bool
            Whether the rig took it.
        reason : str, optional
            Why it was refused.

        Returns
        -------
        PushTaken
            The record (a key of the identity it does not declare refused).
        """
        return cls.from_dict({"user": user, **identity, "accepted": accepted,
                              **({} if reason is None else {"reason": reason})}, "the push's record")


class RigServer:
    """Serve ``executor`` over OPC UA from a process of its own while it runs; see the module docstring.

    ``check_gain_set`` runs in the server's process (a module-level function: it is pickled to
    it). :attr:`pushes` records every push, accepted or refused, in the supervisor.
    """

    def __init__(self, executor: Executor, check_gain_set: GainSetCheck, *, identity: dict[str, Any],
                 endpoint: str = DEFAULT_ENDPOINT, users: dict[str, str] | None = None,
                 certificate: str | Path | None = None, private_key: str | Path | None = None,
                 update_s: float = 0.05) -> None:
        if not users:
            raise ValueError("the server needs at least one user (name and password); anonymous sessions are refused")
        if (certificate is None) != (private_key is None):
            raise ValueError("give both the server certificate and its private key, or neither")
        self.executor = executor
        self.check = check_gain_set
        self.identity = dict(identity)
        self.endpoint = endpoint
        self.certificate, self.private_key = certificate, private_key
        self._passwords = dict(users)
        self.update_s = float(update_s)
        self.pushes: list[PushTaken] = []
        self.server_pid: int | None = None
        self._shown: dict[str, Any] = {}  # node key -> the value last published
        self._events_shown = 0
        self._conn: Any = None
        self._wake: asyncio.Event | None = None
        self._ready: asyncio.Future[int] | None = None
        self._showing: tuple[int, float] | None = None  # an accepted push (its index) until its hash is shown

    # ---- the supervisor's side -------------------------------------------------------------------
    def _values(self) -> dict[str, Any]:
        """Every node's value now (the executor's latest cycle, the running gains and identity)."""
        pending = self.executor.switch_pending  # first: a loop that took a switch has set its controller already
        t, sp, y, v, state = self.executor.latest
        g = self.executor.controller.gains
        values: dict[str, Any] = {"CtrlP": float(g.Kc), "CtrlTi": float(g.Ti_s), "CtrlTd": float(g.Td_s),
                                  "CtrlTf": float(g.Tf_s), "CtrlB": float(g.b), "SetPoint": float(sp),
                                  "MeasuredForce": float(y), "CommandVoltage": float(v), "State": state}
        events = self.executor.events
        if events and len(events) != self._events_shown:
            self._events_shown = len(events)
            values["LastEvent"] = json.dumps(events[-1], default=str)
        if not pending:  # the pushed hash is shown once the loop runs it
            values["GainSetSha256"] = self.identity.get("gain_set_sha256", "")
            values["FeedforwardSha256"] = self.identity.get("feedforward_sha256", "")
        return values

    def _publish(self) -> None:
        """Send the server process the values that changed since the last time (a few hundred bytes)."""
        changed = {k: v for k, v in self._values().items() if self._shown.get(k) != v}
        if changed and self._conn is not None:
            self._shown.update(changed)
            with contextlib.suppress(OSError, ValueError):  # the server process is gone: the rig runs on without it
                self._conn.send(("state", changed))

    def _on_message(self) -> None:
        """The server process's messages (the event loop calls this when the pipe is readable)."""
        conn = self._conn
        try:
            while conn.poll():
                self._handle(conn.recv())
        except (EOFError, OSError):  # the server process ended: stop listening, the loop goes on
            asyncio.get_running_loop().remove_reader(conn.fileno())
            self._conn = None
            if self._ready is not None and not self._ready.done():
                self._ready.set_exception(OSError("the OPC UA server process ended before it served"))
            else:
                self.executor.record("server_exited", detail="the OPC UA server process ended; the run goes on")

    def _handle(self, msg: tuple) -> None:
        kind = msg[0]
        if kind == "ready":
            if self._ready is not None and not self._ready.done():
                self._ready.set_result(int(msg[1]))
        elif kind == "failed":
            if self._ready is not None and not self._ready.done():
                self._ready.set_exception(OSError(msg[1]))
        elif kind == "refused":  # the server process refused it (document, hash, status) and answered the client
            _, user, reason = msg
            self.pushes.append(PushTaken(user, accepted=False, reason=reason))
            self.executor.record("push_refused", user=user, reason=reason)
        elif kind == "push":  # a checked gain set: switch (a buffer flip), answer, show it once it runs
            _, request, user, controller, identity = msg
            t0 = time.monotonic()
            accepted, message = self.push(controller, identity, user)
            if accepted:
                self._showing = (len(self.pushes) - 1, t0)
            self._conn.send(("answer", request, accepted, message))
            if self._wake is not None:
                self._wake.set()

    def push(self, controller: Controller, identity: dict[str, Any], user: str) -> tuple[bool, str]:
        """Hand a checked gain set to the executor; ``(accepted, message)``. Changes nothing if refused."""
        try:
            self.executor.request_switch(controller, {"pushed_by": user, **identity})
        except ValueError as exc:
            self.pushes.append(PushTaken.of(user, identity, accepted=False, reason=str(exc)))
            self.executor.record("push_refused", user=user, reason=str(exc))
            return False, f"refused: {exc}"
        self.identity = {**self.identity, **identity}
        self.pushes.append(PushTaken.of(user, identity, accepted=True))
        return True, f"accepted gain set {identity.get('gain_set_sha256', '')[:12]}; it runs from the next cycle"

    def _config(self) -> _Config:
        self._shown = self._values()
        return _Config(self.check, self._passwords, self.endpoint,
                       None if self.certificate is None else str(self.certificate),
                       None if self.private_key is None else str(self.private_key), dict(self._shown), os.getpid(),
                       SERVER_NICE, logging.getLogger("asyncua").getEffectiveLevel())

    async def run(self, ready: threading.Event | None = None, stop: threading.Event | None = None) -> RunResult:
        """Serve until the executor ends (its reference, a trip, :meth:`Executor.stop`); returns its result.

        The server process is started and serving before the loop starts (no process is
        created while the loop runs) and is stopped after the loop has ended.
        """
        loop = asyncio.get_running_loop()
        conn, child_conn = multiprocessing.Pipe(duplex=True)
        fd = child_conn.fileno()
        proc = subprocess.Popen([sys.executable, "-c", _ENTRY, str(fd)], pass_fds=(fd,), stdin=subprocess.DEVNULL,
                                close_fds=True)
        child_conn.close()
        self._conn, self._ready, self._wake = conn, loop.create_future(), asyncio.Event()
        result: list[RunResult] = []
        try:
            conn.send(self._config())
            loop.add_reader(conn.fileno(), self._on_message)
            self.server_pid = await asyncio.wait_for(self._ready, 120.0)
            self.executor.record("server_started", endpoint=self.endpoint, pid=self.server_pid)
            thread = threading.Thread(target=lambda: result.append(self.executor.run()), name="rig-loop", daemon=True)
            thread.start()
            if ready is not None:
                ready.set()
            while thread.is_alive():
                if stop is not None and stop.is_set():
                    self.executor.stop("stopped by the server", trip=False)
                self._publish()
                self.executor.save_events()
                if self._showing is not None and not self.executor.switch_pending:
                    at, t0 = self._showing  # the supervisor's share of push-to-switch: taken and shown
                    self.pushes[at] = replace(self.pushes[at],
                                              switch_shown_ms=round((time.monotonic() - t0) * 1e3, 3))
                    self._showing = None
                if self.executor.switch_pending:  # a push: shown once the loop takes it (at its next cycle)
                    await asyncio.sleep(0.001)
                    continue
                with contextlib.suppress(TimeoutError):  # the next update after update_s, or at once after a push
                    await asyncio.wait_for(self._wake.wait(), self.update_s)
                self._wake.clear()
            thread.join()
            self._publish()
        finally:
            if self._conn is not None:
                loop.remove_reader(conn.fileno())
                with contextlib.suppress(OSError, ValueError):
                    conn.send(("stop",))
            self._conn = None
            try:
                await loop.run_in_executor(None, proc.wait, 10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            conn.close()
        return result[0]


# ---- the server's process ------------------------------------------------------------------------
#: the server process's program: a fresh interpreter given the supervisor's end of a pipe
_ENTRY = "import sys; from piezopreload.rig.opcua import _serve_process; _serve_process(int(sys.argv[1]))"


def _serve_process(fd: int) -> None:
    """The OPC UA server's process: sessions, password hashing, the pushed documents' checks."""
    conn = multiprocessing.connection.Connection(fd)
    try:
        cfg = conn.recv()
    except EOFError:  # the supervisor is gone already
        return
    with contextlib.suppress(OSError):
        os.nice(cfg.nice)
    logging.getLogger("asyncua").setLevel(cfg.log_level)
    try:
        asyncio.run(_ServerProcess(conn, cfg).run())
    except Exception as exc:  # a server that cannot start (address in use, a bad certificate): say why
        with contextlib.suppress(OSError, ValueError):
            conn.send(("failed", f"the OPC UA server could not start: {type(exc).__name__}: {exc}"))


#: the push method's name, and the name of its first form (one argument, the document), kept beside it
PUSH_METHOD, PUSH_METHOD_V1 = "PushGainSetWithNote", "PushGainSet"
#: PushGainSetWithNote's input arguments: name, type, what
PUSH_INPUTS = (
    ("GainSetDocument", ua.VariantType.String,
     "the gain set file's text, its JSON document as 'piezopreload tune' wrote it (not a path to it)"),
    ("Note", ua.VariantType.String, "why it is pushed, recorded with the push in the run log (may be empty)"),
    ("AcceptedMisses", ua.VariantType.String,
     "a gain set that is not validated: the keys of the requirements it missed that the pusher accepts, separated by "
     "commas (empty for a validated one); recorded with the push"),
)
#: PushGainSet's input argument (its first form's): the document alone
PUSH_INPUTS_V1 = PUSH_INPUTS[:1]
#: the output arguments of both forms
PUSH_OUTPUTS = (
    ("Accepted", ua.VariantType.Boolean, "TRUE: the rig switches to it at its next cycle"),
    ("Message", ua.VariantType.String, "what the rig did, or why it refused, in a sentence"),
)


def _argument(name: str, vtype: ua.VariantType, what: str) -> ua.Argument:
    arg = ua.Argument()
    arg.Name, arg.DataType, arg.ValueRank = name, ua.NodeId(ua.Int32(vtype.value)), -1
    arg.Description = ua.LocalizedText(what)
    return arg


def _push_arguments(args: tuple, method: str = PUSH_METHOD) -> tuple[str, str, tuple[str, ...]]:
    """A push's arguments, checked: ``(document, note, accepted)``; a ValueError says what was expected.

    ``PushGainSetWithNote`` takes its three; ``PushGainSet``, the first form, the document alone, or with the Note
    (and the AcceptedMisses) after it, as the clients written between the two forms send them."""
    names = " and ".join(f"{name} ({what})" for name, _, what in PUSH_INPUTS)
    counts = (len(PUSH_INPUTS),) if method == PUSH_METHOD else (1, 2, len(PUSH_INPUTS))
    if len(args) not in counts or not all(isinstance(a.Value, str) for a in args):
        got = f"got {len(args)} of {', '.join(type(a.Value).__name__ for a in args) or 'none'}"
        if method == PUSH_METHOD:
            raise ValueError(f"{PUSH_METHOD} takes {len(PUSH_INPUTS)} String arguments: {names}; {got}")
        raise ValueError(f"{PUSH_METHOD_V1} takes one String argument, GainSetDocument ({PUSH_INPUTS[0][2]}), "
                         f"optionally followed by Note and AcceptedMisses as {PUSH_METHOD} takes them; {got}")
    document, note, accepted = (*(a.Value for a in args), "", "")[:3]  # Note, AcceptedMisses left out: none
    if not document.lstrip().startswith("{"):
        shown = document if len(document) <= 60 else document[:57] + "..."
        raise ValueError(f"GainSetDocument must be the gain set file's text (its JSON document), not a path or a "
                         f"name: got '{shown}'; read the file and send what it holds")
    return document, note, tuple(k.strip() for k in accepted.split(",") if k.strip())


class _ServerProcess:
    def __init__(self, conn: Any, cfg: _Config) -> None:
        self.conn, self.cfg = conn, cfg
        self._users = _Users(cfg.passwords)
        self._ruleset = _Ruleset()
        self._answers: dict[int, asyncio.Future[tuple[bool, str]]] = {}
        self._requests = 0
        self._incoming: asyncio.Queue[tuple] = asyncio.Queue()

    async def _build(self) -> tuple[Server, _Nodes]:
        cfg = self.cfg
        server = Server(user_manager=self._users)
        await server.init()
        server.set_endpoint(cfg.endpoint)
        server.set_server_name("piezopreload rig executor")
        if cfg.certificate is not None:
            await server.load_certificate(cfg.certificate)
            await server.load_private_key(str(cfg.private_key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                       permission_ruleset=self._ruleset)
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=self._ruleset)
        server.set_identity_tokens([ua.UserNameIdentityToken])
        idx = await server.register_namespace(NAMESPACE)
        root = await server.nodes.objects.add_object(idx, ROOT)
        params = await root.add_object(idx, "ControllerParameters")
        v = cfg.values

        async def var(parent: Any, name: str, desc: str) -> Any:
            node = await parent.add_variable(idx, name, v.get(name, ""))
            await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(desc))))
            return node

        nodes = _Nodes(
            p=await var(params, "CtrlP", "proportional gain Kc, V/N (LADS PidControllerParameterType)"),
            ti=await var(params, "CtrlTi", "integral time Ti, s (LADS PidControllerParameterType)"),
            td=await var(params, "CtrlTd", "derivative time Td, s (LADS PidControllerParameterType)"),
            tf=await var(params, "CtrlTf", "derivative filter time constant, s"),
            b=await var(params, "CtrlB", "setpoint weight of the proportional action"),
            gain_sha=await var(root, "GainSetSha256", "the running gain set"),
            ff_sha=await var(root, "FeedforwardSha256",
                             "SHA-256 of the feedforward's hysteresis model (canonical JSON)"),
            setpoint=await var(root, "SetPoint", "force setpoint, N"),
            force=await var(root, "MeasuredForce", "measured preload force, N"),
            voltage=await var(root, "CommandVoltage", "voltage written to the amplifier, V"),
            state=await var(root, "State", "idle, running, ramping down, completed or tripped"),
            last_event=await var(root, "LastEvent", "the executor's last event as JSON"),
        )
        for name, inputs, callback, what in (
                (PUSH_METHOD, PUSH_INPUTS, self._push_callback, "with a note and the misses accepted by name"),
                (PUSH_METHOD_V1, PUSH_INPUTS_V1, self._push_callback_v1,
                 f"the first form of {PUSH_METHOD}: the document alone")):
            method = await root.add_method(idx, name, callback,
                                           [_argument(a, vtype, w) for a, vtype, w in inputs],
                                           [_argument(a, vtype, w) for a, vtype, w in PUSH_OUTPUTS])
            await method.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(
                "push a validated gain set of this rig's plant; it runs from the next cycle on, switched bumplessly "
                f"({what})"))))
        return server, nodes

    async def _push_callback(self, parent: Any, *args: Any) -> list[ua.Variant]:
        user = self._ruleset.caller or "unknown"  # read before the first await (see the module docstring)
        accepted, message = await self._push(args, user, PUSH_METHOD)
        return [ua.Variant(accepted, ua.VariantType.Boolean), ua.Variant(message, ua.VariantType.String)]

    async def _push_callback_v1(self, parent: Any, *args: Any) -> list[ua.Variant]:
        user = self._ruleset.caller or "unknown"  # read before the first await (see the module docstring)
        accepted, message = await self._push(args, user, PUSH_METHOD_V1)
        return [ua.Variant(accepted, ua.VariantType.Boolean), ua.Variant(message, ua.VariantType.String)]

    async def _push(self, args: tuple, user: str, method: str) -> tuple[bool, str]:
        try:
            document, note, accepted = _push_arguments(args, method)
            # in a thread: the check derives the limits on a simulation and may compile a new structure's step, and
            # the server answers its other sessions (their keep-alive reads) meanwhile
            controller, identity = await asyncio.get_running_loop().run_in_executor(
                None, functools.partial(self.cfg.check, document, accepted=accepted))
            if note:
                identity = {**identity, "note": note}
        except ValueError as exc:  # refused here: the supervisor records it, the client has the reason
            self.conn.send(("refused", user, str(exc)))
            return False, f"refused: {exc}"
        self._requests += 1
        request = self._requests
        answer = asyncio.get_running_loop().create_future()
        self._answers[request] = answer
        self.conn.send(("push", request, user, controller, identity))
        try:
            return await asyncio.wait_for(answer, ANSWER_TIMEOUT_S)
        except TimeoutError:
            return False, f"refused: the rig did not answer within {ANSWER_TIMEOUT_S:g} s"
        finally:
            self._answers.pop(request, None)

    def _readable(self) -> None:
        try:
            while self.conn.poll():
                self._incoming.put_nowait(self.conn.recv())
        except (EOFError, OSError):  # the supervisor is gone
            self._incoming.put_nowait(("stop",))

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        server, nodes = await self._build()
        async with server:
            loop.add_reader(self.conn.fileno(), self._readable)
            self.conn.send(("ready", os.getpid()))
            watch = asyncio.create_task(self._watch_parent())
            try:
                while True:
                    msg = await self._incoming.get()
                    if msg[0] == "stop":
                        break
                    if msg[0] == "state":
                        for key, value in msg[1].items():
                            await getattr(nodes, _NODE_KEYS[key]).write_value(value)
                    elif msg[0] == "answer":
                        answer = self._answers.get(msg[1])
                        if answer is not None and not answer.done():
                            answer.set_result((bool(msg[2]), str(msg[3])))
            finally:
                watch.cancel()
                loop.remove_reader(self.conn.fileno())

    async def _watch_parent(self) -> None:
        """End this process when the supervisor has died (SIGKILL leaves the pipe open to no one for a moment)."""
        while True:
            await asyncio.sleep(PARENT_CHECK_S)
            if os.getppid() != self.cfg.parent_pid:
                os._exit(0)


#: the security policies a client may ask for with a certificate, by name (piezopreload.rig.SECURITY_POLICIES)
SECURITY_POLICIES: dict[str, Any] = dict(zip(POLICY_NAMES, (  # concrete classes: a client instantiates one
    SecurityPolicyBasic256Sha256, SecurityPolicyAes128Sha256RsaOaep, SecurityPolicyAes256Sha256RsaPss), strict=True))
#: the message security modes a client may ask for with a certificate, by name (piezopreload.rig.SECURITY_MODES)
SECURITY_MODES = dict(zip(MODE_NAMES, (ua.MessageSecurityMode.SignAndEncrypt, ua.MessageSecurityMode.Sign),
                          strict=True))


@dataclass(frozen=True)
class Credentials:
    """How a client authenticates and secures its channel: a user name and password (None: anonymous), and with a
    certificate and its private key a secure channel of ``policy`` and ``mode`` (``server_certificate``: the server's,
    to trust it)."""

    username: str | None = None
    password: str | None = None
    certificate: str | Path | None = None
    private_key: str | Path | None = None
    server_certificate: str | Path | None = None
    policy: str = "Basic256Sha256"
    mode: str = "SignAndEncrypt"

    def __post_init__(self) -> None:
        if self.policy not in SECURITY_POLICIES:
            raise ValueError(f"security policy '{self.policy}': expected one of {', '.join(SECURITY_POLICIES)}")
        if self.mode not in SECURITY_MODES:
            raise ValueError(f"security mode '{self.mode}': expected one of {', '.join(SECURITY_MODES)}")
        if (self.certificate is None) != (self.private_key is None):
            raise ValueError("give the client's certificate and its private key, or neither")


async def _client(endpoint: str, timeout_s: float, who: Credentials) -> Client:
    """A client of ``endpoint`` with the user's name and password and, with a certificate, a secure channel.

    Its health probe (a read of the server's state between requests) waits as long as a request: a session of a
    few requests on a loaded host is not dropped because the server took over a second to answer one probe."""
    client = Client(endpoint, timeout=timeout_s, watchdog_intervall=timeout_s)
    if who.username is not None:
        client.set_user(who.username)
        client.set_password(who.password or "")
    if who.certificate is not None:
        server = None if who.server_certificate is None else str(who.server_certificate)
        await client.set_security(SECURITY_POLICIES[who.policy], str(who.certificate), str(who.private_key),
                                  server_certificate=server, mode=SECURITY_MODES[who.mode])
    return client


def lost(endpoint: str, exc: BaseException) -> str:
    """The words for a session that ended before its answer (the push may or may not have been taken)."""
    return (f"the session with {endpoint} ended before its answer ({exc or type(exc).__name__}); read what the server "
            "shows before pushing again")


async def connect(endpoint: str, who: Credentials, timeout_s: float = 10.0) -> Client:
    """A connected session with ``endpoint`` (disconnect it when done); :class:`PushRefused` says why not."""
    client = await _client(endpoint, timeout_s, who)
    await _connect(client, endpoint)
    return client


async def _connect(client: Client, endpoint: str) -> None:
    """Open the session; :class:`PushRefused` says why the server refused it or could not be reached."""
    try:
        try:
            await client.connect()
        except BaseException:
            # a failed connect leaves the socket and secure channel open; close them now, not when the
            # event loop is torn down (the server then met the half-open channel under the next client)
            client.disconnect_socket()
            raise
    except ua.UaStatusCodeError as exc:
        raise PushRefused(f"the server refused the session: {type(exc).__name__} "
                          "(a wrong user name or password, or an untrusted certificate)") from None
    except ua.UaError as exc:
        raise PushRefused(f"the server refused the session: {exc} (it may require encryption: give the client's "
                          "certificate and key)") from None
    except (TimeoutError, OSError) as exc:
        raise PushRefused(f"cannot reach {endpoint}: {exc or type(exc).__name__}") from None


async def _await_running(running_node: Any, running: str, expect_sha256: str, timeout_s: float) -> str:
    """The gain set the server runs, read again until it is ``expect_sha256`` (or ``timeout_s`` has passed)."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while running != expect_sha256:
        if asyncio.get_running_loop().time() > deadline:
            raise PushRefused(f"the server accepted the gain set but still runs {running[:12]} after {timeout_s:g} s")
        await asyncio.sleep(0.02)
        running = await running_node.read_value()
    return running


async def _push_and_read(client: Client, document: str, note: str, timeout_s: float,
                         expect_sha256: str | None,
                         accepted: tuple[str, ...] = ()) -> tuple[bool, str, dict[str, float], str]:
    """Call :data:`PUSH_METHOD` on a connected client; the answer, then the parameters and the gain set the server
    shows."""
    idx = await client.get_namespace_index(NAMESPACE)
    root = await client.nodes.objects.get_child([f"{idx}:{ROOT}"])
    try:
        method = await root.get_child([f"{idx}:{PUSH_METHOD}"])
    except ua.UaStatusCodeError:  # a rig served before the form got its name: its PushGainSet takes the three
        method = await root.get_child([f"{idx}:{PUSH_METHOD_V1}"])
    try:
        taken, message = await root.call_method(method.nodeid, ua.Variant(document, ua.VariantType.String),
                                                ua.Variant(note, ua.VariantType.String),
                                                ua.Variant(",".join(accepted), ua.VariantType.String))
    except ua.UaStatusCodeError as exc:
        raise PushRefused(f"the server refused the call: {type(exc).__name__}") from None
    running_node = await root.get_child([f"{idx}:GainSetSha256"])
    running = await running_node.read_value()
    if taken and expect_sha256 is not None:
        running = await _await_running(running_node, running, expect_sha256, timeout_s)
    params = await root.get_child([f"{idx}:ControllerParameters"])
    values: dict[str, float] = {}
    for name in ("CtrlP", "CtrlTi", "CtrlTd"):
        values[name] = await (await params.get_child([f"{idx}:{name}"])).read_value()
    return taken, message, values, running


@dataclass(frozen=True)
class PushReply:
    """A served rig's answer to a push it took: its message, the parameters it then shows (``CtrlP``, ``CtrlTi``,
    ``CtrlTd``) and the content hash of the gain set it runs."""

    message: str
    server_parameters: dict[str, float]
    server_gain_set_sha256: str

    def to_dict(self) -> dict[str, Any]:
        return {"accepted": True, "message": self.message, "server_parameters": dict(self.server_parameters),
                "server_gain_set_sha256": self.server_gain_set_sha256}


async def push_gain_set(document: str, endpoint: str, who: Credentials, *, timeout_s: float = PUSH_TIMEOUT_S,
                        expect_sha256: str | None = None, note: str = "",
                        accepted: tuple[str, ...] = ()) -> PushReply:
    """Push a gain set's JSON ``document`` through :data:`PUSH_METHOD` (with ``note``, recorded with it, and the keys
    of the requirements a candidate missed that the pusher ``accepted``), in the session ``who`` opens (its user and
    password, and its certificate, policy and mode where it gives them; the one way every push here is given them, as
    :func:`piezopreload.rig.plc_push.push_to_server` is); :class:`PushRefused` says why not.

    With ``expect_sha256``, waits (up to ``timeout_s``) until the server shows that gain set
    running and returns the parameters it then shows.
    """
    client = await connect(endpoint, who, timeout_s)
    try:
        taken, message, values, running = await _push_and_read(client, document, note, timeout_s, expect_sha256,
                                                               accepted)
    except (ConnectionError, TimeoutError) as exc:
        raise PushRefused(lost(endpoint, exc)) from None
    finally:
        await client.disconnect()
    if not taken:
        raise PushRefused(message)
    return PushReply(message, values, running)
