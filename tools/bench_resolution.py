"""Accuracy of the fusion against the camera's resolution: the fusion benchmark's drives rendered
at other image sizes.

Usage::

    .venv/bin/python tools/bench_resolution.py                       # 1280x720 and 640x360, five drives
    .venv/bin/python tools/bench_resolution.py --sizes 640x360 --drives banked_curve_right_7deg
    .venv/bin/python tools/bench_resolution.py --seed-offset 900     # another draw of noise and biases

Each drive of ``tools/bench_fusion.py`` is rendered at each size: the scenario's ``[camera]``
width and height replaced, its field of view, mount, road, motion and IMU as they are, its
``[scenario] seed`` plus ``--seed-offset`` (the same seed draws the same sensor noise and
biases, so with offset 0 only the resolution changes). The scenario's own size with offset 0 is
the fusion benchmark's cached drive; other renders are cached under
``.cache/drives/res-<name>-<W>x<H>-s<seed>-<key>/`` (about 40-50 s each at 640x360 on this
machine). Then ``vifusion run`` on each, as a user would, and per drive and size the RMSE after
2 s of convergence of roll, pitch, yaw relative to the road and of the bank (fused forward
filter; vision alone) and the share of samples whose NEES lies in its 95 % band, against issue
5's bars (roll and pitch 0.15, yaw 0.1, bank 0.3 deg).
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fusion as B  # noqa: E402


def size_arg(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a size is WIDTHxHEIGHT, e.g. 640x360, not {text!r}") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"{text}: width and height must be 64 to 8192 pixels")
    return w, h


def rendered_drive(name: str, size: tuple[int, int] | None, seed_offset: int) -> Path:
    """The drive of scenario ``name`` at ``size`` (None: its own) with its seed moved by
    ``seed_offset``, rendered once and cached."""
    path = B.SCENARIOS / f"{name}.toml"
    data = tomllib.loads(path.read_text())
    own = (int(data["camera"]["width"]), int(data["camera"]["height"]))
    if (size is None or size == own) and seed_offset == 0:
        return B.cached_full_drive(name)
    from drivesim.drive import simulate
    from drivesim.scenario import parse_scenario

    w, h = size or own
    seed = int(data["scenario"].get("seed", 0)) + seed_offset
    data["camera"]["width"], data["camera"]["height"] = w, h
    data["scenario"]["seed"] = seed
    data["scenario"]["name"] = f"{data['scenario']['name']}_{w}x{h}"
    folder = B.CACHE / f"res-{name}-{w}x{h}-s{seed}-{B.drive_key(path.read_bytes() + f'{w}x{h}s{seed}'.encode())}"
    if not (folder / "config.toml").exists():
        print(f"rendering {name} at {w}x{h}, seed {seed} ...", flush=True)
        simulate(parse_scenario(data, str(path)), folder, overwrite=True, progress=False)
    return folder


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=lambda s: [size_arg(v) for v in s.split(",")], default=None,
                    help="comma-separated WIDTHxHEIGHT (default: each scenario's own and 640x360)")
    ap.add_argument("--drives", type=lambda s: s.split(","), default=list(B.DRIVES),
                    help=f"comma-separated scenario names (default: {','.join(B.DRIVES)})")
    ap.add_argument("--seed-offset", type=int, default=0, help="added to each scenario's seed (default 0)")
    args = ap.parse_args(argv)
    for name in args.drives:
        if not (B.SCENARIOS / f"{name}.toml").exists():
            ap.error(f"no scenario {name!r} in {B.SCENARIOS}")
    sizes = args.sizes or [None, (640, 360)]

    rows = []
    for name in args.drives:
        for size in sizes:
            drive = rendered_drive(name, size, args.seed_offset)
            out = drive.parent / (drive.name + "-res-run")
            _, summ = B.run_cli(drive, out, "--no-report")
            cam = tomllib.loads((drive / "config.toml").read_text())["camera"]
            rows.append((name, f"{cam['width']}x{cam['height']}", summ["rmse_deg"]["fused"],
                         summ["rmse_deg"]["vision"] or {}, summ["consistency"]["fraction_inside"]))

    print(f"RMSE against truth after 2 s [deg] (bars of issue 5: roll/pitch 0.15, yaw 0.1, bank 0.3; "
          f"* over the bar), seed offset {args.seed_offset}")
    print(f"{'drive':<26} {'size':>9}   {'fused: roll':>11} {'pitch':>7} {'yaw':>7} {'bank':>7}  "
          f"{'NEES in band':>12}   {'vision: roll':>12} {'pitch':>7} {'yaw':>7}")
    for name, size, fused, vision, nees in rows:
        f = " ".join(f"{fused[a]:6.3f}{'*' if fused[a] > B.BARS[a] else ' '}" for a in ("roll", "pitch", "yaw", "bank"))
        v = " ".join(f"{vision[a]:7.3f}" if vision.get(a) is not None else f"{'':7}" for a in ("roll", "pitch", "yaw"))
        print(f"{name:<26} {size:>9}   {f:>38}  {100 * nees:11.1f}%   {v:>28}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
