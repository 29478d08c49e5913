"""Benchmark: frames per second from a 1-million-frame BLF log to the IMU DataFrame.

Usage::

    .venv/bin/python tools/bench_can.py [--frames 1000000] [--repeats 3] [--file /tmp/bench.blf]
    .venv/bin/python tools/bench_can.py --live 20     # live virtual bus: arrival-to-yield latency

Builds the log once with the simulator's CAN writer (IMU at 100 Hz, wheel speed at 50 Hz and the
extra traffic of ``tools/drivesim/canlog.py``: about 390 frames per second of drive, 1 in 2 mapped)
and caches it. Then, in one process on one core, alternates python-can's bare ``BLFReader``
iteration (the floor: no decoding at all) and :func:`imu.read_log` end to end, and prints the
median of the repeats and their ratio. The first read of each kind warms the page cache and is
not counted.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import can  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from drivesim.canlog import DBC_PATH, signal_map, write_can_log  # noqa: E402
from imu import CanMapping, ImuMount, read_log  # noqa: E402

#: Frames per second of drive written by write_can_log with extra traffic (IMU 2 x 100, ABS 50,
#: ENGINE_1 100, ENGINE_2/DASH/CCVS1/NM 4 x 10, TPMS 2).
FRAMES_PER_S = 392.0


def build(path: Path, n_frames: int) -> None:
    duration_s = n_frames / FRAMES_PER_S
    rng = np.random.default_rng(0)
    t = np.arange(0.0, duration_s, 0.01)
    w = 2 * np.pi * 0.2
    imu = pd.DataFrame({
        "t_s": t,
        "gyro_x_rad_s": 0.3 * np.cos(w * t) + rng.normal(0, 0.002, len(t)),
        "gyro_y_rad_s": rng.normal(0, 0.002, len(t)),
        "gyro_z_rad_s": 0.2 * np.sin(w * t) + rng.normal(0, 0.002, len(t)),
        "accel_x_m_s2": rng.normal(0, 0.05, len(t)),
        "accel_y_m_s2": 3.0 * np.sin(w * t) + rng.normal(0, 0.05, len(t)),
        "accel_z_m_s2": -9.81 + rng.normal(0, 0.05, len(t)),
    })
    ts = np.arange(0.004, duration_s, 0.02)
    speed = pd.DataFrame({"t_s": ts, "speed_m_s": 20.0 + 2.0 * np.sin(0.05 * ts)})
    print(f"building {path} ({duration_s:.0f} s of drive) ...", flush=True)
    write_can_log(path, imu, speed)


def bare(path: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    n = 0
    for _ in can.BLFReader(path):
        n += 1
    return n, time.perf_counter() - t0


def full(path: Path, mapping: CanMapping, mount: ImuMount) -> tuple[int, float, int]:
    t0 = time.perf_counter()
    table, summary = read_log(path, mapping, mount)
    return summary.frames_read, time.perf_counter() - t0, len(table)


def decode_rates(path: Path, mapping: CanMapping, n_max: int = 50_000) -> tuple[float, float, float]:
    """IMU_RATE frames per second: numpy (imu.decode), cantools per message, the scalar twin."""
    from imu.dbc import resolve
    from imu.decode import decode_frame, decode_source

    plan = resolve(mapping)
    src = next(s for s in plan.sources if s.name == "IMU_RATE")
    payloads = []
    for m in can.BLFReader(path):
        if m.arbitration_id == src.frame_id:
            payloads.append(bytes(m.data))
            if len(payloads) >= n_max:
                break
    data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), 8)
    t0 = time.perf_counter()
    vec = decode_source(data, src, True)
    t_np = time.perf_counter() - t0
    msg = src.message
    t0 = time.perf_counter()
    ref = [msg.decode(p, decode_choices=False) for p in payloads]
    t_ct = time.perf_counter() - t0
    t0 = time.perf_counter()
    for p in payloads:
        decode_frame(p, src, True)
    t_sc = time.perf_counter() - t0
    names = [sp.signal.name for sp in src.signals]
    factors = [sp.factor_si for sp in src.signals]
    want = np.array([[r[n] * f for n, f in zip(names, factors)] for r in ref])
    if not np.array_equal(vec.si, want):
        raise SystemExit("numpy decode differs from cantools")
    n = len(payloads)
    return n / t_np, n / t_ct, n / t_sc


def live_latency(duration_s: float) -> np.ndarray:
    """Play a simulated drive onto python-can's ``virtual`` bus in real time from a sender
    thread and read it with :class:`imu.LiveSource`: arrival-to-yield latency per sample, s."""
    import threading
    import uuid

    from drivesim.canlog import write_can_log
    from imu import LiveSource

    t = np.arange(0.0, duration_s, 0.01)
    imu = pd.DataFrame({"t_s": t, **{f"gyro_{a}_rad_s": 0.1 * np.sin(t + i) for i, a in enumerate("xyz")},
                        **{f"accel_{a}_m_s2": np.cos(t + i) for i, a in enumerate("xyz")}})
    speed = pd.DataFrame({"t_s": t[::2], "speed_m_s": np.full(len(t[::2]), 20.0)})
    log = Path(os.environ.get("TMPDIR", "/tmp")) / "vifusion_bench_live.csv"
    write_can_log(log, imu, speed)
    msgs = list(can.LogReader(log))
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    rx = can.Bus(interface="virtual", channel=channel)
    done = threading.Event()

    def send():   # each message at its log time, in real time
        for m in can.MessageSync(msgs):
            tx.send(m)
        done.set()

    source = LiveSource(rx, CanMapping(DBC_PATH, signal_map()), ImuMount(("x", "-y", "-z"), (0.0, 0.0, 0.5)))
    sender = threading.Thread(target=send, daemon=True)
    lat = []
    sender.start()
    for sample in source:
        lat.append(time.perf_counter() - sample.received_s)
        if done.is_set() and len(lat) >= len(imu):
            source.stop()
    sender.join()
    tx.shutdown()
    rx.shutdown()
    return np.array(lat)


def _positive(kind):
    """An argparse type: a number of ``kind`` above 0 (0 repeats had ended in a traceback of
    the median of nothing, 0 frames in one of an empty log, a review)."""
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be above 0, got {text}")
        return value
    return parse


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=_positive(int), default=1_000_000)
    ap.add_argument("--repeats", type=_positive(int), default=3)
    ap.add_argument("--file", type=Path, default=None)
    ap.add_argument("--live", type=_positive(float), default=None, metavar="SECONDS",
                    help="measure the live path's arrival-to-yield latency instead")
    args = ap.parse_args(argv)
    if args.live:
        lat = live_latency(args.live) * 1e6
        print(f"live virtual bus, {len(lat)} samples: arrival-to-yield median {np.median(lat):.0f} us, "
              f"p99 {np.percentile(lat, 99):.0f} us, max {lat.max():.0f} us (budget 1000 us, issue 4)")
        return 0
    path = args.file or Path(os.environ.get("TMPDIR", "/tmp")) / f"vifusion_bench_{args.frames}.blf"
    if not path.exists():
        build(path, args.frames)
    mapping = CanMapping(DBC_PATH, signal_map())
    mount = ImuMount(("x", "-y", "-z"), (0.0, 0.0, 0.5))
    bare(path)
    full(path, mapping, mount)
    bare_rates, full_rates = [], []
    for _ in range(args.repeats):
        n, dt = bare(path)
        bare_rates.append(n / dt)
        n2, dt2, rows = full(path, mapping, mount)
        full_rates.append(n2 / dt2)
    b, f = statistics.median(bare_rates), statistics.median(full_rates)
    print(f"file: {path} ({path.stat().st_size / 1e6:.1f} MB, {n} frames, {rows} IMU samples)")
    print(f"{'measurement':<44} {'frames/s (median of ' + str(args.repeats) + ')':>26}")
    print(f"{'python-can BLFReader, bare iteration':<44} {b:>26,.0f}")
    print(f"{'imu.read_log, BLF to DataFrame (end to end)':<44} {f:>26,.0f}")
    print(f"{'ratio end-to-end / bare reader':<44} {f / b:>26.2f}")
    print(f"{'target (issue 4)':<44} {150_000:>26,}")
    np_rate, ct_rate, sc_rate = decode_rates(path, mapping)
    print(f"{'decode IMU_RATE, numpy per frame ID':<44} {np_rate:>26,.0f}")
    print(f"{'decode IMU_RATE, cantools per message':<44} {ct_rate:>26,.0f}")
    print(f"{'decode IMU_RATE, scalar twin (live path)':<44} {sc_rate:>26,.0f}")
    print("(numpy and cantools results compared: identical)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
