"""Compile the numba kernels of the vision and the fusion once, at install time.

numba compiles a kernel at its first call and caches the machine code next to its source
(``__pycache__``). Without this step the first ``vifusion run`` after an install spends most of
its time compiling: on this project's 2-core machine the bundled 12 s sample drive took 96 s on
a fresh clone against 11 s once compiled (about 50 s for the vision's kernels, 26 s for the
fusion's), and a run with several vision workers compiles the same kernels in each of them.
``make run`` and ``make test`` run this module after installing the package
(``python -m fusion.warmup``); an installation made otherwise can run it once, or pay the same
time on its first run.

It runs the bundled sample drive through the same code as ``vifusion run`` (vision in this
process, IMU-only and fused filters, no report), which compiles every kernel for the argument
types the runs use, then simulates five frames of a test scenario (the simulator's kernels: the
first ``vifusion simulate`` took 30 s), and prints how long that took.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["warm_up", "main"]


def warm_up() -> float:
    """Run the sample drive once (vision in this process, no report); returns the seconds taken."""
    from .cli import main as cli_main

    from vision.video import start_numba

    t0 = time.perf_counter()
    start_numba()        # called before the vision workers fork; the sample runs one worker
    with tempfile.TemporaryDirectory(prefix="vifusion-warmup-") as tmp:
        status = cli_main(["run", "--out", str(Path(tmp) / "run"), "--no-report", "--workers", "1", "--quiet"])
        if status != 0:
            raise RuntimeError(f"the sample drive's run exited with status {status}")
        if SIM_SCENARIO.is_file():     # a checkout (the simulator lives in its tools/)
            status = cli_main(["simulate", str(SIM_SCENARIO), "--out", str(Path(tmp) / "sim"), "--frames", "5",
                               "--quiet"])
            if status != 0:
                raise RuntimeError(f"simulating {SIM_SCENARIO.name} exited with status {status}")
    return time.perf_counter() - t0


#: A small scenario whose simulation compiles the simulator's kernels.
SIM_SCENARIO = Path(__file__).resolve().parents[1] / "configs" / "scenarios" / "test" / "tiny_banked_curve.toml"


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(prog="python -m fusion.warmup", description=__doc__.splitlines()[0]).parse_args(argv)
    print("compiling the vision and fusion kernels (numba, once per install) ...", flush=True)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):   # the run's own summary is not this step's business
        seconds = warm_up()
    print(f"compiled in {seconds:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
