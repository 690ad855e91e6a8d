"""The one closed loop: the compiled loop against the numpy loop, the build cache, the fall-back, and the
paper's numbers, the tuned gains and the validation verdict as the numpy loop gave them before it was compiled."""

import json
import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from piezopreload.core import native
from piezopreload.models.actuator import Plant, PlantModel, Rig
from piezopreload.models.closedloop import Reference, simulate, simulate_open_loop
from piezopreload.models.controller import Controller, ControllerModel, PIDGains
from piezopreload.models.hysteresis import ClassicalPI
from piezopreload.models.loop import LOOP_OUTPUTS, LoopModel, OpenLoopModel, run, step_function
from piezopreload.models.ops import NUMPY
from piezopreload.tuning.calibrate import reproduce
from piezopreload.tuning.pid import tune_pid
from piezopreload.tuning.validate import validate

needs_cc = pytest.mark.skipif(not native.enabled(), reason="no working C compiler (or PIEZOPRELOAD_ENGINE=numpy): "
                                                           "the compiled loop cannot be built here")

#: What the numpy loop gave on the paper's study before the loop was compiled (the commit before the
#: one closed loop, numpy Rig.step + Controller.step_terms): the six step numbers with the paper's gains
#: (seed 0, measured force, band 1.5 N), the tuned gains, and the 200-plant validation of those gains.
BEFORE = {
    "reproduce": {"pid": {"rise_s": 1.256, "peak_s": 2.751, "settling_s": 3.302},
                  "ff+pid": {"rise_s": 0.077, "peak_s": 0.162, "settling_s": 1.886}},
    "gains": {"Kc": 2.079505609670705, "Ti_s": 0.07305119553137648, "Td_s": 0.00678867033156746,
              "Tf_s": 0.0958905881594238, "b": 0.2769066725530569},
    "validation_worst": {"settling_s": 0.18700000000000006, "overshoot_N": 1.352473638893656,
                         "tracking_rms_N": 0.5438044654377532, "peak_voltage_V": 110.0,
                         "tracking_rms_all_N": 3.5291180201888612},
}


def _ff():
    return ClassicalPI(np.array([0.0, 8.0, 20.0, 40.0]), np.array([0.45, 0.12, 0.08, 0.05]), 25.0).inverse()


def _hard_reference():
    """Up into the 110 V clamp (a level the rig cannot reach), down to the bolt preload, back up: the
    controller's clamp, its conditional integration and the amplifier's slew limit all act."""
    return Reference.staircase(25.0, [60.0, 130.0, 30.0, 80.0], 0.6, t_start_s=0.05)


@needs_cc
def test_one_compiled_step_equals_the_numpy_step_from_any_state():
    """The loop's step as C (the runner, one sample each) and on numpy, from 400 random states and plants:
    slewing, clamped and inside both."""
    rng = np.random.default_rng(5)
    base = Plant(bw_gamma_per_V=0.004)
    plants = base.vary(400, {"amp_bandwidth_Hz": 0.3, "amp_current_limit_A": 0.5, "bw_alpha": 0.3,
                             "coupling_stiffness_N_per_um": 0.2, "creep_per_decade": 0.5}, seed=1)
    rig = Rig(plants)
    controller = Controller(PIDGains(Kc=1.5, Ti_s=0.05, Td_s=0.004, Tf_s=0.02, b=0.4), rig.dt_s, _ff())
    model = LoopModel(rig.model, controller.model)
    params = model.parameters(rig.parameter_vector, controller.parameter_vector())
    x = np.zeros((400, model.state.size))
    lay = model.state
    x[:, lay.slice("plant")] = rng.uniform([-5, -20, 0, 0, 0, 0, -10], [115, 20, 40, 40, 40, 40, 130], (400, 7))
    ctrl = x[:, lay.slice("controller")]
    ctrl[:, :5] = rng.normal(0.0, [40.0, 20.0, 50.0, 50.0, 200.0], (400, 5)) + [0.0, 0.0, 60.0, 60.0, 0.0]
    ctrl[:, 5:] = rng.uniform(-30.0, 30.0, (400, 4))
    series = {"reference_N": rng.uniform(20.0, 130.0, (1, 400)), "noise": rng.standard_normal((1, 400)),
              "ff_extra_V": rng.normal(0.0, 5.0, (1, 400))}
    yc, xc, engine = run(model, params, x, series, 1, engine="c")
    yn, xn, _ = run(model, params, x, series, 1, engine="numpy")
    assert engine == "c"
    u = yn[:, LOOP_OUTPUTS.index("command_V"), 0]
    assert np.any(u == 110.0) and np.any(u == 0.0) and np.any((u > 0.0) & (u < 110.0)), "clamp both ways and free"
    dv = xn[:, lay.slice("plant")][:, 0] - x[:, lay.slice("plant")][:, 0]
    slew = rig.parameter_vector[:, rig.model.params.index("slew_V_per_sample")]
    assert np.any(np.isclose(np.abs(dv), slew, rtol=1e-12)), "some plants slew-limited"
    np.testing.assert_allclose(yc, yn, rtol=0, atol=1e-9, err_msg="the outputs of one step")
    np.testing.assert_allclose(xc, xn, rtol=0, atol=1e-9, err_msg="the next states of one step")


@needs_cc
@pytest.mark.parametrize("batch", [None, 6])
def test_the_compiled_loop_runs_the_numpy_loop(batch):
    """simulate with the compiled loop against the numpy loop, one plant and a batch (each its own noise), through
    the clamp, the conditional integration and the slew limit: every sample of every signal to 1e-9."""
    params = Plant(noise_N=0.3, bw_gamma_per_V=0.003)
    if batch:
        params = params.vary(batch, {"amp_current_limit_A": 0.3, "bw_alpha": 0.2, "creep_per_decade": 0.3}, seed=3)
    rig = Rig(params)
    controller = Controller(PIDGains(Kc=1.4, Ti_s=0.05, Td_s=0.004, Tf_s=0.02, b=0.3), rig.dt_s, _ff())
    ref = _hard_reference()
    fast = simulate(rig, controller, ref, seed=11, engine="c")
    slow = simulate(rig, controller, ref, seed=11, engine="numpy")
    assert (fast.engine, slow.engine) == ("c", "numpy")
    assert np.max(slow.command_V) == 110.0 and np.min(slow.command_V) == 0.0, "the clamp acts both ways"
    slew = np.asarray(params.slew_V_per_s) * rig.dt_s
    dv = np.abs(np.diff(slow.voltage_V, axis=-1))
    assert np.all(np.any(np.isclose(dv, np.asarray(slew)[..., None], rtol=1e-12), axis=-1)), "every plant slews"
    for name in LOOP_OUTPUTS.names:
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-9, err_msg=name)


@needs_cc
@pytest.mark.parametrize("delay", [0, 2])
def test_other_structures_compile_to_the_same_numbers(delay):
    """No delay, a two-sample delay line, two creep lags and no feedforward: other layouts, other code."""
    rig = Rig(Plant(noise_N=0.2, delay_samples=delay, creep_tau_s=(0.05, 0.5)))
    c = Controller(PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.002, Tf_s=0.01), rig.dt_s)
    ref = Reference.step(25.0, 70.0, 0.05, 0.5)
    fast, slow = simulate(rig, c, ref, seed=1, engine="c"), simulate(rig, c, ref, seed=1, engine="numpy")
    for name in LOOP_OUTPUTS.names:
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-9, err_msg=name)


@needs_cc
def test_the_compiled_open_loop_runs_the_numpy_open_loop():
    rig = Rig(Plant(noise_N=0.2))
    command = np.concatenate([np.linspace(0.0, 160.0, 900), np.full(400, 160.0), np.full(600, -45.0),
                              np.linspace(-10.0, 90.0, 800)])
    fast = simulate_open_loop(rig, command, seed=2, engine="c")
    slow = simulate_open_loop(rig, command, seed=2, engine="numpy")
    for key in ("voltage_V", "force_N", "measured_N"):
        np.testing.assert_allclose(fast[key], slow[key], rtol=0, atol=1e-9, err_msg=key)
    v = slow["voltage_V"]
    assert 119.99 < v.max() <= 120.0 and -20.0 <= v.min() < -19.99, "the amplifier's range clips the command"


@needs_cc
def test_a_batch_keeps_each_plants_noise_whatever_the_engine():
    """A batch of identical plants draws one noise value per plant and sample, in time order: plant 2 of the
    batch is not the single run with the same seed, but both engines give it alike (the noise is an input)."""
    rig = Rig(Plant(noise_N=0.5))
    c = Controller(PIDGains(Kc=0.3, Ti_s=0.08, Td_s=0.001), rig.dt_s)
    ref = Reference.step(25.0, 60.0, 0.1, 0.5)
    runs = {e: simulate(rig, c, ref, seed=4, batch=(3,), engine=e) for e in ("c", "numpy")}
    z = np.random.default_rng(4).standard_normal((runs["c"].t_s.size, 3))
    for e, run_ in runs.items():
        reading = np.round(run_.force_N + 0.5 * z.T, 6)
        np.testing.assert_allclose(run_.measured_N, reading, atol=rig.params.adc_lsb_N, err_msg=f"noise as drawn ({e})")
    np.testing.assert_allclose(runs["c"].measured_N, runs["numpy"].measured_N, rtol=0, atol=1e-9)


def test_the_numpy_engine_is_forced_by_the_environment(monkeypatch):
    monkeypatch.setenv(native.ENGINE_ENV, "numpy")
    rig = Rig(Plant())
    run_ = simulate(rig, Controller(PIDGains(0.3, 0.08), rig.dt_s), Reference.step(25.0, 30.0, 0.01, 0.05))
    assert run_.engine == "numpy"
    from piezopreload.rig.compiled import controller_step

    assert controller_step(Controller(PIDGains(0.3, 0.08), 1e-3)).kind == "numpy"


def test_no_compiler_falls_back_to_numpy_and_a_failing_one_too(monkeypatch, tmp_path):
    rig = Rig(Plant(delay_samples=3))  # a structure no other test compiles
    c = Controller(PIDGains(0.3, 0.08), rig.dt_s)
    ref = Reference.step(25.0, 30.0, 0.01, 0.05)
    reference = simulate(rig, c, ref, engine="numpy")
    monkeypatch.setattr(native, "compiler", lambda: None)
    assert simulate(rig, c, ref).engine == "numpy"
    monkeypatch.undo()
    # a "compiler" that answers --version but cannot compile
    fake = tmp_path / "broken-cc"
    fake.write_text("#!/bin/sh\nif [ \"$1\" = --version ]; then echo broken 1.0; exit 0; fi\necho nope >&2; exit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    native.reset_failures()
    fallback = simulate(rig, c, ref)
    assert fallback.engine == "numpy"
    np.testing.assert_array_equal(fallback.force_N, reference.force_N)
    monkeypatch.setenv(native.ENGINE_ENV, "c")
    with pytest.raises(native.NativeBuildError, match="broken-cc failed"):
        simulate(Rig(Plant(delay_samples=4)), c, ref)
    native.reset_failures()


@needs_cc
def test_the_cache_rebuilds_when_the_definition_changes(monkeypatch, tmp_path):
    """The library is keyed by its generated source: the same definition is loaded from the cache, a changed one
    (here the plant's force with 1 N added, as an edit of models/actuator.py would) is built anew and gives
    the changed numbers."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    model = OpenLoopModel(PlantModel(n_creep=2, delay_samples=1))
    before = native.build_stats()
    first = native.StepRunner(step_function(model), "pp_test_open_loop")
    again = native.StepRunner(step_function(model), "pp_test_open_loop")
    after = native.build_stats()
    assert after["builds"] - before["builds"] == 1 and after["cache_hits"] - before["cache_hits"] == 1
    assert len(list(tmp_path.glob("piezopreload/pp_test_open_loop-*.so"))) == 1
    original_force = PlantModel.force
    monkeypatch.setattr(PlantModel, "force", lambda self, ops, p, x: original_force(self, ops, p, x) + 1.0)
    changed = native.StepRunner(step_function(model), "pp_test_open_loop")
    assert native.build_stats()["builds"] - after["builds"] == 1
    assert len(list(tmp_path.glob("piezopreload/pp_test_open_loop-*.so"))) == 2
    rig = Rig(Plant(creep_tau_s=(0.1, 1.0)))
    x0 = model.start(NUMPY, rig.parameter_vector)
    u = np.linspace(0.0, 50.0, 20)
    y0, _ = first(rig.parameter_vector, x0, [u, np.zeros(20)], 1)
    y1, _ = changed(rig.parameter_vector, x0, [u, np.zeros(20)], 1)
    y2, _ = again(rig.parameter_vector, x0, [u, np.zeros(20)], 1)
    force = model.outputs.index("force_N")
    np.testing.assert_allclose(y1[0, force] - y0[0, force], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(y2, y0)
    log = [json.loads(line) for line in (tmp_path / "piezopreload" / "builds.jsonl").read_text().splitlines()]
    assert [r["name"] for r in log] == ["pp_test_open_loop"] * 2 and all(r["seconds"] > 0 for r in log)


_BUILD = textwrap.dedent("""
    import sys
    from piezopreload.core import native
    from piezopreload.models.actuator import PlantModel
    from piezopreload.models.loop import OpenLoopModel, step_function
    runner = native.StepRunner(step_function(OpenLoopModel(PlantModel(n_creep=3, delay_samples=2))), "pp_race")
    print(native.build_stats()["builds"])
""")


@needs_cc
@pytest.mark.slow  # tunings, validations, builds
def test_two_processes_building_the_same_library_at_once(tmp_path):
    """Each compiles in a private folder and renames the result into place: both load a whole library."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", _BUILD], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [err for _, err in outs]
    assert len(list(tmp_path.glob("piezopreload/pp_race-*.so"))) == 1
    assert not list(tmp_path.glob("piezopreload/.build-*")), "no build folder left behind"


def test_the_papers_six_numbers_as_before(study):
    """``piezopreload reproduce``'s simulation (now on the compiled loop where it builds) gives the numbers the
    numpy loop gave, to the sample."""
    rep = reproduce(study.plant, study.controller, step=study.references["step"], excitation=study.feedforward,
                    seed=study.seed, band_N=study.band_N, signal=study.signal)
    for controller, metrics in BEFORE["reproduce"].items():
        for key, value in metrics.items():
            assert rep.metrics[controller][key] == pytest.approx(value, abs=1e-9), (controller, key)
    assert rep.runs["ff+pid"].engine == ("c" if native.enabled() else "numpy")


@pytest.mark.slow  # tunings, validations, builds
def test_the_tuned_gains_and_the_validation_verdict_as_before(study, feedforward):
    """The paper's study tuned on the one (smooth) loop gives the gains the separate tuning model gave, and the
    200-plant Monte Carlo validation of them (compiled loop, per-chunk seeds) the same worst cases and verdict."""
    res = tune_pid(study.plant, feedforward.inverse(), study.tuning)
    for key, value in BEFORE["gains"].items():
        assert getattr(res.gains, key) == pytest.approx(value, rel=1e-6), key
    assert res.engine == ("compiled" if native.enabled() else "plain")
    v = validate(res.gains, feedforward, study.plant, study.validation, n_plants=study.validation.plants,
                 seed=study.validation.seed, step=study.references["step"], trajectory=study.references["trajectory"])
    assert v.passed
    summary = v.summary()
    for key, value in BEFORE["validation_worst"].items():
        assert summary[key]["worst"] == pytest.approx(value, rel=1e-6), key


@needs_cc
@pytest.mark.slow  # tunings, validations, builds
def test_compiled_and_plain_tuning_agree():
    """The same NLP with its loop compiled and in CasADi's virtual machine: the same iterates, the same gains."""
    from piezopreload.tuning.pid import TuningSpec

    params = Plant(noise_N=0.0, adc_bits=32, amp_current_limit_A=0.02, creep_per_decade=0.02, bw_kappa=0.05)
    spec = TuningSpec(step=Reference.step(25.0, 50.0, 0.02, 0.2),
                      trajectory=Reference.staircase(25.0, [50.0, 40.0], 0.1, t_start_s=0.02), variants={"gain": 0.1})
    a = tune_pid(params, None, spec, starts=1, engine="compiled")
    b = tune_pid(params, None, spec, starts=1, engine="plain")
    assert (a.engine, b.engine) == ("compiled", "plain") and a.iterations == b.iterations
    for key in ("Kc", "Ti_s", "Td_s", "Tf_s", "b"):
        assert getattr(a.gains, key) == pytest.approx(getattr(b.gains, key), rel=1e-9), key


def test_controller_model_layouts_name_every_number():
    model = Controller(PIDGains(1.0, 0.1), 1e-3, _ff()).model
    assert isinstance(model, ControllerModel) and model.params.names[:8] == (
        "Kc", "Ti_s", "Td_s", "Tf_s", "b", "u_min_V", "u_max_V", "dt_s")
    # offset, bias; r, w, W, r', w'
    assert model.state.field_size("ff") == 4 and model.params.field_size("ff") == 2 + 5 * 4
    loop = LoopModel(PlantModel.of(Plant()), model)
    assert loop.params.size == loop.plant.params.size + model.params.size
    fn = step_function(loop)
    assert isinstance(fn, ca.Function) and fn.name_in() == ["x", "p", "reference_N", "noise", "ff_extra_V"]
    with pytest.raises(ValueError, match="creep lags"):
        PlantModel(n_creep=2).parameters(Plant())
    with pytest.raises(ValueError, match="smoothing"):
        replace(PlantModel(4), smoothing=1.5)


@needs_cc
def test_the_simulated_backends_plant_step_is_the_rigs():
    """The compiled plant step the simulated rig backend runs (read, then write) against Rig.measure/Rig.step."""
    from piezopreload.rig.compiled import PlantStep

    params = Plant(noise_N=0.3, bw_gamma_per_V=0.004)
    fast, slow = PlantStep(params), PlantStep(params, prefer="numpy")
    assert (fast.kind, slow.kind) == ("c", "numpy")
    rig = Rig(params)
    state = rig.initial_state()
    rng = np.random.default_rng(8)
    for k, u in enumerate(np.concatenate([np.linspace(0.0, 140.0, 300), np.full(200, -40.0), np.full(100, 55.0)])):
        z = float(rng.standard_normal())
        reading = float(np.asarray(rig.model.measure(NUMPY, rig.parameter_vector, rig.force(state), z)))
        for plant in (fast, slow):
            force, measured = plant.read(z)
            assert force == pytest.approx(float(rig.force(state)), abs=1e-9), (plant.kind, k)
            assert measured == pytest.approx(reading, abs=1e-9), (plant.kind, k)
            plant.write(u)
        state = rig.step(state, u)
        assert fast.amplifier_V == pytest.approx(float(state.v_amp), abs=1e-9)
    np.testing.assert_allclose(fast.state, rig.vector(state), rtol=0, atol=1e-9)
