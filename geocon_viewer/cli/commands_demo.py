"""``geocon demo``: render a small synthetic clip, say what it contains, and score it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ..shared import fmt
from .commands_score import check_inputs, print_record, score_with_progress
from .commands_synth import check_render_out, render_plans
from .console import MAX_SEED, fail, has_viewer_extra, out, rerun_version

__all__ = ["demo"]


def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("geocon-demo"),
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="Random seed (0 or more).")] = 0,
) -> None:
    """Run the built-in demo: render a static-camera scene with two moving objects, one of
    which deforms non-rigidly, print what the clip contains, then score it."""
    from geocon_core.config import ScoreConfig
    from geocon_core.synth import ClipPlan, clip_targets

    plan = ClipPlan("C4", "elastic", 4.0)
    target, rrd = out_dir / "record", (out_dir / "demo.rrd" if has_viewer_extra("rerun") else None)
    try:
        check_render_out(out_dir)
        clip_file = clip_targets(plan, out_dir)["video"]
        check_inputs(target, rrd=rrd, clip=clip_file)  # the record and the recording: the demo's own, or new
    except ValueError as exc:
        raise fail(str(exc)) from None
    (gt,) = render_plans([plan], out_dir, seed=seed, width=640, height=360, frames=48, fps=24.0, quiet=False)
    table = Table(title="what the demo clip contains", title_justify="left", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("video", str(out_dir / gt.video_path))
    table.add_row("object masks", f"{out_dir / gt.masks_path}/ (one label PNG per frame, 0 = background)")
    table.add_row("ground truth", str(out_dir / f"{gt.clip_id}.gt.json"))
    table.add_row("benchmark metadata", str(out_dir / f"{gt.clip_id}.meta.json"))
    table.add_row("camera", f"static, {gt.fov_x_deg:g}° horizontal field of view, f = {gt.K[0, 0]:.1f} px")
    table.add_row(
        "translation gate", f"t_inf = {gt.t_inf:.3f} -> expected model {gt.expected_gate} (hysteresis 0.03 / 0.05)"
    )
    for o in gt.objects:
        kind = "rigid" if o.rigid else "NON-RIGID (injected elastic warp)"
        table.add_row(
            f"object {o.object_id}", f"{o.name}, {kind}, visible in {len(o.visible_frames)}/{gt.num_frames} frames"
        )
    table.add_row("masked share", f"{gt.masked_share.mean():.1%} of the frame on average")
    out.print(table)
    clip = out_dir / gt.video_path
    # the clip ships its object masks (as a benchmark dataset does through masks_path)
    record = score_with_progress(clip, ScoreConfig(), out_dir=target, masks=out_dir / gt.masks_path, rrd=rrd)
    print_record(record, target)
    truth = {o.object_id: o for o in gt.objects}
    for obj in record.objects:
        t = truth.get(obj.object_id)
        if t is not None:
            out.print(
                f"object {obj.object_id} ({t.name}, {'rigid' if t.rigid else 'non-rigid by construction'}): "
                f"AdaDFRC {fmt(obj.adadfrc, '.3f')} px²",
                soft_wrap=True,
            )
    out.print(
        "Higher AdaDFRC means less rigid motion. Score any clip: geocon score CLIP (built-in masks) or "
        "geocon score CLIP --masks DIR.",
        soft_wrap=True,
    )
    if rrd is not None:
        out.print(
            f"Rerun recording: {rrd}. Browse it with `geocon view {target}` (web viewer on 127.0.0.1 when there is "
            f"no display), or `rerun {rrd}` with rerun-sdk {rerun_version()}.",
            soft_wrap=True,
        )
