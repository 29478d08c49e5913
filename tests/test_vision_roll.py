"""Roll from marker widths (Alrazouk et al. 2024, eqs. (8), (10), section IV.C): the numeric
and the Pade solvers against edges generated from a known roll."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from vision.errors import VisionError
from vision.roll import (coefficients_eq8, coefficients_eq10, pade_polynomial, pade_tan, residual, roll_bound_eq14,
                         roll_sigma, solve_exact, solve_numeric, solve_pade)

#: What the cross-section of a camera rolled by phi sees: alpha = atan(Y / H) + phi (module doc).
def angles(Y, H, phi):
    return np.arctan(np.asarray(Y) / H) + phi


def two_markers(e, L, w1, w2):
    """Edge positions (m, left positive) of two markers, left edge first, centres L apart."""
    return np.array([e + L / 2 + w1 / 2, e + L / 2 - w1 / 2, e - L / 2 + w2 / 2, e - L / 2 - w2 / 2])


geometry = dict(
    H=st.floats(0.8, 2.0), e=st.floats(-1.5, 1.5), L=st.floats(2.8, 4.0), w=st.floats(0.1, 0.3),
    phi=st.floats(-0.6, 0.6),
)


@settings(max_examples=300, deadline=None)
@given(**geometry)
def test_numeric_solver_recovers_roll_of_eq8(H, e, L, w, phi):
    """Noise-free edges from a roll phi: eq. (8) solved numerically returns phi to 1e-6 rad
    (the bracketed root is exact to the solver's tolerance, 1e-12)."""
    a = angles(two_markers(e, L, w, w), H, phi)
    if np.any(np.abs(a) > 1.55):
        return  # an edge beyond the virtual horizon: not in the picture
    assert solve_numeric(a, coefficients_eq8(), 0.0) == pytest.approx(phi, abs=1e-6)


@settings(max_examples=300, deadline=None)
@given(**geometry, ratio=st.floats(0.5, 2.0))
def test_known_unequal_widths(H, e, L, w, phi, ratio):
    """With the widths' ratio known (beyond the paper), unequal markers give the roll too."""
    a = angles(two_markers(e, L, w, w / ratio), H, phi)
    assume(not np.any(np.abs(a) > 1.55))
    assert solve_numeric(a, coefficients_eq8(ratio), 0.0) == pytest.approx(phi, abs=1e-6)


@settings(max_examples=300, deadline=None)
@given(H=st.floats(0.8, 2.0), e=st.floats(-1.5, 1.5), L=st.floats(2.8, 4.0), phi=st.floats(-0.6, 0.6))
def test_numeric_solver_recovers_roll_of_eq10(H, e, L, phi):
    """Three equally spaced line centres: eq. (10) returns phi to 1e-6 rad."""
    a = angles(np.array([e + L, e, e - L]), H, phi)
    assume(not np.any(np.abs(a) > 1.55))
    assert solve_numeric(a, coefficients_eq10(), 0.0) == pytest.approx(phi, abs=1e-6)


def _within(a, phi, limit_deg):
    return np.all(np.abs(a - phi) < math.radians(limit_deg))


@settings(max_examples=300, deadline=None)
@given(**geometry)
def test_pade_solver_recovers_roll_and_agrees_with_numeric(H, e, L, w, phi):
    """The degree-17 Pade polynomial (section IV.C, cubic coefficient corrected to 1/9): its
    real root nearest the seed is phi within 1e-6 rad and within 1e-4 deg of the numeric root,
    for edges up to 63 deg from the nadir (the [5/4] approximant of tan errs by 2.6e-6 relative
    to sec^2 at 1.36 rad; beyond 65 deg the two differ by up to 3e-4 deg, see the next test)."""
    a = angles(two_markers(e, L, w, w), H, phi)
    assume(_within(a, phi, 63.0))
    p_num = solve_numeric(a, coefficients_eq8(), 0.0)
    p_pade = solve_pade(a, coefficients_eq8(), 0.0)
    assert p_pade == pytest.approx(phi, abs=1e-6)
    assert math.degrees(abs(p_pade - p_num)) < 1e-4


def test_pade_disagreement_far_from_the_nadir_is_small_and_known():
    """A marker 78 deg from the nadir (a line 5.25 m to the side of a camera 1.1 m high, the
    simulator's two-line setup): the Pade root is off by less than 5e-4 deg, two orders of
    magnitude below the estimator's error (documented limit of the approximation)."""
    a = angles(two_markers(-1.75, 7.0, 0.15, 0.15), 1.1, math.radians(10.0))
    p_num = solve_numeric(a, coefficients_eq8(), 0.0)
    p_pade = solve_pade(a, coefficients_eq8(), 0.0)
    assert math.degrees(abs(p_pade - p_num)) < 5e-4


def test_pade_polynomial_degrees():
    """Eq. (8) gives a polynomial of degree 17, eq. (10) of degree 13."""
    a4 = np.radians([40.0, 38.0, -30.0, -33.0])
    assert pade_polynomial(a4, coefficients_eq8()).size - 1 == 17
    assert pade_polynomial(a4[:3], coefficients_eq10()).size - 1 == 13


def test_pade_numerator_as_printed_is_a_slip():
    """The paper prints N(x) = x - 5/9 x^3 + x^5/945; the [5/4] approximant of tan has 1/9.
    With 1/9, N/D matches tan to 1e-10 at 0.5 rad; with 5/9 it is off by 6 %."""
    x = 0.5
    n, d = pade_tan(x)
    assert n / d == pytest.approx(math.tan(x), rel=1e-9)
    n_paper = x - 5.0 / 9.0 * x**3 + x**5 / 945.0
    assert abs(n_paper / d - math.tan(x)) / math.tan(x) > 0.05


@settings(max_examples=200, deadline=None)
@given(**geometry)
def test_exact_tangent_substitution_contains_the_root(H, e, L, w, phi):
    """Cross-check: with t = tan(phi), eq. (8) is a quartic in t whose roots include phi."""
    a = angles(two_markers(e, L, w, w), H, phi)
    assume(not np.any(np.abs(a) > 1.55))
    roots = solve_exact(a, coefficients_eq8())
    assert np.min(np.abs(roots - phi)) < 1e-6


def test_residual_sign_and_root():
    """f(phi) vanishes at the true roll and changes sign across it."""
    phi = math.radians(7.0)
    a = angles(two_markers(0.3, 3.5, 0.15, 0.15), 1.2, phi)
    c = coefficients_eq8()
    assert abs(residual(phi, a, c)) < 1e-12
    assert np.sign(residual(phi - 0.01, a, c)) != np.sign(residual(phi + 0.01, a, c))


def test_numeric_solver_stacks_cross_sections():
    """Several cross-sections (beyond the paper) are solved together: same root."""
    phi = math.radians(-12.0)
    rows = np.stack([angles(two_markers(e, 3.5, 0.15, 0.15), 1.1, phi) for e in (-1.0, -0.5, 0.2)])
    assert solve_numeric(rows, coefficients_eq8(), 0.0) == pytest.approx(phi, abs=1e-9)


def test_eq8_always_has_a_root_and_bad_input_raises():
    """Within the domain where every |alpha - phi| < pi/2, f runs from +inf to -inf, so eq. (8)
    always has a root; markers of very unequal widths put it at an absurd roll (the estimator
    rejects attitudes out of range). Non-finite angles raise."""
    a = np.array([0.3, 0.0, -0.2999, -0.3])       # 0.3 rad against 0.0001 rad wide
    phi = solve_numeric(a, coefficients_eq8(), 0.0)
    assert abs(phi) > math.radians(60.0)
    with pytest.raises(VisionError):
        solve_numeric([np.nan, 0.1, 0.2, 0.3], coefficients_eq8(), 0.0)


def test_eq14_expression_underestimates_the_propagated_error():
    """Eq. (14)'s derivation divides by the sum of sec^2 (|dg/dphi| summed) where f depends on
    phi through their signed sum, which nearly cancels. For the simulator's two-line geometry
    (markers 1.75 m and 5.25 m from a camera 1.1 m high) its expression before the final
    inequality is more than ten times smaller than the first-order error of the same 1 px edge
    error; the final bound, dp / f_vx, is loose enough to land near the right order."""
    H, dy = 1.1, 0.018                    # BEV pixel 1.8 cm: f_vx = H / dy
    f_vx = H / dy
    a = angles(two_markers(-1.75, 7.0, 0.15, 0.15), H, 0.0)
    p = f_vx * np.tan(a)                  # BEV columns from the nadir
    q = 1.0 / np.cos(a) ** 2
    dp = 1.0
    expression = np.sum(f_vx / (p**2 + f_vx**2) * q * dp) / np.sum(q)
    sigma_alpha = dp * f_vx / (p**2 + f_vx**2)          # d alpha / d p
    propagated = roll_sigma(a, coefficients_eq8(), 0.0, sigma_alpha)
    assert propagated > 10 * expression
    bound = roll_bound_eq14(889, 16.0, H, 0.0, dp)       # = dp W / (h w_pix) = dp / f_vx
    assert bound == pytest.approx(dp / f_vx, rel=0.01)
    assert 0.3 * propagated < bound < 3 * propagated
