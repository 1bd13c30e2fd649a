"""``geocon pairs``: preference pairs per prompt for DPO-style training (:mod:`geocon_core.reward`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from .console import err, fail, out, progress_bar

__all__ = ["pairs"]


def pairs(
    manifest: Annotated[
        Path,
        typer.Argument(help="A CSV with columns path (a clip, relative to the CSV's folder) and group (the prompt)."),
    ],
    out_path: Annotated[Path, typer.Option("--out", help="The pairs file to write (JSONL; scores go beside it).")],
    preset_name: Annotated[str, typer.Option("--preset", help="The scoring preset (default: reward).")] = "reward",
    workers: Annotated[Optional[int], typer.Option(min=1, help="Threads (default: the CPU count, at most 8).")] = None,
    fresh: Annotated[bool, typer.Option("--fresh", help="Score every clip again instead of resuming.")] = False,
) -> None:
    """Score every clip of a manifest, rank the clips of each group (prompt), and write one pair
    per group: its best clip (chosen) against its worst (rejected), when the margin's interval
    lies above zero. Clips that cannot be judged (frozen, repeated, blurred, textureless, cut)
    are never chosen. A run that stops resumes where it was."""
    from geocon_core.config import PRESETS
    from geocon_core.reward import ManifestError, RewardScorer, read_manifest, write_pairs

    if preset_name not in PRESETS:
        raise fail(f"--preset {preset_name!r} is not a preset; give one of {', '.join(PRESETS)}")
    if out_path.exists() and out_path.is_dir():
        raise fail(f"--out {out_path} is a folder; give the path of a .jsonl file")
    try:
        rows = read_manifest(manifest)
    except ManifestError as exc:
        raise fail(str(exc)) from None
    scorer = RewardScorer(preset_name, workers=workers)
    bar = progress_bar("scoring", "clips", transient=True)
    task = bar.add_task("scoring", total=len(rows))
    with bar:
        try:
            summary = write_pairs(
                manifest,
                out_path,
                scorer,
                resume=not fresh,
                progress=lambda done, total: bar.update(task, completed=done, total=total),
            )
        except ManifestError as exc:
            raise fail(str(exc)) from None
    if summary.resumed:
        err.print(f"resumed: {summary.resumed} clip(s) scored by an earlier run", soft_wrap=True)
    out.print(
        f"{summary.pairs} pair(s) from {summary.groups} group(s) written to {out_path}; "
        f"{summary.in_noise} group(s) inside the noise, {summary.small_groups} with fewer than 2 judged clips; "
        f"{len(summary.unjudged)} of {summary.clips} clip(s) cannot be judged",
        soft_wrap=True,
    )
    for path, reason in summary.unjudged[:10]:
        out.print(f"  cannot judge {path}: {reason}", soft_wrap=True, highlight=False, markup=False)
    if len(summary.unjudged) > 10:
        out.print(f"  ... and {len(summary.unjudged) - 10} more (the scores file lists them)")
