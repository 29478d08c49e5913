"""The compiled pieces of the marker detection and the lane fit against their plain numpy
definitions.

These kernels are written as loops that numba vectorises (a loop from 0, integer compares and
sums); a rewrite that keeps them fast must keep them equal to the definitions here: exactly
for the integer ones, to rounding (1e-12 relative: the compiler may fuse a multiply and an
add) for the floating ones.
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.lanemodel import _sag_weight, sag_weight
from vision.lanes import _binarize, _left_edge_distance, _threshold_sample, marker_response


def _binarize_reference(resp, thr, lo, hi, margin):
    out = np.zeros(resp.shape, np.uint8)
    cols = np.arange(resp.shape[1])
    for v in range(resp.shape[0]):
        a = max(0, int(np.ceil(lo[v] + margin)))
        b = min(resp.shape[1] - 1, int(np.floor(hi[v] - margin)))
        inside = (cols >= a) & (cols <= b)
        out[v] = inside & (resp[v] > thr)
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), thr=st.one_of(st.integers(-600, 900).map(float), st.floats(-600, 900),
                                                   st.sampled_from([-1e6, 1e6])))
def test_binarize_is_the_threshold_inside_the_footprint(seed, thr):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 40)), int(rng.integers(1, 60))
    resp = rng.integers(-500, 800, (h, w)).astype(np.int16)
    lo = rng.uniform(-10.0, w, h)
    hi = lo + rng.uniform(-5.0, w + 10.0, h)         # some rows empty (hi < lo)
    margin = float(rng.uniform(0.0, 5.0))
    assert np.array_equal(_binarize(resp, thr, lo, hi, margin), _binarize_reference(resp, thr, lo, hi, margin))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_threshold_sample_is_every_fourth_pixel_inside_the_footprint(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 50)), int(rng.integers(1, 70))
    resp = rng.integers(-500, 800, (h, w)).astype(np.int16)
    lo = rng.uniform(-10.0, w, h)
    hi = lo + rng.uniform(-5.0, w + 10.0, h)
    margin = float(rng.uniform(0.0, 5.0))
    cols = np.arange(0, w, 4)[None, :]
    inside = (cols >= (lo[::4] + margin)[:, None]) & (cols <= (hi[::4] - margin)[:, None])
    assert np.array_equal(_threshold_sample(resp, lo, hi, margin), resp[::4, ::4][inside])


def test_left_edge_distance_is_the_median_on_common_rows():
    va = np.arange(10.0, 60.0)
    vb = np.arange(40.0, 90.0, 2.0)
    ca, cb = np.array([0.3, -2.0, 100.0]), np.array([0.1, -1.0, 103.0])
    common = np.intersect1d(va, vb)
    ua = np.polyval(ca, (common - 30.0) * 0.01)
    ub = np.polyval(cb, (common - 70.0) * 0.01)
    assert np.isclose(_left_edge_distance(va, ca, 30.0, vb, cb, 70.0), np.median(np.abs(ua - ub)), rtol=1e-12, atol=0)
    assert _left_edge_distance(va, ca, 30.0, vb + 0.5, cb, 70.0) == np.inf      # no common row


def test_marker_response_answers_a_stripe_with_its_contrast_and_a_step_with_nothing():
    """A bright stripe w px wide on a flat road gives w x contrast at its centre; a single step
    (the verge) gives no positive response anywhere."""
    w = 8
    row = np.full(200, 60, np.uint8)
    row[96:104] = 160                                  # stripe, contrast 100
    row[150:] = 120                                    # step
    r = marker_response(row[None, :], w)[0]
    assert r[100] == w * 100
    assert r[130:].max() <= 0


def test_sag_weight_keeps_the_shape_of_its_input():
    x = np.array([[3.0, 10.0], [20.0, 40.0]])
    u = x - 2.0
    expected = u * u / (2.0 * (1.1 - 0.5 * 1e-3 * u * u + 1e-3 * u * x))
    np.testing.assert_allclose(sag_weight(x, 1.1, 2.0, 1e-3), expected, rtol=1e-12, atol=0)
    assert sag_weight(10.0, 1.1, 2.0, 1e-3).shape == ()
    np.testing.assert_allclose(_sag_weight(x.ravel(), 1.1, 2.0, 1e-3), expected.ravel(), rtol=1e-12, atol=0)
