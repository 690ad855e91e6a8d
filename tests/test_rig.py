"""The rig executor: compiled step, bumpless switch, interlocks by fault injection, the limits' sources (the gain
set's study, the command line, the plant), a tripped run's report, the typed run log, the host check, plug-ins."""

import io
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigkit import INTERLOCK_FAULTS, STALL_LIMIT_S, write_gain_set

from piezopreload.artifacts.gainset import GainSet, RigInterlocks
from piezopreload.artifacts.registry import read_artifact
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.validation import Criteria
from piezopreload.cli import main
from piezopreload.core.errors import ArtifactError, InputError
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
    side = RigRunRecord.load(r["log_json"])
    assert side.gain_set_sha256 == read_artifact(gains_path, "gain-set")["content_sha256"]
    assert side.status == "completed" and side.summary.cycles == 10_001 and side.trip is None
    assert side.summary.metrics.settling_s == r["metrics"]["settling_s"], "the sidecar's figures are not the run's"


def _run(gains_path, tmp_path, faults, realtime=False, reference="step", **safety):
    return run_rig(gains_path, realtime=realtime, log_dir=tmp_path, faults=faults, reference=reference,
                   safety=safety, host_check_s=0.2).to_dict()


@pytest.mark.parametrize("fault, cause", INTERLOCK_FAULTS)
def test_each_interlock_ramps_down_disarms_and_logs(gains_path, tmp_path, fault, cause):
    r = _run(gains_path, tmp_path, [fault], ramp_s=0.25, stall_limit_s=STALL_LIMIT_S)
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
    side = RigRunRecord.load(r["log_json"])
    by_kind = {e["event"]: e for e in side.events}
    assert by_kind["interlock"]["cause"] == cause and "ramped_down" in by_kind and "disarmed" in by_kind
    assert side.status == "tripped" and side.trip.cause == cause
    # the interlock event holds the voltage at the trip: the last one written, where the log shows it
    trip_row = int(np.flatnonzero(log["mode"] == 2)[0])
    assert by_kind["interlock"]["voltage_V"] == pytest.approx(log["voltage_V"][trip_row], rel=1e-8)
    assert by_kind["interlock"]["voltage_V"] == side.trip.voltage_V == r["trip"]["voltage_V"] > 5.0
    # a tripped run reports its trip, not step metrics: --json, the sidecar
    assert r["metrics"] is None and side.summary.metrics is None


def test_a_tripped_run_prints_its_trip_and_no_step_metrics(gains_path, tmp_path, capsys):
    """The CLI's text of a tripped run: the interlock, its time and the voltage held, and no 'step:' line."""
    assert main(["rig", "run", str(gains_path), "--fast", "--log-dir", str(tmp_path), "--inject", "offset@1=200"]) == 3
    out = capsys.readouterr().out
    assert "stopped by interlock 'force_high' at t = 1.000 s with" in out and "V held" in out
    assert "step:" not in out and "settling" not in out, out
    assert main(["rig", "run", str(gains_path), "--fast", "--log-dir", str(tmp_path)]) == 0
    assert "step: rise" in capsys.readouterr().out


def test_clamp_and_slew_limit_shape_every_command(study, feedforward, tmp_path):
    log = RunLog(tmp_path, "clamp")
    c = Controller(study.controller, DT, feedforward.inverse())
    ex = Executor(c, SimBackend(study.plant), study.references["step"], Safety(v_max_V=40.0, slew_V_per_s=2000.0),
                  realtime=False, log=log)
    r = ex.run()
    assert r.status == "completed" and r.clamped_cycles > 0
    log = read_run_log(log.csv_path)
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

    c = Controller(study.controller, DT, feedforward.inverse())
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
    a = RunLog(tmp_path, "x")
    b = RunLog(tmp_path, "x")
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
    assert (main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref), "--log-dir",
                  str(tmp_path), "--json"]) == 0)
    r = json.loads(capsys.readouterr().out)
    log = read_run_log(r["log_csv"])
    control = log["mode"] == 0
    assert log["time_s"][control][-1] == pytest.approx(1.0) and set(log["reference_N"][control]) == {25.0, 45.0}
    ref.write_text("time_s,force_N\n0,25\n0.2,nan\n")
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref)]) == 2
    assert f"{ref}:3: column 'force_N'" in capsys.readouterr().err


_PLUGIN = '''
from piezopreload.models.actuator import Plant
from piezopreload.rig.backends import SimBackend

class QuietRig(SimBackend):
    name = "quietrig"

def make(options):
    return QuietRig(Plant(noise_N=0.0), seed=int(options.get("seed", 0)))

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
    assert (main(["rig", "run", str(gains_path), "--backend", "quietrig", "--fast", "--log-dir",
                  str(tmp_path), "--json"]) == 0)
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


@pytest.mark.slow
@pytest.mark.realtime
def test_sigint_ramps_down_and_exits_3(gains_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _spawn(["rig", "run", str(gains_path), "--realtime", "--log-dir", str(log_dir), "--ramp-s", "0.2",
                   "--host-check-s", "0.2", "--accept-host"], tmp_path)
    _wait_for_rows(log_dir, 1000)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 3, err
    side = RigRunRecord.load(next(log_dir.glob("run-*.json")))
    trip = next(e for e in side.events if e["event"] == "interlock")
    assert trip["cause"] == "signal" and trip["detail"] == "SIGINT"
    log = read_run_log(next(log_dir.glob("run-*.csv")))
    assert log["voltage_V"][-1] == 0.0 and log["time_s"][-1] - trip["t_s"] <= 0.2 + DT


@pytest.mark.slow
@pytest.mark.realtime
def test_sigkill_leaves_a_readable_log_up_to_the_last_flush(gains_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _spawn(["rig", "run", str(gains_path), "--realtime", "--log-dir", str(log_dir), "--host-check-s", "0.2",
                   "--accept-host"], tmp_path)
    csv = _wait_for_rows(log_dir, 1000)
    seen = csv.stat().st_size
    proc.kill()
    proc.communicate(timeout=30)
    log = read_run_log(csv)
    assert log["time_s"].size >= 1000 and np.all(np.diff(log["time_s"]) == pytest.approx(DT, abs=1e-6))
    assert csv.stat().st_size >= seen  # nothing that was on disk before the kill is gone
    side = RigRunRecord.load(next(log_dir.glob("run-*.json")))
    assert side.status == "running" and side.events[0]["event"] == "armed" and side.summary is None


def test_the_run_log_flushes_within_flush_s_on_its_clock(tmp_path):
    """On an injected clock (the times given to sample()): after any sample, no row older than flush_s is still
    waiting to be written, and the rows written are whole lines a reader takes."""
    log = RunLog(tmp_path, "flush", flush_s=0.05)
    t0 = time.monotonic()
    times = t0 + 0.003 * np.arange(400)
    for k, now in enumerate(times):
        log.sample((k * DT, 25.0, 25.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, DT, 0.0, 0.0, 0, 0), float(now))
        written = read_run_log(log.csv_path)["time_s"].size
        waiting = times[written:k + 1]
        assert waiting.size == 0 or now - waiting[0] < 0.05 + 1e-9, f"a row waited {now - waiting[0]:.3f} s unwritten"
    assert 0 < written < 400, "nothing or everything flushed: the test shows nothing"
    log.flush()


def test_safety_settings_are_checked():
    with pytest.raises(ValueError, match="safe_V"):
        Safety(safe_V=-5.0)
    with pytest.raises(ValueError, match="finite"):
        Safety(force_max_N=math.nan)
    with pytest.raises(ValueError, match="sensor_min_N"):
        replace(Safety(), force_max_N=2000.0)
    with pytest.raises(ValueError, match="stall_limit_s"):
        Safety(stall_limit_s=0.0)


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
    np.testing.assert_allclose(model(ff), sp, rtol=1e-9, atol=0,
                               err_msg=f"{kind}+creep: model(compiled feedforward) != setpoint")


# ---- the limits: the gain set's study's, the command line's, the plant's ------------------------------------------
_STUDY_INTERLOCKS = RigInterlocks(130.0, 12.0, 0.3, None,
                                  {"force_max_N": "study.toml [rig_run] force_max_N",
                                   "force_low_margin_N": "study.toml [rig_run] force_low_margin_N",
                                   "ramp_s": "study.toml [rig_run] ramp_s"})


def test_the_rig_takes_its_limits_from_the_gain_sets_study_and_the_command_line_overrides(study, feedforward, tmp_path,
                                                                                          capsys):
    """A gain set carrying its study's [rig_run] (force_max_N 130 N, margin 12 N, ramp 0.3 s): the run uses them and
    says so in the sidecar; an offset of 80 N at 60 N trips at 130 N; --force-max-N overrides it, named as such."""
    gains = write_gain_set(tmp_path / "g.json", study, feedforward, rig_interlocks=_STUDY_INTERLOCKS)
    r = _run(gains, tmp_path / "a", [Fault("offset", 1.0, 80.0)])
    side = RigRunRecord.load(r["log_json"])
    assert side.safety.force_max_N == 130.0 and side.safety.force_low_margin_N == 12.0
    assert side.safety.ramp_s == 0.3
    assert side.safety_sources.force_max_N == "the gain set: study.toml [rig_run] force_max_N"
    assert side.safety_sources.bolt_preload_N == "the gain set's plant"
    assert r["trip"]["cause"] == "force_high" and "above the limit 130 N" in r["trip"]["detail"]
    log = read_run_log(r["log_csv"])
    assert log["time_s"][-1] - r["trip"]["t_s"] == pytest.approx(0.3, abs=1.5 * DT), "the study's ramp time"
    assert main(["rig", "run", str(gains), "--fast", "--log-dir", str(tmp_path / "b"), "--inject", "offset@1=80",
                 "--force-max-N", "170", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["interlocks"]["force_max_N"] == 170.0
            and r["interlock_sources"]["force_max_N"] == "the command line (--force-max-N)")
    assert r["interlock_sources"]["ramp_s"] == "the gain set: study.toml [rig_run] ramp_s"


def test_a_gain_set_without_study_limits_gets_them_from_its_plant_not_the_paper_rig(study, feedforward, tmp_path):
    """No [rig_run] in the gain set: force_max_N is derived from its plant (1.25 x what its stacks reach), and the
    low margin (1 % of that reach), here on a stiffer rig whose references reach 1,500 N, far beyond the paper
    rig's 150 N."""
    from piezopreload.models.actuator import reach_N
    from piezopreload.models.closedloop import Reference

    stiff = replace(study.plant, coupling_stiffness_N_per_um=60.0, adc_full_scale_N=5000.0)
    reach = float(reach_N(Rig(stiff), stiff.stack.v_max_V))
    GainSet(gains=replace(study.controller, Kc=0.05), status="validated", feedforward=None, plant=stiff, preset="stiff",
                references={"step": Reference.step(25.0, 1500.0, 0.5, 1.5),
                            "trajectory": study.references["trajectory"]},
                criteria=Criteria(band_N=study.band_N)).save(tmp_path / "stiff.json")
    r = run_rig(tmp_path / "stiff.json", realtime=False, log_dir=tmp_path).to_dict()
    assert r["interlocks"]["force_max_N"] == pytest.approx(1.25 * reach) and reach > 1500.0
    assert r["interlock_sources"]["force_max_N"].startswith("derived: 1.25 x the")
    assert r["status"] == "completed", r["trip"]
    # the low margin too is the plant's: 1 % of its stacks' reach, more than the executor's 10 N here
    assert r["interlocks"]["force_low_margin_N"] == pytest.approx(0.01 * reach) and 0.01 * reach > 10.0
    outside = r"1500 N is outside the rig's safe force range \(([0-9.]+) N, 1400 N\)"
    with pytest.raises(InputError, match=outside) as exc:
        run_rig(tmp_path / "stiff.json", realtime=False, log_dir=tmp_path, safety={"force_max_N": 1400.0})
    low = float(re.search(r"range \(([0-9.]+) N", str(exc.value)).group(1))
    assert low == pytest.approx(25.0 - 0.01 * reach, rel=1e-4), "the floor is not the bolt preload less the margin"


def test_a_candidate_carries_its_studys_rig_run_limits_through_validation(study, feedforward, tmp_path):
    """The candidate gain set (piezopreload.steps.candidate) puts the study's [rig_run] interlock keys into the gain
    set (the others derived, named as such); the verdict keeps them and the saved gain set reads them back."""
    from piezopreload import steps
    from piezopreload.artifacts.tuning import MinimumTimeBound, TrackingFloor, TuningResult, TuningSolve
    from piezopreload.tuning.verdict import validate_gain_set

    changed = study.replace(rig_run={"force_max_N": 130.0, "ramp_s": 0.3})
    solve = TuningSolve("given", 0, 0.0, "none", 0.0, 0.0, 1.0, (), {}, {})  # the study's gains, not tuned here
    tuned = TuningResult(study.controller, study.controller, solve, (),
                         MinimumTimeBound(None, None, reason="not computed"), TrackingFloor(1.0, 1.0, None))
    candidate = steps.candidate(changed, changed.solved, tuned, changed.identify_feedforward())
    carried = candidate.rig_interlocks
    assert (carried.force_max_N, carried.ramp_s, carried.force_low_margin_N) == (130.0, 0.3, 10.0)
    assert carried.sources["force_max_N"] == f"{changed.path} [rig_run] force_max_N"
    assert carried.sources["force_low_margin_N"] == "the executor's default" and carried.stall_limit_s is None
    judged, _ = validate_gain_set(candidate, n_plants=2, seed=0, workers=1)
    back = judged.save(tmp_path / "g.json")
    assert GainSet.load(tmp_path / "g.json").rig_interlocks == carried == back.rig_interlocks


def test_a_study_sets_a_stall_limit_only_below_the_plants(study, feedforward, tmp_path):
    """[rig_run] stall_limit_s (carried by the gain set) or --stall-limit-s may shorten the plant's limit, never
    lengthen it; the simulated watchdog's timeout shortens it too. The sidecar says which."""
    carried = replace(_STUDY_INTERLOCKS, stall_limit_s=0.05,
                      sources={**_STUDY_INTERLOCKS.sources, "stall_limit_s": "study.toml [rig_run] stall_limit_s"})
    gains = write_gain_set(tmp_path / "g.json", study, feedforward, rig_interlocks=carried)
    side = RigRunRecord.load(_run(gains, tmp_path / "a", [])["log_json"])
    assert side.safety.stall_limit_s == 0.05 and side.stall_limit.limit_s == 0.05
    assert side.stall_limit.source == "the gain set: study.toml [rig_run] stall_limit_s"
    assert side.stall_limit.plant_limit_s is None and side.stall_limit.horizon_s == pytest.approx(1.0)
    with pytest.raises(InputError, match="exceeds what the plant tolerates"):
        _run(gains, tmp_path / "b", [], stall_limit_s=5.0)
    r = run_rig(gains, realtime=False, log_dir=tmp_path / "c", backend_options={"watchdog_s": "0.02"}).to_dict()
    assert r["interlocks"]["stall_limit_s"] == 0.02 and "watchdog" in r["interlock_sources"]["stall_limit_s"]


# ---- the stall limit from the plant ---------------------------------------------------------------------------------
def test_the_stall_limit_is_the_held_forces_first_exit_from_the_margin(study, feedforward):
    """Checked against a hold simulated again on the numpy plant: from the binding state of the nominal run, the force
    with the command held stays inside the margin for the limit and leaves it one sample later; a tighter force limit
    gives a shorter stall limit; with no exit inside the horizon the limit is the horizon."""
    from piezopreload.models.closedloop import simulate
    from piezopreload.rig.stall import HORIZON_S, SIGMAS, derive_stall_limit

    c = Controller(study.controller, DT, feedforward.inverse())
    ref = study.references["step"]
    limits = {}
    for force_max in (150.0, 72.0, 68.0):
        limits[force_max] = derive_stall_limit(study.plant, c, ref, force_low_N=15.0, force_max_N=force_max,
                                               v_range=(0.0, 110.0), reference_name="step")
    assert limits[150.0].plant_limit_s is None and limits[150.0].limit_s == pytest.approx(HORIZON_S)
    assert 0.01 < limits[68.0].limit_s < limits[72.0].limit_s < HORIZON_S
    s = limits[68.0]
    rig = Rig(study.plant)
    u = simulate(rig, c, ref, seed=0).command_V
    k0 = int(round(s.worst_t_s / DT))
    assert u[k0] == pytest.approx(s.worst_held_V, abs=1e-9)
    state = rig.initial_state()
    for k in range(k0):
        state = rig.step(state, u[k])
    forces = []
    for _ in range(int(round(s.limit_s / DT)) + 2):
        forces.append(float(rig.force(state)))
        state = rig.step(state, u[k0])
    ceiling = 68.0 - SIGMAS * study.plant.noise_N
    n = int(round(s.limit_s / DT))
    assert max(forces[1:n + 1]) <= ceiling < forces[n + 1], "the limit is not where the held force leaves the margin"


# ---- the host check --------------------------------------------------------------------------------------------------
def test_the_host_checks_criteria_follow_the_budget_and_the_stall_limit():
    """The rate criterion: p99 lateness + p99 step within the period; the stall criterion: the latest wake-up + a
    period + the longest step below the stall limit. Closed-form cases either side of each bound."""
    from piezopreload.rig.hostcheck import judge

    step = np.full(100, 5e-6)
    quiet = np.full(1000, 20e-6)
    assert all(c.passed for c in judge(quiet, step, 1e-3, 0.05))
    late = quiet.copy()
    late[::50] = 2e-3  # 2 % of the wake-ups from a wait a period late: their p99 is over the budget
    rate = judge(late, step, 1e-3, 0.05)[0]
    assert not rate.passed and rate.name == "rate"
    # one stall of 15 ms: the 14 wake-ups after it catch up at once (their deadlines have passed); they are that
    # stall's, judged against the stall limit, not 1.5 % of misses
    one = quiet.copy()
    one[100:115] = np.arange(15, 0, -1) * 1e-3
    assert [c.passed for c in judge(one, step, 1e-3, 0.05)] == [True, True]
    assert [c.passed for c in judge(one, step, 1e-3, 0.0155)] == [True, False]
    stalled = quiet.copy()
    stalled[0] = 0.05 - 1e-3  # with a period and the step it reaches the limit
    assert [c.passed for c in judge(stalled, step, 1e-3, 0.05)] == [True, False]
    stalled[0] = 0.05 - 1e-3 - 6e-6
    assert [c.passed for c in judge(stalled, step, 1e-3, 0.05)] == [True, True]
    assert [c.name for c in judge(quiet, step, 1e-3, None)] == ["rate"], "without a stall limit it is not judged"


@pytest.mark.slow
@pytest.mark.realtime
def test_rig_check_measures_the_host_and_draws_it(gains_path, tmp_path, capsys):
    assert main(["rig", "check", "--seconds", "0.3", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["samples"] == 300 and sum(r["histogram_counts"]) == 300 and r["verdict"] in ("pass", "fail")
    assert [c["name"] for c in r["criteria"]] == ["rate"] and r["stall_limit_s"] is None
    assert r["lateness_p50_s"] <= r["lateness_p99_s"] <= r["lateness_p999_s"] <= r["lateness_max_s"]
    assert set(r["facts"]) >= {"rt_kernel", "sched_fifo", "memory_locked", "cpu_governor", "virtualisation",
                               "isolated_cpus"}
    assert main(["rig", "check", "--gains", str(gains_path), "--seconds", "0.3", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "stall limit 1000 ms" in out and "verdict: " in out and "lateness histogram:" in out
    assert (tmp_path / "host-check.png").read_bytes().startswith(b"\x89PNG")
    assert main(["rig", "check", "--gains", str(gains_path), "--rate", "500"]) == 2
    assert "--rate 500" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.realtime
def test_a_realtime_run_refuses_a_host_that_fails_its_check_unless_accepted(gains_path, tmp_path, monkeypatch, capsys):
    """The check before arming is injected to fail: the run is refused (exit 2, nothing armed, no log); with
    --accept-host it runs and the sidecar records the failed check and the acceptance."""
    from piezopreload.rig import hostcheck, session

    def failing(**kw):
        checked = hostcheck.check_host(**{**kw, "seconds": 0.05})
        return replace(checked, criteria=(hostcheck.Criterion("stall", False, "injected"),))

    monkeypatch.setattr(session, "check_host", failing)
    ref = tmp_path / "ref.csv"
    ref.write_text("time_s,force_N\n0,25\n0.1,40\n0.3,40\n")
    argv = ["rig", "run", str(gains_path), "--realtime", "--reference", str(ref), "--log-dir", str(tmp_path / "runs")]
    assert main(argv) == 2
    assert "this host failed the check before arming (injected)" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
    assert main([*argv, "--accept-host", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    side = RigRunRecord.load(r["log_json"])
    assert side.host_accepted and side.host_check.verdict == "fail" and r["host_check"]["verdict"] == "fail"


# ---- the sidecar, typed; the pipeline's rig stage -----------------------------------------------------------------
def test_the_sidecar_is_one_typed_record_that_names_a_bad_field(gains_path, tmp_path):
    r = _run(gains_path, tmp_path, [])
    side = RigRunRecord.load(r["log_json"])
    assert RigRunRecord.from_dict(side.to_dict()).to_dict() == side.to_dict()
    doc = json.loads(Path(r["log_json"]).read_text())
    del doc["summary"]["timing"]["held_max_s"]
    with pytest.raises(ArtifactError, match=r"field 'summary.timing.held_max_s' is missing"):
        RigRunRecord.from_dict(doc, "the run's sidecar")
    doc = json.loads(Path(r["log_json"]).read_text())
    doc["summary"]["trip"] = {"cause": "force_high", "detail": "x", "t_s": 1.0, "voltage_V": 3.0}
    with pytest.raises(ArtifactError, match="a tripped run has no 'metrics'"):
        RigRunRecord.from_dict(doc)


def test_the_pipelines_rig_stage_reports_a_trip_and_no_step_figures(gains_path, study, tmp_path):
    """The rig stage reads the sidecar typed: a tripped run fails the stage with the trip (cause, time, voltage) and
    a summary without step figures, which the stage runner records."""
    from piezopreload.core.stages import Partial, StageFailed, run_stages, sha256_file
    from piezopreload.pipeline import _Ctx, _stage_rig
    from piezopreload.progress import Progress

    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(gains_path, out / "gains.json")
    records = {"validate": {"status": "done", "key": "k",  # a validate stage's record, as pipeline.json holds one
                            "outputs": {"gains": {"path": "gains.json", "sha256": sha256_file(out / "gains.json")}}}}
    tight = study.replace(rig_run={"force_max_N": 60.5})  # the step's overshoot reads above it
    ctx = _Ctx(tight, out, Progress(stream=io.StringIO()), records)
    with pytest.raises(StageFailed, match="stopped by the interlock 'force_high' at t = .* V held") as failed:
        _stage_rig(ctx)
    partial = failed.value.__cause__
    assert isinstance(partial, Partial) and partial.summary["trip"]["cause"] == "force_high"
    assert "settling_s" not in partial.summary and partial.summary["force_max_N"] == 60.5

    class Stage:
        name, what = "rig", "the rig"

    def run(stage):
        raise failed.value

    with pytest.raises(StageFailed):
        run_stages([Stage()], records, out, Progress(stream=io.StringIO()), force=True, key=lambda s: "k",
                   applies=lambda s: None, run=run, save=lambda: None)
    assert records["rig"]["status"] == "failed" and records["rig"]["summary"]["trip"]["cause"] == "force_high"


def test_the_low_force_margin_a_study_leaves_unset_follows_the_stacks_reach():
    """default_interlocks: the executor's 10 N on a rig of a few hundred newtons (the paper's: its stacks reach 143 N),
    1 % of the stacks' reach where that is more (the designed machine axis: 6,329 N), each with its source."""
    from piezopreload.models.actuator import Plant, reach_N
    from piezopreload.rig.interlocks import Safety
    from piezopreload.rig.tables import LOW_MARGIN_SHARE, default_interlocks
    from piezopreload.study import load_study

    small = Plant()  # the paper's rig
    values, sources = default_interlocks(small)
    assert values["force_low_margin_N"] == Safety().force_low_margin_N == 10.0
    assert sources["force_low_margin_N"] == "the executor's default"
    big = load_study("machine_axis").plant  # the designed axis: three stacks against the nuts' Hertz contacts
    reach = float(reach_N(Rig(big), float(big.stack.v_max_V)))
    assert reach > 2000.0, reach
    values, sources = default_interlocks(big)
    assert values["force_low_margin_N"] == pytest.approx(LOW_MARGIN_SHARE * reach, rel=1e-12)
    assert sources["force_low_margin_N"].startswith("derived: 1% of the"), sources["force_low_margin_N"]


def test_a_reference_file_longer_than_a_run_plays_is_refused_before_anything_is_written(gains_path, tmp_path, capsys):
    """A time_s column in the wrong unit (here 1e95 s, found by the fuzz test as an internal failure) is refused by
    name, exit 2, and no run log is written; an hour is the longest a run plays."""
    from piezopreload.rig.session import MAX_REFERENCE_S

    ref = tmp_path / "ref.csv"
    ref.write_text("time_s,force_N\n0,25\n1e95,60\n")
    logs = tmp_path / "logs"
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref), "--log-dir", str(logs)]) == 2
    err = capsys.readouterr().err
    assert f"{ref}: the reference lasts 2e+95 s" in err and f"at most {MAX_REFERENCE_S:g} s" in err, err
    assert not logs.exists() or not any(logs.iterdir()), "a refused run wrote a log"
