"""The roll loop of Damon et al. 2018 ("Inverse Perspective Mapping Roll Angle Estimation for
Motorcycles", ICARCV), the baseline of Alrazouk et al. 2024.

For each frame (section IV of the 2018 paper):

1. BEV with the roll ``phi_j``, the pitch fixed to the mount tilt and no yaw
   (``R = R_c R_phi R_mu``, height ``h_c = z_c cos(phi)``); ``phi_0 = phi_prev - Delta_phi / 2``;
2. filter and track the three lines (:mod:`vision.lanes`, the same code as the 2024 method,
   so that the speed ratio compares the algorithms, not two implementations);
3. fit them with cubic polynomials (eq. (7)) and compute the areas between the left and centre
   lines and between the centre and right lines over the rows all three cover;
4. stop when the area difference is below the threshold; else ``phi_(j+1) = phi_j + delta_phi``.

The paper leaves the threshold open. Here it is half the change of the area difference over
one step (the difference, per BEV row and in metres, changes by ``2 L^2 / H`` per radian of
roll for lanes of width ``L``): "below the threshold" then means "within half a step of the
balance", and a change of sign between two steps (a balance skipped over) stops the loop too,
at the better of the two. The roll is the vehicle's roll (rotation about its x axis). Pitch
and yaw come from the vanishing point of the straight lines in the last BEV (as in the 2024
paper's plain method), the loop itself does not estimate them.
"""

from __future__ import annotations

import math

import numpy as np

from .estimator import (DebugInfo, Estimator, VisionEstimate, _R_o_from_cp, camera_xyz_from_vehicle,
                        vehicle_from_camera_xyz)
from .lanes import LaneOptions
from .vanishing import angle_sigmas, r3_from_vp, vp_bounds, yaw_pitch_from_r3

__all__ = ["damon_estimate", "area_difference"]


def area_difference(lines, dy_m: float) -> float | None:
    """Mean over the common rows of ``(u_c - u_l) - (u_r - u_c)``, m (left-centre minus
    centre-right spacing, from the centre fits of the three lines); None without overlap."""
    v_lo = max(m.v_far for m in lines)
    v_hi = min(m.v_near for m in lines)
    if v_hi <= v_lo:
        return None
    v = np.arange(math.ceil(v_lo), math.floor(v_hi) + 1, dtype=float)
    if v.size < 2:
        return None
    c = [0.5 * np.add(*m.u_at(v)) for m in lines]
    # Areas A_L = sum (u_c - u_l), A_R = sum (u_r - u_c); per row, in metres.
    return float(np.mean((c[1] - c[0]) - (c[2] - c[1])) * dy_m)


def damon_estimate(est: Estimator, gray: np.ndarray, seed_rpy, keep_debug: bool = False) -> VisionEstimate:
    """One frame of the 2018 loop with ``est``'s camera, mount, road and options
    (``damon_step_deg``, ``damon_range_deg``, ``fit_degree``, ``edges``)."""
    o = est.options
    step = math.radians(o.damon_step_deg)
    span = math.radians(o.damon_range_deg)
    phi_prev = seed_rpy[0] if seed_rpy is not None else 0.0
    lane_opts = LaneOptions(edges=o.edges, fit_degree=o.fit_degree)
    L = est.road.lane_width_m
    threshold = 0.5 * step * 2.0 * L * L / est.mount.height_m
    n_steps = int(round(span / step)) + 1
    phi = phi_prev - 0.5 * span
    prev = None           # (phi, diff, bev, lines)
    found = None
    iterations = 0
    most_lines = 0
    for _ in range(n_steps):
        iterations += 1
        pose = camera_xyz_from_vehicle(phi, 0.0, 0.0, est.mount.tilt_rad)
        H, _ = est.height_of(*pose)
        bev, img, markers = est.markers_at(gray, _R_o_from_cp(*pose), H, lane_opts)
        lines, idx = est.select_lines(bev, markers, True)
        most_lines = max(most_lines, len(lines))
        diff = area_difference(lines, bev.grid.dy_m) if len(lines) == 3 else None
        if diff is not None:
            cur = (phi, diff, bev, lines, img, markers, idx)
            if abs(diff) < threshold:
                found = cur
                break
            if prev is not None and np.sign(diff) != np.sign(prev[1]):
                found = cur if abs(diff) < abs(prev[1]) else prev
                break
            prev = cur
        phi += step
    if found is None:
        if most_lines < 3:
            why = f"the loop needs three lines, found at most {most_lines}"
        else:
            why = (f"no balance of the lane areas within +-{o.damon_range_deg / 2:g} deg "
                   f"of {math.degrees(phi_prev):.1f} deg")
        return VisionEstimate.invalid(why, "damon2018", iterations=iterations)
    roll, _, bev, lines, img, markers, idx = found
    # Pitch and yaw: vanishing point of straight lines through the markers in the image.
    vp, segs = est._vp_image_lines(bev, lines)
    psi1, theta1 = yaw_pitch_from_r3(r3_from_vp(est.camera.K, vp))
    # Camera XYZ roll giving the vehicle ZYX roll found by the loop (two fixed-point steps).
    phi1 = roll
    for _ in range(3):
        (r, _, _), _ = vehicle_from_camera_xyz(phi1, theta1, psi1, est.mount.tilt_rad)
        phi1 += roll - r
    (r, p, y), _ = vehicle_from_camera_xyz(phi1, theta1, psi1, est.mount.tilt_rad)
    (A, B), (C, D) = segs[-1], segs[0]
    dx, dy, _ = vp_bounds(A, B, C, D, 0.5)
    s_psi, s_theta = angle_sigmas(est.camera.K, vp, 0.5 * dx, 0.5 * dy)
    dbg = DebugInfo(bev_image=img, bev=bev, markers=markers, used=idx, vp_px=(float(vp[0]), float(vp[1])),
                    image_lines=segs) if keep_debug else None
    lateral, curvature, spacing = _lane_geometry(est, bev, lines, phi1, theta1, psi1)
    reason = ""
    if not all(math.isfinite(v) for v in (r, p, y, s_psi, s_theta, lateral, curvature)):
        reason = "non-finite result"
    elif abs(spacing - L) > MAX_SPACING_ERROR * L:
        # three bright stripes balanced, but not the road's lines (a review on KITTI frames:
        # lines 14 and 22.6 m apart on a 3.5 m lane, valid, with rolls of -77 and 171 deg)
        reason = f"lines {spacing:.2f} m apart against the road's lanes of {L:g} m: not its lines"
    elif abs(r) > math.radians(MAX_ROLL_DEG):
        reason = f"roll {math.degrees(r):.0f} deg beyond {MAX_ROLL_DEG:g} deg"
    return VisionEstimate(
        r, p, y, step / math.sqrt(12.0), s_theta, s_psi, not reason,
        curvature_1_m=curvature, lateral_offset_m=lateral, line_spacing_m=spacing,
        camera_xyz_rad=(phi1, theta1, psi1), vp_px=(float(vp[0]), float(vp[1])), n_lines=3,
        roll_equation="damon2018", iterations=iterations, warps=iterations, method="damon2018",
        reason=reason, debug=dbg)


#: The loop's balance is accepted when the mean spacing of its three lines is within this share
#: of the road's lane width, and its roll within MAX_ROLL_DEG (a motorcycle's lean stays under
#: 65 deg): the 2018 paper checks neither, and says nothing of an uncertainty. Its roll sigma
#: here is the step's quantisation (``delta_phi / sqrt(12)``), a lower bound: give the fusion the
#: 2024 method, whose sigmas come from its fits.
MAX_SPACING_ERROR = 0.35
MAX_ROLL_DEG = 70.0


def _lane_geometry(est: Estimator, bev, lines, phi1, theta1, psi1):
    """Lateral offset (m), curvature (1/m) and line spacing (m) from the centre fits of the outer
    lines in the loop's last BEV (metric up to its pitch and yaw, which the loop assumes)."""
    g = bev.grid
    _, R_o_from_v = vehicle_from_camera_xyz(phi1, theta1, psi1, est.mount.tilt_rad)
    cam = R_o_from_v @ est.mount.position_v
    v_c = float(g.row_of_x(-cam[0]))
    ys, ks = [], []
    for m in (lines[0], lines[-1]):
        t = (v_c - m.v0) * 0.01
        c = 0.5 * (np.asarray(m.fit_left) + np.asarray(m.fit_right))
        ys.append(float(g.y_of_col(np.polyval(c, t))))
        d2u_dv2 = np.polyval(np.polyder(c, 2), t) * 1e-4 if c.size > 2 else 0.0
        ks.append(float(-g.dy_m * d2u_dv2 / g.dx_m**2))
    lateral = -float(cam[1]) - 0.5 * (ys[0] + ys[1])
    return lateral, float(np.mean(ks)), abs(ys[0] - ys[1]) / (len(lines) - 1)
