"""The feedforward in every export: the PLC's Structured Text function block and the LabVIEW table each run the
numpy inverse step (:class:`~piezopreload.models.hysteresis.InverseStep`) on a test signal; a hysteresis model
exports alone; every format comes from one module (``pp.export``).

The ST block is executed by ``tests/stkit.py``, a translation of the subset the export writes into Python (its
docstring says why that is faithful); the LabVIEW file is read as LabVIEW's configuration-file VIs read it (INI
sections, keys, comma-separated rows) and its stated algorithm is run here from those numbers alone, written
from the algorithm's text, not from the library's step.

Tolerance: the block, the table's loop and numpy sum the same terms in other orders (numpy's sum is pairwise,
the loops sequential), so they agree to the rounding of sums of about n terms of up to 100 V: 1e-9 V.
"""

import configparser
import json
import os
import shutil
import subprocess

import numpy as np
import pytest
from stkit import STError, translate

import piezopreload as pp
from piezopreload.cli import main
from piezopreload.models.hysteresis import (
    AsymmetricPI,
    ClassicalPI,
    Creep,
    CreepPI,
    ModifiedPI,
    inverse_at,
    log_spaced_time_constants,
    uniform_thresholds,
)
from piezopreload.rig.export import INVERSE_STEP_ALGORITHM, ExportError, export

ATOL_V = 1e-9
KINDS = ["classical", "modified", "paper-asymmetric"]


def _model(kind, creep, n=12, dt=0.002, seed=7):
    rng = np.random.default_rng(seed)
    r = uniform_thresholds(n, 100.0)
    w = rng.uniform(0.005, 0.05, n)
    w[0] = 0.3
    if kind == "classical":
        h = ClassicalPI(r, w, offset=1.0)
    elif kind == "paper-asymmetric":
        h = AsymmetricPI(r, w, w * rng.uniform(0.8, 1.3, n), offset=1.0)
    else:
        h = ModifiedPI(r, w, deadzone_thresholds=[-8.0, -3.0, 0.0, 4.0, 9.0],
                       deadzone_weights=[0.3, -0.2, 1.1, 0.5, -0.6], bias=-1.0, offset=2.0)
    return CreepPI(h, Creep(log_spaced_time_constants(0.01, 10.0), [0.02, 0.0, 0.03, 0.01], dt)) if creep else h


def _targets(n=1500):
    """Rising, falling and held forces inside the model's outputs: reversals at several amplitudes, and holds."""
    t = np.linspace(0.0, 6.0, n)
    f = 15.0 + 12.0 * np.sin(2 * np.pi * 0.7 * t) * np.exp(-0.15 * t) + 3.0 * np.sin(2 * np.pi * 3.1 * t)
    f[2 * n // 5:7 * n // 15] = f[2 * n // 5]  # a held target
    return f


def _numpy(model, dt, targets):
    return inverse_at(model, dt).run(targets)[0]


# --------------------------------------------------------------------------------------
# the Structured Text block
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("creep", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_the_structured_text_block_runs_the_numpy_inverse_step(kind, creep):
    """A model alone, its lags discretised at a period that is not the model's own (1 ms against 2 ms)."""
    model, dt, targets = _model(kind, creep), 0.001, _targets()
    block = translate(export(model, "plc", sample_period_s=dt))
    commands = np.array([block(target_N=f, reset=(i == 0))["command_v"] for i, f in enumerate(targets)])
    expected = _numpy(model, dt, targets)
    assert np.ptp(expected) > 10.0, "the signal must move the operators"
    np.testing.assert_allclose(commands, expected, rtol=0, atol=ATOL_V, err_msg=f"{model.kind}: the ST block")
    # reset: back at rest, the block gives what a fresh numpy step gives
    again = [block(target_N=f, reset=(i == 0))["command_v"] for i, f in enumerate(targets[:50])]
    np.testing.assert_allclose(again, expected[:50], rtol=0, atol=ATOL_V, err_msg="after reset")


_C_FEEDFORWARD_MAIN = """#include <stdio.h>
int pp_feedforward_step(double target, double* state, double* command);
int main(void) {
  double state[256] = {0}, target, command;
  while (scanf("%lf", &target) == 1) {
    if (pp_feedforward_step(target, state, &command)) return 1;
    printf("%.17g\\n", command);
  }
  return 0;
}
"""


@pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                    reason="no C compiler to build the generated code")
@pytest.mark.parametrize("kind", KINDS)
def test_the_structured_text_block_and_the_c_are_one_generated_step(kind, tmp_path):
    """PP_FEEDFORWARD and pp_feedforward.c are written from one CasADi function of the inverse step: the ST (run by
    tests/stkit.py) and the compiled C give the same doubles, to the last bit, on a sweep of targets through
    reversals and holds, and both the library's inverse within 1e-9 V; every variable the block declares its body
    reads (the dead-zone numbers of a modified model only where it has dead zones, the falling weights only where
    the direction switches)."""
    model, dt, targets = _model(kind, True), 0.001, _targets(800)
    text = export(model, "plc", sample_period_s=dt)
    block = translate(text)
    st = np.array([block(target_N=f, reset=(i == 0))["command_v"] for i, f in enumerate(targets)])
    (tmp_path / "ff.c").write_text(export(model, "casadi-c", sample_period_s=dt))
    (tmp_path / "main.c").write_text(_C_FEEDFORWARD_MAIN)
    cc = shutil.which(os.environ.get("CC", "cc"))
    subprocess.run([cc, "-std=c99", "-O2", "-o", str(tmp_path / "ff"), str(tmp_path / "main.c"), str(tmp_path / "ff.c"),
                    "-lm"], check=True)
    run = subprocess.run([str(tmp_path / "ff")], input="\n".join(repr(float(f)) for f in targets) + "\n",
                         capture_output=True, text=True, check=True)
    c = np.array(run.stdout.split(), float)
    expected = _numpy(model, dt, targets)
    np.testing.assert_allclose(st, expected, rtol=0, atol=ATOL_V, err_msg=f"{kind}: the ST block")
    np.testing.assert_allclose(c, expected, rtol=0, atol=ATOL_V, err_msg=f"{kind}: the C")
    assert np.array_equal(st, c), f"{kind}: the ST and the C are not one algorithm ({np.sum(st != c)} samples differ)"
    unread = sorted(n for n, v in block.variables.items() if v.section != "VAR_OUTPUT" and n not in block.read)
    assert not unread, f"{kind}: declared but never read by the body: {unread}"


def test_the_gain_sets_plc_block_runs_its_feedforward_at_the_plants_period(gain_set_with_creep):
    """The gain set's PP_CONTROLLER: its feedforward (creep identified at 1 ms) discretised at the plant's 2 ms, as
    the controller step runs it (tests/test_plc_export.py holds the whole step to the C and the numpy step)."""
    gs = gain_set_with_creep
    dt = gs.plant.sample_period_s
    assert gs.feedforward.sample_period_s != dt, "the test needs a model identified at another period"
    block, targets = translate(export(gs, "plc"), "PP_CONTROLLER"), _targets(800)
    block(enable=False, track_V=0.0)
    ff = [block(enable=True, setpoint_N=f, pv_N=f, track_V=0.0)["ff_v"] for f in targets]
    np.testing.assert_allclose(ff, _numpy(gs.feedforward, dt, targets), rtol=0, atol=ATOL_V)
    assert block.memory["dt_s"] == dt


def test_the_translator_keeps_the_standards_meaning():
    """The translator itself: precedence, types, bounds and the block's memory, as IEC 61131-3 has them."""
    src = """FUNCTION_BLOCK T
    VAR_INPUT a : LREAL; END_VAR
    VAR_OUTPUT out : LREAL; n : DINT; END_VAR
    VAR CONSTANT C : ARRAY[2..3] OF LREAL := [1.5, -2.0E+00]; END_VAR
    VAR k : DINT; END_VAR
    out := 1.0 + 2.0 * a - C[2] / 3.0;   (* precedence: * and / before + and - *)
    FOR k := 2 TO 3 DO n := n + k; END_FOR;
    END_FUNCTION_BLOCK"""
    block = translate(src)
    assert block(a=4.0) == {"out": 1.0 + 2.0 * 4.0 - 1.5 / 3.0, "n": 5}
    assert block(a=0.0)["n"] == 10, "a function block keeps its variables between calls"
    for bad, why in [("out := C[4];", "outside"), ("out := k;", "assigning a DINT"), ("a := 1.0;", "VAR_INPUT"),
                     ("out := 1.0 + k;", "one type"), ("IF a THEN out := 1.0; END_IF;", "BOOL"),
                     ("out := q;", "not declared"), ("out := 1.0 ** 2.0;", "expected")]:
        with pytest.raises((STError, IndexError), match=why):
            translate(src.replace("FOR k := 2 TO 3 DO n := n + k; END_FOR;", bad))(a=1.0)


# --------------------------------------------------------------------------------------
# the LabVIEW table
# --------------------------------------------------------------------------------------
def _row(value):
    return np.array([float(x) for x in value.split(",")])


def _labview_step(ini):
    """The algorithm the file states (INVERSE_STEP_ALGORITHM), run on the file's numbers alone."""
    f, ops = ini["feedforward"], ini["feedforward operators"]
    n, m, d = int(f["operators n"]), int(f["creep lags m"]), int(f["dead zones d"])
    switched = f["direction switched"] == "TRUE"
    offset, bias = float(f["offset (N)"]), float(f["bias (N)"])
    r = _row(ops["r threshold (V)"])
    dirs = {s: [_row(ops[f"{key} {s} ({u})"]) for key, u in (("w weight", "N/V"), ("W partial sum", "N/V"),
                                                                 ("ri inverse threshold", "N"),
                                                                 ("wi inverse weight", "V/N"))]
            for s in (("rising", "falling") if switched else ("rising",))}
    dz = (_row(ini["feedforward dead zones"]["dz threshold (N)"]), _row(ini["feedforward dead zones"]["u weight"])) \
        if d else None
    c, a, e = ((_row(ini["feedforward creep"][k]) for k in ("c weight (N/V)", "a decay", "e input gain"))
               if m else (np.zeros(0),) * 3)
    y, s, state = [0.0] * n, [0.0] * m, {"v_prev": 0.0}

    def one_direction(g, w, W, ri, wi):
        v = 0.0
        for k in range(n):
            z = W[k] * y[k] + sum(w[i] * y[i] for i in range(k + 1, n))
            v += wi[k] * max(g - ri[k], min(g + ri[k], z))
        return v

    def step(target):
        x = target - offset
        if dz is not None:
            x = sum(u * (max(x - t, 0.0) if t > 0 else min(x - t, 0.0) if t < 0 else x) for t, u in zip(*dz))
        g = x - bias - sum(c[j] * s[j] for j in range(m))
        v = one_direction(g, *dirs["rising"])
        if switched:
            vp = state["v_prev"]
            vf = one_direction(g, *dirs["falling"])
            tol = 1e-9 * (1 + abs(vp))
            rise_ok, fall_ok = v >= vp - tol, vf < vp + tol
            v, vf = max(v, vp), min(vf, vp - tol)
            v = (v if v - vp <= vp - vf else vf) if rise_ok and fall_ok else v if rise_ok else vf if fall_ok else vp
            state["v_prev"] = v
        for k in range(n):
            y[k] = max(v - r[k], min(v + r[k], y[k]))
        for j in range(m):
            s[j] = a[j] * s[j] + e[j] * v
        return v

    return step


def _ini(text):
    parser = configparser.ConfigParser(comment_prefixes=(";",), delimiters=("=",), interpolation=None)
    parser.optionxform = str  # keys as written
    parser.read_string(text)
    return parser


@pytest.mark.parametrize("creep", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_the_labview_table_runs_the_numpy_inverse_step(kind, creep):
    model, dt, targets = _model(kind, creep), 0.001, _targets(600)
    text = export(model, "labview", sample_period_s=dt)
    assert all(f"; {line}" in text for line in INVERSE_STEP_ALGORITHM), "the algorithm is stated in the file"
    step = _labview_step(_ini(text))
    commands = [step(f) for f in targets]
    np.testing.assert_allclose(commands, _numpy(model, dt, targets), rtol=0, atol=ATOL_V,
                               err_msg=f"{model.kind}: the LabVIEW table")


def test_the_gain_sets_labview_file_holds_its_gains_and_its_feedforward_at_the_plants_period(gain_set_with_creep):
    gs = gain_set_with_creep
    ini = _ini(export(gs, "labview"))
    assert float(ini["PID gains"]["Ti (min)"]) * 60 == pytest.approx(gs.gains.Ti_s, rel=1e-11)
    assert float(ini["feedforward"]["sample period (s)"]) == gs.plant.sample_period_s
    step, targets = _labview_step(ini), _targets(500)
    np.testing.assert_allclose([step(f) for f in targets], _numpy(gs.feedforward, gs.plant.sample_period_s, targets),
                               rtol=0, atol=ATOL_V)


# --------------------------------------------------------------------------------------
# a model alone, the one module, the CLI
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A model identified from the paper's simulated loop, saved as model.json (the hysteresis-model artifact)."""
    from piezopreload.tuning.feedforward import LoopExcitation, identify_feedforward

    study = pp.load_study("paper2021")
    ff = identify_feedforward(study.plant, LoopExcitation(n_operators=10, kind="classical", creep=True),
                              check_range_N=None)
    path = tmp_path_factory.mktemp("model") / "model.json"
    return ff.record.save(path), path


@pytest.fixture(scope="module")
def gain_set_with_creep(identified, tmp_path_factory):
    """A validated gain set whose feedforward has creep identified at 1 ms, on a plant sampled every 2 ms."""
    import dataclasses

    study = pp.load_study("paper2021")
    record, _ = identified
    plant = dataclasses.replace(study.plant, sample_period_s=0.002)
    gs = pp.GainSet(gains=study.controller, status="validated", feedforward=record.model, plant=plant,
                    preset="paper2021", inputs={"test": "exports"})
    return gs.save(tmp_path_factory.mktemp("gs") / "gains.json")


def _with_feedforward(gs, model):
    import dataclasses

    return dataclasses.replace(gs, feedforward=model)


@pytest.mark.parametrize("fmt", ["json", "labview", "plc", "c-header", "casadi-c"])
def test_a_hysteresis_model_exports_alone_from_the_cli(identified, tmp_path, capsys, fmt):
    record, path = identified
    out = tmp_path / f"ff.{fmt}"
    assert main(["export", str(path), "--format", fmt, "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["kind"] == "hysteresis-model" and summary["file_sha256"] == record.file_sha256
    assert out.read_text() == pp.export(pp.IdentifiedModel.load(path), fmt)
    assert "Kc" not in out.read_text() and "PP_KC" not in out.read_text(), "a model alone carries no gains"


def test_the_model_alones_json_and_its_period(identified):
    record, _ = identified
    doc = json.loads(pp.export(record, "json", sample_period_s=0.0005))
    step = doc["feedforward_inverse_step"]
    assert step["sample_period_s"] == 0.0005 and step["creep_lags"] == record.model.n_lags
    a = np.exp(-0.0005 / record.model.creep.time_constants_s)
    np.testing.assert_allclose(step["parameters"]["creep_decay"], a, rtol=1e-14, err_msg="lags at the asked period")
    assert doc["identified"]["output_range"] == list(record.output_range)


@pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                    reason="no C compiler to build the generated code")
def test_the_model_alones_c_code_runs_the_numpy_step(identified, tmp_path):
    record, _ = identified
    (tmp_path / "ff.c").write_text(pp.export(record, "casadi-c"))
    (tmp_path / "main.c").write_text(
        '#include <stdio.h>\n#include <math.h>\nint pp_feedforward_step(double target, double* state, double* u);\n'
        "int main(void){double x[64] = {0}; double u; int i; for (i = 0; i < 300; ++i) {"
        "pp_feedforward_step(40.0 + 30.0 * sin(0.05 * i), x, &u); printf(\"%.17g\\n\", u);} return 0;}\n")
    cc = shutil.which(os.environ.get("CC", "cc"))
    subprocess.run([cc, "-o", str(tmp_path / "ff"), str(tmp_path / "main.c"),
                    str(tmp_path / "ff.c"), "-lm"], check=True)
    out = np.array(subprocess.run([str(tmp_path / "ff")], capture_output=True, text=True, check=True).stdout.split(),
                   float)
    targets = 40.0 + 30.0 * np.sin(0.05 * np.arange(300))
    np.testing.assert_allclose(out, _numpy(record.model, record.model.sample_period_s, targets), rtol=0, atol=1e-9)


def test_one_module_exports_everything_and_refuses_what_it_cannot(identified, gain_set_with_creep, capsys, tmp_path):
    record, path = identified
    with pytest.raises(ExportError, match="unknown format"):
        pp.export(record, "pdf")
    with pytest.raises(ExportError, match="plant's sample period"):
        pp.export(gain_set_with_creep, "plc", sample_period_s=0.001)
    with pytest.raises(ExportError, match="cannot export a str"):
        pp.export("gains.json", "json")
    gain_set_with_creep.save(tmp_path / "gains.json")
    assert main(["export", str(tmp_path / "gains.json"), "--format", "plc", "--sample-period", "0.001"]) == 2
    assert "--sample-period is for a hysteresis model alone" in capsys.readouterr().err
    assert not hasattr(pp.GainSet, "export"), "the gain set's text formats live in rig.export"



def test_the_docs_state_the_algorithm_the_exports_state():
    """docs/exports.md holds the algorithm's text as the LabVIEW file states it: one source, quoted."""
    from pathlib import Path

    docs = (Path(__file__).resolve().parents[1] / "docs" / "exports.md").read_text()
    assert "\n".join(INVERSE_STEP_ALGORITHM) in docs
