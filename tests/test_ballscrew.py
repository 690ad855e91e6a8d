"""The ball-screw and feed-drive models against closed forms and catalogue rows.

Catalogue rows and formulas: ``docs/references.md`` ([HIWIN]: HIWIN "Ballscrews &
Accessories" BS-08-2-EN-1704, ground double nut RDI, rigidity stated at 0.1 C_dyn preload) and
``docs/models.md``, section 5.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezopreload.models.ballscrew import (
    CASADI_OPS,
    LIFT_OFF_RATIO,
    NUMPY_OPS,
    STEEL,
    BallScrew,
    DutyCase,
    _contact_constants,
    hiwin_loaded_nut_force,
    lift_off_load_N,
    load_share,
)
from piezopreload.models.feed_drive import FeedDrive, PiezoPreload, stack_loop_um

# (model, d x lead, ball, turns per nut, rigidity N/um, C_dyn N, C_0 N), HIWIN RDI rows
HIWIN_ROWS = [
    ("R32-5T4-RDI", 32.0, 5.0, 3.175, 4, 820.0, 14310.0, 41080.0),
    ("R40-10T4-RDI", 40.0, 10.0, 6.350, 4, 1010.0, 37890.0, 94260.0),
]


@pytest.mark.parametrize("row", HIWIN_ROWS, ids=[r[0] for r in HIWIN_ROWS])
def test_rigidity_at_a_tenth_of_c_dyn_is_within_20_percent_of_the_catalogue(row):
    name, d, lead, ball, turns, rigidity, c_dyn, _ = row
    screw = BallScrew(d, lead, ball, turns, c_dyn_N=c_dyn)  # the same defaults for both rows
    predicted = float(screw.rigidity_N_per_um(0.1 * c_dyn))
    assert abs(predicted / rigidity - 1.0) <= 0.20, f"{name}: {predicted:.0f} N/um against {rigidity:.0f}"
    # the corrections matter: Hertz alone (all balls, rigid bodies) is far above the catalogue
    hertz_only = BallScrew(d, lead, ball, turns, c_dyn_N=c_dyn, load_sharing=1.0)
    contact = float(hertz_only.nut_loads(0.1 * c_dyn).contact_stiffness_N_per_um)
    assert contact / rigidity > 1.4, f"{name}: Hertz-only {contact:.0f} N/um"


@pytest.mark.parametrize("row", HIWIN_ROWS, ids=[r[0] for r in HIWIN_ROWS])
def test_static_rating_from_hertz_at_4200_MPa_is_near_the_catalogue(row):
    name, d, lead, ball, turns, _, _, c0 = row
    screw = BallScrew(d, lead, ball, turns)
    assert abs(screw.static_rating_N / c0 - 1.0) < 0.10, f"{name}: C_0 {screw.static_rating_N:.0f} against {c0:.0f}"
    # at C_0 the most pressed contact is at the limit
    contact = screw.contact(screw.static_rating_N)
    np.testing.assert_allclose(contact.peak_pressure_MPa, 4200.0, rtol=1e-9)


def test_dynamic_rating_estimate_calibrated_on_one_row_predicts_the_other():
    # the constant is set on R40-10T4 (module docstring); R32-5T4 is a check
    r40 = BallScrew(40.0, 10.0, 6.35, 4)
    r32 = BallScrew(32.0, 5.0, 3.175, 4)
    assert abs(r40.dynamic_rating_N / 37890.0 - 1.0) < 1e-3
    assert abs(r32.dynamic_rating_N / 14310.0 - 1.0) < 0.10, r32.dynamic_rating_N


def test_exact_load_sharing_against_the_hiwin_formula_and_the_force_balance():
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    fp = 3252.0
    fa = np.linspace(0.0, LIFT_OFF_RATIO * fp * (1 - 1e-12), 2001)
    loads = screw.nut_loads(fp, fa)
    # force balance (eqs. (5)-(7)): the loaded nut gains what the other loses plus F_a
    np.testing.assert_allclose(loads.loaded_nut_N - loads.unloaded_nut_N, fa, atol=1e-8 * fp)
    # deformation compatibility (eq. (8)): the two nuts' approaches sum to twice the preload's
    c = screw.axial_constant_um
    np.testing.assert_allclose(c * loads.loaded_nut_N ** (2 / 3) + c * loads.unloaded_nut_N ** (2 / 3),
                               2 * c * fp ** (2 / 3), rtol=1e-12)
    hiwin = hiwin_loaded_nut_force(fp, fa)
    err = hiwin / loads.loaded_nut_N - 1.0
    assert err.max() <= 0.025 and err.min() >= -1e-12, f"HIWIN formula off by {err.min():.4f}..{err.max():.4f}"
    assert abs(err[0]) < 1e-12 and abs(err[-1]) < 1e-6, "the HIWIN formula is exact at both ends"


@pytest.mark.parametrize("ratio", [0.0, 1.0, 2.5])
def test_contact_stiffness_is_the_derivative_of_load_over_deflection(ratio):
    # dF_a/dx by central differences of the exact solution, against the closed form
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    fp, h = 2000.0, 1e-3
    fa = ratio * fp + np.array([-h, h])
    x = screw.nut_loads(fp, fa).deflection_um
    k = screw.nut_loads(fp, ratio * fp).contact_stiffness_N_per_um
    np.testing.assert_allclose(2 * h / (x[1] - x[0]), k, rtol=1e-6)


def test_lift_off_at_two_to_the_three_halves_of_the_preload():
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    fp = 2000.0
    np.testing.assert_allclose(lift_off_load_N(fp), 2 ** 1.5 * fp)
    below = screw.nut_loads(fp, 2 ** 1.5 * fp * (1 - 1e-9))
    above = screw.nut_loads(fp, 2 ** 1.5 * fp * 1.5)
    assert not below.lifted_off and below.unloaded_nut_N < 1e-5 * fp
    assert above.lifted_off and above.unloaded_nut_N == 0.0
    np.testing.assert_allclose(above.loaded_nut_N, 2 ** 1.5 * fp * 1.5, rtol=1e-12)
    # past lift-off one nut alone carries the load: its approach is c_h F_a^(2/3)
    c = screw.axial_constant_um
    np.testing.assert_allclose(above.deflection_um + c * fp ** (2 / 3), c * (2 ** 1.5 * fp * 1.5) ** (2 / 3), rtol=1e-12)
    # the sign of the load says which nut is loaded, not how much
    np.testing.assert_allclose(screw.nut_loads(fp, -3000.0).loaded_nut_N, screw.nut_loads(fp, 3000.0).loaded_nut_N)


def test_load_share_solves_eq_10_on_numpy_and_casadi():
    import casadi as ca

    ratio = np.linspace(0, LIFT_OFF_RATIO * (1 - 1e-12), 501)
    u = load_share(ratio)
    np.testing.assert_allclose((1 + u) ** 1.5 - (1 - u) ** 1.5, ratio, atol=1e-13)
    r = ca.SX.sym("r")
    fun = ca.Function("u", [r], [load_share(r, CASADI_OPS)])
    np.testing.assert_allclose(np.asarray(fun(ratio[1::50])).ravel(), u[1::50], rtol=1e-14)
    # the derivative the design NLP sees is the implicit one: du/dr = 1 / (1.5 (sqrt(1+u) + sqrt(1-u)))
    dfun = ca.Function("du", [r], [ca.jacobian(load_share(r, CASADI_OPS), r)])
    for x, ux in zip(ratio[1:-1:100], u[1:-1:100]):
        np.testing.assert_allclose(float(dfun(x)), 1 / (1.5 * (math.sqrt(1 + ux) + math.sqrt(1 - ux))), rtol=1e-8)


def test_contact_stiffness_grows_as_the_cube_root_of_preload_and_linearises_to_eq_11():
    screw = BallScrew(40.0, 10.0, 6.35, 4)
    fp = np.array([1000.0, 2000.0, 4000.0])
    k = screw.nut_loads(fp).contact_stiffness_N_per_um
    np.testing.assert_allclose(k[1:] / k[:-1], 2 ** (1 / 3), rtol=1e-12)
    r = screw.rigidity_N_per_um(fp)  # with the body in series: less than the cube root, still growing
    np.testing.assert_allclose(1 / r, 1 / k + 1 / screw.body_stiffness_N_per_um, rtol=1e-12)
    assert np.all(r[1:] / r[:-1] > 1.0) and np.all(r[1:] / r[:-1] < 2 ** (1 / 3))
    # eq. (11): for a small load F_a / F_p = 3 d_a / d_p
    fa = 1e-4 * 2000.0
    d_p = screw.axial_constant_um * 2000.0 ** (2 / 3)
    np.testing.assert_allclose(screw.nut_loads(2000.0, fa).deflection_um / d_p, fa / 2000.0 / 3, rtol=1e-4)


def _exact_hertz(E_prime, inv_Rx, inv_Ry, Q):
    """Hertz's point contact with the complete elliptic integrals (scipy), no approximation:
    the ellipticity k = a/b solves R_y/R_x = (k^2 E(m) - K(m)) / (K(m) - E(m)), m = 1 - 1/k^2
    (Hamrock and Brewe 1983, the relation their fits approximate)."""
    from scipy.optimize import brentq
    from scipy.special import ellipe, ellipk

    ratio = inv_Rx / inv_Ry

    def gap(k):
        m = 1 - 1 / k ** 2
        return (k ** 2 * ellipe(m) - ellipk(m)) / (ellipk(m) - ellipe(m)) - ratio

    k = brentq(gap, 1.0 + 1e-9, 100.0, xtol=1e-14)
    m = 1 - 1 / k ** 2
    e_int, f_int = ellipe(m), ellipk(m)
    R = 1 / (inv_Rx + inv_Ry)
    delta = f_int * (9 / (2 * e_int * R) * (Q / (math.pi * k * E_prime)) ** 2) ** (1 / 3)
    a = (6 * k ** 2 * e_int * Q * R / (math.pi * E_prime)) ** (1 / 3)
    b = (6 * e_int * Q * R / (math.pi * k * E_prime)) ** (1 / 3)
    return delta, 3 * Q / (2 * math.pi * a * b)


@pytest.mark.parametrize("side", ["screw", "nut"])
def test_hamrock_brewe_contact_matches_exact_hertz_with_elliptic_integrals(side):
    # the curvatures of a 32 x 10 screw with 6.35 mm balls, beta 45 deg, f 0.55
    D_w, D_pw, cb, f = 6.35, 32.0, math.cos(math.radians(45)), 0.55
    inv_Ry = (2 - 1 / f) / D_w
    inv_Rx = 2 / D_w + 2 * cb / (D_pw - D_w * cb) if side == "screw" else 2 / D_w - 2 * cb / (D_pw + D_w * cb)
    E_prime = STEEL.contact_modulus_MPa
    c_delta, c_p = _contact_constants(NUMPY_OPS, E_prime, inv_Rx, inv_Ry)
    Q = 150.0
    delta, p0 = _exact_hertz(E_prime, inv_Rx, inv_Ry, Q)
    # Hamrock and Brewe give their fits as within about 3 % over 1 <= R_y/R_x <= 100
    np.testing.assert_allclose(c_delta * Q ** (2 / 3), delta, rtol=0.03, err_msg=f"{side} approach")
    np.testing.assert_allclose(c_p * Q ** (1 / 3), p0, rtol=0.03, err_msg=f"{side} peak pressure")


def test_life_and_drag_closed_forms():
    screw = BallScrew(40.0, 10.0, 6.35, 4, c_dyn_N=37890.0)
    fp = 3000.0
    # no axial load: both nuts at F_p; L = 2^(-9/10) (C / (f_p F_p))^3 1e6
    life = screw.life(fp, [DutyCase(0.0, 1000.0, 1.0)], load_factor=1.2)
    L_nut = (37890.0 / (1.2 * fp)) ** 3 * 1e6
    np.testing.assert_allclose(life.revolutions, 2 ** (-0.9) * L_nut, rtol=1e-12)
    np.testing.assert_allclose(life.hours, life.revolutions / (60 * 1000.0), rtol=1e-12)
    assert screw.life(fp, [DutyCase(0.0, 1000.0, 1.0)], reliability=0.99).revolutions == pytest.approx(0.21 * life.revolutions)
    # drag torque T = K_p F_p P / (2000 pi), K_p = 0.05 / sqrt(tan(helix))
    helix = math.atan(10.0 / (math.pi * 40.0))
    np.testing.assert_allclose(screw.drag_torque_Nm(fp), 0.05 / math.sqrt(math.tan(helix)) * fp * 10.0 / (2000 * math.pi))
    # a heavier load shortens life
    assert screw.life(fp, [DutyCase(5000.0, 1000.0, 1.0)]).revolutions < life.revolutions


def test_feed_drive_chain_and_natural_frequency():
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    drive = FeedDrive(table_mass_kg=300.0, screw_length_mm=1000.0, bearing_stiffness_N_per_um=800.0,
                      travel_mm=(100.0, 900.0))
    EA = 206e3 * math.pi * screw.root_diameter_mm ** 2 / 4 * 1e-3
    x = 300.0
    left = 1 / (1 / 800.0 + x / EA)
    right = 1 / (1 / 800.0 + (1000.0 - x) / EA)
    k_nut = float(screw.rigidity_N_per_um(2000.0))
    k = 1 / (1 / k_nut + 1 / (left + right))
    np.testing.assert_allclose(drive.axial_stiffness_N_per_um(screw, 2000.0, x), k, rtol=1e-12)
    np.testing.assert_allclose(drive.natural_frequency_Hz(screw, 2000.0, x), math.sqrt(k * 1e6 / 300.0) / (2 * math.pi),
                               rtol=1e-12)
    # fixed-fixed: softest in the middle; more preload, a higher mode
    f = drive.natural_frequency_Hz(screw, 2000.0, np.linspace(100, 900, 81))
    assert np.argmin(f) == 40
    assert drive.natural_frequency_Hz(screw, 4000.0, 500.0) > drive.natural_frequency_Hz(screw, 2000.0, 500.0)
    fs = FeedDrive(300.0, 1000.0, 800.0, (100.0, 900.0), mounting="fixed-supported")
    np.testing.assert_allclose(fs.screw_side_stiffness_N_per_um(screw.root_diameter_mm, x), left)


def test_stacks_reach_closes_the_loop_equation():
    screw = BallScrew(32.0, 10.0, 6.35, 4)
    stacks = PiezoPreload()
    f_max = stacks.max_preload_N(screw, 500.0)
    used = stack_loop_um(screw.axial_constant_um, 500.0, f_max, stacks.stiffness_N_per_um)
    np.testing.assert_allclose(used, stacks.stroke_um, rtol=1e-9)
    assert 500.0 < f_max < 500.0 + stacks.blocked_force_N
    # half the voltage, less reach
    assert PiezoPreload(drive_V=50.0).max_preload_N(screw, 500.0) < f_max


@pytest.mark.parametrize("kwargs, field", [
    (dict(conformity_screw=0.5), "conformity_screw"),
    (dict(contact_angle_deg=80.0), "contact_angle_deg"),
    (dict(ball_mm=11.0), "ball_mm"),
    (dict(turns=float("nan")), "turns"),
])
def test_invalid_screws_name_the_field(kwargs, field):
    base = dict(nominal_diameter_mm=32.0, lead_mm=10.0, ball_mm=6.35, turns=4)
    with pytest.raises(ValueError, match=field):
        BallScrew(**{**base, **kwargs})
