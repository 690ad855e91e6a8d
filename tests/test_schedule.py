"""The gain schedule on the preload level: the controller step, the gain set's table, its exports."""

import json
import re
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest
from stkit import translate

from piezopreload.artifacts.gainset import GainSet, GainsTable, gains_from_dict
from piezopreload.artifacts.registry import write_artifact
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import Reference, simulate
from piezopreload.models.controller import Controller, GainSchedule, PIDGains, controller_functions
from piezopreload.models.ops import NUMPY
from piezopreload.rig.export import export

SCHEDULE = GainSchedule(levels_N=(30.0, 60.0, 100.0), Kc=(0.9, 1.6, 0.7), Ti_s=(0.08, 0.04, 0.06),
                        Td_s=(0.0, 0.004, 0.002))
BASE = dict(Kc=1.2, Ti_s=0.05, Td_s=0.003, Tf_s=0.002, b=0.4, u_min_V=0.0, u_max_V=110.0)
#: the same table with a setpoint weight per entry (tuned with each entry)
SCHEDULE_B = GainSchedule(levels_N=SCHEDULE.levels_N, Kc=SCHEDULE.Kc, Ti_s=SCHEDULE.Ti_s, Td_s=SCHEDULE.Td_s,
                          b=(0.3, 0.8, 0.5))
BOTH = pytest.mark.parametrize("table", [SCHEDULE, SCHEDULE_B], ids=["single b", "b per entry"])


@pytest.fixture
def rng():
    return np.random.default_rng(20)


def _piecewise(levels, values, x):
    """An independent interpolation: numpy's interp (clamped at the ends)."""
    return np.interp(x, levels, values)


def test_schedule_interpolates_linearly_and_clamps_at_the_ends_on_numpy_and_casadi():
    x = np.array([-50.0, 30.0, 45.0, 60.0, 61.0, 99.0, 100.0, 400.0])
    got = SCHEDULE.at(x)
    for name, col in zip(("Kc", "Ti_s", "Td_s"), got):
        want = _piecewise(SCHEDULE.levels_N, getattr(SCHEDULE, name), x)
        np.testing.assert_allclose(col, want, rtol=0, atol=1e-15, err_msg=f"{name} is not numpy.interp's")
    controller = Controller(PIDGains(**BASE, schedule=SCHEDULE), 1e-3)
    model, p = controller.model, controller.parameter_vector()
    s = ca.SX.sym("s")
    fn = ca.Function("g", [s], list(model.gains_at(__import__("piezopreload").models.ops.CASADI,
                                                   model.params.unpack(ca.DM(p)), s)))
    for xi in x:
        cas = [float(v) for v in fn(xi)]
        np.testing.assert_allclose(cas[:3], [c[list(x).index(xi)] for c in got], rtol=0, atol=1e-14,
                                   err_msg=f"CasADi's gains at {xi} N differ from numpy's")
        assert cas[3:] == [BASE["Tf_s"], BASE["b"]], "Tf and b are single"
    # a b column: b interpolated as the gains are (numpy's interp), Tf still single, and the numpy face agrees
    controller = Controller(PIDGains(**BASE, schedule=SCHEDULE_B), 1e-3)
    model, p = controller.model, controller.parameter_vector()
    fn = ca.Function("g", [s], list(model.gains_at(__import__("piezopreload").models.ops.CASADI,
                                                   model.params.unpack(ca.DM(p)), s)))
    for xi in x:
        cas = [float(v) for v in fn(xi)]
        want = float(np.interp(xi, SCHEDULE_B.levels_N, SCHEDULE_B.b))
        assert cas[4] == pytest.approx(want, abs=1e-14), f"b at {xi} N: CasADi {cas[4]}, numpy.interp {want}"
        assert float(SCHEDULE_B.b_at(xi, 0.4)) == pytest.approx(want, abs=1e-14) and cas[3] == BASE["Tf_s"]
    assert float(SCHEDULE.b_at(61.0, 0.4)) == 0.4, "a table without a b column does not use the single b"


def test_a_flat_b_column_is_the_single_b_exactly():
    """A b column whose entries are all the single b gives the very commands of no column (to 1e-12)."""
    flat = GainSchedule(SCHEDULE.levels_N, SCHEDULE.Kc, SCHEDULE.Ti_s, SCHEDULE.Td_s, b=(BASE["b"],) * 3)
    rig = Rig(Plant(noise_N=0.2))
    ref = Reference.staircase(25.0, [60.0, 110.0, 40.0], 0.3, t_start_s=0.05)
    one = simulate(rig, Controller(PIDGains(**BASE, schedule=SCHEDULE), rig.dt_s), ref, seed=3)
    col = simulate(rig, Controller(PIDGains(**BASE, schedule=flat), rig.dt_s), ref, seed=3)
    np.testing.assert_allclose(col.command_V, one.command_V, rtol=0, atol=1e-12)
    other = simulate(rig, Controller(PIDGains(**BASE, schedule=SCHEDULE_B), rig.dt_s), ref, seed=3)
    assert np.max(np.abs(other.command_V - one.command_V)) > 0.1, "the b column does not reach the step"


def test_identical_entries_give_the_unscheduled_controller():
    """A schedule whose entries are all the single set is that set, in closed loop on the rig (to 1e-12)."""
    flat = GainSchedule((25.0, 70.0, 120.0), (BASE["Kc"],) * 3, (BASE["Ti_s"],) * 3, (BASE["Td_s"],) * 3)
    rig = Rig(Plant(noise_N=0.2))
    ref = Reference.staircase(25.0, [60.0, 110.0, 40.0], 0.3, t_start_s=0.05)
    one = simulate(rig, Controller(PIDGains(**BASE), rig.dt_s), ref, seed=3)
    sch = simulate(rig, Controller(PIDGains(**BASE, schedule=flat), rig.dt_s), ref, seed=3)
    np.testing.assert_allclose(sch.command_V, one.command_V, rtol=0, atol=1e-12,
                               err_msg="a flat schedule changed the command")
    assert np.ptp(one.command_V) > 10.0  # the run does move the controller


def test_unscheduled_parameters_are_as_before():
    """No schedule: the parameter layout ends with the feedforward's numbers, as it always did."""
    c = Controller(PIDGains(**BASE), 1e-3)
    assert c.model.schedule_size == 0 and c.model.params.names[-1] == "ff" and c.parameter_vector().size == 8


def _ramp_open_loop(gains, y0=40.0, n=2000, dt=1e-3, s0=20.0, s1=80.0):
    """The controller alone, its measurement held at ``y0`` while the setpoint ramps ``s0 -> s1``."""
    c = Controller(gains, dt)
    sp = np.linspace(s0, s1, n)
    state = c.initial_state(sp[0], y0, u0=30.0)
    u = np.empty(n)
    for k in range(n):
        u[k], state = c.step(state, sp[k], y0)
    return sp, u


def test_a_ramp_through_the_entries_moves_the_output_as_the_closed_form_says():
    """Measurement held, setpoint ramping through the 60 N entry (Td acts on the measurement only, which is held):
    u_k - u_{k-1} = (Kc_k - Kc_{k-1}) (b s_k - y) + Kc_{k-1} b (s_k - s_{k-1}) + Kc_k / Ti_k (e_k + e_{k-1}) / 2 dt,
    because the integral state is the integral action (V): a change of gains moves nothing stored. So each
    sample's jump is bounded by the ramp's increment times the gains and their slopes."""
    g = PIDGains(**{**BASE, "u_min_V": -1e4, "u_max_V": 1e4}, schedule=SCHEDULE)  # a range the output never reaches
    y, dt, b = 40.0, 1e-3, BASE["b"]
    sp, u = _ramp_open_loop(g, y0=y, dt=dt)
    assert np.all(np.abs(u) < 1e4), "the check is for the unclamped output"
    Kc, Ti, _ = SCHEDULE.at(sp)
    e = sp - y
    du = np.diff(u)
    want = np.diff(Kc) * (b * sp[1:] - y) + Kc[:-1] * b * np.diff(sp) + Kc[1:] / Ti[1:] * 0.5 * (e[1:] + e[:-1]) * dt
    np.testing.assert_allclose(du, want, rtol=0, atol=1e-11,
                               err_msg="the output's increments are not the closed form's")
    ds = float(np.max(np.abs(np.diff(sp))))
    lv, kc = np.array(SCHEDULE.levels_N), np.array(SCHEDULE.Kc)
    slope = float(np.max(np.abs(np.diff(kc) / np.diff(lv))))
    bound = ds * (slope * np.max(np.abs(b * sp - y)) + kc.max() * b) + np.max(Kc / Ti) * np.max(np.abs(e)) * dt
    assert np.max(np.abs(du)) <= bound, f"a jump of {np.max(np.abs(du)):.3g} V exceeds the bound {bound:.3g} V"


def test_a_ramp_through_entries_with_their_own_b_moves_the_output_as_the_closed_form_says():
    """With a b column the proportional action is Kc(s) (b(s) s - y), both interpolated in the setpoint s: the
    increments are
    u_k - u_{k-1} = Kc_k (b_k s_k - y) - Kc_{k-1} (b_{k-1} s_{k-1} - y) + Kc_k / Ti_k (e_k + e_{k-1}) / 2 dt
    (measurement held, so no derivative action; the integral state is the integral action)."""
    g = PIDGains(**{**BASE, "u_min_V": -1e4, "u_max_V": 1e4}, schedule=SCHEDULE_B)
    y, dt = 40.0, 1e-3
    sp, u = _ramp_open_loop(g, y0=y, dt=dt)
    Kc, Ti, _ = SCHEDULE_B.at(sp)
    b = np.interp(sp, SCHEDULE_B.levels_N, SCHEDULE_B.b)
    e = sp - y
    p = Kc * (b * sp - y)
    want = np.diff(p) + Kc[1:] / Ti[1:] * 0.5 * (e[1:] + e[:-1]) * dt
    np.testing.assert_allclose(np.diff(u), want, rtol=0, atol=1e-11, err_msg="the output's increments with a b column")


@BOTH
def test_numpy_and_casadi_steps_agree_with_a_schedule(rng, table):
    g = PIDGains(**BASE, schedule=table)
    c = Controller(g, 1e-3)
    _, step = controller_functions(c.model)
    p = c.parameter_vector()
    x = c.state_vector(c.initial_state(25.0, 25.0, u0=10.0))
    for sp, pv in zip(rng.uniform(10, 130, 300), rng.uniform(10, 130, 300)):
        nxt, t = c.model.step(NUMPY, p, x, sp, pv)
        out = step(x, sp, pv, p)
        assert abs(float(out[0]) - float(t.u)) < 1e-12, f"u at sp {sp:.3g}: CasADi {float(out[0])} numpy {float(t.u)}"
        np.testing.assert_allclose(np.asarray(out[5], float).ravel(), nxt, rtol=0, atol=1e-12)
        x = nxt


@BOTH
def test_switching_to_and_from_a_schedule_is_bumpless(table):
    """Controller.switch (the rig's gain change) with schedules: a loop resting with a 1 N error at 80 N (between
    two entries) moves by the new controller's integral increment only, Kc(80)/Ti(80) * 1 N * dt."""
    dt = 1e-3
    robust = Controller(PIDGains(**BASE), dt)
    scheduled = Controller(PIDGains(**BASE, schedule=table), dt)
    for a, b in ((robust, scheduled), (scheduled, robust)):
        state = a.initial_state(80.0, 79.0, u0=50.0)
        for _ in range(300):
            u_last, state = a.step(state, 80.0, 79.0)
        u_next, _ = b.step(a.switch(state, b), 80.0, 79.0)
        Kc, Ti, _ = b.gains.at(80.0)
        assert float(u_next - u_last) == pytest.approx(float(Kc / Ti * 1.0 * dt), abs=1e-12), \
            f"switching {'to' if b is scheduled else 'from'} the schedule jumped the output by {u_next - u_last:.3g} V"
        swapped, _ = b.step(state, 80.0, 79.0)  # the gains swapped without switch(): a jump of the P action
        assert abs(swapped - u_next) > 1e-3, "the case does not tell a bumpless switch from a swap"


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda d: d.update(levels_N=[30.0, 30.0, 100.0]), "gains.schedule.levels_N"),
    (lambda d: d.update(levels_N=[30.0, float("nan"), 100.0]), "gains.schedule.levels_N"),
    (lambda d: d.update(Kc_V_per_N=[1.0, 2.0]), "gains.schedule.Kc_V_per_N"),
    (lambda d: d.update(Ti_s=[0.1, -0.1, 0.1]), "gains.schedule.Ti_s"),
    (lambda d: d.update(Td_s="none"), "gains.schedule.Td_s"),
    (lambda d: d.update(levels_N=list(range(40)), Kc_V_per_N=[1.0] * 40, Ti_s=[0.1] * 40, Td_s=[0.0] * 40),
     "gains.schedule.levels_N"),
    (lambda d: d.pop("Ti_s"), "gains.schedule.Ti_s"),
    (lambda d: d.update(b=[0.3, float("inf"), 0.5]), "gains.schedule.b"),
    (lambda d: d.update(b=[0.3, 0.5]), "gains.schedule.b"),
    (lambda d: d.update(b="half"), "gains.schedule.b"),
])
def test_a_bad_schedule_is_refused_naming_its_field(mutate, field):
    doc = GainsTable.from_value(PIDGains(**BASE, schedule=SCHEDULE_B)).to_dict()
    mutate(doc["schedule"])
    with pytest.raises(InputError, match=re.escape(f"'{field}'")):
        gains_from_dict(doc)


def _gain_set(tmp_path, schedule=SCHEDULE, name="gains.json"):
    gains = GainsTable.from_value(PIDGains(**BASE, schedule=schedule)).to_dict()
    path = tmp_path / name
    write_artifact(path, "gain-set", {"status": "validated", "gains": gains, "inputs": {},
                                      "plant": {"rig": Plant(noise_N=0.2).to_dict()}})
    return path


@BOTH
def test_the_schedule_round_trips_and_its_hash_covers_it(tmp_path, table):
    path = _gain_set(tmp_path, table)
    loaded = GainSet.load(path)
    assert loaded.gains.schedule == table, "the table did not come back"
    assert ("b" in json.loads(path.read_text())["gains"]["schedule"]) == (table.b is not None)
    again = GainSet.from_dict(loaded.to_dict())
    assert again.gains == loaded.gains
    doc = json.loads(path.read_text())
    doc["gains"]["schedule"]["Kc_V_per_N"][1] = 1.7
    path.write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match="content_sha256"):
        GainSet.load(path)


def _ini_table(text, section="[gain schedule]"):
    body = text.split(section, 1)[1]
    rows = {}
    for line in body.strip().splitlines():
        if line.startswith("["):
            break
        key, _, value = line.partition(" = ")
        rows[key] = [float(x) for x in value.split(",")]
    return rows


@BOTH
def test_every_text_format_writes_the_table(tmp_path, table):
    gs = GainSet.load(_gain_set(tmp_path, table))
    js = json.loads(export(gs, "json"))["gain_schedule"]
    assert GainSchedule(js["levels_N"], js["Kc_V_per_N"], js["Ti_s"], js["Td_s"], js.get("b")) == table
    assert "linear in the setpoint" in js["interpolation"]
    lv = _ini_table(export(gs, "labview"))
    np.testing.assert_allclose(lv["setpoint (N)"], SCHEDULE.levels_N, rtol=1e-12)
    np.testing.assert_allclose(lv["Kc"], SCHEDULE.Kc, rtol=1e-12)
    np.testing.assert_allclose(np.array(lv["Ti (min)"]) * 60.0, SCHEDULE.Ti_s, rtol=1e-11)
    np.testing.assert_allclose(np.array(lv["Td (min)"]) * 60.0, SCHEDULE.Td_s, rtol=1e-11)
    plc = translate(export(gs, "plc"), "PP_CONTROLLER").memory  # the block's variables as it starts
    for name in ("levels_N", "Kc", "Ti_s", "Td_s"):
        assert plc[f"schedule_{name}".lower()] == list(getattr(SCHEDULE, name)), f"the PLC block's schedule_{name}"
    header = export(gs, "c-header")
    if table.b is None:  # the single b holds for every entry: no column in the tables, the single b in the step's
        assert "setpoint weight beta" not in lv and "PP_SCHEDULE_B[" not in header
        assert plc["schedule_b"] == [BASE["b"]] * 3
    else:
        np.testing.assert_allclose(lv["setpoint weight beta"], table.b, rtol=1e-12)
        assert plc["schedule_b"] == list(table.b)
        assert "PP_SCHEDULE_B[PP_SCHEDULE_N] = {0.3, 0.8, 0.5}" in header
    for fmt in ("json", "labview", "plc", "c-header"):
        plain = export(GainSet.load(_gain_set(tmp_path, None, "plain.json")), fmt)
        assert "schedule" not in plain.lower(), f"{fmt}: a table where there is no schedule"


def _cc():
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler on this machine")
    return cc


_HEADER_MAIN = r"""#include <stdio.h>
#include "gains.h"
/* the interpolation the header's comment states, written from it */
static double at(const double* k, double r) {
  int i;
  if (r <= PP_SCHEDULE_LEVELS_N[0]) return k[0];
  for (i = 0; i + 1 < PP_SCHEDULE_N; ++i)
    if (r <= PP_SCHEDULE_LEVELS_N[i + 1])
      return k[i] + (k[i + 1] - k[i]) * (r - PP_SCHEDULE_LEVELS_N[i]) / (PP_SCHEDULE_LEVELS_N[i + 1] - PP_SCHEDULE_LEVELS_N[i]);
  return k[PP_SCHEDULE_N - 1];
}
int main(void) {
  double r;
  while (scanf("%lf", &r) == 1)
    printf("%.17g %.17g %.17g %.17g\n", at(PP_SCHEDULE_KC_V_PER_N, r), at(PP_SCHEDULE_TI_S, r), at(PP_SCHEDULE_TD_S, r),
           at(PP_SCHEDULE_B, r));
  return 0;
}
"""  # noqa: E501 (C source kept as written)


def test_the_c_header_table_interpolates_as_the_step(tmp_path):
    cc = _cc()
    gs = GainSet.load(_gain_set(tmp_path, SCHEDULE_B))
    (tmp_path / "gains.h").write_text(export(gs, "c-header"))
    (tmp_path / "main.c").write_text(_HEADER_MAIN)
    subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-Wno-unused-const-variable", "-o", str(tmp_path / "m"),
                    str(tmp_path / "main.c")], check=True)
    x = np.linspace(0.0, 140.0, 57)
    res = subprocess.run([str(tmp_path / "m")], input="\n".join(repr(float(v)) for v in x) + "\n",
                         capture_output=True, text=True, check=True)
    got = np.array(res.stdout.split(), float).reshape(-1, 4).T
    want = np.array([*SCHEDULE_B.at(x), SCHEDULE_B.b_at(x, BASE["b"])])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14,
                               err_msg="the header's table does not give the step's gains")


_STEP_MAIN = """#include <stdio.h>
int pp_controller_initial_state(double setpoint0, double pv0, double u0, double* state);
int pp_controller_step(double setpoint, double pv, double* state, double* u);
int main(void) {
  double state[64], sp, pv, u;
  if (scanf("%lf %lf", &sp, &pv) != 2 || pp_controller_initial_state(sp, pv, 0.0, state)) return 1;
  while (scanf("%lf %lf", &sp, &pv) == 2) {
    if (pp_controller_step(sp, pv, state, &u)) return 1;
    printf("%.17g\\n", u);
  }
  return 0;
}
"""


@BOTH
def test_the_casadi_c_step_is_the_scheduled_step(tmp_path, table):
    """The generated C (the schedule compiled in) against Controller.step over a closed loop through every entry."""
    cc = _cc()
    gs = GainSet.load(_gain_set(tmp_path, table))
    controller = gs.controller()
    rig = Rig(Plant(noise_N=0.2))
    ref = Reference.staircase(25.0, [45.0, 80.0, 120.0, 60.0, 30.0], 0.5, t_start_s=0.1)
    run = simulate(rig, controller, ref, seed=2)
    sp, pv = run.reference_N, run.measured_N
    state = controller.initial_state(sp[0], 25.0, u0=0.0)
    u_py = np.empty(sp.size)
    for k in range(sp.size):
        u_py[k], state = controller.step(state, sp[k], pv[k])
    np.testing.assert_allclose(u_py, run.command_V, rtol=0, atol=1e-9, err_msg="the step is not the simulation's")
    text = export(gs, "casadi-c")
    assert "gain schedule (3 entries)" in text and (("b: 0.3, 0.8, 0.5" in text) == (table.b is not None))
    (tmp_path / "pp_controller.c").write_text(text)
    (tmp_path / "main.c").write_text(_STEP_MAIN)
    exe = tmp_path / "step"
    subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-o", str(exe), str(tmp_path / "pp_controller.c"),
                    str(tmp_path / "main.c"), "-lm"], check=True)
    lines = [f"{float(sp[0])!r} 25.0"] + [f"{float(a)!r} {float(b)!r}" for a, b in zip(sp, pv)]
    res = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True, text=True, check=True)
    u_c = np.array(res.stdout.split(), float)
    np.testing.assert_allclose(u_c, u_py, rtol=0, atol=1e-9, err_msg="the C step differs from the Python step")


@BOTH
@pytest.mark.parametrize("prefer", ["numpy", "c"])
def test_the_rig_step_switches_to_a_schedule_as_the_controller_does(prefer, table):
    """The rig executor's step (numpy, or the compiled C step: another structure, another library) switching from the
    robust set to a schedule mid-run gives the numpy controller's outputs, switch included."""
    from piezopreload.rig.compiled import controller_step

    if prefer == "c":
        _cc()
    dt = 1e-3
    robust = Controller(PIDGains(**BASE), dt)
    scheduled = Controller(PIDGains(**BASE, schedule=table), dt)
    step = controller_step(robust, prefer=prefer)
    assert step.kind == prefer
    step.start(30.0, 30.0, 5.0)
    state = robust.initial_state(30.0, 30.0, u0=5.0)
    ref = np.concatenate([np.linspace(30.0, 90.0, 300), np.full(200, 90.0)])
    pv = ref - 2.0 + 0.5 * np.sin(np.arange(ref.size) / 7.0)
    now = robust
    for k, (r, y) in enumerate(zip(ref, pv)):
        if k == 250:
            step.switch(scheduled)
            state, now = robust.switch(state, scheduled), scheduled
        u, *_ = step.step(float(r), float(y))
        u_ref, state = now.step(state, r, y)
        assert abs(u - float(u_ref)) < 1e-9, f"sample {k}: the rig step gives {u}, the controller {float(u_ref)}"
