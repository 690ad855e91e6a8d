"""Play operators and P-I models against their definitions and closed forms."""

import dataclasses

import numpy as np
import pytest

from piezopreload.models.hysteresis import (
    AsymmetricPI,
    ClassicalPI,
    DeadZone,
    ModifiedPI,
    NotInvertibleError,
    deadzone,
    model_from_dict,
    play,
    uniform_thresholds,
)


def play_reference(v, r, y0=None):
    """Eq. (14) of the paper, sample by sample, written out plainly."""
    y = np.zeros(len(r)) if y0 is None else np.array(y0, float)
    out = []
    for x in v:
        y = np.array([max(x - rk, min(x + rk, yk)) for rk, yk in zip(r, y)])
        out.append(y)
    return np.array(out)


@pytest.fixture
def rng():
    return np.random.default_rng(20211)


@pytest.mark.parametrize("signal", ["smooth", "noisy", "flat-runs"])
def test_play_matches_its_definition(rng, signal):
    t = np.linspace(0, 3, 600)
    v = 80 * np.sin(2 * np.pi * 1.3 * t) * np.exp(-0.3 * t) + 20
    if signal == "noisy":
        v = v + rng.normal(0, 2.0, t.size)
    if signal == "flat-runs":
        v = np.round(v / 10) * 10  # long runs of equal samples
    r = uniform_thresholds(12, 100.0)
    y0 = rng.uniform(-20, 20, r.size)
    np.testing.assert_allclose(play(v, r, y0), play_reference(v, r, y0), rtol=0, atol=1e-12)


def test_play_batch_equals_one_signal_at_a_time(rng):
    v = rng.normal(0, 30, (7, 300)).cumsum(axis=1) / 5  # random walks: many reversals
    r = uniform_thresholds(9, 60.0)
    batch = play(v, r)
    for j in range(v.shape[0]):
        np.testing.assert_allclose(batch[j], play_reference(v[j], r), atol=1e-12, err_msg=f"signal {j}")


def test_play_triangle_wave_closed_form():
    """Periodic triangle between -A and A: ascending branch max(v - r, r - A), descending min(v + r, A - r)."""
    amplitude, r = 10.0, np.array([0.0, 2.0, 4.5, 9.0])
    up = np.linspace(-amplitude, amplitude, 201)
    one_period = np.concatenate([up[100:], up[::-1][1:], up[1:101]])  # 0 -> A -> -A -> 0
    v = np.tile(one_period, 3)
    y = play(v, r)
    last = slice(2 * one_period.size, None)
    v_last, y_last = v[last], y[last]
    rising = np.r_[True, np.diff(v_last) > 0]
    expected = np.where(
        rising[:, None], np.maximum(v_last[:, None] - r, r - amplitude), np.minimum(v_last[:, None] + r, amplitude - r)
    )
    np.testing.assert_allclose(y_last, expected, atol=1e-12)


def test_play_describing_function_of_a_sine():
    """The fundamental of the play output for ``A sin`` is the backlash describing function."""
    amplitude, r = 1.0, 0.3
    n = 20000
    theta = np.arange(3 * n) * 2 * np.pi / n
    y = play(amplitude * np.sin(theta), [r])[2 * n :, 0]
    th = theta[2 * n :]
    a1 = 2 / n * np.sum(y * np.sin(th))
    b1 = 2 / n * np.sum(y * np.cos(th))
    # backlash describing function (e.g. Gelb & Vander Velde), with c = 1 - 2r/A
    c = 1 - 2 * r / amplitude
    in_phase = amplitude / np.pi * (np.pi / 2 + np.arcsin(c) + c * np.sqrt(1 - c**2))
    quadrature = -amplitude / np.pi * (1 - c**2)
    np.testing.assert_allclose([a1, b1], [in_phase, quadrature], atol=2 * np.pi / n * amplitude)


def _random_pi(rng, n=15, reach=100.0):
    w = rng.uniform(0.0, 0.05, n)
    w[0] = 0.4
    return ClassicalPI(uniform_thresholds(n, reach), w, offset=3.0)


def test_inverse_weights_are_eqs_19_20(rng):
    model = _random_pi(rng)
    inv = model.inverse()
    r, w = model.thresholds, model.weights
    for k in range(r.size):
        assert inv.thresholds[k] == pytest.approx(sum(w[i] * (r[k] - r[i]) for i in range(k + 1)), abs=1e-12)
        expected = 1 / w[0] if k == 0 else -w[k] / (sum(w[: k + 1]) * sum(w[:k]))
        assert inv.weights[k] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("kind", ["classical", "modified"])
def test_model_of_inverse_is_identity(rng, kind):
    pi = _random_pi(rng)
    if kind == "classical":
        model = pi
    else:
        model = ModifiedPI(
            pi.thresholds, pi.weights, deadzone_thresholds=[-8.0, -3.0, 0.0, 4.0, 9.0],
            deadzone_weights=[0.3, -0.2, 1.1, 0.5, -0.6], bias=-1.0, offset=2.0,
        )
    t = np.linspace(0, 4, 4000)
    target = 25 + 18 * np.sin(2 * np.pi * t) * np.exp(-0.4 * t) + rng.normal(0, 0.5, t.size)
    inv = model.inverse()
    v = inv(target)
    np.testing.assert_allclose(model(v), target, rtol=1e-9, atol=0, err_msg=f"{kind}: model(inverse(y)) != y")
    # and inverse(model(v)) == v from a state left by an earlier history
    history = 60 * np.sin(np.linspace(0, 9, 500))
    y_hist = play(history, model.thresholds)[-1]
    u = 50 + 30 * np.sin(np.linspace(0, 12, 900))
    np.testing.assert_allclose(inv(model(u, y_hist), inv.state_from_forward(y_hist)), u, rtol=1e-9, atol=1e-9)


def test_step_equals_whole_signal(rng):
    model = _random_pi(rng)
    inv = model.inverse()
    v = 50 + 40 * np.sin(np.linspace(0, 20, 300))
    state, z = model.initial_state(), inv.initial_state()
    for i, x in enumerate(v):
        out, state = model.step(state, x)
        back, z = inv.step(z, out)
        assert out == pytest.approx(model(v)[i], abs=1e-12)
        assert back == pytest.approx(x, abs=1e-9)


def test_not_invertible_is_reported():
    model = ClassicalPI([0.0, 1.0, 2.0], [0.5, -0.7, 0.1])
    assert not model.invertible
    with pytest.raises(NotInvertibleError, match=r"w_1 \+ ... \+ w_2 = -0.2"):
        model.inverse()
    assert not AsymmetricPI([0.0, 1.0], [1.0, 0.1], [1.0, 0.2]).invertible, "eq. (18) has gaps at reversals"
    with pytest.raises(NotInvertibleError, match="rising weights"):
        AsymmetricPI([0.0, 1.0], [1.0, -1.5], [1.0, 0.2]).inverse()
    with pytest.raises(NotInvertibleError, match="negative side"):
        DeadZone([-1.0, 0.0], [-2.0, 1.0]).inverse()


def test_deadzone_operator_definition():
    z = np.array([-5.0, -1.0, 0.0, 2.0, 6.0])
    d = deadzone(z, [-2.0, 0.0, 3.0])
    np.testing.assert_array_equal(d[:, 0], [-3.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(d[:, 1], z)
    np.testing.assert_array_equal(d[:, 2], [0.0, 0.0, 0.0, 0.0, 3.0])


def test_asymmetric_model_switches_on_direction():
    r = uniform_thresholds(4, 10.0)
    w_up, w_down = np.array([1.0, 0.2, 0.1, 0.05]), np.array([0.8, 0.3, 0.0, 0.1])
    model = AsymmetricPI(r, w_up, w_down, offset=1.0)
    v = np.array([0.0, 3.0, 8.0, 8.0, 5.0, 1.0, 4.0])
    y = play(v, r)
    rising = np.array([True, True, True, True, False, False, True])  # v_i >= v_{i-1}, v_-1 = 0
    expected = np.where(rising, y @ w_up, y @ w_down) + 1.0
    np.testing.assert_allclose(model(v), expected)
    np.testing.assert_allclose(AsymmetricPI(r, w_up, w_up)(v), ClassicalPI(r, w_up)(v))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(thresholds=[1.0, 2.0], weights=[1.0, 1.0]), r"thresholds\[0\] must be 0"),
        (dict(thresholds=[0.0, 2.0, 2.0], weights=[1.0, 1.0, 1.0]), "strictly increasing"),
        (dict(thresholds=[0.0, 2.0], weights=[1.0, np.nan]), r"weights\[1\] is nan"),
        (dict(thresholds=[0.0, 2.0], weights=[1.0]), "must have 2 entries"),
        (dict(thresholds=[0.0, 2.0], weights=[1.0, 1.0], offset=np.inf), "offset must be finite"),
    ],
)
def test_parameters_validate_themselves(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ClassicalPI(**kwargs)


def test_parameters_are_frozen(rng):
    model = _random_pi(rng)
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.offset = 1.0
    with pytest.raises(ValueError):
        model.weights[0] = 2.0  # read-only array


def test_dict_round_trip(rng):
    pi = _random_pi(rng)
    models = [
        pi,
        AsymmetricPI(pi.thresholds, pi.weights, pi.weights[::-1], 2.0),
        ModifiedPI(pi.thresholds, pi.weights, [-1.0, 0.0, 2.0], [0.5, 1.0, 0.2], bias=0.3, offset=-1.0),
    ]
    v = 40 * np.sin(np.linspace(0, 10, 200)) + 30
    for model in models:
        back = model_from_dict(model.to_dict())
        assert type(back) is type(model)
        np.testing.assert_array_equal(back(v), model(v), err_msg=f"{model.kind} round trip")
    bad = pi.to_dict()
    del bad["weights"]
    with pytest.raises(ValueError, match=r"model.weights is missing"):
        model_from_dict(bad)
    with pytest.raises(ValueError, match="model.kind must be one of"):
        model_from_dict({**pi.to_dict(), "kind": "preisach"})
