"""``geocon synth``, ``geocon synth-failures`` and ``geocon synth-bench``: synthetic clips with
exact ground truth."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer
from rich.table import Table

from .console import MAX_FRAMES, MAX_SCENES, MAX_SEED, fail, out, parse_size, progress_bar

if TYPE_CHECKING:
    from geocon_core.synth import ClipPlan, GroundTruth

__all__ = ["check_render_out", "render_plans", "synth", "synth_failures", "synth_bench"]


def check_render_out(out_dir: Path) -> None:
    """``--out`` can take rendered clips (:func:`~geocon_core.files.check_out_dir`: a folder, or one
    that can be made, and :func:`~geocon_core.files.claim`: not a record, results, report or
    validation folder of GeoCon's, nor inside a part of one; ``ValueError`` with one sentence).
    Rendering reads no file, so no output can write over an input."""
    from geocon_core.files import check_out_dir, claim

    check_out_dir(out_dir, "--out")
    claim("--out", out_dir, "folder")


def render_plans(
    plans: list[ClipPlan],
    out_dir: Path,
    *,
    seed: int,
    width: int,
    height: int,
    frames: int,
    fps: float,
    quiet: bool,
    noise: float = 2.0,
) -> list[GroundTruth]:
    from geocon_core.files import parents_made
    from geocon_core.synth import check_clip_targets, write_clip

    for plan in plans:  # every clip's files checked before the first is rendered
        check_clip_targets(plan, out_dir)
    results = []
    with (
        parents_made(out_dir),
        progress_bar("{task.description}", "frames", disable=quiet, transient=False) as progress,
    ):
        task = progress.add_task("rendering", total=len(plans) * frames)
        for i, plan in enumerate(plans, 1):
            progress.update(task, description=f"[{i}/{len(plans)}] {plan.clip_id}")
            gt = write_clip(
                plan,
                out_dir,
                seed=seed,
                width=width,
                height=height,
                num_frames=frames,
                fps=fps,
                noise=noise,
                on_frame=lambda _t: progress.advance(task),
            )
            results.append(gt)
    return results


def _summary_rows(gts: list[GroundTruth]) -> list[dict[str, Any]]:
    rows = []
    for gt in gts:
        rows.append(
            {
                "clip_id": gt.clip_id,
                "family": gt.family,
                "failure": None
                if gt.failure is None
                else {"kind": gt.failure.kind, "severity": gt.failure.severity, "unit": gt.failure.unit},
                "frames": gt.num_frames,
                "size": [gt.width, gt.height],
                "fps": gt.fps,
                "t_inf": gt.t_inf,
                "rotation_deg": gt.rotation_deg,
                "expected_gate": gt.expected_gate,
                "objects": [
                    {"id": o.object_id, "name": o.name, "rigid": o.rigid, "visible_frames": len(o.visible_frames)}
                    for o in gt.objects
                ],
                "video": gt.video_path,
            }
        )
    return rows


def _print_table(gts: list[GroundTruth], out_dir: Path) -> None:
    table = Table(title=f"synthetic clips in {out_dir}", title_justify="left")
    for col in ("clip", "family", "frames", "t_inf", "rot °", "gate", "objects", "failure"):
        table.add_column(col, justify="right" if col in ("frames", "t_inf", "rot °") else "left", no_wrap=col == "clip")
    for gt in gts:
        objects = ", ".join(f"{o.object_id}:{o.name}{'' if o.rigid else ' (non-rigid)'}" for o in gt.objects) or "-"
        failure = f"{gt.failure.kind} {gt.failure.severity:g}" if gt.failure else "-"
        table.add_row(
            gt.clip_id,
            gt.family,
            str(gt.num_frames),
            f"{gt.t_inf:.3f}",
            f"{gt.rotation_deg:.1f}",
            gt.expected_gate,
            objects,
            failure,
        )
    out.print(table)


def synth(
    family: Annotated[
        str,
        typer.Argument(
            help="Scene family: C1..C6 (or c1_static, c2_rotation, c3_translation, c4_objects, c5_complex, "
            "c6_stress), or 'all'."
        ),
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder (created if missing).")],
    frames: Annotated[int, typer.Option(min=2, max=MAX_FRAMES, help="Frames per clip.")] = 48,
    size: Annotated[str, typer.Option(help="Frame size WxH (even numbers).")] = "640x360",
    fps: Annotated[float, typer.Option(min=0.1, max=1000.0, help="Frames per second (0.1 to 1000).")] = 24.0,
    seed: Annotated[
        int, typer.Option(min=0, max=MAX_SEED, help="Random seed (0 or more); the same seed gives identical files.")
    ] = 0,
    failure: Annotated[
        Optional[str],
        typer.Option(help="Inject a failure: breathing, slide, missing_parallax, elastic, boiling, letterbox."),
    ] = None,
    severity: Annotated[
        Optional[float], typer.Option(help="Failure severity in the failure's unit (see `geocon synth-failures`).")
    ] = None,
    noise: Annotated[float, typer.Option(help="Sensor noise, standard deviation in grey levels (0 to 255).")] = 2.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout instead of a table.")] = False,
) -> None:
    """Render synthetic clips with exact ground truth: video (mp4), object masks, ground truth
    (.gt.json) and benchmark metadata (.meta.json) per clip.

    'all' renders one clip per family plus one variant per failure kind."""
    from geocon_core.synth import MAX_NOISE, plan_clips

    width, height = parse_size(size)
    if not 0 <= noise <= MAX_NOISE:  # NaN fails too
        raise fail(f"--noise must be a standard deviation of 0 to {MAX_NOISE:g} grey levels, got {noise:g}")
    try:
        check_render_out(out_dir)
        plans = plan_clips(family, failure, severity)
        gts = render_plans(
            plans, out_dir, seed=seed, width=width, height=height, frames=frames, fps=fps, quiet=as_json, noise=noise
        )
    except ValueError as exc:
        raise fail(str(exc)) from None
    if as_json:
        sys.stdout.write(json.dumps(_summary_rows(gts), indent=1) + "\n")
    else:
        _print_table(gts, out_dir)


def synth_failures() -> None:
    """List the injectable failures with their severity units, defaults and ranges."""
    from geocon_core.synth import FAILURES

    table = Table(title="injectable failures (geocon synth --failure KIND --severity X)", title_justify="left")
    for col in ("kind", "what", "severity unit", "default", "range"):
        table.add_column(col)
    for spec in FAILURES.values():
        table.add_row(spec.kind, spec.summary, spec.unit, f"{spec.default:g}", f"({spec.low:g}, {spec.high:g}]")
    out.print(table)


def synth_bench(
    out_dir: Annotated[Path, typer.Option("--out", help="Dataset folder (created).")],
    scenes: Annotated[
        int, typer.Option(min=1, max=MAX_SCENES, help="Scenes (seeds) per family; every platform renders each.")
    ] = 3,
    families: Annotated[str, typer.Option(help="Comma-separated families.")] = "C1,C2,C3,C4,C5",
    frames: Annotated[int, typer.Option(min=2, max=MAX_FRAMES, help="Frames per clip.")] = 24,
    size: Annotated[str, typer.Option(help="Frame size WxH (even numbers).")] = "320x180",
) -> None:
    """Render a synthetic benchmark dataset for `geocon bench`: the same scenes from three
    "platforms" (clean, breathing background, elastic objects), with sidecar metadata."""
    from geocon_core.files import parents_made
    from geocon_core.synth import check_benchmark_targets, plan_benchmark, write_benchmark

    width, height = parse_size(size)
    names = [f.strip() for f in families.split(",") if f.strip()]
    if not names:
        raise fail(f"--families names no family, got {families!r}: give some of C1..C6, e.g. C1,C2")
    try:
        check_render_out(out_dir)
        clips = plan_benchmark(families=names, scenes=scenes)
        check_benchmark_targets(out_dir, clips)
    except ValueError as exc:
        raise fail(str(exc)) from None
    with parents_made(out_dir), progress_bar("rendering", "frames", eta=False) as bar:
        task = bar.add_task("render", total=len(clips) * frames)
        written = write_benchmark(
            out_dir, clips, width=width, height=height, num_frames=frames, on_frame=lambda _t: bar.advance(task)
        )
    out.print(
        f"{len(set(written))} clips in {out_dir} (platforms clean, breathing, elastic). "
        f"Next: geocon bench {out_dir} --out RESULTS",
        soft_wrap=True,
    )
