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
``doctor``          which backends, viewers and extras are usable here (:mod:`.commands_doctor`)
==================  ============================================================================
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
from typing import Annotated

import typer

from geocon_core import __version__

from . import (
    commands_bench,
    commands_dataset,
    commands_demo,
    commands_doctor,
    commands_pose,
    commands_score,
    commands_synth,
    commands_teach,
    commands_validate,
    commands_view,
)
from .console import out

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


app.command("synth")(commands_synth.synth)
app.command("synth-failures")(commands_synth.synth_failures)
app.command("demo")(commands_demo.demo)
app.command("score")(commands_score.score)
app.command("synth-bench")(commands_synth.synth_bench)
app.command("dataset")(commands_dataset.dataset)
app.command("bench")(commands_bench.bench)
app.command("report")(commands_bench.report)
app.command("presets")(commands_bench.presets)
app.command("view")(commands_view.view)
app.command("serve")(commands_view.serve)
app.command("teach")(commands_teach.teach)
app.command("validate")(commands_validate.validate)
app.command("footage")(commands_validate.footage)
app.command("pose-log")(commands_pose.pose_log)
app.command("doctor")(commands_doctor.doctor)


RESOURCE_ERRORS = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EROFS: "the file system is read-only",
    errno.EPIPE: "the output was closed",
    errno.EIO: "an input/output error",
    errno.EFBIG: "a file grew past the file system's limit",
    errno.ENAMETOOLONG: "a file name is too long for the file system",
}
"""Errors of the machine, not of GeoCon: said in one sentence (what, where), never a traceback."""


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


def main() -> None:
    """The ``geocon`` console script. A full disk, a read-only folder or a closed output ends the
    command with one sentence (exit 1) instead of a traceback; nothing half-written is left. An
    address-space limit too small for the native libraries is refused before any work."""
    small = _address_space_sentence()
    if small is not None and not {"--help", "--version"} & set(sys.argv[1:]):
        _say_and_exit(small, 1)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:  # `kill` stops as cleanly as Ctrl-C: no partial files
        signal.signal(signal.SIGTERM, _terminated)
    try:
        app(standalone_mode=True)
    except OSError as exc:
        if exc.errno not in RESOURCE_ERRORS:
            raise
        _say_and_exit(_resource_sentence(exc), 1)
    except MemoryError:
        _say_and_exit(
            "error: the process ran out of memory (a memory limit, or a clip too large for it); "
            "try a smaller --working-size or fewer workers; the previous results are unchanged",
            1,
        )


TERM_GRACE_S = 10.0
"""After ``kill`` (SIGTERM), seconds the run may take to clean up before it exits regardless."""


def _terminated(_signum: int, _frame: object) -> None:
    """``kill``: stop as Ctrl-C does (staging folders removed, nothing half-moved), and exit
    anyway after :data:`TERM_GRACE_S` should the clean-up wait on worker threads."""
    import threading

    timer = threading.Timer(TERM_GRACE_S, os._exit, args=(130,))
    timer.daemon = True
    timer.start()
    raise KeyboardInterrupt


def _say_and_exit(sentence: str, code: int) -> None:
    """Write ``sentence`` to stderr even when stdout is what failed, then exit with ``code``
    without flushing a broken stdout again."""
    with contextlib.suppress(OSError):
        sys.stderr.write(sentence + "\n")
        sys.stderr.flush()
    with contextlib.suppress(OSError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush must not fail again
    os._exit(code)
