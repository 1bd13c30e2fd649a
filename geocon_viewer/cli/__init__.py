"""The ``geocon`` command line. Every command is a plain function in a ``commands_*`` module,
registered here by name; the commands import the core and the viewers they need when they run,
so ``geocon --help`` loads neither Rerun nor Viser.

==================  ============================================================================
``synth``           synthetic clips with exact ground truth (:mod:`.commands_synth`)
``synth-failures``  the injectable failures
``demo``            render, describe and score a small synthetic clip (:mod:`.commands_demo`)
``score``           score one clip (:mod:`.commands_score`)
``synth-bench``     a synthetic benchmark dataset
``dataset``         what ``bench`` reads from a dataset, and its sidecars (:mod:`.commands_dataset`)
``bench``           score a dataset, write tables (:mod:`.commands_bench`)
``report``          the paper's tables and figures from benchmark results
``presets``         the named scoring presets
``view``            a saved record in the Rerun viewer (:mod:`.commands_view`)
``serve``           a results folder in the Viser audit app
``teach``           a synthetic scene in the Viser teaching app (:mod:`.commands_teach`)
``validate``        the validation report: synthetic grid and annotated real clips (:mod:`.commands_validate`)
``footage``         the footage cache of the validation: status, fill from local clones
``pose-log``        a pose log from a COLMAP model or a DUSt3R scene (:mod:`.commands_pose`)
``plant``           a failure planted into a real clip, with its clean twin (:mod:`.commands_plant`)
``pairs``           preference pairs per prompt for training (:mod:`.commands_pairs`)
``doctor``          which backends, viewers and extras are usable here (:mod:`.commands_doctor`)
==================  ============================================================================
"""

from __future__ import annotations

import codecs
import contextlib
import errno
import io
import os
import signal
import sys
from typing import Annotated


def _interrupted_while_loading(_signum: int, _frame: object) -> None:
    """Ctrl-C while the command's libraries load (the first half second): nothing has started,
    so the command ends at once (130), without the traceback of the import it cut short."""
    raise SystemExit(130)


try:
    _SIGINT_BEFORE_LOADING = signal.signal(signal.SIGINT, _interrupted_while_loading)
except ValueError:  # imported outside the main thread: no handler can be set there
    _SIGINT_BEFORE_LOADING = None

import typer  # noqa: E402

from geocon_core import __version__  # noqa: E402

from . import (  # noqa: E402
    commands_bench,
    commands_dataset,
    commands_demo,
    commands_doctor,
    commands_pairs,
    commands_plant,
    commands_pose,
    commands_score,
    commands_synth,
    commands_teach,
    commands_validate,
    commands_view,
)
from .console import PathsChecked, out  # noqa: E402

__all__ = ["app", "main"]

app = typer.Typer(
    name="geocon",
    help="GeoCon: is a generated video geometrically real? Ground-truth-free audit of background and object "
    "consistency.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version_callback(value: bool) -> None:
    if value:
        out.print(f"geocon {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """GeoCon: is a generated video geometrically real?"""


app.command("synth", cls=PathsChecked)(commands_synth.synth)
app.command("synth-failures", cls=PathsChecked)(commands_synth.synth_failures)
app.command("demo", cls=PathsChecked)(commands_demo.demo)
app.command("score", cls=PathsChecked)(commands_score.score)
app.command("synth-bench", cls=PathsChecked)(commands_synth.synth_bench)
app.command("dataset", cls=PathsChecked)(commands_dataset.dataset)
app.command("bench", cls=PathsChecked)(commands_bench.bench)
app.command("report", cls=PathsChecked)(commands_bench.report)
app.command("presets", cls=PathsChecked)(commands_bench.presets)
app.command("view", cls=PathsChecked)(commands_view.view)
app.command("serve", cls=PathsChecked)(commands_view.serve)
app.command("teach", cls=PathsChecked)(commands_teach.teach)
app.command("validate", cls=PathsChecked)(commands_validate.validate)
app.command("footage", cls=PathsChecked)(commands_validate.footage)
app.command("pose-log", cls=PathsChecked)(commands_pose.pose_log)
app.command("plant", cls=PathsChecked)(commands_plant.plant)
app.command("pairs", cls=PathsChecked)(commands_pairs.pairs)
app.command("doctor", cls=PathsChecked)(commands_doctor.doctor)

if _SIGINT_BEFORE_LOADING is not None:  # loaded: Ctrl-C is handled as before (main() sets its own)
    signal.signal(signal.SIGINT, _SIGINT_BEFORE_LOADING)


RESOURCE_ERRORS = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EROFS: "the file system is read-only",
    errno.EPIPE: "the output was closed",
    errno.EIO: "an input/output error",
    errno.EFBIG: "a file grew past the file system's limit",
    errno.ENAMETOOLONG: "a file name is too long for the file system",
    errno.EMFILE: "too many open files for this process's limit (raise it with ulimit -n, e.g. ulimit -n 4096)",
    errno.ENFILE: "too many open files on this system (close other programs, or raise the system's fs.file-max)",
}
"""Errors of the machine, not of GeoCon: said in one sentence (what, where), never a traceback."""

MEMORY_ADVICE = {
    "score": "use --preset fast (it scores at 512x360) or score a shorter clip",
    "demo": "close other programs and run it again",
    "bench": "give a smaller --working-size (e.g. 640x360) or fewer --workers",
    "report": "give fewer --bootstrap resamples (e.g. 1000)",
    "synth": "give a smaller --size or fewer --frames",
    "synth-bench": "give a smaller --size, fewer --frames or fewer --scenes",
    "validate": "give fewer --jobs, or --quick",
    "view": "view the record of a shorter clip, or use --headless (no viewer is opened)",
    "teach": "give fewer --frames",
    "plant": "give fewer --frames",
    "pairs": "give fewer --workers",
}
"""What each command can do with less memory, naming only its own options (the advice of the
one-sentence out-of-memory error; other commands are told to close other programs)."""


def _resource_sentence(exc: OSError) -> str:
    where = f" ({exc.filename})" if exc.filename else ""
    what = RESOURCE_ERRORS[exc.errno] if exc.errno is not None else str(exc)
    return (
        f"error: {what}{where}; GeoCon stopped there (records, recordings and reports are written whole or not "
        "at all: what was there before is unchanged)"
    )


MIN_ADDRESS_SPACE = 2 << 30
"""Address space (``ulimit -v``) below which a command is refused up front: OpenCV and FFmpeg do
not survive allocations that fail (measured: a small clip scores at 1.8 GB and crashes at 1.5 GB)."""


def _address_space_sentence() -> str | None:
    """Why this process cannot run GeoCon's native libraries (an address-space limit below
    :data:`MIN_ADDRESS_SPACE`), or None."""
    import resource

    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY or soft >= MIN_ADDRESS_SPACE:
        return None
    return (
        f"error: this process may use only {soft / 2**30:.2f} GiB of address space (ulimit -v); GeoCon's "
        f"decoders and OpenCV need at least {MIN_ADDRESS_SPACE / 2**30:.0f} GiB (more for large clips): raise the limit"
    )


MIN_OPEN_FILES = 64
"""Open files (``ulimit -n``) below which a command is refused up front, unless the hard limit lets
the soft one be raised (measured: a small ``geocon score`` needs 6, 12 with ``--rrd``, below which
Rerun aborts; ``geocon bench --workers 8`` needs 32)."""
RAISED_OPEN_FILES = 1024
"""The soft open-files limit a command raises a lower one to, where the hard limit allows."""


def _open_files_sentence() -> str | None:
    """Why this process cannot run GeoCon (an open-files limit below :data:`MIN_OPEN_FILES` that
    cannot be raised), or None; a soft limit below it is raised when the hard limit allows."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= MIN_OPEN_FILES:
        return None
    if hard == resource.RLIM_INFINITY or hard >= MIN_OPEN_FILES:
        target = RAISED_OPEN_FILES if hard == resource.RLIM_INFINITY else min(hard, RAISED_OPEN_FILES)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            return None
    return (
        f"error: this process may open only {soft} files at once (ulimit -n {soft}); GeoCon needs at least "
        f"{MIN_OPEN_FILES} (more with many workers): raise the limit, e.g. ulimit -n 1024"
    )


ASCII_STAND_INS = str.maketrans(
    "\u00b2\u00b0\u2026\u2192\u2190\u2014\u2013\u00d7\u00b1\u2264\u2265"
    "\u2260\u00b5\u03c4\u00b7\u2501\u2500\u2022\u26a0\u25c0\u25b6",
    "2o.><--x~<>#ut.--*!<>",
)
"""Characters of GeoCon's tables, bars and sentences and the ASCII character a terminal that cannot
show them gets instead (one for one, so tables stay aligned; any other character prints as ``?``,
twice for a wide one)."""


def _ascii_stand_in(exc: UnicodeError) -> tuple[str, int]:
    """The ``geocon-ascii`` codec error handler: :data:`ASCII_STAND_INS`, else ``?`` per cell."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    from rich.cells import cell_len

    text = exc.object[exc.start : exc.end]
    stand_in = "".join(ch if ord(ch) < 128 else "?" * max(1, cell_len(ch)) for ch in text.translate(ASCII_STAND_INS))
    return stand_in, exc.end


def _plain_output() -> None:
    """Let stdout and stderr print what their encoding cannot show (an ASCII locale,
    ``PYTHONIOENCODING=ascii``) as ASCII stand-ins instead of raising ``UnicodeEncodeError``."""
    codecs.register_error("geocon-ascii", _ascii_stand_in)
    for stream in (sys.stdout, sys.stderr):
        encoding = codecs.lookup(getattr(stream, "encoding", None) or "ascii").name
        if encoding != "utf-8":
            with contextlib.suppress(AttributeError, ValueError, OSError):
                stream.reconfigure(errors="geocon-ascii")  # type: ignore[union-attr]


def _command() -> str | None:
    """The command this process runs (the first word of the command line that is no option)."""
    return next((arg for arg in sys.argv[1:] if not arg.startswith("-")), None)


def _memory_sentence(command: str | None) -> str:
    advice = MEMORY_ADVICE.get(command or "", "close other programs and run it again")
    return (
        f"error: the process ran out of memory (a memory limit, or a clip too large for it); {advice}; the "
        "previous results are unchanged"
    )


def main() -> None:
    """The ``geocon`` console script. A full disk, a read-only folder or a closed output ends the
    command with one sentence (exit 1) instead of a traceback; nothing half-written is left. An
    address-space or open-files limit too small for the native libraries is refused before any
    work. Text the terminal's encoding cannot show prints as ASCII stand-ins, and the decoders' own
    lines are kept off it. Ctrl-C, ``kill``, a closed terminal and a used-up CPU time limit stop the
    run cleanly (:func:`_stop`)."""
    _closed_streams()
    _plain_output()
    from geocon_core.media import quiet_decoder_logs

    quiet_decoder_logs()
    if not {"--help", "--version"} & set(sys.argv[1:]):
        small = _address_space_sentence() or _open_files_sentence()
        if small is not None:
            _say_and_exit(small, 1)
    _stop_on_signals()
    from geocon_core.files import tune_allocator

    tune_allocator()  # few arenas, frame-sized blocks back to the system: flat memory over long clips
    try:
        app(standalone_mode=True)
    except SystemExit:
        if _STOPPED_BY == [signal.SIGXCPU]:
            _say_and_exit(_cpu_time_sentence(), 1)
        raise
    except ClosedOutputError:
        _say_and_exit(
            "error: the standard output is closed (>&-), so the command's output has nowhere to go; give it a "
            "file or a pipe (> out.txt)",
            1,
        )
    except OSError as exc:
        if exc.errno not in RESOURCE_ERRORS:
            raise
        _say_and_exit(_resource_sentence(exc), 1)
    except MemoryError:
        _say_and_exit(_memory_sentence(_command()), 1)


class ClosedOutputError(OSError):
    """Writing to a standard output the caller closed (``>&-``)."""


class _ClosedOutput(io.TextIOBase):
    """Stands in for ``sys.stdout`` when the caller closed it: printing to it raises
    :class:`ClosedOutputError` (Python leaves ``sys.stdout`` None, where a write is a traceback)."""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        raise ClosedOutputError(errno.EBADF, "the standard output is closed", "<stdout>")


def _closed_streams() -> None:
    """Standard streams the caller closed (``<&-``, ``>&-``, ``2>&-``): their descriptors are
    opened on the null device, so that no file the command opens takes one of them (a native
    library's message on stderr would land in it); a closed stdout is refused where the command
    prints (:class:`_ClosedOutput`), a closed stderr swallows what is said."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: this one
    if sys.stdout is None:
        sys.stdout = _ClosedOutput()
    if sys.stderr is None:
        sys.stderr = open(2, "w", closefd=False)  # the process's stderr, open until it ends


TERM_GRACE_S = 10.0
"""After ``kill`` (SIGTERM), seconds the run may take to clean up before it exits regardless."""

_STOPPED_BY: list[int] = []
"""The signals that stopped this run (:func:`_stop`), the first first."""


def _stop_on_signals() -> None:
    """Ctrl-C (SIGINT), ``kill`` (SIGTERM), a closed terminal (SIGHUP) and the CPU time limit of
    ``ulimit -t`` (SIGXCPU) stop the run through :func:`_stop`; a signal the caller ignores (Ctrl-C
    of a background job) stays ignored."""
    for signum, default in (
        (signal.SIGINT, signal.default_int_handler),
        (signal.SIGTERM, signal.SIG_DFL),
        (signal.SIGHUP, signal.SIG_DFL),
        (signal.SIGXCPU, signal.SIG_DFL),
    ):
        if signal.getsignal(signum) is default:
            signal.signal(signum, _stop)


def _stop(signum: int, _frame: object) -> None:
    """Stop the run as Ctrl-C does (staging folders removed, nothing half-moved; exit 130), and
    exit anyway after :data:`TERM_GRACE_S` should the clean-up wait on worker threads. Signals
    that follow (a second Ctrl-C, SIGXCPU repeated every second past the soft limit) leave the
    clean-up to finish: cut short, it left temporary folders behind, and the interpreter aborted
    in native threads (``terminate called without an active exception``)."""
    import threading

    if _STOPPED_BY:
        return
    _STOPPED_BY.append(signum)
    timer = threading.Timer(TERM_GRACE_S, os._exit, args=(130,))
    timer.daemon = True
    timer.start()
    raise KeyboardInterrupt


def _cpu_time_sentence() -> str:
    # no number: the kernel raised the soft limit by a second when it sent SIGXCPU
    return (
        "error: the CPU time limit of this process (ulimit -t) ran out; GeoCon stopped there (records, "
        "recordings and reports are written whole or not at all: what was there before is unchanged); raise "
        "the limit or give it less work"
    )


def _say_and_exit(sentence: str, code: int) -> None:
    """Write ``sentence`` to stderr even when stdout is what failed, then exit with ``code``
    without flushing a broken stdout again."""
    with contextlib.suppress(OSError, AttributeError):
        sys.stderr.write(sentence + "\n")
        sys.stderr.flush()
    with contextlib.suppress(OSError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)  # the interpreter's final flush must not fail again
    os._exit(code)
