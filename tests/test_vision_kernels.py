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
from vision.video import _LUMA_TO_GREY, _video_range_to_grey


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


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_lane_fit_linear_response_is_a_refit(seed):
    """``LaneModel.linear_response`` (the fit's weights, concentric scale and normal matrix
    held, the priors on the vertical curvature applied after) against refitting points moved
    by ``dy`` (a smooth 0.02 to 0.12 mm): three straight lines of two edges, 2 cm of noise
    (clipped at 3 sigma: no outliers).
    Agreement to 2 % of the largest parameter change plus 1e-9 (measured: 0.5 %). What the
    response leaves out, as the refit re-derives its design from the moved points: on curves
    the lines' concentric scale, ``1 / (1 - kappa0 a_j)`` from the first pass, whose change
    multiplies the shape (at 5e-3 1/m the offsets differ by up to 40 %, the slopes by 7 %, the
    curvature by 1.3 %; at 1e-3 1/m up to 30 % on the offsets), and the vertical-curvature
    column, whose values come from the points (its change against the noise's residuals).
    ``dy`` stays far under the noise: the refit's weights come from its residuals."""
    from vision.lanemodel import fit_lane_model_points

    rng = np.random.default_rng(seed)
    xs, ys, counts = [], [], []
    for j, a in enumerate((5.25, 1.75, -1.75)):
        for side, da in ((0, 0.075), (1, -0.075)):
            x = np.sort(rng.uniform(5.0, 40.0, 120))
            xs.append(x)
            # noise clipped at 3 sigma: a point near the second pass's outlier cut (4 sigma of
            # the first pass's residuals) that ``dy`` moves across it changes the refit by a
            # step no linear response follows (seed 22190: a 27 times larger change)
            ys.append(a + da + 0.01 * x + 0.02 * np.clip(rng.standard_normal(x.size), -3.0, 3.0))
            counts.append(x.size)
    x, y = np.concatenate(xs), np.concatenate(ys)
    lines, sides = [0, 0, 1, 1, 2, 2], [0, 1, 0, 1, 0, 1]
    args = (np.array(counts), lines, sides, 3, 1e9)

    def fit(yy):
        m = fit_lane_model_points(x, yy, *args, select=False)
        return m, np.concatenate([m.a, m.b, m.c])

    base, p0 = fit(y)
    dy = 2e-5 * np.sin(x / 7.0) * (1.0 + np.repeat(np.arange(6), counts))
    _, p1 = fit(y + dy)
    lin = base.linear_response(dy)
    np.testing.assert_allclose(lin, p1 - p0, atol=0.02 * np.max(np.abs(p1 - p0)) + 1e-9)


def test_video_range_to_grey_is_the_table_for_every_value_and_width():
    # every value at every column position of rows of widths around the vector lengths (the
    # compiled loop's vector body and its scalar remainder), from a strided view as PyAV's planes
    for w in (1, 3, 7, 15, 16, 17, 31, 33, 63, 65, 255, 256, 257, 1280):
        plane = ((np.arange(256)[:, None] + np.arange(w + 11)[None, :]) % 256).astype(np.uint8)
        luma = plane[:, :w]
        out = _video_range_to_grey(luma)
        assert out.flags.c_contiguous and out.dtype == np.uint8
        assert np.array_equal(out, _LUMA_TO_GREY[luma])
