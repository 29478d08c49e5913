"""``vifusion`` command line: a thin layer, one module per subcommand.

Each subcommand module has ``add_parser(subparsers)`` and ``run(args) -> int``. Errors that the
user can fix (bad input, bad config) are printed as one line ``error: ...`` with exit status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import sys

def _interrupted_while_loading() -> None:
    """Ctrl-C while the command's modules load: its one line and exit 130, at once. Not by
    SystemExit: with it the process now and then ended by its own SIGINT after the line (exit
    -2, as Python does when it takes a KeyboardInterrupt for unhandled at the top: 3 of 30
    interrupts at ``vision.frames``'s import, measured; 0 of 80 this way), which
    `test_ctrl_c_while_the_command_loads_is_one_line` caught in CI runs. Why (found later, the
    same death after an interrupt while the filter loads): CPython 3.11 marks a KeyboardInterrupt
    as unhandled when it ends code that a library ran through ``PyRun_*``, caught or not, and
    ``python -m`` then exits by SIGINT (``fusion/__main__.py``). Nothing is written yet to clean
    up."""
    import os

    print("error: interrupted", file=sys.stderr)
    sys.stderr.flush()
    os._exit(130)


def _note_interrupt_while_loading(signum, frame):
    """SIGINT while the modules load: noted, then raised as Python's own handler does. A
    library can lose the KeyboardInterrupt (raised inside a finalizer it is only printed as
    'Exception ignored'; C code can clear it): `test_ctrl_c_while_the_command_loads_is_one_line`
    once saw the interrupt at numpy's import have no effect, the run going on to exit 0."""
    _LOADING_INTERRUPTED.append(signum)
    raise KeyboardInterrupt


_LOADING_INTERRUPTED: list[int] = []
import signal  # noqa: E402  (built in: no time)
import threading  # noqa: E402

_NOTE_LOADING = (threading.current_thread() is threading.main_thread()
                 and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
if _NOTE_LOADING:
    signal.signal(signal.SIGINT, _note_interrupt_while_loading)
try:   # numpy loads here (0.15 s): an interrupt during the imports is said as any other (main's)
    import argparse
    import errno
    import gc
    import importlib
    import os
    import re
    import time
    from pathlib import Path

    from imu.errors import ImuError
    from vision.errors import VisionError

    from ..errors import FusionError
    from ..files import write_atomically
except KeyboardInterrupt:
    _interrupted_while_loading()
if _NOTE_LOADING:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if _LOADING_INTERRUPTED:      # lost inside a library's import: said all the same
    _interrupted_while_loading()


def _process_started_s() -> float:
    """``time.perf_counter()`` at the moment this process started: its age from ``/proc``
    (Linux, 10 ms steps), so that a run's fixed costs include the interpreter's start and the
    imports before this module; elsewhere, the moment this module was loaded."""
    now = time.perf_counter()
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])   # field 22, starttime
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        age_s = uptime_s - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return now
    return now - age_s if 0.0 <= age_s < 3600.0 else now


#: When the process started: the start of a run's fixed costs (interpreter and imports included).
STARTED_S = _process_started_s()


__all__ = ["main", "USER_ERRORS"]

#: The running command's interrupt watch (:func:`main`).
_WATCH = None

#: Subcommands, in the order ``vifusion --help`` lists them.
SUBCOMMANDS = ("run", "campaign", "vision", "can", "simulate")

#: Flags that every command takes, before or after its name: (flag, help).
COMMON_FLAGS = (("--debug", "show tracebacks"), ("--quiet", "no progress bars"))

#: Exceptions that mean bad input rather than a bug: reported in one line, exit status 2. Every
#: operating-system refusal is the user's to fix (a path, a full disk, a read-only file
#: system, a name too long), not only missing files.
USER_ERRORS = (FusionError, ImuError, VisionError, OSError)


class _Parser(argparse.ArgumentParser):
    """argparse with its errors in the program's form: one line ``error: ...`` (naming the
    command's ``--help``), exit status 2, instead of the usage block before it."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="vifusion",
        description="Vehicle attitude and road bank angle from a camera fused with a CAN-bus IMU.",
    )
    for flag, text in COMMON_FLAGS:
        parser.add_argument(flag, action="store_true", help=text)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        importlib.import_module(f".{name}", __name__).add_parser(sub)
    for p in sub.choices.values():      # 'vifusion COMMAND --debug' as well as 'vifusion --debug COMMAND'
        for flag, text in COMMON_FLAGS:
            action = p._option_string_actions.get(flag) or p.add_argument(flag, action="store_true", help=text)
            # no default of the command's own: it would overwrite the flag given before the command
            # ('vifusion --quiet can ...' had been "unrecognized arguments", a review)
            action.default = argparse.SUPPRESS
    return parser


def main(argv: list[str] | None = None) -> int:
    global _WATCH
    args = interrupted = None
    collecting = gc.isenabled()
    try:
        # the subcommands' modules load here: an interrupt during them is said as any other
        # (it was a traceback of the imports, a review; the package's own imports before this
        # are light: imu and vision load their heavy parts on first use). One try from here to
        # the command's end: an interrupt between the parsing and the watch's handler, or
        # between that and the command, escaped as a traceback and a death by SIGINT (exit -2;
        # once in the tests, `test_ctrl_c_while_the_command_loads_is_one_line`)
        parser = build_parser()
        argv = sys.argv[1:] if argv is None else argv
        args = parser.parse_args(argv)
        _check_path_names(args)
        if not args.debug:
            # FFmpeg inside OpenCV prints its own line for a video it cannot open ("moov atom not
            # found") before the one-line error this program gives for it
            os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
        interrupted = _WATCH = _InterruptWatch(quiet=not args.debug)
        interrupted.start()   # after the assignment: an interrupt inside it is closed in `finally`
        gc.disable()   # until the command's imports are done (settle_heap)
        status = int(args.func(args) or 0)
        if interrupted.seen:   # a library dropped the KeyboardInterrupt and the run went on
            print("warning: interrupted where it could not stop (inside a library): the run went on to the end",
                  file=sys.stderr)
        return status
    except BrokenPipeError:
        # the reader of the output went away ('vifusion can LOG ... | head'): no more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:
        if interrupted is None:
            print("error: interrupted", file=sys.stderr)
            return 130
        return interrupted.said()
    except Exception as e:
        if args is None:       # the parser itself: a bug, not a user's error
            raise
        if interrupted is not None and interrupted.seen and not args.debug:
            # Ctrl-C that surfaced as another error: numba's compiler turns it into "no compiled
            # object yet", a pool worker's into SystemError (2 of 21 interrupts in a review)
            return interrupted.said()
        if not isinstance(e, USER_ERRORS) or args.debug:
            raise
        print(f"error: {_one_line(e)}", file=sys.stderr)
        return 2
    finally:
        (gc.enable if collecting else gc.disable)()   # as the caller had it
        if interrupted is not None:
            interrupted.close()
        _WATCH = None


def _check_path_names(args: argparse.Namespace) -> None:
    """Every file or folder named on the command line has a name that is UTF-8: OpenCV's
    video reader and writer crashed the process on one that is not (a segmentation fault, no
    message; a review, a name with the byte 0xfc), and pyarrow and the HTML report raised on it."""
    from ..errors import InputError

    for value in vars(args).values():
        for p in value if isinstance(value, list) else [value]:
            if isinstance(p, Path):
                try:
                    str(p).encode("utf-8")
                except UnicodeEncodeError:
                    shown = os.fsencode(p).decode("utf-8", "backslashreplace")
                    raise InputError(f"{shown}: the name is not UTF-8 (the video and table libraries cannot "
                                     "open it): rename it") from None


def settle_heap() -> None:
    """Called by a command once its imports are done: the objects so far (about 200,000: the
    modules of numba, OpenCV, SciPy, pandas) are moved out of the garbage collector's reach
    (``gc.freeze``) and the collector, which :func:`main` stops for the imports, runs again.
    Collected while they were imported, they cost 0.2-0.4 s of full collections that free
    nothing; scanned after, every full collection took 20-180 ms (a 60 s drive's run: 0.5 s in
    its main process, measured), and the vision workers' collections wrote to every page they
    share with the run's process. Once per process: a campaign's later drives would freeze the
    earlier ones' uncollected cycles (the report's figures) for good (a review)."""
    if not gc.get_freeze_count():
        gc.freeze()
    gc.enable()


def interrupt_seen() -> bool:
    """Whether the command running got SIGINT: an error after it is the interrupt's (a
    campaign's drive that fails then ends the campaign instead of being skipped)."""
    return _WATCH is not None and _WATCH.seen


class _InterruptWatch:
    """Records whether this process got SIGINT (and raises KeyboardInterrupt as Python's own
    handler does), for as long as the command runs; only where Python's handler is in place,
    in the main thread. With ``quiet``, once interrupted: a KeyboardInterrupt raised where
    Python cannot pass it on (numba's LLVM callbacks: "Exception ignored ...") is raised again
    in the main thread instead of printed and lost, and the other errors of finalizers that the
    interrupt left half built are not printed (``--debug`` prints them). SIGTERM, where it has
    its default action (the process killed on the spot, a simulation's or a run's ``.partial``
    folder left behind, which ``run --drive`` took: a review), is taken the same way and noted
    in ``terminated``, so that the command's clean-up runs."""

    def __init__(self, quiet: bool = True):
        self.seen = self.terminated = False
        self._signum = signal.SIGINT
        self._quiet = quiet
        self._before = signal.getsignal(signal.SIGINT)
        self._hook = sys.unraisablehook
        self._resent: list[threading.Thread] = []
        self._active = self._term = False     # the handlers this watch installed (`start`)

    def start(self) -> None:
        """Installs the handlers. Apart from the constructor, so that the caller holds the
        watch before any handler is in place: an interrupt that arrives while they are being
        installed (the first raises it already) leaves none behind once :meth:`close` has run
        (a review: made in one step, an interrupt there left the handler in the process)."""
        main = threading.current_thread() is threading.main_thread()
        # SIGTERM on its own: a command started in the background of a script has SIGINT
        # ignored and SIGTERM still default (a review found it killed outright then)
        term = main and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        if main and self._before is signal.default_int_handler:
            self._active = True         # before: restoring a handler never replaced is harmless
            signal.signal(signal.SIGINT, self._on_interrupt)
        if term:
            self._term = True
            signal.signal(signal.SIGTERM, self._on_interrupt)

    def said(self) -> int:
        """The command's end after an interrupt: its one line, and the exit status."""
        if self.terminated:   # SIGTERM (kill, a batch system): the same clean-up, its own status
            print("error: terminated (SIGTERM)", file=sys.stderr)
            return 143
        print("error: interrupted", file=sys.stderr)
        return 130

    def _on_interrupt(self, signum, frame):
        self.seen = True
        self.terminated = self.terminated or signum == signal.SIGTERM
        self._signum = signum
        if self._quiet:
            sys.unraisablehook = self._unraisable
        raise KeyboardInterrupt

    def _unraisable(self, unraisable) -> None:
        if (unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt)
                and not self._resent):   # once: one Ctrl-C, one interrupt
            # the interrupt again, where it can stop the command: from another thread once this
            # hook has returned (raised in the hook it would be lost again), as a real signal to
            # the main thread (which wakes it from a sleep, as _thread.interrupt_main would not)
            returned = threading.Event()
            thread = threading.Thread(target=self._interrupt_after, args=(returned, self._signum), daemon=True)
            try:
                thread.start()
                self._resent.append(thread)
            except RuntimeError:         # the interpreter is shutting down: it stops anyway
                pass
            returned.set()
        # others after the interrupt: what it left half built (llvmlite's finalizers: "'PassBuilder'
        # object has no attribute '_as_parameter_'"); --debug shows them

    @staticmethod
    def _interrupt_after(returned: threading.Event, signum: int) -> None:
        returned.wait(1.0)
        time.sleep(0.01)                 # the hook's last steps
        signal.pthread_kill(threading.main_thread().ident, signum)

    def close(self) -> None:
        mine = [sig for sig, on in ((signal.SIGINT, self._active), (signal.SIGTERM, self._term)) if on]
        if self._resent:                 # an interrupt sent again after the command ended: not raised
            for sig in mine:
                signal.signal(sig, lambda signum, frame: None)
            for thread in self._resent:
                thread.join(2.0)
            time.sleep(0.001)            # Python code runs the no-op on the signal, if one is pending
        if self._active:
            signal.signal(signal.SIGINT, self._before)
        if self._term:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        sys.unraisablehook = self._hook


def workers_arg(text: str) -> int:
    """``--workers N``: a whole number of processes, at least 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of processes, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"needs at least 1 process, got {n}")
    return n


def mapped_as(mapping, channel: str) -> str:
    """How the config's ``[can] signals`` maps IMU channel ``channel``, for an error line."""
    return f"mapped as {mapping.signals[channel]}" if channel in mapping.signals else "not mapped in [can] signals"


def write_table(df, path: Path) -> None:
    """One output table, CSV or Parquet by the suffix, written to ``PATH.partial`` and renamed.
    CSV numbers keep 9 significant digits (a fixed 6 decimals kept 2 of a curvature sigma of
    9e-5 1/m, a review found), the times ``t_s`` their microseconds, an empty field for NaN."""
    if path.suffix.lower() == ".parquet":
        write_atomically(path, lambda tmp: df.to_parquet(tmp, index=False))  # keeps df.attrs
        return
    text = numeric_csv(df)
    if text is not None:
        write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8", newline=""))
        return
    if "t_s" in df.columns:
        import numpy as np

        t = df["t_s"].to_numpy(dtype=float)
        df = df.assign(t_s=np.where(np.isnan(t), "", np.char.mod("%.6f", t)))   # NaN empty, as numeric_csv
    write_atomically(path, lambda tmp: df.to_csv(tmp, index=False, float_format="%.9g"))


#: A field that is the float NaN as ``"%.9g"`` writes it, to be written empty as pandas does.
_NAN_FIELD = re.compile(r"(?<![^,\n])nan(?![^,\n])")


def numeric_csv(df) -> str | None:
    """The CSV text that ``write_table`` writes of a table whose columns are all numbers or
    booleans (``fused.csv``), byte for byte as pandas' ``to_csv`` with ``float_format="%.9g"``
    (``tests/test_cli_run.py``; a NaN time written empty, as ``write_table`` writes it in
    every table) at a third of its time: one ``%`` per row instead of three
    Python calls per value (the 60 s drive's ``fused.csv``, 6000 x 37: 0.12 s against 0.29);
    ``None`` for another table (a string column: pandas' quoting; one column: pandas writes its
    NaN as ``""``, an empty line being no row)."""
    kinds = [df[c].dtype.kind if hasattr(df[c].dtype, "kind") else "O" for c in df.columns]
    if len(df.columns) < 2 or any(k not in "fiub" for k in kinds) or df.columns.duplicated().any():
        return None
    if any(str(c) != c or any(ch in c for ch in ',"\n\r') for c in df.columns):
        return None
    codes = {"f": "%.9g", "i": "%d", "u": "%d", "b": "%s"}
    fmt = ",".join("%.6f" if c == "t_s" else codes[k] for c, k in zip(df.columns, kinds))
    rows = [fmt % row for row in zip(*(df[c].tolist() for c in df.columns))]
    body = _NAN_FIELD.sub("", "\n".join(rows)) if "f" in kinds else "\n".join(rows)
    return ",".join(df.columns) + "\n" + body + ("\n" if rows else "")


def check_output_file(path: Path) -> None:
    """An output file's place, checked before any work (a review: a path under a file, or in a
    folder that cannot be written, was said after the whole video or log, a debug video left
    behind): not a folder, and the nearest existing folder above it (the rest is made on
    writing) a folder this process may write in."""
    from ..errors import InputError

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a file name")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"{path}: {folder} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{path}: cannot write in {folder} (permission denied)")


def check_debug_video(path: Path) -> None:
    """``--debug-video``: a container the writer knows (:meth:`vision.debug.DebugWriter.check`)
    in a place that can be written (:func:`check_output_file`), before any work."""
    from vision.debug import DebugWriter

    DebugWriter.check(path)
    check_output_file(path)


def refuse_inputs_as_outputs(outputs, inputs) -> None:
    """An output path that is one of the command's input files (after links) is refused
    before any work: it would be overwritten (a review: ``vifusion can X.csv --out X.csv``
    replaced the recording with its decode, ``--debug-video`` equal to ``--video`` the video)."""
    from ..errors import InputError

    given = {os.path.realpath(p): p for p in inputs if p is not None}
    for out in outputs:
        same = given.get(os.path.realpath(out)) if out is not None else None
        if same is not None:
            raise InputError(f"{out}: is an input of this command ({same}) and would be "
                             "overwritten: write the output elsewhere")


def write_tables(df, stem: Path) -> None:
    """``STEM.csv`` and ``STEM.parquet`` (:func:`write_table`)."""
    for suffix in (".csv", ".parquet"):
        write_table(df, stem.with_name(stem.name + suffix))


#: What the operating system's refusals mean for an output or input path, in words.
_OS_WORDS = {errno.ENOTDIR: "a file is in the way where a folder is needed",
             errno.EEXIST: "exists already (a file where a folder is needed?)",
             errno.ENOENT: "no such file or folder (or its parent folder is missing)",
             errno.EACCES: "permission denied", errno.EPERM: "not permitted",
             errno.ENOSPC: "no space left on the device", errno.EROFS: "on a read-only file system",
             errno.ENAMETOOLONG: "file name too long"}


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename:
        text = f"{e.filename}: {_OS_WORDS.get(e.errno, e.strerror)}"
    else:
        text = str(e)
    return " ".join(text.split()) or type(e).__name__
