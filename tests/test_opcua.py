"""End to end on loopback: serve the rig over OPC UA, push gain sets with a real asyncua client."""

import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from asyncua import Client, ua
from rigkit import write_gain_set

from piezopreload.artifacts.gainset import RigInterlocks
from piezopreload.artifacts.registry import read_artifact
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.cli import main
from piezopreload.models.controller import GainSchedule, PIDGains
from piezopreload.rig.opcua import NAMESPACE, ROOT, Credentials, PushRefused, push_gain_set
from piezopreload.rig.runlog import read_run_log
from piezopreload.rig.session import serve as serve_rig

USER, PASSWORD = "operator", "correct horse"
#: a short host check before arming: these tests are about the server (the check has its own, tests/test_rig.py)
QUICK = {"host_check_s": 0.2, "accept_host": True}

pytestmark = [pytest.mark.realtime, pytest.mark.slow]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _on_root(endpoint, action):
    """``action(root, idx)`` on the rig's root object in an authenticated session."""
    client = Client(endpoint)
    client.set_user(USER)
    client.set_password(PASSWORD)
    async with client:
        idx = await client.get_namespace_index(NAMESPACE)
        return await action(await client.nodes.objects.get_child([f"{idx}:{ROOT}"]), idx)


async def _call_raw(endpoint, *args, method="PushGainSet"):
    """``method`` called with whatever arguments, as a client of its own (or a malformed one) would."""
    async def call(root, idx):
        return await root.call_method(await root.get_child([f"{idx}:{method}"]), *args)
    return await _on_root(endpoint, call)


async def _input_arguments(endpoint, method):
    """The names of ``method``'s input arguments, as the server declares them (its InputArguments property)."""
    async def read(root, idx):
        node = await root.get_child([f"{idx}:{method}"])
        return [a.Name for a in await (await node.get_child(["0:InputArguments"])).read_value()]
    return await _on_root(endpoint, read)


async def _read(endpoint, name):
    async def read(root, idx):
        return await (await root.get_child([f"{idx}:{name}"])).read_value()
    return await _on_root(endpoint, read)


def _gain_sets(tmp_path, study, feedforward):
    """The served set, the pushed one, and three the server must refuse (a candidate, a changed file, another
    study's force limit)."""
    # a quieter sensor (0.05 N) than the paper's (0.25 N): the command's sample-to-sample noise then stays
    # well below the 0.5 V the switch is held to, so what the test sees at the switch is the switch
    quiet = replace(study.plant, noise_N=0.05)
    # b = 0: a proportional action on the measurement alone, -0.5 V/N x 60 N = -30 V away from the paper's
    # (b = 1, e ~ 0): a switch that is not bumpless jumps by that much
    tuned = PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.001, Tf_s=0.01, b=0.0, u_min_V=0.0, u_max_V=110.0)
    sets = {"first": write_gain_set(tmp_path / "paper.json", study, feedforward, plant=quiet),
            "second": write_gain_set(tmp_path / "tuned.json", study, feedforward, gains=tuned, plant=quiet),
            "candidate": write_gain_set(tmp_path / "candidate.json", study, feedforward, gains=tuned,
                                        status="candidate", plant=quiet),
            # a gain set of a study with another force limit: the served rig was armed with the first one's
            "other": write_gain_set(tmp_path / "other.json", study, feedforward, gains=tuned, plant=quiet,
                                    rig_interlocks=RigInterlocks(130.0, 10.0, 0.5, None,
                                                                 {"force_max_N": "other.toml [rig_run]"}))}
    doc = json.loads(sets["second"].read_text())
    doc["gains"]["Kc_V_per_N"] = 5.0
    return sets, json.dumps(doc)


def _refusals(endpoint, sets, tampered):
    with pytest.raises(PushRefused, match="candidate"):
        asyncio.run(push_gain_set(sets["candidate"].read_text(), endpoint, Credentials(USER, PASSWORD)))
    with pytest.raises(PushRefused, match="content_sha256"):
        asyncio.run(push_gain_set(tampered, endpoint, Credentials(USER, PASSWORD)))
    with pytest.raises(PushRefused, match=r"limits trip the force above 130 N \(the gain set: other.toml "
                                          r"\[rig_run\]\), this rig trips only above 143"):
        asyncio.run(push_gain_set(sets["other"].read_text(), endpoint, Credentials(USER, PASSWORD)))
    with pytest.raises(PushRefused, match="refused the session"):
        asyncio.run(push_gain_set(sets["first"].read_text(), endpoint, Credentials(USER, "wrong")))
    with pytest.raises(PushRefused, match="refused the session"):  # anonymous
        asyncio.run(push_gain_set(sets["first"].read_text(), endpoint, Credentials()))
    accepted, message = asyncio.run(_call_raw(endpoint, ua.Variant(7, ua.VariantType.Int32)))
    assert accepted is False and "PushGainSet takes one String argument, GainSetDocument" in message, message
    accepted, message = asyncio.run(_call_raw(endpoint, ua.Variant(7, ua.VariantType.Int32),
                                              method="PushGainSetWithNote"))
    assert accepted is False and "PushGainSetWithNote takes 3 String arguments: GainSetDocument" in message
    # the command line: a candidate is refused before anything is sent, a wrong password by the server
    assert main(["rig", "push", str(sets["candidate"]), "--endpoint", endpoint, "--user", USER]) == 2


def _switched_bumplessly(s, sha2):
    """The push's record and event, and the command at the switch: no jump, the new gains running after it."""
    pushes = s["pushes"]
    assert [p["accepted"] for p in pushes] == [True, False, False, False, False, False, True]
    assert pushes[0]["user"] == USER and pushes[0]["gain_set_sha256"] == sha2
    assert all(p["user"] == USER for p in pushes)
    side = RigRunRecord.load(s["log_json"])
    switch = next(e for e in side.events if e["event"] == "gains_switched")
    assert switch["pushed_by"] == USER and switch["gain_set_sha256"] == sha2 and "utc" in switch
    assert sum(e["event"] == "push_refused" for e in side.events) == 5
    log = read_run_log(s["log_csv"])
    k = int(np.searchsorted(log["time_s"], switch["t_s"]))
    u = log["command_V"]
    assert abs(u[k] - u[k - 1]) <= 0.5  # bumpless
    assert np.percentile(np.abs(np.diff(u[k - 500:k])), 99) < 0.25  # the noise's share stays below that
    # and the gains did change there: the proportional action is Kc (b r - y)
    before, after = slice(k - 200, k), slice(k + 1, k + 200)
    e = log["reference_N"][before] - log["measured_N"][before]
    assert np.median(log["p_V"][before][np.abs(e) > 0.2] / e[np.abs(e) > 0.2]) == pytest.approx(0.3)
    np.testing.assert_allclose(log["p_V"][after], -0.5 * log["measured_N"][after], rtol=1e-6)


def _wait_for_the_loop(endpoint, t_s, timeout_s=120.0):
    """Until the served run's timeline has passed ``t_s`` (read from the server; a loaded host only makes it slower)."""
    t_end = time.monotonic() + timeout_s
    while asyncio.run(_read(endpoint, "SetPoint")) != 60.0 or asyncio.run(_read(endpoint, "State")) != "running":
        assert time.monotonic() < t_end, "the served run never reached its step"
        time.sleep(0.05)
    time.sleep(t_s)  # then some of the held level, for the samples before the switch


def test_serve_push_and_refusals(tmp_path, study, feedforward):
    sets, tampered = _gain_sets(tmp_path, study, feedforward)
    sha1 = read_artifact(sets["first"], "gain-set")["content_sha256"]
    sha2 = read_artifact(sets["second"], "gain-set")["content_sha256"]
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/piezopreload/"
    ready, stop, out = threading.Event(), threading.Event(), {}

    def serve():
        out["summary"] = serve_rig(sets["first"], endpoint=endpoint, users={USER: PASSWORD}, log_dir=tmp_path / "runs",
                                   ready=ready, stop=stop, **QUICK).to_dict()

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    try:
        assert ready.wait(120)  # liveness on a loaded host, not a timing bound
        _wait_for_the_loop(endpoint, 1.0)  # past the step (at 0.5 s), holding 60 N
        assert asyncio.run(_read(endpoint, "GainSetSha256")) == sha1
        reply = asyncio.run(push_gain_set(sets["second"].read_text(), endpoint, Credentials(USER, PASSWORD),
                                          expect_sha256=sha2))
        assert reply.server_parameters == {"CtrlP": 0.5, "CtrlTi": 0.05, "CtrlTd": 0.001}
        assert reply.server_gain_set_sha256 == sha2
        _refusals(endpoint, sets, tampered)
        assert asyncio.run(_read(endpoint, "GainSetSha256")) == sha2  # nothing the refusals sent changed it
        # a client written against the method's first form: PushGainSet with the document alone, as it declares
        assert asyncio.run(_input_arguments(endpoint, "PushGainSet")) == ["GainSetDocument"]
        assert asyncio.run(_input_arguments(endpoint, "PushGainSetWithNote")) == ["GainSetDocument", "Note",
                                                                                   "AcceptedMisses"]
        accepted, message = asyncio.run(_call_raw(endpoint, ua.Variant(sets["first"].read_text(),
                                                                       ua.VariantType.String)))
        assert accepted is True and f"accepted gain set {sha1[:12]}" in message, message
        t_end = time.monotonic() + 60.0
        while asyncio.run(_read(endpoint, "GainSetSha256")) != sha1:
            assert time.monotonic() < t_end, "the one-argument push never ran"
            time.sleep(0.05)
    finally:
        stop.set()
        server.join(60)
    s = out["summary"]
    assert s["status"] == "completed", s["trip"]
    _switched_bumplessly(s, sha2)


def test_push_needs_a_password_from_the_environment(tmp_path, study, feedforward, capsys, monkeypatch):
    gains = write_gain_set(tmp_path / "g.json", study, feedforward)
    monkeypatch.delenv("PIEZOPRELOAD_RIG_PASSWORD", raising=False)
    monkeypatch.setattr("sys.stdin.isatty", lambda: False)
    assert main(["rig", "push", str(gains), "--user", USER]) == 2
    assert "PIEZOPRELOAD_RIG_PASSWORD" in capsys.readouterr().err
    monkeypatch.setenv("PIEZOPRELOAD_RIG_PASSWORD", PASSWORD)
    assert (main(["rig", "push", str(gains), "--user", USER, "--endpoint",
                  f"opc.tcp://127.0.0.1:{_free_port()}/x/"]) == 2)
    assert "cannot reach" in capsys.readouterr().err


def _push_from_a_shell(gains, endpoint, password, *options):
    """``piezopreload rig push --json`` in a process of its own, the password in its environment."""
    env = {**os.environ, "PIEZOPRELOAD_RIG_PASSWORD": password}
    return subprocess.run([sys.executable, "-m", "piezopreload.cli", "rig", "push", str(gains), "--endpoint", endpoint,
                           "--user", USER, "--json", *options], env=env, capture_output=True, text=True, timeout=120)


def test_basic256sha256_channel_with_a_password(tmp_path, study, feedforward):
    """With a server certificate: only SignAndEncrypt; an unencrypted session is refused, an encrypted one pushes."""
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    async def make():
        await setup_self_signed_certificate(tmp_path / "server.pem", tmp_path / "server.der",
                                            "urn:freeopcua:python:server", "localhost",
                                            [ExtendedKeyUsageOID.SERVER_AUTH], {"commonName": "rig"})
        await setup_self_signed_certificate(tmp_path / "client.pem", tmp_path / "client.der", "urn:freeopcua:client",
                                            "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "bench"})

    asyncio.run(make())
    first = write_gain_set(tmp_path / "paper.json", study, feedforward)
    second = write_gain_set(tmp_path / "tuned.json", study, feedforward,
                            gains=PIDGains(Kc=0.4, Ti_s=0.06, Td_s=0.001, u_min_V=0.0, u_max_V=110.0))
    sha2 = read_artifact(second, "gain-set")["content_sha256"]
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/piezopreload/"
    ready, stop, out = threading.Event(), threading.Event(), {}

    def serve():
        out["summary"] = serve_rig(first, endpoint=endpoint, users={USER: PASSWORD}, log_dir=tmp_path / "runs",
                                   certificate=str(tmp_path / "server.der"), private_key=str(tmp_path / "server.pem"),
                                   ready=ready, stop=stop, **QUICK).to_dict()

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    secure = ["--certificate", str(tmp_path / "client.der"), "--private-key", str(tmp_path / "client.pem"),
              "--server-certificate", str(tmp_path / "server.der")]
    try:
        assert ready.wait(120)  # liveness on a loaded host, not a timing bound
        # the client is another process, as an operator's shell is: loading its 2048-bit RSA key
        # (cryptography checks the key) takes about 30 ms of C that holds the interpreter, and in
        # this process each push stalled the 1 kHz loop by 30-42 ms, near its 50-cycle interlock
        refused = _push_from_a_shell(second, endpoint, PASSWORD)  # no encryption offered: refused
        assert refused.returncode == 2 and refused.stderr.startswith("error: ") and refused.stdout == ""
        accepted = _push_from_a_shell(second, endpoint, PASSWORD, *secure)
        assert accepted.returncode == 0, accepted.stderr
        reply = json.loads(accepted.stdout)
        assert reply["server_parameters"]["CtrlP"] == 0.4 and reply["server_gain_set_sha256"] == sha2
        wrong = _push_from_a_shell(first, endpoint, "wrong", *secure)
        assert wrong.returncode == 2 and "refused the session" in wrong.stderr
    finally:
        stop.set()
        server.join(60)
    assert out["summary"]["status"] == "completed", out["summary"]["trip"]
    assert [p["user"] for p in out["summary"]["pushes"] if p["accepted"]] == [USER]


def _running(pid: int) -> bool:
    """The process exists and is not a zombie (a dead child its new parent has not reaped yet)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc (Linux)")
def test_the_server_runs_in_its_own_process_and_dies_with_the_supervisor(tmp_path, study, feedforward):
    """'rig serve' killed with SIGKILL: its OPC UA server process (niced, another pid) ends within its parent check."""
    from piezopreload.rig.opcua import PARENT_CHECK_S, SERVER_NICE

    gains = write_gain_set(tmp_path / "g.json", study, feedforward)
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/piezopreload/"
    env = {**os.environ, "PIEZOPRELOAD_RIG_PASSWORD": PASSWORD}
    proc = subprocess.Popen([sys.executable, "-m", "piezopreload.cli", "rig", "serve", str(gains), "--endpoint",
                             endpoint, "--user", USER, "--log-dir", str(tmp_path / "runs"), "--host-check-s", "0.2",
                             "--accept-host"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pid = None
    try:
        t_end = time.monotonic() + 120
        while pid is None:
            assert proc.poll() is None and time.monotonic() < t_end, "the server did not start"
            time.sleep(0.1)
            for side in (tmp_path / "runs").glob("*.json"):
                events = json.loads(side.read_text()).get("events", [])
                pid = next((e["pid"] for e in events if e["event"] == "server_started"), None)
        assert pid != proc.pid and _running(pid)
        # niceness stops at 19 (a test run itself under 'nice' leaves less room)
        parent = os.getpriority(os.PRIO_PROCESS, proc.pid)
        assert os.getpriority(os.PRIO_PROCESS, pid) == min(19, parent + SERVER_NICE)
        assert asyncio.run(_read(endpoint, "State")) in ("running", "idle")  # it serves the rig
        proc.send_signal(9)
        proc.wait(10)
        t_kill = time.monotonic()
        while _running(pid):  # it checks its parent every PARENT_CHECK_S; 30 s is liveness, not a timing bound
            assert time.monotonic() - t_kill < PARENT_CHECK_S + 30.0, "the server outlived its supervisor"
            time.sleep(0.02)
    finally:
        if proc.poll() is None:
            proc.kill()
        if pid is not None and _running(pid):
            os.kill(pid, 9)


def test_a_server_that_cannot_start_is_refused_before_the_loop_runs(tmp_path, study, feedforward, capsys, monkeypatch):
    """The endpoint's port taken: the server's process says why, 'rig serve' exits 2 and the rig was never armed."""
    gains = write_gain_set(tmp_path / "g.json", study, feedforward)
    monkeypatch.setenv("PIEZOPRELOAD_RIG_PASSWORD", PASSWORD)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["rig", "serve", str(gains), "--endpoint", f"opc.tcp://127.0.0.1:{port}/x/", "--user", USER,
                     "--log-dir", str(tmp_path / "runs"), "--host-check-s", "0.2", "--accept-host"]) == 2
    err = capsys.readouterr().err
    assert "error: rig serve: the OPC UA server could not start" in err and "address already in use" in err, err
    side = json.loads(next((tmp_path / "runs").glob("*.json")).read_text())
    assert side["status"] == "not started" and not any(e["event"] == "armed" for e in side["events"])


# --------------------------------------------------------------------------------------
# a retuned and a redesigned gain set pushed to a served rig
# --------------------------------------------------------------------------------------
#: a gain schedule on the setpoint where the served gain set had none (b = 0: the proportional action is -Kc(r) y, so
#: the log shows which gains run)
REDESIGNED = PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.001, Tf_s=0.01, b=0.0, u_min_V=0.0, u_max_V=110.0,
                      schedule=GainSchedule(levels_N=(40.0, 60.0, 100.0), Kc=(0.4, 0.6, 0.5), Ti_s=(0.06, 0.05, 0.05),
                                            Td_s=(0.001, 0.001, 0.001), b=(0.0, 0.0, 0.0)))
RETUNED = PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.001, Tf_s=0.01, b=0.0, u_min_V=0.0, u_max_V=110.0)


def _serve_in_thread(gains, endpoint, tmp_path, **options):
    """``rig serve`` in a thread: (thread, ready, stop, out) with ``out["summary"]`` when it has ended."""
    ready, stop, out = threading.Event(), threading.Event(), {}

    def serve():
        out["summary"] = serve_rig(gains, endpoint=endpoint, users={USER: PASSWORD}, log_dir=tmp_path / "runs",
                                   ready=ready, stop=stop, **QUICK, **options).to_dict()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return thread, ready, stop, out


def _push(path, endpoint, note=""):
    """``rig push`` from another process, as an operator's shell (a client in this process would share its
    interpreter with a Python loop at 1 kHz)."""
    sha = read_artifact(path, "gain-set")["content_sha256"]
    run = _push_from_a_shell(path, endpoint, PASSWORD, "--note", note)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout), sha


def _at_switch(log, event, period_s):
    """The switch in the log: the sample that took it, taken within one period of the request, without a bump."""
    assert event["cycle"] - event["requested_cycle"] in (0, 1), f"not taken within one period: {event}"
    k = int(np.searchsorted(log["time_s"], event["t_s"]))
    assert log["time_s"][k] == pytest.approx(event["cycle"] * period_s)
    u = log["command_V"]
    assert abs(u[k] - u[k - 1]) <= 0.5, f"the command jumps by {u[k] - u[k - 1]:.3g} V at the switch"
    assert np.percentile(np.abs(np.diff(u[k - 300:k])), 99) < 0.25  # the noise's share stays below that
    return k


@pytest.mark.parametrize("loop", ["native", "python"])
def test_a_retuned_and_a_redesigned_gain_set_switch_within_one_period_without_a_bump(tmp_path, study, feedforward,
                                                                                     loop):
    """The served rig (the paper's PID with its feedforward) takes a retuned PID, then a redesign with a gain schedule
    (another controller structure) whose study allows a higher force than the rig was armed with (the rig keeps its
    own, and says so); each switch is taken at the next cycle without a bump and the gains change there. A gain set
    for another plant, and a path sent instead of the document, are refused in a sentence."""
    quiet = replace(study.plant, noise_N=0.05)
    first = write_gain_set(tmp_path / "paper.json", study, feedforward, plant=quiet)
    retuned = write_gain_set(tmp_path / "retuned.json", study, feedforward, gains=RETUNED, plant=quiet)
    redesigned = write_gain_set(tmp_path / "redesigned.json", study, feedforward, gains=REDESIGNED, plant=quiet,
                                rig_interlocks=RigInterlocks(200.0, 10.0, 0.5, None,
                                                             {"force_max_N": "redesign.toml [rig_run]"}))
    elsewhere = write_gain_set(tmp_path / "elsewhere.json", study, feedforward, gains=RETUNED)  # the paper's 0.25 N
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/piezopreload/"
    thread, ready, stop, out = _serve_in_thread(first, endpoint, tmp_path, loop=loop)
    try:
        assert ready.wait(120)  # liveness on a loaded host, not a timing bound
        _wait_for_the_loop(endpoint, 1.0)
        reply, sha_retuned = _push(retuned, endpoint, note="retuned at Ms 1.4")
        assert reply["server_parameters"]["CtrlP"] == 0.5
        time.sleep(0.5)
        reply, sha_redesigned = _push(redesigned, endpoint)
        assert reply["server_gain_set_sha256"] == sha_redesigned
        time.sleep(0.5)
        refused = _push_from_a_shell(elsewhere, endpoint, PASSWORD)
        assert refused.returncode == 2 and re.search(r"validated on another plant .* a gain set runs only on the plant",
                                                     refused.stderr), refused.stderr
        accepted, message = asyncio.run(_call_raw(endpoint, ua.Variant(str(retuned), ua.VariantType.String),
                                                  ua.Variant("", ua.VariantType.String)))
        assert accepted is False and "not a path or a name" in message and str(retuned)[:40] in message
    finally:
        stop.set()
        thread.join(60)
    s = out["summary"]
    assert s["status"] == "completed", s["trip"]
    assert [p["accepted"] for p in s["pushes"]] == [True, True, False, False]
    side = RigRunRecord.load(s["log_json"])
    switches = [e for e in side.events if e["event"] == "gains_switched"]
    assert [e["gain_set_sha256"] for e in switches] == [sha_retuned, sha_redesigned]
    assert switches[0]["note"] == "retuned at Ms 1.4" and switches[0]["pushed_by"] == USER
    assert "a gain schedule of 3 entries" in switches[1]["controller"]
    assert switches[1]["interlocks_kept"][0].startswith("force_max_N: the rig keeps 143")
    log, dt = read_run_log(s["log_csv"]), study.plant.sample_period_s
    k1, k2 = (_at_switch(log, e, dt) for e in switches)
    y, p = log["measured_N"], log["p_V"]
    np.testing.assert_allclose(p[k1 + 1:k2], -0.5 * y[k1 + 1:k2], rtol=1e-6, err_msg="the retuned gains do not run")
    kc = np.interp(log["reference_N"][k2 + 1:k2 + 300], (40.0, 60.0, 100.0), (0.4, 0.6, 0.5))
    np.testing.assert_allclose(p[k2 + 1:k2 + 300], -kc * y[k2 + 1:k2 + 300], rtol=1e-6,
                               err_msg="the scheduled gains do not run")


# --------------------------------------------------------------------------------------
# the documentation's page: its client example and its address space
# --------------------------------------------------------------------------------------
_PAGE = Path(__file__).resolve().parents[1] / "docs" / "targets" / "rig-opcua.md"


def _page_example():
    text = _PAGE.read_text()
    block = text.split("<!-- client-example-start -->", 1)[1].split("<!-- client-example-end -->", 1)[0]
    return block.split("```python", 1)[1].rsplit("```", 1)[0]


def _page_nodes():
    """The address space as the page lists it: path -> (type, access)."""
    rows = re.findall(r"^\| `PreloadRig/([\w/]+)` \| (\w+) \| (\w+) \|", _PAGE.read_text(), re.MULTILINE)
    return {path: (kind, access) for path, kind, access in rows}


async def _served_nodes(endpoint):
    """Every node under PreloadRig as the server has it: path -> (type, access)."""
    client = Client(endpoint)
    client.set_user(USER)
    client.set_password(PASSWORD)
    out = {}
    async with client:
        idx = await client.get_namespace_index(NAMESPACE)
        root = await client.nodes.objects.get_child([f"{idx}:{ROOT}"])

        async def walk(node, prefix):
            for child in await node.get_children():
                name = (await child.read_browse_name()).Name
                kind = await child.read_node_class()
                if kind == ua.NodeClass.Object:
                    await walk(child, f"{prefix}{name}/")
                elif kind == ua.NodeClass.Method:
                    out[prefix + name] = ("Method", "call")
                elif kind == ua.NodeClass.Variable and (await child.read_browse_name()).NamespaceIndex == idx:
                    dtype = await child.read_data_type()
                    access = await child.read_attribute(ua.AttributeIds.UserAccessLevel)
                    writable = access.Value.Value & ua.AccessLevel.CurrentWrite.mask
                    out[prefix + name] = (ua.ObjectIdNames[dtype.Identifier], "write" if writable else "read")
        await walk(root, "")
    return out


def test_the_pages_client_example_pushes_and_the_address_space_is_the_pages(tmp_path, study, feedforward):
    """docs/targets/rig-opcua.md: its Python client pushes a retuned gain set to a served rig, and its table of the
    address space is the server's, node for node (type and access)."""
    first = write_gain_set(tmp_path / "paper.json", study, feedforward)
    retuned = write_gain_set(tmp_path / "retuned.json", study, feedforward, gains=RETUNED)
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/piezopreload/"
    thread, ready, stop, out = _serve_in_thread(first, endpoint, tmp_path)
    namespace: dict = {}
    exec(compile(_page_example(), str(_PAGE), "exec"), namespace)
    try:
        assert ready.wait(120)  # liveness on a loaded host, not a timing bound
        _wait_for_the_loop(endpoint, 0.2)
        served = asyncio.run(_served_nodes(endpoint))
        running = asyncio.run(namespace["push"](endpoint, USER, PASSWORD, str(retuned), "from the docs"))
    finally:
        stop.set()
        thread.join(60)
    assert served == _page_nodes(), "the page's address space is not the server's"
    assert running == read_artifact(retuned, "gain-set")["content_sha256"]
    assert out["summary"]["pushes"][0]["note"] == "from the docs" and out["summary"]["status"] == "completed"
