"""``geocon plant``: a failure planted into a real clip, with its clean twin and exact ground truth."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from .console import err, fail, out

__all__ = ["plant"]


def plant(
    clip: Annotated[Path, typer.Argument(help="The video to plant the failure into (read, never changed).")],
    failure: Annotated[
        str, typer.Option("--failure", help="What to plant: morph, redraw, breathing or slide (docs: plant.md).")
    ],
    severity: Annotated[
        str, typer.Option("--severity", help="low, middle or high (each kind's amplitudes: docs: plant.md).")
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder (created if missing).")],
    seed: Annotated[
        int, typer.Option(min=0, max=2**32 - 1, help="Random seed (0 or more); the same seed gives identical files.")
    ] = 0,
    frames: Annotated[
        Optional[int], typer.Option(min=2, help="Plant into the first N frames only (default: every frame).")
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the ground truth's summary as JSON on stdout.")
    ] = False,
) -> None:
    """Plant a smooth, seeded failure into a real clip: writes the planted clip, the clean clip
    encoded the same way (codec and quality matched to the source) and the ground truth
    (.gt.json: the region, the frames, the exact displacement field), plus sidecars that let
    `geocon bench` pair the two by scene."""
    from geocon_core.media import ClipError
    from geocon_core.plant import LEVELS, PLANT_KINDS, plant_clip

    if failure not in PLANT_KINDS:
        raise fail(f"--failure {failure!r} is not a failure geocon plant knows; give one of {', '.join(PLANT_KINDS)}")
    if severity not in LEVELS:
        raise fail(f"--severity {severity!r} is not a severity level; give one of {', '.join(LEVELS)}")
    try:
        result = plant_clip(clip, failure, severity, seed, out_dir, frames=frames)
    except (ClipError, ValueError) as exc:
        raise fail(str(exc)) from None
    truth = result.truth
    for warning in result.warnings:
        err.print(f"warning: {warning}", soft_wrap=True, highlight=False, markup=False)
    if as_json:
        summary = {
            key: truth[key]
            for key in ("clip_id", "scene_id", "kind", "severity", "amplitude", "unit", "seed", "frames_affected")
        }
        summary.update(
            planted=str(result.planted),
            clean=str(result.clean),
            ground_truth=str(result.ground_truth),
            encoding={k: truth["encoding"][k] for k in ("codec", "encoder", "quality", "pix_fmt", "rate")},
            display_rotation=truth["source"]["display_rotation"]["degrees"],
            timing=truth["source"]["timing"],
            warnings=list(result.warnings),
        )
        sys.stdout.write(json.dumps(summary, indent=1) + "\n")
        return
    affected = truth["frames_affected"]
    span = f"frames {affected[0]}-{affected[-1]}" if affected else "no frame"
    enc = truth["encoding"]
    quality = enc["quality"]
    out.print(
        f"planted {truth['kind']} ({truth['severity']}: {truth['amplitude']:g} {truth['unit']}) into {span} of "
        f"{clip} ({truth['source']['frames_used']} frames)",
        soft_wrap=True,
    )
    turned = truth["source"]["display_rotation"]
    if turned["degrees"]:
        (w, h), (sw, sh) = truth["source"]["size"], turned["stored_size"]
        out.print(
            f"  the source's display matrix turns its {sw}x{sh} frames {turned['degrees']} degrees "
            f"counter-clockwise: planted and written upright ({w}x{h}), as geocon score reads it",
            soft_wrap=True,
        )
    out.print(f"  planted clip: {result.planted}", soft_wrap=True)
    out.print(f"  clean clip:   {result.clean}", soft_wrap=True)
    out.print(f"  ground truth: {result.ground_truth}", soft_wrap=True)
    out.print(
        f"  both encoded {enc['codec']} ({enc['encoder']}, {quality['option']} {quality['value']}, {enc['pix_fmt']}, "
        f"{enc['rate']} fps); the source: {truth['source']['codec']}, {truth['source']['bits_per_pixel']:.3f} "
        "bits per pixel",
        soft_wrap=True,
    )
