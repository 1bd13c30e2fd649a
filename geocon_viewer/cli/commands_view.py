"""``geocon view`` and ``geocon serve``: a saved record in the Rerun viewer, a results folder in the
Viser audit app. The viewer modules load only when these commands run."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from geocon_core.config import DEFAULT_PRESET

from .commands_score import is_input_error, score_with_progress
from .console import (
    VIEWER_EXTRA,
    default_out,
    err,
    fail,
    has_viewer_extra,
    out,
    progress_bar,
    reach,
    rerun_version,
    serve_until_stopped,
)

__all__ = ["view", "serve"]


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _resolve_record(target: Path, preset_name: str) -> Path:
    """A record folder for ``target``: the folder itself, the saved record of a clip, or a new
    record scored now (said on stderr)."""
    if target.is_dir() and (target / "record.json").exists():
        return target
    if target.name == "record.json" and target.exists():
        return target.parent
    if not target.exists():
        raise fail(f"{target} does not exist: give a clip or a record folder (one with record.json)")
    from geocon_core.media import ClipError, check_clip, is_rerun_recording, rerun_refusal

    if target.is_file() and is_rerun_recording(target):
        raise fail(rerun_refusal(str(target)))
    owner = target.parent.parent if target.parent.name == "overlays" else target.parent
    if (
        target.is_file()
        and (target.name == "matches.npz" or owner != target.parent)
        and (owner / "record.json").is_file()
    ):
        raise fail(
            f"{target} is a part of the record {owner}, not a clip: give the record folder (geocon view {owner})"
        )
    folder = default_out(target, has_out=False)
    if (folder / "record.json").exists():
        err.print(f"using the saved record {folder} (delete it or run `geocon score` to re-score)")
        return folder
    from geocon_core.config import preset

    try:
        cfg = preset(preset_name)
    except ValueError as exc:
        raise fail(str(exc)) from None
    try:
        check_clip(target)  # a file that is no clip is refused before anything is said or made
    except ClipError as exc:
        raise fail(str(exc)) from None
    err.print(f"no saved record for {target}: scoring it first (record: {folder})")
    try:
        score_with_progress(target, cfg, out_dir=folder)
    except ValueError as exc:
        if not is_input_error(exc):
            raise
        raise fail(str(exc)) from None
    return folder


def _say_where_the_clip_is(record: Any, folder: Path) -> None:
    """Refuse a record whose clip was replaced by another; warn (and show the scores without
    frames) when the clip is gone."""
    from geocon_core.media import ClipError, OtherClipError, locate_clip

    try:
        locate_clip(record.video, folder)
    except OtherClipError as exc:
        raise fail(str(exc)) from None
    except ClipError as exc:
        err.print(f"warning: {exc}; the recording shows the scores without frames", soft_wrap=True, highlight=False)


def _check_outputs(record: Any, folder: Path, rrd: Path, screenshot: Path | None) -> None:
    """The recording and the screenshot never replace the clip, the masks or the record's own files."""
    from geocon_core.files import check_apart, check_out_file, claim

    inputs = [("clip", Path(record.video.path))]
    outputs = [("--save", rrd)] + ([] if screenshot is None else [("--screenshot", screenshot)])
    check_apart(outputs, inputs, records=[folder])
    check_out_file(rrd, "--save")
    claim("--save", rrd, "recording", own=[folder])
    if screenshot is not None:
        check_out_file(screenshot, "--screenshot", "screenshot.png")
        claim("--screenshot", screenshot, "png", own=[folder])


def _check_connect(url: str | None) -> None:
    """Refuse a ``--connect`` URL that is malformed (exit 2) or where no viewer answers (exit 1),
    before anything is scored or rendered."""
    from ..capture import ViewerUnreachable, ViewerUrlError, check_viewer_url

    if url is None:
        return
    try:
        check_viewer_url(url)
    except ViewerUrlError as exc:
        raise fail(str(exc)) from None
    except ViewerUnreachable as exc:
        raise fail(str(exc), code=1) from None


def _stream_failed(connect: str | None, exc: RuntimeError) -> typer.Exit:
    """The one sentence (exit 1) of a viewer that went away while the recording streamed to it;
    ``exc`` itself when nothing streamed (a bug, with its traceback). A viewer that stopped taking
    the recording (:class:`~geocon_viewer.rerun.log.ViewerStalled`) leaves Rerun's client waiting
    for it for ever, at exit too: the process ends at once after its sentence (``os._exit``; the
    partial recording is already removed)."""
    from ..rerun import ViewerStalled

    if connect is None:
        raise exc
    if isinstance(exc, ViewerStalled):
        fail(
            f"the Rerun viewer at {connect} stopped answering while the recording streamed ({exc}); the recording "
            "is not kept: check the viewer, then rerun the command",
            code=1,
        )
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(1)
    return fail(
        f"the Rerun viewer at {connect} stopped answering while the recording streamed ({exc}); the recording "
        "is not kept: start the viewer again and rerun the command",
        code=1,
    )


def _check_options(
    at: int | None, preset_name: str, *, serve: bool, headless: bool, connect: str | None, screenshot: Path | None
) -> None:
    """The options of ``geocon view`` that are wrong whatever the record: a negative ``--at``,
    ``--serve`` with an option that opens no viewer or another one, an unknown ``--preset`` (even
    when the saved record leaves it unused)."""
    if at is not None and at < 0:
        raise fail(f"--at must be a frame index (0 or more), got {at}")
    others = {"--headless": headless, "--connect": connect is not None, "--screenshot": screenshot is not None}
    clash = next((option for option, given in others.items() if given), None)
    if serve and clash is not None:
        raise fail(f"--serve and {clash} exclude each other (--serve serves the web viewer); give one of them")
    from geocon_core.config import preset

    try:
        preset(preset_name)
    except ValueError as exc:
        raise fail(str(exc)) from None


def view(
    target: Annotated[
        Path,
        typer.Argument(
            help="A record folder (from `geocon score`/`geocon demo`) or a clip (its saved record is used, or it "
            "is scored first)."
        ),
    ],
    save: Annotated[
        Optional[Path],
        typer.Option("--save", help="Write the recording here (default: audit.rrd in the record folder)."),
    ] = None,
    connect: Annotated[
        Optional[str],
        typer.Option("--connect", help="Stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy."),
    ] = None,
    serve: Annotated[
        bool, typer.Option("--serve", help="Serve the web viewer on 127.0.0.1 even when a display is available.")
    ] = False,
    headless: Annotated[bool, typer.Option("--headless", help="Only write the recording; open no viewer.")] = False,
    screenshot: Annotated[
        Optional[Path],
        typer.Option(
            "--screenshot",
            help="Save a PNG of the default layout at --at: the headless native viewer (needs a Vulkan driver, "
            "e.g. Debian mesa-vulkan-drivers), else the web viewer in headless Chromium.",
        ),
    ] = None,
    at: Annotated[
        Optional[int], typer.Option("--at", help="Frame to show first (default: the worst-scoring pair).")
    ] = None,
    preset_name: Annotated[
        str, typer.Option("--preset", help="Preset used when the clip has to be scored first.")
    ] = DEFAULT_PRESET,
) -> None:
    """Re-render the Rerun recording of a saved record without re-scoring, then open it: the
    native viewer when a display is available, otherwise the web viewer served on 127.0.0.1."""
    _check_options(at, preset_name, serve=serve, headless=headless, connect=connect, screenshot=screenshot)
    if not has_viewer_extra("rerun"):
        raise fail(f"geocon view needs the viewer extra: {VIEWER_EXTRA}")
    _check_connect(connect)
    from geocon_core.record import read_overlays, read_record

    from ..rerun import evidence, quiet_encoder_logs, worst_frame, write_rrd

    quiet_encoder_logs()
    folder = _resolve_record(target, preset_name)
    try:
        record = read_record(folder)  # before any rendering: a corrupt record is one sentence naming its file
        read_overlays(folder, record)  # and overlays of another record, or outside its frames
    except ValueError as exc:  # a RecordError, or the overlays'
        raise fail(str(exc)) from None
    if record.model_note() is not None:
        err.print(f"note: {folder / 'record.json'} was {record.model_note()}", soft_wrap=True, highlight=False)
    n = record.video.num_frames
    if at is not None and at >= n:
        raise fail(f"--at {at} is past the last frame of {record.clip}: it has {n} frames (0 to {n - 1})")
    _say_where_the_clip_is(record, folder)
    rrd = save or folder / "audit.rrd"
    try:
        _check_outputs(record, folder, rrd, screenshot)
    except ValueError as exc:
        raise fail(str(exc)) from None
    try:
        with progress_bar("rendering", "frames", elapsed=False, eta=False) as bar:
            task = bar.add_task("render", total=None)
            try:
                write_rrd(
                    folder,
                    rrd,
                    connect=connect,
                    progress=lambda done, total: bar.update(task, completed=done, total=total),
                )
            except BaseException:
                bar.live.transient = True  # a failed render leaves its error, not a half-filled bar
                raise
    except ValueError as exc:
        raise fail(str(exc)) from None
    except RuntimeError as exc:  # Rerun's gRPC client: the viewer went away while the recording streamed
        raise _stream_failed(connect, exc) from None
    strongest = evidence(record)[1]  # a flagged clip: where the reading its score leans on is strongest
    frame = at if at is not None else (strongest if strongest is not None else worst_frame(record))
    out.print(
        f"recording: {rrd} ({rrd.stat().st_size / 1e6:.1f} MB, Rerun {rerun_version()}: open it with a viewer "
        "of the same version)"
    )
    if screenshot is not None:
        from ..capture import ScreenshotError, screenshot_rrd

        try:
            screenshot_rrd(rrd, screenshot, at=f"frame@{frame}")
        except ScreenshotError as exc:
            raise fail(str(exc)) from None
        out.print(f"screenshot: {screenshot}")
    if headless or connect is not None or screenshot is not None:
        return
    from ..rerun import open_native, serve_web

    if _has_display() and not serve:
        open_native(rrd, frame=frame)
        out.print(f"opened the native viewer at the worst pair (frame {frame})")
        return
    try:
        serve_web(
            rrd,
            announce=lambda url: out.print(
                f"web viewer: {url}  (127.0.0.1 only; Ctrl-C to stop). Worst pair: frame {frame}.", soft_wrap=True
            ),
        )
    except RuntimeError as exc:
        raise fail(str(exc)) from None


def serve(
    results: Annotated[
        Path, typer.Argument(help="A results folder from `geocon bench`, or a record folder from `geocon score --out`.")
    ],
    port: Annotated[
        int,
        typer.Option(
            "--port", help="Port to serve on (a busy port moves to the next free one; 0 picks any free port)."
        ),
    ] = 8080,
    host: Annotated[
        str,
        typer.Option(
            "--host",
            help="Address to bind. The default serves this machine only; 0.0.0.0 exposes the app to your network.",
        ),
    ] = "127.0.0.1",
    screenshot: Annotated[
        Optional[Path],
        typer.Option("--screenshot", help="Save a PNG of the page as headless Chromium shows it, then stop."),
    ] = None,
    clip: Annotated[
        Optional[str], typer.Option("--clip", help="Clip id to select first (default: the most severe).")
    ] = None,
) -> None:
    """Browse a benchmark's clips in the Viser audit app: the triage list (most severe first), live
    re-gating at other thresholds, the 3D scene, frames with overlays and the IR/GE/AdaDFRC plots."""
    from ..capture import BindError, check_bind

    try:
        check_bind(host, port)  # before anything starts: a server thread that cannot bind fails unseen
    except BindError as exc:
        raise fail(str(exc)) from None
    if not has_viewer_extra("viser"):
        raise fail(f"geocon serve needs the viewer extra: {VIEWER_EXTRA}")
    if screenshot is not None:
        from geocon_core.files import OutPathError, check_out_file, claim

        try:
            check_out_file(screenshot, "--screenshot", "screenshot.png")  # before the server starts
            claim("--screenshot", screenshot, "png")
        except OutPathError as exc:
            raise fail(str(exc)) from None
    from geocon_core.results import ResultsError, ResultsIndex
    from geocon_core.signals import load_clip_model

    from ..audit import AuditApp
    from ..rerun import quiet_encoder_logs

    quiet_encoder_logs()  # the app writes recordings on request

    start = time.perf_counter()
    try:
        index = ResultsIndex.open(results)
        if any(c.finding is not None for c in index.clips):  # the clip model decides them: its file is usable
            load_clip_model()
        if clip is not None and clip not in index.by_id:  # before the server starts
            ids = sorted(index.by_id)
            named = ", ".join(ids[:5]) + (f" and {len(ids) - 5} more" if len(ids) > 5 else "")
            raise fail(f"--clip {clip!r} is not a clip of {results}; its clips are {named}")
        audit = AuditApp(index, host=host, port=port)
    except (ResultsError, ValueError) as exc:
        raise fail(str(exc)) from None
    except OSError as exc:
        raise fail(f"could not serve on {host}:{port}: {exc}") from None
    try:
        if clip is not None:
            audit.clip.value = clip  # type: ignore[misc]  # viser setter typing gap

        n = len(audit.index.clips)
        ready = time.perf_counter() - start
        serve_until_stopped(
            audit,
            host=host,
            port=port,
            banner=f"GeoCon audit app: {audit.url}  ({n} clip{'s' if n != 1 else ''}, ready in {ready:.1f} s; "
            f"{reach(audit.host)}; Ctrl-C to stop)",
            screenshot=screenshot,
            before_shot=lambda: audit.view is not None and audit.view.frames_ready.wait(60),
        )
    except KeyboardInterrupt:
        err.print("stopping")
    finally:
        audit.stop()
