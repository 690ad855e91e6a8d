"""The rig executor: compiled step, bumpless switch, interlocks by fault injection, run log, plug-ins."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigkit import INTERLOCK_FAULTS, write_gain_set

from piezopreload.artifacts.gainset import GainSet
from piezopreload.cli import main
from piezopreload.core.artifacts import read_artifact
from piezopreload.models.actuator import Rig
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.hysteresis import AsymmetricPI, ClassicalPI, Creep, CreepPI, ModifiedPI
from piezopreload.rig.backends import Fault, FaultInjector, SimBackend, open_backend
from piezopreload.rig.compiled import PythonStep, controller_step
from piezopreload.rig.executor import Executor, Safety
from piezopreload.rig.runlog import RunLog, read_run_log
from piezopreload.rig.session import run as run_rig

DT = 1e-3


@pytest.fixture(scope="module")
def gains_path(tmp_path_factory, study, feedforward):
    return write_gain_set(tmp_path_factory.mktemp("gains") / "gains.json", study, feedforward)


def _controller(ff=None, **kw):
    g = dict(Kc=1.4, Ti_s=0.05, Td_s=0.004, Tf_s=0.02, b=0.3)
    g.update(kw)
    return Controller(PIDGains(**g), DT, ff)


@pytest.mark.parametrize("creep, extra", [(False, False), (True, False), (False, True), (True, True)])
def test_compiled_step_equals_the_numpy_step_through_a_switch(creep, extra):
    """The C step (CasADi codegen, ctypes) against the numpy step, before and after a gain/model switch;
    classical feedforwards, then the paper's asymmetric model with creep switching to the modified one with creep;
    with ``extra`` a learned signal's ff_extra per sample (the C entry point's input) from the start on."""
    if creep:
        bank = Creep([0.01, 0.1, 1.0], [0.03, 0.02, 0.04], DT)
        r, w = np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05])
        ff1 = CreepPI(AsymmetricPI(r, w, w * np.array([1.1, 0.8, 1.2, 0.9]), 25.0), bank).inverse()
        ff2 = CreepPI(ModifiedPI(r, w, [-6.0, 0.0, 5.0], [0.2, 1.0, -0.3], bias=-1.0, offset=24.0), bank).inverse()
    else:
        ff1 = ClassicalPI(np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05]), 25.0).inverse()
        ff2 = ClassicalPI(np.array([0.0, 5.0, 15.0, 30.0]), np.array([0.5, 0.1, 0.1, 0.02]), 24.0).inverse()
    c1, c2 = _controller(ff1), _controller(ff2, Kc=0.8, Ti_s=0.08, b=1.0)
    fast = controller_step(c1)
    if fast.kind != "c":
        pytest.skip("no working C compiler on this machine: the executor runs the numpy step")
    slow = PythonStep(c1)
    rng = np.random.default_rng(3)
    sp = np.repeat([25.0, 60.0, 120.0, 40.0], 500)
    pv = np.convolve(sp, np.ones(40) / 40, mode="same") + 0.3 * rng.standard_normal(sp.size)
    fx = 4.0 * np.sin(np.arange(sp.size) * 0.013) + rng.standard_normal(sp.size) if extra else np.zeros(sp.size)
    fast.start(sp[0], pv[0], 0.0, fx[0])
    slow.start(sp[0], pv[0], 0.0, fx[0])
    out = []
    for k in range(sp.size):
        if k == 1000:
            fast.switch(c2)
            slow.switch(c2)
        out.append((fast.step(sp[k], pv[k], fx[k]), slow.step(sp[k], pv[k], fx[k])))
    a, b = (np.array(x) for x in zip(*out))
    assert np.max(a[:, 0]) == 110.0  # the clamp and the anti-windup are exercised
    if extra:  # the signal reaches the output: the feedforward term differs from the run without it by fx
        plain = PythonStep(c1)
        plain.start(sp[0], pv[0], 0.0, fx[0])
        assert plain.step(sp[0], pv[0])[4] == pytest.approx(b[0, 4] - fx[0], abs=1e-12), "ff_extra is not in ff"
    # the C code and numpy evaluate the same float64 expressions, in another order: agreement to rounding
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg="the compiled step and the numpy step differ")


@pytest.mark.parametrize("new_ff", [False, True])
def test_switch_is_bumpless(new_ff):
    """After switch(), the new controller's output at the last sample's inputs is the old one's last output."""
    ff1 = ClassicalPI(np.array([0.0, 10.0]), np.array([0.5, 0.2]), 25.0).inverse()
    ff2 = ClassicalPI(np.array([0.0, 12.0]), np.array([0.4, 0.3]), 23.0).inverse() if new_ff else ff1
    old, new = _controller(ff1), _controller(ff2, Kc=0.6, Td_s=0.01, b=1.0)
    state = old.initial_state(25.0, 25.0, u0=0.0)
    for y in np.linspace(25.0, 58.0, 200):
        terms, state = old.step_terms(state, 60.0, y)
    last = float(terms.u)
    switched = old.switch(state, new)
    # the same inputs once more: no derivative (pv unchanged), and the integral's increment is the same
    # trapezoid under both gains' Kc/Ti; remove it to compare the actions
    u_new, _ = new.step(switched, 60.0, 58.0)
    inc_new = new.gains.Kc / new.gains.Ti_s * 0.5 * 2 * (60.0 - 58.0) * DT
    dpv_decay = -new.gains.Kc * new.gains.Td_s * (new.gains.Tf_s / (new.gains.Tf_s + DT) - 1.0) * float(state.dpv)
    assert float(u_new) - inc_new - dpv_decay == pytest.approx(last, abs=1e-9)
    # without the switch the gains' change would jump the output by the change of the P action
    u_jump, _ = new.step(state, 60.0, 58.0)
    assert abs(float(u_jump) - float(u_new)) > 0.5


def test_rig_run_reproduces_the_simulation(gains_path, study, tmp_path, capsys):
    """'rig run --fast' on the simulated backend gives simulate's step metrics within one sample."""
    assert main(["rig", "run", str(gains_path), "--fast", "--log-dir", str(tmp_path), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    sim = study.simulate(GainSet.load(gains_path), reference="step").to_dict()
    for key in ("rise_s", "peak_s", "settling_s"):
        assert r["metrics"][key] == pytest.approx(sim[key], abs=DT), key
    assert r["metrics"]["overshoot_N"] == pytest.approx(sim["overshoot_N"], abs=study.plant.adc_lsb_N)
    assert r["status"] == "completed" and r["cycles"] == 10_001
    side = read_artifact(r["log_json"], "rig-run")
    assert side["gain_set_sha256"] == read_artifact(gains_path, "gain-set")["content_sha256"]
    assert side["status"] == "completed" and side["summary"]["cycles"] == 10_001


def _run(gains_path, tmp_path, faults, realtime=False, reference="step", **safety):
    return run_rig(gains_path, realtime=realtime, log_dir=tmp_path, faults=faults, reference=reference,
                   safety=safety).to_dict()


@pytest.mark.parametrize("fault, cause", INTERLOCK_FAULTS)
def test_each_interlock_ramps_down_disarms_and_logs(gains_path, tmp_path, fault, cause):
    r = _run(gains_path, tmp_path, [fault], ramp_s=0.25)
    assert r["status"] == "tripped" and r["exit_code"] == 3 and r["trip"]["cause"] == cause
    t_trip = r["trip"]["t_s"]
    stale_s = 0.01 if cause == "sensor_stale" else 0.0  # stale: tripped once the sample is older than the limit
    assert fault.at_s <= t_trip <= fault.at_s + stale_s + 2 * DT
    log = read_run_log(r["log_csv"])
    # nothing lost: every sample from 0 to the end of the ramp, one per period
    np.testing.assert_allclose(np.diff(log["time_s"]), DT, atol=1e-6)
    assert log["time_s"][0] == 0.0
    ramp = log["mode"] == 1
    assert log["mode"][~ramp][-1] == 2  # the sample that tripped, then the ramp
    v = log["voltage_V"]
    assert v[ramp][-1] == 0.0 and log["time_s"][ramp][-1] - t_trip <= 0.25 + DT
    assert np.all(np.diff(v[ramp]) <= 1e-9)  # monotone down from where it was
    assert v[~ramp][-1] > 5.0  # it had somewhere to ramp from
    side = json.loads(Path(r["log_json"]).read_text())
    events = {e["event"]: e for e in side["events"]}
    assert events["interlock"]["cause"] == cause and "ramped_down" in events and "disarmed" in events
    assert side["status"] == "tripped" and side["summary"]["trip"]["cause"] == cause


def test_missed_deadline_streak_stops_a_realtime_run(gains_path, tmp_path):
    r = _run(gains_path, tmp_path, [Fault("delay", 0.3, 0.003)], realtime=True, missed_streak=5, ramp_s=0.05)
    assert r["trip"]["cause"] == "deadline" and r["timing"]["missed_deadlines"] >= 5
    log = read_run_log(r["log_csv"])
    assert log["missed"][log["mode"] == 0][-5:].tolist() == [1] * 5
    np.testing.assert_allclose(np.diff(log["time_s"]), DT, atol=1e-6)
    assert log["voltage_V"][-1] == 0.0


def test_clamp_and_slew_limit_shape_every_command(gains_path, tmp_path):
    r = _run(gains_path, tmp_path, [], v_max_V=40.0, slew_V_per_s=2000.0, force_max_N=150.0)
    assert r["status"] == "completed" and r["clamped_cycles"] > 0
    log = read_run_log(r["log_csv"])
    # a run that reaches its end ramps down right after its last sample: nothing skipped
    np.testing.assert_allclose(np.diff(log["time_s"]), DT, atol=1e-6)
    assert log["voltage_V"][-1] == 0.0
    v = log["voltage_V"]
    assert v.max() == pytest.approx(40.0) and np.max(np.abs(np.diff(v))) <= 2.0 + 1e-9
    assert np.nanmax(log["command_V"]) > 40.0  # the controller asked for more


def test_sim_backend_is_the_closed_loop_simulation(study, feedforward):
    """The executor on SimBackend, sample by sample, against models.closedloop.simulate with the same seed.

    The amplifier's voltage is compared: what the stacks see, and what a lost or doubled sample would shift.
    """
    from piezopreload.models.closedloop import simulate

    c = Controller(study.gains, DT, feedforward.inverse())
    ref = study.references["step"]
    sim = simulate(Rig(study.plant), c, ref, seed=7)
    backend = SimBackend(study.plant, seed=7)
    amp = []

    class Probe(FaultInjector):
        def write_voltage(self, volts):
            amp.append(self.inner.amplifier_V)
            super().write_voltage(volts)

    ex = Executor(c, Probe(backend, []), ref, Safety(), realtime=False, step="numpy")
    assert ex.run().ok
    # the same noise draws, sample for sample; the one difference: the executor starts its controller
    # bumplessly on the first *reading* (a real rig has nothing else), simulate on the true rest force,
    # an offset of a few hundredths of a newton that the integral carries as a few millivolts
    assert len(amp) == sim.t_s.size + 500  # and then the 0.5 s ramp down
    np.testing.assert_allclose(amp[:sim.t_s.size], sim.voltage_V, rtol=0, atol=0.01)


def test_run_logs_never_overwrite_and_refuse_candidates(gains_path, study, feedforward, tmp_path, capsys):
    a = RunLog(tmp_path, "x", {})
    b = RunLog(tmp_path, "x", {})
    assert a.csv_path != b.csv_path and a.json_path != b.json_path
    cand = write_gain_set(tmp_path / "cand.json", study, feedforward, status="candidate")
    assert main(["rig", "run", str(cand), "--fast"]) == 2
    assert "not 'validated'" in capsys.readouterr().err
    doc = json.loads(gains_path.read_text())
    doc["gains"]["Kc_V_per_N"] = 3.0
    tampered = tmp_path / "tampered.json"
    tampered.write_text(json.dumps(doc))
    assert main(["rig", "run", str(tampered), "--fast"]) == 2
    assert "content_sha256" in capsys.readouterr().err
    assert main(["rig", "run", str(gains_path), "--backend", "nosuch"]) == 2
    assert "not installed" in capsys.readouterr().err


def test_reference_from_csv(gains_path, tmp_path, capsys):
    ref = tmp_path / "ref.csv"
    ref.write_text("time_s,force_N\n0,25\n0.2,45\n0.6,45\n")
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref), "--log-dir", str(tmp_path), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    log = read_run_log(r["log_csv"])
    control = log["mode"] == 0
    assert log["time_s"][control][-1] == pytest.approx(1.0) and set(log["reference_N"][control]) == {25.0, 45.0}
    ref.write_text("time_s,force_N\n0,25\n0.2,nan\n")
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref)]) == 2
    assert f"{ref}:3: column 'force_N'" in capsys.readouterr().err


_PLUGIN = '''
from piezopreload.models.actuator import RigParams
from piezopreload.rig.backends import SimBackend

class QuietRig(SimBackend):
    name = "quietrig"

def make(options):
    return QuietRig(RigParams(noise_N=0.0), seed=int(options.get("seed", 0)))

def broken(options):
    raise RuntimeError("no card")

class CardRig:  # hardware: no 'simulated' attribute
    name = "cardrig"
    def arm(self):
        raise AssertionError("a hardware backend was armed for a run back to back")
    def read_force(self, t_s):
        raise AssertionError("read")
    def write_voltage(self, volts):
        raise AssertionError("written")
    def disarm(self):
        pass

def card(options):
    return CardRig()
'''


def test_hardware_backends_are_entry_point_plugins(gains_path, tmp_path, monkeypatch, capsys):
    """A package with an entry point in 'piezopreload.rig_backends' (installed as a dist-info on sys.path)."""
    (tmp_path / "quietrig_plugin.py").write_text(_PLUGIN)
    dist = tmp_path / "quietrig_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: quietrig-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[piezopreload.rig_backends]\nquietrig = quietrig_plugin:make\n"
                                           "brokenrig = quietrig_plugin:nosuchname\ncardrig = quietrig_plugin:card\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    backend = open_backend("quietrig", {"seed": "3"})
    assert backend.name == "quietrig" and backend.seed == 3
    assert main(["rig", "run", str(gains_path), "--backend", "quietrig", "--fast", "--log-dir", str(tmp_path), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["backend"] == "quietrig" and r["status"] == "completed"
    assert main(["rig", "run", str(gains_path), "--backend", "brokenrig", "--fast"]) == 2
    assert "cannot be loaded" in capsys.readouterr().err
    # hardware never runs back to back
    assert main(["rig", "run", str(gains_path), "--backend", "cardrig", "--fast", "--log-dir", str(tmp_path)]) == 2
    assert "'cardrig' does not declare itself a simulation" in capsys.readouterr().err


def _spawn(args, tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "piezopreload.cli", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_rows(log_dir, rows, timeout=30.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        csvs = list(log_dir.glob("run-*.csv"))
        if csvs and csvs[0].read_text().count("\n") > rows:
            return csvs[0]
        time.sleep(0.05)
    raise AssertionError("the run log did not grow")


def test_sigint_ramps_down_and_exits_3(gains_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _spawn(["rig", "run", str(gains_path), "--realtime", "--log-dir", str(log_dir), "--ramp-s", "0.2"], tmp_path)
    _wait_for_rows(log_dir, 1000)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 3, err
    side = json.loads(next(log_dir.glob("run-*.json")).read_text())
    trip = next(e for e in side["events"] if e["event"] == "interlock")
    assert trip["cause"] == "signal" and trip["detail"] == "SIGINT"
    log = read_run_log(next(log_dir.glob("run-*.csv")))
    assert log["voltage_V"][-1] == 0.0 and log["time_s"][-1] - trip["t_s"] <= 0.2 + DT


def test_sigkill_leaves_a_readable_log_up_to_the_last_flush(gains_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _spawn(["rig", "run", str(gains_path), "--realtime", "--log-dir", str(log_dir)], tmp_path)
    csv = _wait_for_rows(log_dir, 200)
    # watch the file grow for a second: it must grow at least every 100 ms (flushes every 50 ms)
    seen, t_seen, gaps = csv.stat().st_size, time.monotonic(), []
    t_end = t_seen + 1.0
    while time.monotonic() < t_end:
        time.sleep(0.005)
        size = csv.stat().st_size
        if size != seen:
            now = time.monotonic()
            gaps.append(now - t_seen)
            seen, t_seen = size, now
    proc.kill()
    proc.communicate(timeout=30)
    assert len(gaps) >= 8 and max(gaps) < 0.2, gaps  # 0.1 s plus this machine's scheduling jitter
    log = read_run_log(csv)
    assert log["time_s"].size >= 1000 and np.all(np.diff(log["time_s"]) == pytest.approx(DT, abs=1e-6))
    assert csv.stat().st_size >= seen  # nothing that was on disk before the kill is gone
    side = json.loads(next(log_dir.glob("run-*.json")).read_text())
    assert side["status"] == "running" and side["events"][0]["event"] == "armed"


def test_safety_settings_are_checked():
    with pytest.raises(ValueError, match="safe_V"):
        Safety(safe_V=-5.0)
    with pytest.raises(ValueError, match="finite"):
        Safety(force_max_N=math.nan)
    with pytest.raises(ValueError, match="sensor_min_N"):
        replace(Safety(), force_max_N=2000.0)


@pytest.mark.parametrize("kind", ["classical", "modified"])
def test_compiled_feedforward_compensates_a_creeping_model(kind):
    """The compiled step's feedforward term through the forward model with creep gives the setpoint back to 1e-9."""
    r, w = np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05])
    h = ClassicalPI(r, w, 25.0) if kind == "classical" else ModifiedPI(r, w, [-6.0, 0.0, 5.0], [0.2, 1.0, -0.3],
                                                                         bias=-1.0, offset=24.0)
    model = CreepPI(h, Creep([0.01, 0.1, 1.0], [0.03, 0.02, 0.04], DT))
    fast = controller_step(_controller(model.inverse()))
    if fast.kind != "c":
        pytest.skip("no working C compiler on this machine: the executor runs the numpy step")
    t = np.arange(0, 4, DT)
    sp = 45 + 15 * np.sin(2 * np.pi * 1.3 * t) * np.exp(-0.4 * t) + 10 * (t > 2)
    fast.start(sp[0], sp[0], 0.0)
    ff = np.array([fast.step(s, s)[4] for s in sp])
    np.testing.assert_allclose(model(ff), sp, rtol=1e-9, atol=0, err_msg=f"{kind}+creep: model(compiled feedforward) != setpoint")
