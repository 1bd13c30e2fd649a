"""The ``geocon`` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from ._version import __version__

app = typer.Typer(
    name="geocon",
    help="GeoCon: is a generated video geometrically real? Ground-truth-free audit of background and object consistency.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True)
out = Console()


def _fail(message: str) -> typer.Exit:
    err.print(f"[bold red]error:[/] {message}")
    return typer.Exit(code=2)


def _parse_size(size: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError:
        raise _fail(f"--size must look like 640x360, got {size!r}") from None
    if w % 2 or h % 2 or w < 16 or h < 16:
        raise _fail(f"--size needs an even width and height of at least 16 (H.264 4:2:0), got {size!r}")
    return w, h


def _version_callback(value: bool) -> None:
    if value:
        out.print(f"geocon {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit.")] = False,
) -> None:
    """GeoCon: is a generated video geometrically real?"""


def _render_plans(plans, out_dir: Path, *, seed: int, width: int, height: int, frames: int, fps: float, quiet: bool, noise: float = 1.0):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from .synth import write_clip

    results = []
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"), TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn())
    with Progress(*columns, console=err, disable=quiet, transient=False) as progress:
        task = progress.add_task("rendering", total=len(plans) * frames)
        for i, plan in enumerate(plans, 1):
            progress.update(task, description=f"[{i}/{len(plans)}] {plan.clip_id}")
            gt = write_clip(
                plan, out_dir, seed=seed, width=width, height=height, num_frames=frames, fps=fps, noise=noise,
                on_frame=lambda _t: progress.advance(task),
            )
            results.append(gt)
    return results


def _summary_rows(gts) -> list[dict]:
    rows = []
    for gt in gts:
        rows.append(
            {
                "clip_id": gt.clip_id,
                "family": gt.family,
                "failure": None if gt.failure is None else {"kind": gt.failure.kind, "severity": gt.failure.severity, "unit": gt.failure.unit},
                "frames": gt.num_frames,
                "size": [gt.width, gt.height],
                "fps": gt.fps,
                "t_inf": gt.t_inf,
                "rotation_deg": gt.rotation_deg,
                "expected_gate": gt.expected_gate,
                "objects": [{"id": o.object_id, "name": o.name, "rigid": o.rigid, "visible_frames": len(o.visible_frames)} for o in gt.objects],
                "video": gt.video_path,
            }
        )
    return rows


def _print_table(gts, out_dir: Path) -> None:
    table = Table(title=f"synthetic clips in {out_dir}", title_justify="left")
    for col in ("clip", "family", "frames", "t_inf", "rot °", "gate", "objects", "failure"):
        table.add_column(col, justify="right" if col in ("frames", "t_inf", "rot °") else "left", no_wrap=col == "clip")
    for gt in gts:
        objects = ", ".join(f"{o.object_id}:{o.name}{'' if o.rigid else ' (non-rigid)'}" for o in gt.objects) or "-"
        failure = f"{gt.failure.kind} {gt.failure.severity:g}" if gt.failure else "-"
        table.add_row(gt.clip_id, gt.family, str(gt.num_frames), f"{gt.t_inf:.3f}", f"{gt.rotation_deg:.1f}", gt.expected_gate, objects, failure)
    out.print(table)


@app.command()
def synth(
    family: Annotated[str, typer.Argument(help="Scene family: C1..C6 (or c1_static, c2_rotation, c3_translation, c4_objects, c5_complex, c6_stress), or 'all'.")],
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder (created if missing).")],
    frames: Annotated[int, typer.Option(min=2, help="Frames per clip.")] = 48,
    size: Annotated[str, typer.Option(help="Frame size WxH (even numbers).")] = "640x360",
    fps: Annotated[float, typer.Option(min=0.1, help="Frames per second.")] = 24.0,
    seed: Annotated[int, typer.Option(help="Random seed; the same seed gives identical files.")] = 0,
    failure: Annotated[Optional[str], typer.Option(help="Inject a failure: breathing, slide, missing_parallax, elastic, boiling, letterbox.")] = None,
    severity: Annotated[Optional[float], typer.Option(help="Failure severity in the failure's unit (see `geocon synth-failures`).")] = None,
    noise: Annotated[float, typer.Option(min=0.0, help="Sensor noise, standard deviation in grey levels.")] = 1.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout instead of a table.")] = False,
) -> None:
    """Render synthetic clips with exact ground truth: video (mp4), object masks, ground truth
    (.gt.json) and benchmark metadata (.meta.json) per clip.

    'all' renders one clip per family plus one variant per failure kind."""
    from .synth import plan_clips

    width, height = _parse_size(size)
    try:
        plans = plan_clips(family, failure, severity)
        gts = _render_plans(plans, out_dir, seed=seed, width=width, height=height, frames=frames, fps=fps, quiet=as_json, noise=noise)
    except ValueError as exc:
        raise _fail(str(exc)) from None
    if as_json:
        sys.stdout.write(json.dumps(_summary_rows(gts), indent=1) + "\n")
    else:
        _print_table(gts, out_dir)


@app.command("synth-failures")
def synth_failures() -> None:
    """List the injectable failures with their severity units, defaults and ranges."""
    from .synth import FAILURES

    table = Table(title="injectable failures (geocon synth --failure KIND --severity X)", title_justify="left")
    for col in ("kind", "what", "severity unit", "default", "range"):
        table.add_column(col)
    for spec in FAILURES.values():
        table.add_row(spec.kind, spec.summary, spec.unit, f"{spec.default:g}", f"({spec.low:g}, {spec.high:g}]")
    out.print(table)


@app.command()
def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("geocon-demo"),
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Run the built-in demo: render a static-camera scene with two moving objects, one of
    which deforms non-rigidly, and print what the clip contains."""
    from .synth import ClipPlan

    plan = ClipPlan("C4", "elastic", 4.0)
    (gt,) = _render_plans([plan], out_dir, seed=seed, width=640, height=360, frames=48, fps=24.0, quiet=False)
    table = Table(title="what the demo clip contains", title_justify="left", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("video", str(out_dir / gt.video_path))
    table.add_row("object masks", f"{out_dir / gt.masks_path}/ (one label PNG per frame, 0 = background)")
    table.add_row("ground truth", str(out_dir / f"{gt.clip_id}.gt.json"))
    table.add_row("benchmark metadata", str(out_dir / f"{gt.clip_id}.meta.json"))
    table.add_row("camera", f"static, {gt.fov_x_deg:g}° horizontal field of view, f = {gt.K[0, 0]:.1f} px")
    table.add_row("translation gate", f"t_inf = {gt.t_inf:.3f} -> expected model {gt.expected_gate} (hysteresis 0.03 / 0.05)")
    for o in gt.objects:
        table.add_row(f"object {o.object_id}", f"{o.name}, {'rigid' if o.rigid else 'NON-RIGID (injected elastic warp)'}, visible in {len(o.visible_frames)}/{gt.num_frames} frames")
    table.add_row("masked share", f"{gt.masked_share.mean():.1%} of the frame on average")
    out.print(table)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
