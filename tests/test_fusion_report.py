"""What the report's plots show: every estimate against truth, the fused 2-sigma band, the
vision, the IMU alone and the plain IMU-minus-vision bank (issue 5). The figures are read
where they are drawn (their axes' artists and legends, in this process: ``processes=1``), not
from the PNG's pixels."""

import pandas as pd
import pytest

from fusion import report
from fusion.pipeline import fuse, plain_bank

from fusion_support import synth_drive


@pytest.fixture(scope="module")
def drawn():
    """The report's figures of a 6 s synthetic drive: ``{png name: [(ylabel, labels, bands,
    ylim)]}`` with each axis's legend labels, the number of filled bands on it and its y-limits;
    ``drawn["inputs"]``: what was drawn."""
    d = synth_drive("banked_curves_60s.toml", duration_s=6.0, vision_sigma_deg=0.1)
    run = fuse(d.imu, d.vision, lever_arm_m=d.lever_arm_m)
    imu_only = fuse(d.imu, None, lever_arm_m=d.lever_arm_m).fused
    inputs = report.ReportInputs(fused=run.fused, vision=d.vision, imu_only=imu_only,
                                 plain_bank=plain_bank(imu_only, d.vision), truth=d.truth, cov=run.cov)
    drawn_in_order = []
    real = report._fig_to_png

    def to_png(fig):
        drawn_in_order.append([(ax.get_ylabel(), [t.get_text() for t in ax.get_legend().get_texts()]
                                if ax.get_legend() else [], len(ax.collections), ax.get_ylim()) for ax in fig.axes])
        return real(fig)

    mp = pytest.MonkeyPatch()
    mp.setattr(report, "_fig_to_png", to_png)
    try:
        figs = report._plots(inputs, processes=1)
    finally:
        mp.undo()
    assert all(len(png) > 10_000 and png[:4] == b"\x89PNG" for png in figs.values())
    return {**dict(zip(figs, drawn_in_order)), "inputs": inputs}   # figs is filled in drawing order


def test_attitude_against_truth_with_the_band(drawn):
    """The fused estimate with its 2-sigma band, the truth, and the vision with its own 2-sigma
    as bars (a collection of its own: they were points alone, a review)."""
    rows = dict((y, (labels, bands)) for y, labels, bands, _ in drawn["attitude.png"])
    for a in ("roll", "pitch", "yaw"):
        labels, bands = rows[f"{a} [deg]"]
        assert {"vision, its own 2-sigma", "fused", "fused 2-sigma", "truth"} <= set(labels) and bands >= 2, (a, labels)
    labels, bands = rows["bank [deg]"]
    assert {"IMU roll - vision roll (Damon 2018)", "fused", "fused 2-sigma", "truth"} <= set(labels), labels


def test_gravity_referenced_attitude_with_the_imu_alone(drawn):
    """World roll and pitch with the IMU alone; the road's grade with its band and the truth (the
    simulator's road pitch: the grade had been neither drawn nor scored)."""
    rows = dict((y, (labels, bands)) for y, labels, bands, _ in drawn["world.png"])
    assert list(rows) == ["roll_world [deg]", "pitch_world [deg]", "grade [deg], + downhill"]
    for y, (labels, bands) in rows.items():
        want = {"fused", "fused 2-sigma", "truth"} | ({"IMU only"} if "world" in y else set())
        assert want <= set(labels) and bands >= 1, (y, labels)


def test_errors_against_truth_with_the_band(drawn):
    """Every error panel: the fused error, its 2-sigma band, the vision's error; a vision error
    beyond the panel (scaled to the fused estimate's) is drawn at its edge and the legend says
    how many and the largest (a review: 12 % of the sample drive's vision roll errors, up to 2.5
    deg, went off the panel unmarked)."""
    import numpy as np

    from fusion.metrics import interp_truth, wrap_deg

    rows = dict((y, (labels, bands, lim)) for y, labels, bands, lim in drawn["errors.png"])
    vis = drawn["inputs"].vision
    vis = vis[vis["valid"].astype(bool)]
    tv = interp_truth(drawn["inputs"].truth, vis["t_s"].to_numpy())
    for a in ("roll", "pitch", "yaw"):
        labels, bands, (lo, hi) = rows[f"{a} error [deg]"]
        ev = wrap_deg(vis[f"{a}_deg"].to_numpy() - tv[f"{a}_deg"].to_numpy())
        off = (ev < lo) | (ev > hi)
        said = [x for x in labels if x.startswith("vision - truth")]
        assert {"fused - truth", "+-2 sigma"} <= set(labels) and bands >= 1 and len(said) == 1, (a, labels)
        if off.any():
            assert said[0] == (f"vision - truth ({int(off.sum())} beyond the panel, up to "
                               f"{np.abs(ev[off]).max():.2f}: at its edge)"), (a, said)
        else:
            assert said[0] == "vision - truth", (a, said)
    labels, bands, _ = rows["bank error [deg]"]
    assert {"fused - truth", "+-2 sigma"} <= set(labels) and bands >= 1, labels
    for a in ("roll_world", "pitch_world"):
        labels, bands, _ = rows[f"{a} error [deg]"]
        assert {"fused - truth", "+-2 sigma", "IMU only - truth"} <= set(labels) and bands >= 1, (a, labels)
    labels, bands, _ = rows["grade error [deg]"]
    assert {"fused - truth", "+-2 sigma"} <= set(labels) and bands >= 1, labels


def test_a_truth_of_world_angles_only_has_their_errors_drawn():
    """A real recording's reference (an INS: KITTI's OXTS) has the world angles only: the error
    figure shows those two (it was four empty panels of the road angles, a review found)."""
    import pandas as pd

    d = synth_drive("banked_curves_60s.toml", duration_s=4.0, vision_sigma_deg=0.1)
    run = fuse(d.imu, d.vision, lever_arm_m=d.lever_arm_m)
    truth = d.truth[["t_s", "roll_world_deg", "pitch_world_deg"]]
    assert isinstance(truth, pd.DataFrame)
    got = []
    real = report._fig_to_png

    def to_png(fig):
        got.append([ax.get_ylabel() for ax in fig.axes])
        return real(fig)

    mp = pytest.MonkeyPatch()
    mp.setattr(report, "_fig_to_png", to_png)
    try:
        figs = report._plots(report.ReportInputs(fused=run.fused, vision=d.vision, truth=truth, cov=run.cov), processes=1)
    finally:
        mp.undo()
    assert dict(zip(figs, got))["errors.png"] == ["roll_world error [deg]", "pitch_world error [deg]"]


def test_the_panels_are_scaled_to_the_converged_estimates(drawn):
    """The first seconds' sigmas (degrees: the filter has not met the vision yet) no longer set
    the scale: the 60 s drive's bank error of tenths of a degree was drawn on +-50 deg. Each
    error panel shows every fused error after the 2 s of convergence and is at most 1.5 times
    the larger of that error and most (95 %) of its 2-sigma band; the bank panel shows the
    truth within a few degrees of it."""
    import numpy as np

    from fusion.metrics import interp_truth

    f = drawn["inputs"].fused
    truth = interp_truth(drawn["inputs"].truth, f["t_s"].to_numpy())
    settled = f["t_s"].to_numpy() - f["t_s"].iloc[0] >= report.CONVERGENCE_S
    assert f.loc[~settled, "bank_sigma_deg"].max() > 5 * f.loc[settled, "bank_sigma_deg"].max()   # the case
    limits = {y: lim for y, _, _, lim in drawn["errors.png"]}
    for a in ("roll", "pitch", "yaw", "bank"):
        e = (f[f"{a}_deg"] - truth[f"{a}_deg"]).to_numpy()[settled]
        e = e[np.isfinite(e)]                   # the truth ends before the last sample
        half = 0.5 * (limits[f"{a} error [deg]"][1] - limits[f"{a} error [deg]"][0])
        lo, hi = limits[f"{a} error [deg]"]
        wide = np.percentile(2 * f[f"{a}_sigma_deg"].to_numpy()[settled], 95)
        assert lo <= e.min() and e.max() <= hi, (a, e.min(), e.max(), lo, hi)
        assert half <= 1.5 * max(np.abs(e).max(), wide), (a, half, np.abs(e).max(), wide)
    lo, hi = {y: lim for y, _, _, lim in drawn["attitude.png"]}["bank [deg]"]
    tb = truth["bank_deg"].dropna().to_numpy()
    assert lo <= tb.min() and tb.max() <= hi and hi - lo < tb.max() - tb.min() + 6.0, (lo, hi, tb.min(), tb.max())


def test_the_biases_with_their_band(drawn):
    """Each bias estimate with its 2-sigma band (the lateral accelerometer's sigma bounds the
    bank: README): six bands on the two panels."""
    bands = [b for _, _, b, _ in drawn["biases.png"]]
    assert bands == [3, 3], bands


def test_truth_headings_are_interpolated_the_short_way_round():
    """A heading that crosses +-180 deg between two truth samples: the truth at a time between
    them is near 180, not near 0, so an estimate equal to the truth scores 0 deg RMSE (a review
    measured 3.8 deg with the estimate 3 ms off the truth's samples). 0.1 s samples turning at
    20 deg/s: between 179 and -179 the truth is 180 +- 1 deg."""
    import numpy as np
    import pandas as pd

    from fusion.metrics import interp_truth, rmse_table

    t = np.arange(0.0, 10.0, 0.1)
    yaw = (170.0 + 20.0 * t + 180.0) % 360.0 - 180.0
    truth = pd.DataFrame({"t_s": t, "yaw_deg": yaw, "roll_deg": np.full_like(t, np.nan)})
    tf = t[:-1] + 0.003
    got = interp_truth(truth, tf)
    want = (170.0 + 20.0 * tf + 180.0) % 360.0 - 180.0
    assert np.max(np.abs((got["yaw_deg"] - want + 180.0) % 360.0 - 180.0)) < 1e-9
    assert got["roll_deg"].isna().all()          # a column of NaN stays NaN
    assert rmse_table(pd.DataFrame({"t_s": tf, "yaw_deg": want}), truth)["yaw"] < 1e-9


def test_a_summary_without_truth_has_its_scores_null(drawn):
    """The README promises ``null`` for a value that does not exist: without a truth the RMSE and
    the NEES keys were left out while ``time_offset`` was null (a review). Every key is there,
    the scores null; with the truth they are filled."""
    import json
    from dataclasses import replace

    inputs = drawn["inputs"]
    bare = json.loads(json.dumps(report.summarise(replace(inputs, truth=None))))
    assert bare["rmse_deg"] is None and bare["consistency"] is None and bare["time_offset"] is None
    scored = report.summarise(inputs)
    assert set(scored) == set(bare)
    assert 0.0 < scored["rmse_deg"]["fused"]["roll"] < 1.0 and 0.0 <= scored["consistency"]["fraction_inside"] <= 1.0


def test_the_summary_has_the_reports_own_time(drawn, tmp_path):
    """summary.json's timings had every step's time but the report's (the run's clock stops
    before it): the plots' and page's time is in it when they are drawn, not without them; the
    run's own timings are kept."""
    import json
    from dataclasses import replace

    inputs = replace(drawn["inputs"], timings_s={"vision": 1.5})
    report.write_report(inputs, tmp_path / "with")
    t = json.loads((tmp_path / "with" / "summary.json").read_text())["timings_s"]
    assert t["vision"] == 1.5 and 0.0 < t["report"] < 120.0
    report.write_report(inputs, tmp_path / "without", plots=False)
    assert json.loads((tmp_path / "without" / "summary.json").read_text())["timings_s"] == {"vision": 1.5}


def test_a_source_without_a_value_is_null_and_not_a_row_of_blanks(drawn, tmp_path):
    """A run without a valid vision frame: the vision's and the plain bank's RMSE are null (the
    plain bank's key had been left out, its keys changing from run to run), the page has no
    row of blanks for them but a line saying so, and its run table has the camera offset, the
    samples and the duration as summary.json has them (a review)."""
    import json
    from dataclasses import replace

    inputs = drawn["inputs"]
    blind = replace(inputs, vision=inputs.vision.assign(valid=0), plain_bank=inputs.plain_bank.iloc[:0],
                    camera_time_offset_s=0.1)
    summary = report.write_report(blind, tmp_path)
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["rmse_deg"]["imu_minus_vision"] is None and saved["rmse_deg"]["vision"]["roll"] is None
    assert saved["rmse_deg"]["vision"]["valid_fraction"] == 0.0
    assert saved["rmse_deg"]["fused"]["roll"] > 0 and set(saved["rmse_deg"]) == {"fused", "vision",
                                                                                  "imu_minus_vision", "imu_only"}
    page = (tmp_path / "report.html").read_text()
    assert "<td>vision</td>" not in page and "<td>imu_minus_vision</td>" not in page
    assert "No RMSE of vision, imu_minus_vision" in page
    assert "+0.1000" in page and f"<td>{summary['samples']}</td>" in page and "0.0 % of the drive's frames" in page
    assert f"<td>{summary['timings_s']['report']:.2f} s</td>" in page


def test_every_source_has_every_angle_key_null_where_it_has_none(drawn, tmp_path):
    """summary.json's ``rmse_deg``: every source has every angle's key (README: "every key is
    always there"), null where it has no value: the vision had only roll, pitch and yaw, the
    IMU-minus-vision bank only bank, and with an INS truth of roll_world and pitch_world alone
    ``["fused"]["bank"]`` was a KeyError (a review). The page still lists the scores."""
    import json
    from dataclasses import replace

    from fusion.metrics import ANGLES

    inputs = drawn["inputs"]
    ins = inputs.truth[["t_s", "roll_world_deg", "pitch_world_deg"]]
    for name, r in (("full", inputs), ("ins", replace(inputs, truth=ins))):
        report.write_report(r, tmp_path / name)
        acc = json.loads((tmp_path / name / "summary.json").read_text())["rmse_deg"]
        assert set(acc) == {"fused", "vision", "imu_minus_vision", "imu_only"}
        for src, vals in acc.items():   # a source without any value is null as a whole
            assert vals is None or set(vals) == {*ANGLES, *(["valid_fraction"] if src == "vision" else [])}, \
                (name, src, vals)
        assert acc["imu_only"]["grade"] is None and acc["imu_only"]["roll_world"] > 0
        page = (tmp_path / name / "report.html").read_text()
        assert f"<td>{acc['fused']['roll_world']:.3f}</td>" in page
    assert acc["fused"]["bank"] is None and acc["fused"]["roll"] is None and acc["fused"]["roll_world"] > 0
    assert acc["imu_minus_vision"] is None       # no bank in the truth: nothing to score
    full = json.loads((tmp_path / "full" / "summary.json").read_text())["rmse_deg"]
    assert full["vision"]["bank"] is None and full["vision"]["roll"] > 0
    assert full["imu_minus_vision"]["roll"] is None and full["imu_minus_vision"]["bank"] > 0


def test_a_drive_shorter_than_the_convergence_is_scaled_to_its_estimates(drawn):
    """A drive under 2 s: the panels were scaled to the values after the first 2 s, none, and
    so the bias panel to the truth alone, the estimates off it (a review); now to all of it."""
    from dataclasses import replace

    inputs = drawn["inputs"]
    short = inputs.fused[inputs.fused["t_s"] < inputs.fused["t_s"].iloc[0] + 1.0]
    seen = []
    real = report._fig_to_png

    def record(fig):
        seen.append([(ax.get_ylabel(), ax.get_ylim()) for ax in fig.axes])
        return real(fig)

    mp = pytest.MonkeyPatch()
    mp.setattr(report, "_fig_to_png", record)
    try:
        zero = pd.DataFrame({"t_s": short["t_s"], **{f"{k}_bias_{a}_{u}": 0.0 for k, u in (("gyro", "rad_s"),
                                                                                        ("accel", "m_s2"))
                                                      for a in "xyz"}})   # a simulated IMU without biases
        report._plots(replace(inputs, fused=short, cov=inputs.cov[:len(short)], imu_truth=zero), processes=1)
    finally:
        mp.undo()
    lims = dict(seen[-1])    # biases.png, drawn last
    z = short["accel_bias_z_m_s2"].to_numpy()
    lo, hi = lims["accel bias [m/s^2]"]
    assert lo <= z.min() and z.max() <= hi


def test_a_smoothed_run_says_so_in_every_figure(drawn):
    """With ``--smooth`` the estimate drawn is the smoother's: its legends, the figures' titles
    and the page's RMSE row say so (a review: only the page's "estimate" row and summary.json
    did, the legends said "fused" beside the forward-only baselines). The bank rate is drawn with
    its 2-sigma band, from ``bank_rate_sigma_deg_s``."""
    from dataclasses import replace

    got = []
    real = report._fig_to_png

    def to_png(fig):
        got.append([(ax.get_title(), [t.get_text() for t in ax.get_legend().get_texts()] if ax.get_legend() else [],
                     len(ax.collections)) for ax in fig.axes])
        return real(fig)

    mp = pytest.MonkeyPatch()
    mp.setattr(report, "_fig_to_png", to_png)
    try:
        figs = report._plots(replace(drawn["inputs"], smoothed=True), processes=1)
    finally:
        mp.undo()
    axes = dict(zip(figs, got))
    for name in ("attitude.png", "world.png", "road.png"):
        for _, labels, _ in axes[name]:
            assert "fused (smoothed)" in labels and "fused" not in labels, (name, labels)
    for name in ("attitude.png", "world.png", "errors.png"):
        assert "smoothed" in axes[name][0][0], (name, axes[name][0][0])
    _, labels, bands = axes["road.png"][1]
    assert "fused (smoothed) 2-sigma" in labels and bands >= 1, labels
    page = report._table_html({"smoothed": True, "rmse_deg": {"fused": {"roll": 0.1}}})
    assert "<td>fused (smoothed)</td>" in page


@pytest.mark.skipif(not report._can_fork(), reason="no fork or a single core: the figures are drawn in-process")
def test_figures_drawn_in_two_processes_are_those_of_one(drawn, monkeypatch):
    """The figures a forked process draws are the pixels this one draws, in the page's order,
    call after call (a campaign reports every drive in one process); the child's error is raised
    here, as is its death, not a hang nor the figures of the parent alone."""
    import os
    from concurrent.futures.process import BrokenProcessPool

    inputs = drawn["inputs"]
    alone = report._plots(inputs, processes=1)
    assert list(alone) == list(report.FIGURES)
    for _ in range(2):
        assert report._plots(inputs) == alone
    real = report._panels

    def failing(n, height_in):   # the attitude figure's four panels: drawn by the child
        if n == 4:
            raise RuntimeError("the child failed")
        return real(n, height_in)

    monkeypatch.setattr(report, "_panels", failing)
    with pytest.raises(RuntimeError, match="the child failed"):
        report._plots(inputs)
    monkeypatch.setattr(report, "_panels", lambda n, height_in: os._exit(3) if n == 4 else real(n, height_in))
    with pytest.raises(BrokenProcessPool):
        report._plots(inputs)
