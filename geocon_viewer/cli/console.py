"""What every ``geocon`` command shares: the consoles, the one-sentence failure, argument parsing
helpers."""

from __future__ import annotations

import importlib.util
import signal
import time
from contextlib import suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import typer
from rich.console import Console
from rich.markup import escape
from typer.core import TyperCommand, TyperOption

if TYPE_CHECKING:
    from rich.progress import Progress

__all__ = [
    "err",
    "out",
    "fail",
    "parse_size",
    "MAX_FRAMES",
    "MAX_SCENES",
    "MAX_SEED",
    "rerun_version",
    "default_out",
    "has_viewer_extra",
    "VIEWER_EXTRA",
    "progress_bar",
    "reach",
    "serve_until_stopped",
    "PathsChecked",
]

err = Console(stderr=True)
out = Console()

VIEWER_EXTRA = "pip install 'geocon[viewer]' (or run bash scripts/bootstrap.sh viewer)"
"""How to install the viewers, quoted when a command needs them."""


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``message`` as an error on stderr; the caller raises the returned exit (code 2: bad
    input or options; 1: the machine or the network failed)."""
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    return typer.Exit(code=code)


PATH_LIKE = frozenset({"masks"})
"""Parameters typed ``str`` that take a path too (``--masks DIR`` or ``--masks sam2``)."""


class PathsChecked(TyperCommand):
    """A command that refuses an empty path, ``--out ''`` or ``--out=``, with one sentence before
    anything runs: the command would otherwise see ``Path('')``, which is ``.``, the current folder
    (and write there, or fail with a traceback). Checked on the raw words of the command line,
    since once converted an empty path and ``.`` are one value. So are an option whose value is
    another option (``--out --json`` would write a record folder named ``--json``) and an option
    given twice with different values (``--frames 8 ... --frames 9``, ``--rrd --no-rrd``), of which
    the parser would keep the last without a word (:func:`_misused_option`)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        if not ctx.resilient_parsing:
            misused = _misused_option(self, args)
            if misused is not None:
                raise fail(misused)
            empty = _empty_path(self, ctx, args)
            if empty is not None:
                raise fail(f"{empty} is an empty path; give a file or folder name (`.` for the current folder)")
        return super().parse_args(ctx, args)


def _misused_option(command: TyperCommand, args: list[str]) -> str | None:
    """Why the options in ``args`` cannot mean what they say, or None: an option whose value is
    one of the command's options (``--out --json``; ``--out=--json`` is taken as written), or a
    single-valued option given twice with different values (the same value twice is harmless;
    repeatable options such as ``--root`` may repeat)."""
    options = {o: p for p in command.params if isinstance(p, TyperOption) for o in (*p.opts, *p.secondary_opts)}
    names = set(options) | {"--help"}
    seen: dict[str, tuple[str, object]] = {}
    words = iter(args)
    for word in words:
        if word == "--":
            break
        name, has_value, inline = word.partition("=")
        param = options.get(name)
        if param is None:
            continue
        value: object
        if param.is_flag:
            value = name in param.opts
        elif has_value:
            value = inline
        else:
            value = next(words, None)
            if value in names:
                return (
                    f"{name} has no value: the word after it, {value}, is an option; give {name} its value "
                    f"(a path that begins with -- as ./{value})"
                )
        if param.multiple or param.count:
            continue
        first = seen.setdefault(param.name or name, (name, value))
        if first[1] != value:
            if param.is_flag:
                return f"{first[0]} and {name} contradict each other; give one of them"
            return f"{name} is given twice ({first[1]} and {value}); give it once"
    return None


def _empty_path(command: TyperCommand, ctx: Any, args: list[str]) -> str | None:
    """The option (``--out``) or argument (``CLIP``) of ``command`` given an empty path in
    ``args``, or None; a command line the parser rejects is left to it to report."""
    try:
        opts, _rest, _order = command.make_parser(ctx).parse_args(args=list(args))
    except Exception:  # a usage error: said by the real parse that follows
        return None
    for param in command.params:
        annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
        if not ("Path" in str(annotation) or param.name in PATH_LIKE):
            continue
        value = opts.get(param.name)
        values = value if isinstance(value, (list, tuple)) else [value]
        if "" in values:
            return param.opts[0] if isinstance(param, TyperOption) else (param.name or "").upper()
    return None


MAX_SIDE = 8192
"""The largest width or height ``--size`` accepts (8K; H.264 encoders and a laptop's memory stop near it)."""
MAX_PIXELS = 8192 * 4320
"""The most pixels a ``--size`` frame may have (an 8K frame; 8192x8192 took minutes a frame)."""
MAX_FRAMES = 100_000
"""The most frames a rendered clip may have (``--frames``; over an hour at 24 fps)."""
MAX_SCENES = 10_000
"""The most scenes per family ``geocon synth-bench --scenes`` renders."""
MAX_SEED = 2**32 - 1
"""The largest seed of the synthetic scenes (``--seed``; 0 is the smallest)."""


def parse_size(size: str, option: str = "--size") -> tuple[int, int]:
    """``"640x360"`` -> (640, 360); even sizes of 16 to :data:`MAX_SIDE` px (H.264 4:2:0) of at
    most :data:`MAX_PIXELS`. A bad size is refused with one sentence naming ``option``."""
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError:
        raise fail(f"{option} must look like 640x360, got {size!r}") from None
    if w % 2 or h % 2 or w < 16 or h < 16:
        raise fail(f"{option} needs an even width and height of at least 16 (H.264 4:2:0), got {size!r}")
    if w > MAX_SIDE or h > MAX_SIDE:
        why = "which no encoder here writes" if option == "--size" else "beyond any clip GeoCon scores"
        raise fail(f"{option} {size} is larger than {MAX_SIDE} px on a side (8K), {why}")
    if w * h > MAX_PIXELS:
        raise fail(
            f"{option} {size} has {w * h / 1e6:.0f} million pixels, more than an 8K frame (8192x4320, "
            f"{MAX_PIXELS / 1e6:.1f} million); give a smaller size"
        )
    return w, h


def rerun_version() -> str:
    """The installed rerun-sdk version (without importing it), or ``"?"``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rerun-sdk")
    except PackageNotFoundError:
        return "?"


def has_viewer_extra(module: str = "rerun") -> bool:
    """Whether ``module`` (a viewer dependency) is installed, without importing it."""
    return importlib.util.find_spec(module) is not None


def record_clip(folder: Path, clip: Path) -> str | None:
    """None when the record in ``folder`` was scored on ``clip`` (the same file, where it lay when
    scored or beside the record as it moved, or a clip of the same bytes), or when its
    ``record.json`` cannot be read (a damaged record is scored again); else the other clip's name."""
    import os

    from geocon_core.media import clip_fingerprint
    from geocon_core.record import read_record_json

    try:
        doc = read_record_json(folder)[1]
    except ValueError:
        return None
    found = doc.get("video")
    video: dict[str, Any] = found if isinstance(found, dict) else {}
    if video.get("abs_path") == os.path.abspath(clip):  # scored from this very place
        return None
    places = [video.get("abs_path"), video.get("from_record")]
    for place in places:
        if isinstance(place, str) and place:
            at = Path(os.path.normpath(folder.resolve().parent / place))
            with suppress(OSError):
                if at.exists() and clip.exists() and os.path.samefile(at, clip):
                    return None
    fingerprint = video.get("fingerprint")
    if isinstance(fingerprint, str) and clip.exists() and clip_fingerprint(clip) == fingerprint:
        return None
    other = doc.get("clip")
    return str(other) if isinstance(other, str) and other else "another clip"


def record_of(clip: Path) -> Callable[[Any], str | None]:
    """The ``mine`` test of :func:`geocon_core.files.claim` for a record folder: a record of
    ``clip`` may be replaced, the record of another clip not (:func:`record_clip`)."""

    def mine(there: Any) -> str | None:
        other = record_clip(there.path, clip)
        return None if other is None else f"the record of {other}, not of {clip}"

    return mine


def default_out(clip: Path, *, has_out: bool = True) -> Path:
    """Where ``geocon score`` writes the record of ``clip`` by default: ``geocon-out/<clip name>``.
    A folder there that holds the record of another clip with the same name is not used: the
    command refuses and asks for ``--out`` (``has_out``) or for a record folder of its own."""
    target = Path("geocon-out") / (clip.name if clip.is_dir() else clip.stem)
    if not (target / "record.json").is_file():
        return target
    other = record_clip(target, clip)
    if other is not None:
        remedy = (
            f"pass --out to choose a folder for {clip}"
            if has_out
            else f"score {clip} into a folder of its own (geocon score {clip} --out DIR) and give DIR"
        )
        raise fail(f"{target} already holds the record of {other}; {remedy} (or remove {target})")
    return target


def progress_bar(
    label: str, unit: str, *, failed: bool = False, elapsed: bool = True, eta: bool = True, **options: Any
) -> Progress:
    """A progress bar on stderr: ``label``, the bar, ``done/total unit``, with ``failed`` the task's
    ``failed`` field in red, the elapsed time and, with ``eta``, the time remaining. ``options`` go to
    :class:`rich.progress.Progress` (``disable``, ``transient``)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns: list[ProgressColumn] = [TextColumn(label), BarColumn(), MofNCompleteColumn(), TextColumn(unit)]
    if failed:
        columns.append(TextColumn("[red]{task.fields[failed]} failed"))
    if elapsed:
        columns.append(TimeElapsedColumn())
    if eta:
        columns += [TextColumn("eta"), TimeRemainingColumn()]
    return Progress(*columns, console=err, **options)


def reach(host: str) -> str:
    """Who can open a page served on ``host``."""
    return "this machine only" if host in ("127.0.0.1", "localhost", "::1") else "reachable from the network"


def serve_until_stopped(
    app: Any,
    *,
    host: str,
    port: int,
    banner: str,
    screenshot: Path | None = None,
    before_shot: Callable[[], object] = lambda: None,
) -> None:
    """Serve ``app`` (a :class:`~geocon_viewer.audit.served.ServedApp`) until Ctrl-C or ``kill``
    (raised as KeyboardInterrupt, even when started with SIGINT ignored, as a background job of a
    non-interactive shell is), after printing ``banner`` and a note when ``port`` was busy; with
    ``screenshot``, save a PNG of the page (after ``before_shot()``) and return instead. The caller
    stops the app."""

    def on_term(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)  # `kill` stops as cleanly as Ctrl-C
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if port != 0 and app.port != port:
        err.print(f"port {port} on {host} is in use: serving on port {app.port} instead", soft_wrap=True)
    out.print(banner, soft_wrap=True)
    if screenshot is not None:
        from ..capture import ScreenshotError, screenshot_url

        before_shot()
        try:
            screenshot_url(app.url, screenshot)
        except ScreenshotError as exc:
            raise fail(str(exc)) from None
        out.print(f"screenshot: {screenshot}")
        return
    while True:
        time.sleep(0.5)
