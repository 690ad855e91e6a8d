"""``rig push GAINS --to URL --map NODES.toml``: a gain set's numbers written to a PLC's own OPC UA server.

Two servers play the PLC, each publishing the variables of an instance of PP_CONTROLLER as a PLC's server does
(REAL scalars and arrays as Float, LREAL as Double, a STRING for the gain set's hash), with a user and password and
anonymous sessions refused: an asyncua server in this process, and node-opcua (another implementation, in node.js;
skipped with its reason where node or npm is absent). The push must round-trip every value (an LREAL to the last
bit, a REAL to its single-precision rounding: the report says which), and refuse by name, writing nothing, a node
that is missing, of another type or length, or not writable, and a gain set that is not validated.
"""

import asyncio
import json
import os
import shutil
import socket
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from asyncua import Server, ua
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole

from piezopreload.artifacts.gainset import GainSet
from piezopreload.cli import main
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import GainSchedule, PIDGains
from piezopreload.models.hysteresis import ClassicalPI
from piezopreload.rig.controller_code import controller_code

pytestmark = pytest.mark.slow

USER, PASSWORD = "engineer", "plc password"
NAMESPACE = "urn:piezopreload:test-plc"
PREFIX = "PLC.PP_LOOP.ctrl."
#: the numbers a PLC keeps in REAL (single precision); the others in LREAL
REALS = {"Kc", "Ti_s", "Td_s", "Tf_s", "b", "ff_thresholds", "ff_weights_rising", "ff_partial_rising",
         "ff_inverse_thresholds_rising", "ff_inverse_weights_rising"}


def _gain_set(path, status="validated"):
    """A gain set with everything a push writes: gains, a feedforward's table, a gain schedule's table."""
    schedule = GainSchedule(levels_N=(30.0, 60.0, 100.0), Kc=(0.9, 1.6, 0.7), Ti_s=(0.08, 0.04, 0.06),
                            Td_s=(0.0, 0.004, 0.002), b=(0.3, 0.8, 0.5))
    gains = PIDGains(Kc=1.4, Ti_s=0.05, Td_s=0.004, Tf_s=0.02, b=0.3, u_min_V=0.0, u_max_V=110.0, schedule=schedule)
    ff = ClassicalPI(np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05]), 25.0)
    GainSet(gains=gains, status=status, feedforward=ff, plant=Plant(), preset="test").save(path)
    return path


def _parameters(path, every=False):
    """The numbers a push writes: those the controller's step reads (``every``: the whole parameter vector's, as a
    block exported before the export declared only what its step reads)."""
    code = controller_code(GainSet.load(path).controller())
    return {p.name: p for p in (code.parameters if every else code.read)}


def _spec(path, **changes):
    """The PLC's variables for the gain set at ``path`` (every parameter's, a scheduled set's unread single gains too):
    zeros before the push; ``changes`` replaces a node's entry (None: the PLC has no such variable)."""
    nodes = {name: {"id": PREFIX + name, "type": "Float" if name in REALS else "Double",
                    "length": p.size if p.array else None, "value": [0.0] * p.size if p.array else 0.0,
                    "writable": True} for name, p in _parameters(path, every=True).items()}
    nodes["gain_set_sha256"] = {"id": "PLC.PP_LOOP.gain_set_sha256", "type": "String", "length": None, "value": "",
                                "writable": True}
    for name, entry in changes.items():
        if entry is None:
            del nodes[name]
        else:
            nodes[name] = {**nodes[name], **entry}
    return list(nodes.values())


def _map(tmp_path, extra=""):
    path = tmp_path / "nodes.toml"
    path.write_text(f'prefix = "nsu={NAMESPACE};s={PREFIX}"\n[nodes]\n'
                    f'gain_set_sha256 = "nsu={NAMESPACE};s=PLC.PP_LOOP.gain_set_sha256"\n{extra}')
    return path


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Users:
    def get_user(self, iserver, username=None, password=None, certificate=None):
        if username == USER and password == PASSWORD:
            return User(role=UserRole.User, name=username)
        return None


_VTYPES = {"Float": ua.VariantType.Float, "Double": ua.VariantType.Double, "String": ua.VariantType.String,
           "Int16": ua.VariantType.Int16}


class AsyncuaPlc:
    """An asyncua server playing the PLC, in a thread of its own; :meth:`values` reads every variable."""

    def __init__(self, spec, certificate=None):
        self.spec, self.port, self.certificate = spec, _free_port(), certificate
        self.endpoint = f"opc.tcp://127.0.0.1:{self.port}/plc"
        self._ready, self._loop, self._nodes = threading.Event(), None, {}

    async def _serve(self):
        server = Server(user_manager=_Users())
        await server.init()
        server.set_endpoint(self.endpoint)
        if self.certificate is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=SimpleRoleRuleset())
        else:  # a PLC that offers an encrypted channel only
            await server.load_certificate(str(self.certificate[0]))
            await server.load_private_key(str(self.certificate[1]))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                       permission_ruleset=SimpleRoleRuleset())
        server.set_identity_tokens([ua.UserNameIdentityToken])
        idx = await server.register_namespace(NAMESPACE)
        plc = await server.nodes.objects.add_object(idx, "PLC")
        for n in self.spec:
            vtype = _VTYPES[n["type"]]
            node = await plc.add_variable(ua.NodeId(n["id"], idx), n["id"], ua.Variant(n["value"], vtype),
                                          datatype=ua.NodeId(vtype.value))
            if n["length"] is not None or "rank" in n:  # the ValueRank the spec gives, else 1 for an array
                rank = n.get("rank", 1)
                await node.write_attribute(ua.AttributeIds.ValueRank,
                                           ua.DataValue(ua.Variant(rank, ua.VariantType.Int32)))
            if n["length"] is not None and n.get("rank", 1) > 0:  # as node-opcua: no dimensions for a ValueRank <= 0
                await node.write_attribute(ua.AttributeIds.ArrayDimensions,
                                           ua.DataValue(ua.Variant([n["length"]], ua.VariantType.UInt32)))
            if n["writable"]:
                await node.set_writable()
            self._nodes[n["id"]] = node
        self._stop = asyncio.Event()
        async with server:
            self._ready.set()
            await self._stop.wait()

    def __enter__(self):
        def run():
            self._loop = asyncio.new_event_loop()
            self._loop.run_until_complete(self._serve())

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        assert self._ready.wait(30), "the asyncua PLC did not start"
        return self

    def __exit__(self, *exc):
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30)

    def values(self):
        async def read():
            return {k: await n.read_value() for k, n in self._nodes.items()}
        return asyncio.run_coroutine_threadsafe(read(), self._loop).result(10)


# --------------------------------------------------------------------------------------
# node-opcua, installed on first use into a cache folder
# --------------------------------------------------------------------------------------
NODE_OPCUA = "2.186.4"
#: the server and the two of its own dependencies the script requires, at the versions it depends on
NODE_PACKAGES = [f"node-opcua-server@{NODE_OPCUA}", f"node-opcua-variant@{NODE_OPCUA}",
                 "node-opcua-status-code@2.186.1"]
NODE_CACHE = Path(os.environ.get("PIEZOPRELOAD_NODE_CACHE",
                                 Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "piezopreload-tests"))


def node_modules():
    """node-opcua's node_modules folder (npm installs it into NODE_CACHE the first time), or the test skips saying
    why."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node.js and npm are not installed: the test against node-opcua needs them")
    folder = NODE_CACHE / f"node-opcua-{NODE_OPCUA}"
    if not (folder / "node_modules" / "node-opcua-server").is_dir():
        folder.mkdir(parents=True, exist_ok=True)
        run = subprocess.run(["npm", "install", "--prefix", str(folder), "--no-audit", "--no-fund", "--loglevel=error",
                              *NODE_PACKAGES], capture_output=True, text=True, timeout=900)
        if run.returncode != 0:
            pytest.skip(f"npm could not install node-opcua {NODE_OPCUA}: {run.stderr.strip()[-300:]}")
    return folder / "node_modules"


class NodeOpcuaPlc:
    """tests/node_opcua_plc.js serving ``spec``; :meth:`values` reads every variable through asyncua."""

    def __init__(self, spec, tmp_path):
        self.spec, self.port = spec, _free_port()
        self.endpoint = f"opc.tcp://127.0.0.1:{self.port}/plc"
        self.file = tmp_path / "plc.json"
        self.file.write_text(json.dumps({"port": self.port, "user": USER, "password": PASSWORD, "nodes": spec}))

    def __enter__(self):
        env = {**os.environ, "NODE_PATH": str(node_modules())}
        script = Path(__file__).with_name("node_opcua_plc.js")
        self.proc = subprocess.Popen(["node", str(script), str(self.file)], env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for line in self.proc.stdout:
            if line.startswith("listening"):
                return self
        raise AssertionError(f"node-opcua did not start (exit {self.proc.wait(10)})")

    def __exit__(self, *exc):
        self.proc.stdin.close()
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()

    def values(self):
        from asyncua import Client

        async def read():
            client = Client(self.endpoint)
            client.set_user(USER)
            client.set_password(PASSWORD)
            async with client:
                idx = await client.get_namespace_index(NAMESPACE)
                return {n["id"]: await client.get_node(ua.NodeId(n["id"], idx)).read_value() for n in self.spec}
        return asyncio.run(read())


def _server(kind, spec, tmp_path):
    return AsyncuaPlc(spec) if kind == "asyncua" else NodeOpcuaPlc(spec, tmp_path)


SERVERS = pytest.mark.parametrize("kind", ["asyncua", "node-opcua"])


def _push(capsys, gains, endpoint, node_map, *options, user=USER):
    code = main(["rig", "push", str(gains), "--to", endpoint, "--map", str(node_map), "--json",
                 *(["--user", user] if user else []), *options])
    out = capsys.readouterr()
    return code, (json.loads(out.out) if code == 0 else out.err)


@pytest.fixture(autouse=True)
def _password(monkeypatch):
    monkeypatch.setenv("PIEZOPRELOAD_RIG_PASSWORD", PASSWORD)


@SERVERS
def test_every_value_round_trips(kind, tmp_path, capsys):
    """Every number the step reads, to nodes as a PLC states them: a table's node of ValueRank 1 or 0 ("one or more
    dimensions", which holds a one-dimensional array: OPC UA Part 3, ValueRank). The scheduled set's single Kc, Ti_s,
    Td_s and b, which its step does not read, are not written though the PLC has nodes of those names."""
    gains = _gain_set(tmp_path / "gains.json")
    spec = _spec(gains, schedule_Kc={"rank": 0})
    with _server(kind, spec, tmp_path) as plc:
        code, report = _push(capsys, gains, plc.endpoint, _map(tmp_path))
        assert code == 0, report
        held = plc.values()
    sha = GainSet.load(gains).content_sha256
    assert held["PLC.PP_LOOP.gain_set_sha256"] == sha
    for name, p in _parameters(gains).items():
        want = np.asarray(p.values, np.float32 if name in REALS else np.float64)
        got = np.atleast_1d(np.asarray(held[PREFIX + name], float))
        assert np.array_equal(got, want.astype(float)), f"{name}: the PLC holds {got}, the gain set {p.values}"
    rows = {r["name"]: r for r in report["nodes"]}
    assert all(r["as_written"] for r in rows.values()) and set(rows) == {*_parameters(gains), "gain_set_sha256"}
    assert not {"Kc", "Ti_s", "Td_s", "b"} & set(rows), "a scheduled set's step does not read its single gains"
    assert all(held[PREFIX + n] == 0.0 for n in ("Kc", "Ti_s", "Td_s", "b")), "a node the step does not read written"
    assert rows["Tf_s"]["type"] == "Float (REAL)" and rows["Tf_s"]["relative_difference"] == pytest.approx(
        abs(float(np.float32(0.02)) - 0.02) / 0.02)
    assert rows["schedule_Kc"]["difference"] == 0.0 and rows["dt_s"]["type"] == "Double (LREAL)"
    assert rows["Tf_s"]["before"] == 0.0 and report["exact"] is False
    assert 0 < report["max_relative_difference"] < 2 ** -23


def _nothing_written(plc, spec):
    held = plc.values()
    for n in spec:
        assert np.all(np.asarray(held[n["id"]]) == np.asarray(n["value"])), f"{n['id']} was written"


@SERVERS
def test_a_node_missing_of_another_type_or_length_or_read_only_is_refused_and_nothing_written(kind, tmp_path,
                                                                                              capsys):
    gains = _gain_set(tmp_path / "gains.json")
    spec = _spec(gains, Tf_s={"type": "Int16", "value": 0}, ff_thresholds={"length": 3, "value": [0.0] * 3},
                 dt_s={"writable": False}, u_min_V=None, schedule_Ti_s={"rank": -1, "length": None, "value": 0.0},
                 u_max_V={"rank": 1, "length": 2, "value": [0.0, 0.0]})
    with _server(kind, spec, tmp_path) as plc:
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path))
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
        assert "nothing was written" in err
        assert f"node 'nsu={NAMESPACE};s={PREFIX}Tf_s' for Tf_s is of type Int16; expected Float (REAL) or Double" \
            in err
        # the shapes, by what the server states (ValueRank, ArrayDimensions) against what the number needs
        assert ("for ff_thresholds has ValueRank 1 (a one-dimensional array, ArrayDimensions [3]) on the server; the "
                "gain set's ff_thresholds needs a one-dimensional array (ValueRank 1) of 4") in err
        assert ("for schedule_Ti_s has ValueRank -1 (a scalar) on the server; the gain set's schedule_Ti_s needs a "
                "one-dimensional array (ValueRank 1) of 3") in err
        assert ("for u_max_V has ValueRank 1 (a one-dimensional array, ArrayDimensions [2]) on the server; the gain "
                "set's u_max_V is a scalar (ValueRank -1)") in err
        assert f"for dt_s is not writable for {USER}" in err
        assert "for u_min_V does not exist on the server (BadNodeIdUnknown)" in err
        _nothing_written(plc, spec)


def test_the_status_the_map_and_the_session_are_checked_first(tmp_path, capsys, monkeypatch):
    gains = _gain_set(tmp_path / "gains.json")
    spec = _spec(gains)
    with AsyncuaPlc(spec) as plc:
        code, err = _push(capsys, _gain_set(tmp_path / "cand.json", "candidate"), plc.endpoint, _map(tmp_path))
        assert code == 2 and "cand.json is a 'candidate', not 'validated'" in err, err
        assert "only validated gains are pushed" in err, err
        partial = tmp_path / "partial.toml"
        partial.write_text('[nodes]\nTf_s = "ns=2;s=PLC.PP_LOOP.ctrl.Tf_s"\n')
        code, err = _push(capsys, gains, plc.endpoint, partial)
        assert code == 2 and "no node for u_min_V, u_max_V, dt_s" in err and "schedule_Kc" in err
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path, 'Kc = "ns=2;s=PLC.PP_LOOP.ctrl.Kc"\n'))
        assert code == 2 and ("field 'nodes.Kc' names a number this gain set's controller does not read (a "
                              "scheduled set's step runs on the schedule's arrays)") in err, err
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path, 'Kp = "ns=2;s=x"\n'))
        assert code == 2 and "field 'nodes.Kp' names no number of this gain set's controller" in err
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path), "--note", "retuned")
        assert code == 2 and "a push to a PLC (--to) keeps no note" in err, "an option the push would drop"
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path), user=None)
        assert code == 2 and "refused the session" in err, "an anonymous session"
        monkeypatch.setenv("PIEZOPRELOAD_RIG_PASSWORD", "wrong")
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path))
        assert code == 2 and "refused the session" in err
        _nothing_written(plc, spec)


def test_a_plc_that_offers_an_encrypted_channel_only(tmp_path, capsys):
    """The user's security settings: a certificate and the policy and mode asked for reach a PLC that offers only
    Basic256Sha256 SignAndEncrypt; without them the session is refused and nothing is written."""
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    async def make():
        await setup_self_signed_certificate(tmp_path / "plc.pem", tmp_path / "plc.der", "urn:test:plc", "localhost",
                                            [ExtendedKeyUsageOID.SERVER_AUTH], {"commonName": "plc"})
        await setup_self_signed_certificate(tmp_path / "client.pem", tmp_path / "client.der", "urn:freeopcua:client",
                                            "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "bench"})

    asyncio.run(make())
    gains = _gain_set(tmp_path / "gains.json")
    spec = _spec(gains)
    secure = ["--certificate", str(tmp_path / "client.der"), "--private-key", str(tmp_path / "client.pem"),
              "--server-certificate", str(tmp_path / "plc.der"), "--security-policy", "Basic256Sha256",
              "--security-mode", "SignAndEncrypt"]
    with AsyncuaPlc(spec, (tmp_path / "plc.der", tmp_path / "plc.pem")) as plc:
        code, err = _push(capsys, gains, plc.endpoint, _map(tmp_path))
        assert code == 2 and "refused the session" in err, "no encryption asked for: refused"
        _nothing_written(plc, spec)
        code, report = _push(capsys, gains, plc.endpoint, _map(tmp_path), *secure)
        assert code == 0, report
        assert all(r["as_written"] for r in report["nodes"])
        assert plc.values()[PREFIX + "dt_s"] == Plant().sample_period_s
