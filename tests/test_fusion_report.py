"""What the report's plots show: every estimate against truth, the fused 2-sigma band, the
vision, the IMU alone and the plain IMU-minus-vision bank (issue 5). The figures are read
where they are drawn (their axes' artists and legends), not from the PNG's pixels."""

import pytest

from fusion import report
from fusion.pipeline import fuse, plain_bank

from fusion_support import synth_drive


@pytest.fixture(scope="module")
def drawn():
    """The report's figures of a 6 s synthetic drive: ``{png name: [(ylabel, labels, bands)]}``
    with each axis's legend labels and the number of filled bands on it."""
    d = synth_drive("banked_curves_60s.toml", duration_s=6.0, vision_sigma_deg=0.1)
    run = fuse(d.imu, d.vision, lever_arm_m=d.lever_arm_m)
    imu_only = fuse(d.imu, None, lever_arm_m=d.lever_arm_m).fused
    inputs = report.ReportInputs(fused=run.fused, vision=d.vision, imu_only=imu_only,
                                 plain_bank=plain_bank(imu_only, d.vision), truth=d.truth, cov=run.cov)
    drawn_in_order = []
    real = report._fig_to_png

    def to_png(fig):
        drawn_in_order.append([(ax.get_ylabel(), [t.get_text() for t in ax.get_legend().get_texts()]
                                if ax.get_legend() else [], len(ax.collections)) for ax in fig.axes])
        return real(fig)

    mp = pytest.MonkeyPatch()
    mp.setattr(report, "_fig_to_png", to_png)
    try:
        figs = report._plots(inputs)
    finally:
        mp.undo()
    assert all(len(png) > 10_000 and png[:4] == b"\x89PNG" for png in figs.values())
    return dict(zip(figs, drawn_in_order))          # figs is filled in drawing order


def test_attitude_against_truth_with_the_band(drawn):
    rows = dict((y, (labels, bands)) for y, labels, bands in drawn["attitude.png"])
    for a in ("roll", "pitch", "yaw"):
        labels, bands = rows[f"{a} [deg]"]
        assert {"vision", "fused", "fused 2-sigma", "truth"} <= set(labels) and bands >= 1, (a, labels)
    labels, bands = rows["bank [deg]"]
    assert {"IMU roll - vision roll (Damon 2018)", "fused", "fused 2-sigma", "truth"} <= set(labels), labels


def test_gravity_referenced_attitude_with_the_imu_alone(drawn):
    for _, labels, bands in drawn["world.png"]:
        assert {"fused", "fused 2-sigma", "IMU only", "truth"} <= set(labels) and bands >= 1, labels


def test_errors_against_truth_with_the_band(drawn):
    rows = dict((y, (labels, bands)) for y, labels, bands in drawn["errors.png"])
    for a in ("roll", "pitch", "yaw"):
        labels, bands = rows[f"{a} error [deg]"]
        assert {"fused - truth", "+-2 sigma", "vision - truth"} <= set(labels) and bands >= 1, (a, labels)
    labels, bands = rows["bank error [deg]"]
    assert {"fused - truth", "+-2 sigma"} <= set(labels) and bands >= 1, labels
