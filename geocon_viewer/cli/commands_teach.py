"""``geocon teach``: the Viser teaching app on a synthetic scene. The viewer modules load only
when the command runs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from .console import MAX_SEED, VIEWER_EXTRA, err, fail, has_viewer_extra, out, reach, serve_until_stopped

__all__ = ["teach"]


def teach(
    port: Annotated[
        int,
        typer.Option(
            "--port", help="Port to serve on (0 picks any free port; a busy port moves to the next free one)."
        ),
    ] = 0,
    host: Annotated[
        str,
        typer.Option(
            "--host",
            help="Address to bind. The default serves this machine only; 0.0.0.0 exposes the app to your network.",
        ),
    ] = "127.0.0.1",
    frames: Annotated[int, typer.Option("--frames", help="Frames per rendered clip (4 to 120).")] = 16,
    seed: Annotated[
        int, typer.Option("--seed", min=0, max=MAX_SEED, help="Seed of the scene's layout, textures and noise.")
    ] = 0,
    screenshot: Annotated[
        Optional[Path],
        typer.Option(
            "--screenshot",
            help="Save a PNG of the page (1600x1000) as headless Chromium shows it once the first clip is scored, "
            "then stop.",
        ),
    ] = None,
) -> None:
    """Teach two-view geometry on a synthetic scene: sliders move the camera (rotation,
    translation), break the background (breathing, a sliding panel) and the objects (elasticity,
    speed); each change re-renders a short clip, scores it with the `fast` preset and shows the
    gate (H/U/F against t_inf's 0.03/0.05 band), IR/GE against the report gate, each object's
    AdaDFRC, the inliers of a pair and one sentence on what changed and why. Each update's latency
    is printed."""
    from ..capture import BindError, check_bind

    try:
        check_bind(host, port)  # before anything starts: a server thread that cannot bind fails unseen
    except BindError as exc:
        raise fail(str(exc)) from None
    if not has_viewer_extra("viser"):
        raise fail(f"geocon teach needs the viewer extra: {VIEWER_EXTRA}")
    if screenshot is not None:
        from geocon_core.files import OutPathError, check_out_file, claim

        try:
            check_out_file(screenshot, "--screenshot", "screenshot.png")  # before the server starts
            claim("--screenshot", screenshot, "png")
        except OutPathError as exc:
            raise fail(str(exc)) from None
    from ..teach import TeachApp, TeachParams, TeachUpdate

    try:
        params = TeachParams(num_frames=frames, seed=seed)
    except ValueError as exc:
        raise fail(str(exc)) from None

    def report(u: TeachUpdate) -> None:
        if u.record is None:
            err.print(f"update {u.index}: {u.error}", soft_wrap=True)
            return
        out.print(
            f"update {u.index}: {u.latency_s:.2f} s from the change to the numbers (render {u.render_s:.2f} s, "
            f"score {u.score_s:.2f} s) · gate {u.gate_label} · {u.explanation}",
            soft_wrap=True,
            highlight=False,
        )

    try:
        app = TeachApp(host=host, port=port, params=params, on_update=report)
    except OSError as exc:
        raise fail(f"could not serve on {host}:{port}: {exc}") from None
    try:
        serve_until_stopped(
            app,
            host=host,
            port=port,
            banner=f"GeoCon teach: {app.url}  ({reach(app.host)}; the first clip is on its way; Ctrl-C to stop)",
            screenshot=screenshot,
            before_shot=lambda: app.wait(timeout=300.0),
        )
    except KeyboardInterrupt:
        err.print("stopping")
    finally:
        app.stop()
