"""Types where strings chose behaviour: each member knows what it chooses, and the JSON it writes is the strings' own.

The expected JSON texts below are what the code wrote before these types (``piezopreload autotune --json`` on the same
plants), so a type that changed a single byte of a record fails here.
"""

import json

import numpy as np
import pytest

from piezopreload.tuning.loopshape import BOUNDS, Bound, bound_numerators, peaks


def test_each_bound_knows_its_magnitude_and_its_symbol():
    """|S| = 1/|1 + L|, |T| = |L|/|1 + L|, |KS| = |C|/|1 + L| (L = C G), by the definitions, at a few points."""
    C = np.array([2.0 + 1.0j, 0.5 - 0.2j, 10.0 + 0.0j])
    G = np.array([0.3 - 0.4j, 1.5 + 0.1j, -0.05 + 0.02j])
    L = C * G
    expected = {"Ms": 1 / np.abs(1 + L), "Mt": np.abs(L) / np.abs(1 + L), "Mks": np.abs(C) / np.abs(1 + L)}
    for b in BOUNDS:
        np.testing.assert_allclose(b.magnitude(C, G), expected[b.value], rtol=1e-14, err_msg=f"{b} magnitude")
        np.testing.assert_allclose(bound_numerators(C.real, C.imag, L.real, L.imag)[b], np.abs(b.numerator(C, L)) ** 2,
                                   rtol=1e-14, err_msg=f"{b} numerator")
    assert [b.symbol for b in BOUNDS] == ["|S|", "|T|", "|KS|"]
    assert peaks(C, G) == {b: pytest.approx(float(np.max(expected[b.value]))) for b in BOUNDS}
    with pytest.raises(ValueError):
        Bound("Mx")


def test_the_autotuners_record_is_written_as_before():
    """The bounds, the user's, the defaults (keyed by Bound), the form and the metric (Form, Metric): the same JSON
    as the strings wrote."""
    from piezopreload.tuning.autotune import autotune

    keys = ("form", "metric", "bounds", "user_bounds", "defaults")
    r = autotune(_tf([1.0], [1.0, 3.0, 3.0, 1.0]), Ms=1.4, Mt=1.4)
    assert json.dumps({k: r.to_dict()[k] for k in keys}) == (
        '{"form": "PID", "metric": "IE", "bounds": {"Ms": 1.4, "Mt": 1.4}, "user_bounds": {"Ms": 1.4, "Mt": 1.4}, '
        '"defaults": {}}')
    r = autotune(_tf([2.0], [1.0, 1.0]), delay_s=0.2, Ms=1.6, u_min=0.0, u_max=10.0, Ts=0.05)
    assert json.dumps({k: r.to_dict()[k] for k in keys}) == (
        '{"form": "PID", "metric": "IE", "bounds": {"Ms": 1.6, "Mks": 10.0}, "user_bounds": {"Ms": 1.6}, '
        '"defaults": {"Mks": {"value": 10.0, "reason": "set from the actuator\'s range 0..10: one measured unit of '
        'noise may move the command across at most its span (10); give Mks for your measurement\'s noise"}, '
        '"Tf_min_s": {"value": 0.05, "reason": "the derivative filter\'s floor at Ts 0.05 s: a faster filter does not '
        'filter in the controller step (its pole below z = 1/2)"}}}')


def _tf(num, den):
    import control

    return control.tf(num, den)


def test_the_exchange_sizes_its_trust_region_by_the_form_not_by_the_vectors_length():
    """A PID's region holds the derivative within reach/2 of its scale and the filter's log within reach/2; a PI's
    has no such rows, and a vector of the other form's length is refused (it was told apart by ``x.size == 4``)."""
    from piezopreload.core.errors import InternalError
    from piezopreload.tuning.autosearch import _region
    from piezopreload.tuning.pidopt import Form

    lo, hi = _region(np.array([1.0, 1.0, 0.5, 0.0]), Form.PID, reach=1.0)
    np.testing.assert_allclose(lo, [1 / 1.5, 1 / 1.5, 0.5 - 0.25, -0.5])
    np.testing.assert_allclose(hi, [1.5, 1.5, 0.5 + 0.25, 0.5])
    lo, hi = _region(np.array([1.0, 2.0]), Form.PI, reach=2.0)
    np.testing.assert_allclose(lo, [0.5, 1.0])
    np.testing.assert_allclose(hi, [2.0, 4.0])
    with pytest.raises(InternalError, match="PID's trust region needs 4 variables"):
        _region(np.array([1.0, 2.0]), Form.PID)
    assert Form.of(0) is Form.PI and Form.of(2) is Form.PID and json.dumps(Form.PID) == '"PID"'


def test_the_objective_is_a_type_and_says_what_is_minimised():
    from piezopreload.tuning.pidopt import IE, LoadStepIAE

    assert IE.value(123.0, ki=4.0) == -4.0
    assert LoadStepIAE(lambda g: g, 2.0).value(0.7, ki=4.0) == 0.7
    with pytest.raises(Exception, match="scale must be a positive number"):
        LoadStepIAE(lambda g: g, 0.0)


def test_the_thermal_cases_and_the_assumptions_ranges_are_types():
    from piezopreload.artifacts.thermal import CASES, PreloadCase
    from piezopreload.design.sensitivity import ASSUMPTIONS, Around, Assumption, Effect

    assert json.dumps({c: 1 for c in CASES}) == '{"schedule": 1, "constant": 1}'
    assert PreloadCase("schedule") is PreloadCase.SCHEDULE
    assert Around.ADD.ends(10.0, -1.0, 2.0) == (9.0, 12.0) and Around.TIMES.ends(10.0, 0.5, 2.0) == (5.0, 20.0)
    assert Around.ENDS.ends(10.0, 1.0, 2.0) == (1.0, 2.0)
    assert all(isinstance(a.around, Around) and all(isinstance(m, Effect) for m in a.moves) for a in ASSUMPTIONS)
    with pytest.raises(ValueError, match="around must be an Around"):
        Assumption("k", "n", 0.0, 1.0, "-", "s", (0.0, 2.0), (Effect.THERMAL,), around="add")
    with pytest.raises(ValueError, match="moves must name"):
        Assumption("k", "n", 0.0, 1.0, "-", "s", (0.0, 2.0), ("thermal",))
