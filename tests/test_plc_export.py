"""The PLC export: PP_CONTROLLER and PP_LOOP, the controller step as the C export and the simulation run it.

For a PID, a PID with the paper's direction-switched feedforward (with creep), a gain schedule and a PID
whose measurement passes through the second-order filter (``filter_order`` 2, as the autotuner tunes it), a
closed loop on the noisy rig is recorded (setpoint and measured force, 10,000 samples through
saturation and reversals); the recording is replayed through three implementations of one controller
step: the numpy step (:meth:`Controller.step`), the C of ``export --format casadi-c`` compiled by the
system's compiler, and the Structured Text of ``export --format plc`` run by ``tests/stkit.py``
(a translator of the subset the export writes, its docstring says why it is faithful). Each must give
the numpy step's command within 1e-9 V: the three evaluate the same operations on doubles (the C and the
ST in the same order, so they agree to the last bit; numpy may round a sum differently).

Every exported source is parsed by blark, an IEC 61131-3 parser written by others (its grammar is
TwinCAT's flavour of the third edition), so a source our translator accepts but the standard does not
fails here.
"""

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from stkit import translate

from piezopreload.artifacts.gainset import GainSet
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import GainSchedule, PIDGains
from piezopreload.models.hysteresis import AsymmetricPI, Creep, CreepPI
from piezopreload.rig.export import export

ATOL_V = 1e-9
GAINS = dict(Kc=1.4, Ti_s=0.05, Td_s=0.004, Tf_s=0.02, b=0.3, u_min_V=0.0, u_max_V=110.0)
SCHEDULE = GainSchedule(levels_N=(30.0, 60.0, 100.0), Kc=(0.9, 1.6, 0.7), Ti_s=(0.08, 0.04, 0.06),
                        Td_s=(0.0, 0.004, 0.002), b=(0.3, 0.8, 0.5))
KINDS = ("pid", "pid+feedforward", "scheduled", "pid+filter2")


def _feedforward():
    """The paper's direction-switched P-I model with creep: both directions' weights, the switch, the lags."""
    r, w = np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05])
    h = AsymmetricPI(r, w, w * np.array([1.1, 0.8, 1.2, 0.9]), 25.0)
    return CreepPI(h, Creep([0.01, 0.1, 1.0, 10.0], [0.03, 0.0, 0.02, 0.04], 2e-3))


def gain_set(kind, path):
    """A validated gain set of ``kind`` on a noisy rig sampled at 1 ms, saved at ``path``."""
    gains = PIDGains(**GAINS, schedule=SCHEDULE if kind == "scheduled" else None,
                     filter_order=2 if kind == "pid+filter2" else 1)
    ff = _feedforward() if kind == "pid+feedforward" else None
    return GainSet(gains=gains, status="validated", feedforward=ff, plant=Plant(noise_N=0.2), preset="test",
                   inputs={"test": "plc export"}).save(path)


def recording(gs):
    """The closed loop on the rig: setpoints and readings of 10,001 samples that step up to saturation (110 V: the
    clamp and the conditional integration), reverse and come back through every entry of the schedule."""
    ref = Reference.staircase(25.0, [60.0, 135.0, 80.0, 35.0, 70.0], 1.6, t_start_s=2.0)
    run = simulate(Rig(gs.plant), gs.controller(), ref, seed=4)
    assert run.reference_N.size >= 10_000 and np.max(run.command_V) == 110.0, "the recording must saturate"
    return run.reference_N, run.measured_N


def python_steps(gs, sp, pv, u0=0.0):
    c = gs.controller()
    state = c.initial_state(sp[0], pv[0], u0=u0)
    u = np.empty(sp.size)
    for k in range(sp.size):
        u[k], state = c.step(state, sp[k], pv[k])
    return u


_C_MAIN = """#include <stdio.h>
int pp_controller_initial_state(double setpoint0, double pv0, double u0, double* state);
int pp_controller_step(double setpoint, double pv, double* state, double* u);
int main(void) {
  double state[256], sp, pv, u;
  int first = 1;
  while (scanf("%lf %lf", &sp, &pv) == 2) {
    if (first && pp_controller_initial_state(sp, pv, 0.0, state)) return 1;
    first = 0;
    if (pp_controller_step(sp, pv, state, &u)) return 1;
    printf("%.17g\\n", u);
  }
  return 0;
}
"""


def c_steps(gs, sp, pv, folder):
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler on this machine to build the exported C")
    (folder / "pp_controller.c").write_text(export(gs, "casadi-c"))
    (folder / "main.c").write_text(_C_MAIN)
    subprocess.run([cc, "-std=c99", "-O2", "-o", str(folder / "step"), str(folder / "main.c"),
                    str(folder / "pp_controller.c"), "-lm"], check=True)
    lines = "\n".join(f"{a!r} {b!r}" for a, b in zip(sp.tolist(), pv.tolist())) + "\n"
    out = subprocess.run([str(folder / "step")], input=lines, capture_output=True, text=True, check=True).stdout
    return np.array(out.split(), float)


def st_steps(text, sp, pv):
    block = translate(text, "PP_CONTROLLER")
    block(enable=False, track_V=0.0)
    return np.array([block(enable=True, setpoint_N=a, pv_N=b, track_V=0.0)["u_v"] for a, b in zip(sp, pv)])


def parse_iec(text):
    """blark's parse of ``text``; a failure names the line."""
    from blark import parse_source_code

    result = parse_source_code(text)
    return result.exception


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_the_c_and_the_structured_text_run_the_python_step(kind, tmp_path):
    gs = gain_set(kind, tmp_path / "gains.json")
    sp, pv = recording(gs)
    want = python_steps(gs, sp, pv)
    text = export(gs, "plc")
    got_st = st_steps(text, sp, pv)
    np.testing.assert_allclose(got_st, want, rtol=0, atol=ATOL_V, err_msg=f"{kind}: PP_CONTROLLER")
    got_c = c_steps(gs, sp, pv, tmp_path)
    np.testing.assert_allclose(got_c, want, rtol=0, atol=ATOL_V, err_msg=f"{kind}: the exported C")
    assert np.array_equal(got_c, got_st), "the C and the ST evaluate one algorithm: they agree to the last bit"
    assert parse_iec(text) is None, "blark does not parse the exported source"


def test_the_block_holds_the_gain_sets_numbers_by_the_c_arrays_names(tmp_path):
    """Each parameter the step reads is a variable of the block with the gain set's number, the C array's entry of that
    name."""
    gs = gain_set("scheduled", tmp_path / "gains.json")
    block = translate(export(gs, "plc"), "PP_CONTROLLER")
    m = block.memory
    assert (m["tf_s"], m["u_max_v"], m["dt_s"]) == (0.02, 110.0, gs.plant.sample_period_s)
    assert m["schedule_levels_n"] == [30.0, 60.0, 100.0] and m["schedule_b"] == [0.3, 0.8, 0.5]
    c = export(gs, "casadi-c")
    assert "/* schedule_Kc: gain schedule: Kc, V/N */ 0.9, 1.6, 0.7," in c
    single = translate(export(gain_set("pid", tmp_path / "pid.json"), "plc"), "PP_CONTROLLER").memory
    assert (single["kc"], single["ti_s"], single["b"]) == (1.4, 0.05, 0.3)


#: what a PLC engineer retunes, by the gain set's structure: the single gains, or the schedule's arrays and the
#: single Tf; and the output range (the issue's words: the header says which numbers to change)
TUNED = {"single": {"kc", "ti_s", "td_s", "tf_s", "b", "u_min_v", "u_max_v"},
         "scheduled": {"schedule_levels_n", "schedule_kc", "schedule_ti_s", "schedule_td_s", "schedule_b", "tf_s",
                       "u_min_v", "u_max_v"}}


def _header_names(text):
    """The names in the header's sentence on which numbers to change (an identifier with an underscore, Kc or b)."""
    words = " ".join(text.split())
    assert "To retune, change " in words, "the header must say which numbers to change"
    sentence = words.split("To retune, change ", 1)[1].split(" in the VAR section")[0]
    return {n.lower() for n in re.findall(r"\b(?:[A-Za-z]\w*_\w+|Kc|b)\b", sentence)}


@pytest.mark.parametrize("kind", KINDS)
def test_the_block_declares_only_what_its_body_reads_and_its_header_names_the_numbers_to_change(kind, tmp_path):
    """Every variable PP_CONTROLLER declares (inputs, numbers, state, work variables) is read by its body: a scheduled
    set runs on the schedule's arrays, so its single Kc, Ti_s, Td_s and b are not declared; the header's sentence on
    what to change names those numbers, each a variable of the block, and no other."""
    text = export(gain_set(kind, tmp_path / "gains.json"), "plc")
    block = translate(text, "PP_CONTROLLER")
    unread = sorted(n for n, v in block.variables.items() if v.section != "VAR_OUTPUT" and n not in block.read)
    assert not unread, f"{kind}: declared but never read by the body: {unread}"
    named = _header_names(text)
    assert named <= set(block.variables), f"{kind}: the header names {sorted(named - set(block.variables))}, " \
                                          "which the block does not declare"
    assert named == TUNED["scheduled" if kind == "scheduled" else "single"], f"{kind}: the header names {named}"


def _loop(program, sp, pv, automatic, manual_V):
    """PP_LOOP cycle by cycle: the operator's switch and manual value, the sensor; the command it writes."""
    out = np.empty(sp.size)
    m = program.memory
    for k in range(sp.size):
        m["setpoint_n"], m["force_n"], m["automatic"] = float(sp[k]), float(pv[k]), bool(automatic[k])
        if not automatic[k] and (k == 0 or automatic[k - 1] == automatic[k] and k in manual_V):
            m["manual_v"] = manual_V[k]
        program()
        out[k] = m["command_v"]
    return out


def test_the_program_switches_between_manual_and_automatic_bumplessly(tmp_path):
    """PP_LOOP: manual at 40 V, automatic from 0.5 s, manual again from 1.2 s (the command held), the operator
    moves it to 55 V, automatic again from 1.6 s. Each start is the rig's bumpless start from the command
    held (ControllerModel.start), and the command does not jump at any switch."""
    gs = gain_set("pid+feedforward", tmp_path / "gains.json")
    sp, pv = recording(gs)
    sp, pv = sp[1500:3500], pv[1500:3500]  # around the step to 120 N: the loop has work to do
    automatic = np.zeros(sp.size, bool)
    automatic[500:1200] = automatic[1600:] = True
    got = _loop(translate(export(gs, "plc"), "PP_LOOP"), sp, pv, automatic, {0: 40.0, 1400: 55.0})
    # what the rig does: a bumpless start from the last command, then the step; in manual the command held
    c = gs.controller()
    want, held, state = np.empty(sp.size), 40.0, None
    for k in range(sp.size):
        if automatic[k]:
            if state is None:
                state = c.initial_state(sp[k], pv[k], u0=held)
            want[k], state = c.step(state, sp[k], pv[k])
            held = want[k]
        else:
            state, held = None, 55.0 if k >= 1400 else held
            want[k] = held
    np.testing.assert_allclose(got, want, rtol=0, atol=ATOL_V, err_msg="PP_LOOP is not the rig's switching")
    for k in (500, 1600):  # a start moves the command by its first integral increment, Kc/Ti e dt, and no more
        increment = GAINS["Kc"] / GAINS["Ti_s"] * (sp[k] - pv[k]) * gs.plant.sample_period_s
        assert abs(got[k] - got[k - 1] - increment) < ATOL_V, f"the command jumps at sample {k}"
    assert got[1200] == got[1199], "switching to manual holds the last command"
    assert np.ptp(got[500:1200]) > 5.0, "the loop must move the command while it runs"


@pytest.mark.slow
def test_blark_parses_every_plc_export_and_refuses_a_broken_one(tmp_path):
    """A model alone's PP_FEEDFORWARD of every kind, with and without creep (tests/test_exports.py runs them), parses;
    a source with a statement cut short does not (the check can fail). The gain sets' sources of every kind are
    parsed by the test above, each once (blark's Earley parser takes seconds a source)."""
    from test_exports import KINDS as MODEL_KINDS
    from test_exports import _model

    assert set(KINDS) >= {"pid", "scheduled"}, "the test above no longer parses these gain sets' sources"
    for kind in MODEL_KINDS:
        for creep in (False, True):
            alone = export(_model(kind, creep), "plc", sample_period_s=0.001)
            assert parse_iec(alone) is None, f"blark does not parse PP_FEEDFORWARD of a {kind} model, creep {creep}"
    broken = export(gain_set("pid", tmp_path / "b.json"), "plc").replace("active := enable;", "active := ;")
    assert parse_iec(broken) is not None, "blark accepts a statement without its expression"
