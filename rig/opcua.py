"""The rig executor as an OPC UA server, and the client that pushes gain sets to it (asyncua).

Address space (namespace ``urn:piezopreload:rig``), under ``Objects/PreloadRig``:

* ``ControllerParameters``: ``CtrlP`` (V/N), ``CtrlTi`` (s) and ``CtrlTd`` (s), named as the
  OPC UA LADS companion specification's ``PidControllerParameterType`` names them, and
  ``CtrlTf`` (s, the derivative filter) and ``CtrlB`` (the setpoint weight);
* ``GainSetSha256`` and ``FeedforwardSha256``: which gain set runs, and which hysteresis model
  its feedforward inverts (the hash of the model's JSON);
* ``SetPoint`` (N), ``MeasuredForce`` (N), ``CommandVoltage`` (V), ``State`` and ``LastEvent``;
* the method ``PushGainSet(document: String) -> (accepted: Boolean, message: String)``.

Every variable is read-only to clients; the one way to change the controller is the method,
which checks the document again (its hash, its status, its sample period), hands it to the
executor to switch bumplessly between two cycles, and records who pushed what and when.

Security: sessions authenticate with a user name and password (``users``); anonymous
sessions are refused.
With ``certificate`` and ``private_key`` the server offers only the Basic256Sha256
SignAndEncrypt policy; without, it offers no encryption, which is for loopback use only (the
default endpoint binds 127.0.0.1).

The pushing user's name comes from the permission check that asyncua runs on each request,
right before it dispatches the call (no other request can run between the two).

The server shares the interpreter with the 1 kHz loop; a session with a pushing client in
another process stalls the loop by 6 ms at most here. A client in the *same* process (a
notebook, a test) is another matter: loading its 2048-bit RSA key for Basic256Sha256 holds
the interpreter for about 30 ms (cryptography checks the key), close to the missed-deadline
interlock's 50 cycles. Push from another process, as ``piezopreload rig push`` does.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import json
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Client, Server, ua
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from piezopreload.core.errors import PiezopreloadError
from piezopreload.models.controller import Controller
from piezopreload.rig import DEFAULT_ENDPOINT
from piezopreload.rig.executor import Executor, RunResult

__all__ = ["RigServer", "push_gain_set", "PushRefused", "NAMESPACE", "DEFAULT_ENDPOINT", "ROOT"]

NAMESPACE = "urn:piezopreload:rig"
ROOT = "PreloadRig"

#: check_gain_set(document text) -> (controller, {"gain_set_sha256": ..., "feedforward_sha256": ...});
#: raises ValueError with the reason when the document cannot run
GainSetCheck = Callable[[str], tuple[Controller, dict[str, Any]]]


class PushRefused(PiezopreloadError, RuntimeError):
    """The server refused the push (or the session); the message says why."""


def _hash_password(password: str, salt: bytes) -> bytes:
    return hashlib.pbkdf2_hmac("sha256", password.encode(), salt, 200_000)


class _Users:
    """User names with salted password hashes."""

    def __init__(self, passwords: dict[str, str]) -> None:
        self._salt = os.urandom(16)
        self._hashes = {name: _hash_password(pw, self._salt) for name, pw in passwords.items()}

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if username is not None:
            known = self._hashes.get(username)
            if known is not None and password is not None and hmac.compare_digest(known, _hash_password(password, self._salt)):
                return User(role=UserRole.User, name=username)
        return None


class _Ruleset(SimpleRoleRuleset):
    """asyncua's role rules, remembering who makes each method call (see the module docstring)."""

    caller: str | None = None

    def check_validity(self, user: User, action_type_id: Any, body: Any) -> bool:
        ok = super().check_validity(user, action_type_id, body)
        if ok and action_type_id == ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary):
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


class RigServer:
    """Serve ``executor`` over OPC UA while it runs; see the module docstring."""

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
        self._users = _Users(users)
        self.update_s = float(update_s)
        self.pushes: list[dict[str, Any]] = []
        self._ruleset = _Ruleset()
        self._lock = threading.Lock()
        self._shown: dict[Any, Any] = {}  # node -> the value last written to it
        self._events_shown = 0

    async def _build(self) -> tuple[Server, _Nodes]:
        server = Server(user_manager=self._users)
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name("piezopreload rig executor")
        if self.certificate is not None:
            await server.load_certificate(str(self.certificate))
            await server.load_private_key(str(self.private_key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                       permission_ruleset=self._ruleset)
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=self._ruleset)
        server.set_identity_tokens([ua.UserNameIdentityToken])
        idx = await server.register_namespace(NAMESPACE)
        root = await server.nodes.objects.add_object(idx, ROOT)
        params = await root.add_object(idx, "ControllerParameters")
        g = self.executor.controller.gains

        async def var(parent: Any, name: str, value: Any, desc: str) -> Any:
            node = await parent.add_variable(idx, name, value)
            await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(desc))))
            return node

        nodes = _Nodes(
            p=await var(params, "CtrlP", float(g.Kc), "proportional gain Kc, V/N (LADS PidControllerParameterType)"),
            ti=await var(params, "CtrlTi", float(g.Ti_s), "integral time Ti, s (LADS PidControllerParameterType)"),
            td=await var(params, "CtrlTd", float(g.Td_s), "derivative time Td, s (LADS PidControllerParameterType)"),
            tf=await var(params, "CtrlTf", float(g.Tf_s), "derivative filter time constant, s"),
            b=await var(params, "CtrlB", float(g.b), "setpoint weight of the proportional action"),
            gain_sha=await var(root, "GainSetSha256", self.identity.get("gain_set_sha256", ""), "the running gain set"),
            ff_sha=await var(root, "FeedforwardSha256", self.identity.get("feedforward_sha256", ""),
                             "SHA-256 of the feedforward's hysteresis model (canonical JSON)"),
            setpoint=await var(root, "SetPoint", 0.0, "force setpoint, N"),
            force=await var(root, "MeasuredForce", 0.0, "measured preload force, N"),
            voltage=await var(root, "CommandVoltage", 0.0, "voltage written to the amplifier, V"),
            state=await var(root, "State", "idle", "idle, running, ramping down, completed or tripped"),
            last_event=await var(root, "LastEvent", "", "the executor's last event as JSON"),
        )
        method = await root.add_method(idx, "PushGainSet", self._push_callback, [ua.VariantType.String],
                                       [ua.VariantType.Boolean, ua.VariantType.String])
        await method.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText(
            "push a validated gain set (the JSON document); it runs from the next cycle on, switched bumplessly"))))
        return server, nodes

    def _push_callback(self, parent: Any, *args: Any) -> list[ua.Variant]:
        user = self._ruleset.caller or "unknown"
        accepted, message = self.push(args, user)
        return [ua.Variant(accepted, ua.VariantType.Boolean), ua.Variant(message, ua.VariantType.String)]

    def push(self, args: tuple, user: str) -> tuple[bool, str]:
        """Check a pushed gain set and hand it to the executor; ``(accepted, message)``. Changes nothing if refused."""
        record: dict[str, Any] = {"user": user}
        try:
            if len(args) != 1 or not isinstance(args[0].Value, str):
                raise ValueError("PushGainSet takes one String argument: the gain set's JSON document")
            controller, identity = self.check(args[0].Value)
            record.update(identity)
            with self._lock:
                self.executor.request_switch(controller, {"pushed_by": user, **identity})
                self.identity = {**self.identity, **identity}
        except ValueError as exc:
            record.update(accepted=False, reason=str(exc))
            self.pushes.append(record)
            self.executor.record("push_refused", user=user, reason=str(exc))
            return False, f"refused: {exc}"
        record.update(accepted=True)
        self.pushes.append(record)
        return True, f"accepted gain set {identity.get('gain_set_sha256', '')[:12]}; it runs from the next cycle"

    async def _update(self, nodes: _Nodes) -> None:
        """Write the nodes whose values changed since the last update (the loop shares the interpreter)."""
        t, sp, y, v, state = self.executor.latest
        g = self.executor.controller.gains
        values = [(nodes.p, float(g.Kc)), (nodes.ti, float(g.Ti_s)), (nodes.td, float(g.Td_s)),
                  (nodes.tf, float(g.Tf_s)), (nodes.b, float(g.b)),
                  (nodes.setpoint, float(sp)), (nodes.force, float(y)), (nodes.voltage, float(v)), (nodes.state, state)]
        events = self.executor.events
        if events and len(events) != self._events_shown:
            self._events_shown = len(events)
            values.append((nodes.last_event, json.dumps(events[-1], default=str)))
        if not self.executor.switch_pending:
            values += [(nodes.gain_sha, self.identity.get("gain_set_sha256", "")),
                       (nodes.ff_sha, self.identity.get("feedforward_sha256", ""))]
        for node, value in values:
            if self._shown.get(node) != value:
                self._shown[node] = value
                await node.write_value(value)

    async def run(self, ready: threading.Event | None = None, stop: threading.Event | None = None) -> RunResult:
        """Serve until the executor ends (its reference, a trip, :meth:`Executor.stop`); returns its result."""
        server, nodes = await self._build()
        result: list[RunResult] = []
        async with server:
            # every node written once before the loop starts: the first update writes them all, and
            # that interpreter time must not fall into the loop's first cycles
            await self._update(nodes)
            thread = threading.Thread(target=lambda: result.append(self.executor.run()), name="rig-loop", daemon=True)
            thread.start()
            if ready is not None:
                ready.set()
            while thread.is_alive():
                if stop is not None and stop.is_set():
                    self.executor.stop("stopped by the server", trip=False)
                await self._update(nodes)
                await asyncio.sleep(self.update_s)
            thread.join()
            await self._update(nodes)
        return result[0]


async def push_gain_set(document: str, endpoint: str, *, username: str | None = None, password: str | None = None,
                        certificate: str | Path | None = None, private_key: str | Path | None = None,
                        server_certificate: str | Path | None = None, timeout_s: float = 10.0,
                        expect_sha256: str | None = None) -> dict[str, Any]:
    """Push a gain set's JSON ``document`` through ``PushGainSet``; :class:`PushRefused` says why not.

    With ``expect_sha256``, waits (up to ``timeout_s``) until the server shows that gain set
    running and returns the parameters it then shows.
    """
    client = Client(endpoint, timeout=timeout_s)
    if username is not None:
        client.set_user(username)
        client.set_password(password or "")
    if certificate is not None:
        await client.set_security(SecurityPolicyBasic256Sha256, str(certificate), str(private_key),
                                  server_certificate=None if server_certificate is None else str(server_certificate),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
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
    try:
        idx = await client.get_namespace_index(NAMESPACE)
        root = await client.nodes.objects.get_child([f"{idx}:{ROOT}"])
        method = await root.get_child([f"{idx}:PushGainSet"])
        try:
            accepted, message = await root.call_method(method, ua.Variant(document, ua.VariantType.String))
        except ua.UaStatusCodeError as exc:
            raise PushRefused(f"the server refused the call: {type(exc).__name__}") from None
        running_node = await root.get_child([f"{idx}:GainSetSha256"])
        running = await running_node.read_value()
        deadline = asyncio.get_running_loop().time() + timeout_s
        while accepted and expect_sha256 is not None and running != expect_sha256:
            if asyncio.get_running_loop().time() > deadline:
                raise PushRefused(f"the server accepted the gain set but still runs {running[:12]} after {timeout_s:g} s")
            await asyncio.sleep(0.02)
            running = await running_node.read_value()
        params = await root.get_child([f"{idx}:ControllerParameters"])
        values = {}
        for name in ("CtrlP", "CtrlTi", "CtrlTd"):
            values[name] = await (await params.get_child([f"{idx}:{name}"])).read_value()
    finally:
        await client.disconnect()
    if not accepted:
        raise PushRefused(message)
    return {"accepted": True, "message": message, "server_parameters": values, "server_gain_set_sha256": running}
