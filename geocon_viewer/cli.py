"""The ``geocon`` command line with the viewers: the core commands plus ``geocon view`` and the
``--rrd`` recorder of ``geocon score`` (registered here, so the core never imports a viewer)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Annotated, Optional

import typer

from geocon_core.cli import (
    FRAME_SINKS,
    RECORD_RENDERERS,
    _default_out,
    _fail,
    _rerun_version,
    _score_with_progress,
    app,
    err,
    out,
)


def _rrd_sink(path: Path):
    from .rerun_log import RrdSink

    return RrdSink(path)


if importlib.util.find_spec("rerun") is not None:  # the viewer extra is installed
    FRAME_SINKS["rrd"] = _rrd_sink
    RECORD_RENDERERS["rrd"] = "geocon_viewer.rerun_log:write_rrd"


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
        raise _fail(f"{target} does not exist: give a clip or a record folder (one with record.json)")
    folder = _default_out(target)
    if (folder / "record.json").exists():
        err.print(f"using the saved record {folder} (delete it or run `geocon score` to re-score)")
        return folder
    from geocon_core.config import preset
    from geocon_core.reader import ClipError

    err.print(f"no saved record for {target}: scoring it first (record: {folder})")
    try:
        _score_with_progress(target, preset(preset_name), out_dir=folder)
    except (ClipError, ValueError) as exc:
        raise _fail(str(exc)) from None
    return folder


@app.command()
def view(
    target: Annotated[
        Path,
        typer.Argument(
            help="A record folder (from `geocon score`/`geocon demo`) or a clip (its saved record is used, or it is scored first)."
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
            help="Save a PNG of the default layout at --at: the headless native viewer (needs a Vulkan driver, e.g. Debian mesa-vulkan-drivers), else the web viewer in headless Chromium.",
        ),
    ] = None,
    at: Annotated[
        Optional[int], typer.Option("--at", help="Frame to show first (default: the worst-scoring pair).")
    ] = None,
    preset_name: Annotated[
        str, typer.Option("--preset", help="Preset used when the clip has to be scored first.")
    ] = "paper",
) -> None:
    """Re-render the Rerun recording of a saved record without re-scoring, then open it: the
    native viewer when a display is available, otherwise the web viewer served on 127.0.0.1."""
    if "rrd" not in FRAME_SINKS:
        raise _fail(
            "geocon view needs the viewer extra: pip install 'geocon[viewer]' (or run bash scripts/bootstrap.sh viewer)"
        )
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from geocon_core.record import read_record

    from .rerun_log import worst_frame, write_rrd

    folder = _resolve_record(target, preset_name)
    rrd = save or folder / "audit.rrd"
    try:
        with Progress(
            TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"), console=err
        ) as bar:
            task = bar.add_task("render", total=None)
            write_rrd(
                folder, rrd, connect=connect, progress=lambda done, total: bar.update(task, completed=done, total=total)
            )
    except ValueError as exc:
        raise _fail(str(exc)) from None
    frame = at if at is not None else worst_frame(read_record(folder))
    out.print(
        f"recording: {rrd} ({rrd.stat().st_size / 1e6:.1f} MB, Rerun {_rerun_version()}: open it with a viewer of the same version)"
    )
    if screenshot is not None:
        from .screenshot import ScreenshotError, screenshot_rrd

        try:
            screenshot_rrd(rrd, screenshot, at=f"frame@{frame}")
        except ScreenshotError as exc:
            raise _fail(str(exc)) from None
        out.print(f"screenshot: {screenshot}")
    if headless or connect is not None or screenshot is not None:
        return
    from .serve import open_native, serve_web

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
        raise _fail(str(exc)) from None


@app.command()
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
    if importlib.util.find_spec("viser") is None:
        raise _fail(
            "geocon serve needs the viewer extra: pip install 'geocon[viewer]' (or run bash scripts/bootstrap.sh viewer)"
        )
    import time

    from geocon_core.results import ResultsError

    from .audit_app import AuditApp

    start = time.perf_counter()
    try:
        audit = AuditApp(results, host=host, port=port)
    except (ResultsError, ValueError) as exc:
        raise _fail(str(exc)) from None
    except OSError as exc:
        raise _fail(f"could not serve on {host}:{port}: {exc}") from None
    try:
        if clip is not None:
            if clip not in audit.index.by_id:
                raise _fail(f"no clip {clip!r} in {results}")
            audit.clip.value = clip
        n = len(audit.index.clips)
        out.print(
            f"GeoCon audit app: {audit.url}  ({n} clip{'s' if n != 1 else ''}, ready in {time.perf_counter() - start:.1f} s; "
            f"{'this machine only' if audit.host in ('127.0.0.1', 'localhost', '::1') else 'reachable from the network'}; Ctrl-C to stop)",
            soft_wrap=True,
        )
        if screenshot is not None:
            from .screenshot import ScreenshotError, screenshot_url

            if audit.view is not None:
                audit.view.frames_ready.wait(60)
            try:
                screenshot_url(audit.url, screenshot)
            except ScreenshotError as exc:
                raise _fail(str(exc)) from None
            out.print(f"screenshot: {screenshot}")
            return
        import signal

        def on_term(*_: object) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, on_term)  # `kill` stops as cleanly as Ctrl-C
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        err.print("stopping")
    finally:
        audit.stop()


def main() -> None:
    app()


if __name__ == "__main__":
    main()
