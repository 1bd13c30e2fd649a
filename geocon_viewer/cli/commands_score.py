"""``geocon score`` and ``geocon demo``: score one clip, print its summary, write its record and,
on request, a Rerun recording of the audit."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Callable, Optional

import typer
from rich.markup import escape
from rich.table import Table

import geocon_core
from geocon_core.config import DEFAULT_PRESET

from ..shared import fmt
from .console import (
    VIEWER_EXTRA,
    default_out,
    err,
    fail,
    has_viewer_extra,
    out,
    progress_bar,
    record_of,
    rerun_version,
)

if TYPE_CHECKING:
    from geocon_core.config import ScoreConfig
    from geocon_core.record import ClipRecord

__all__ = ["score", "score_with_progress", "print_record", "is_input_error", "MAX_OBJECT_ROWS"]

MAX_OBJECT_ROWS = 12
"""The summary table lists at most this many objects (the longest-lived ones)."""
_CORE_DIR = Path(geocon_core.__file__).resolve().parent


def is_input_error(exc: BaseException) -> bool:
    """Whether ``exc`` is one of GeoCon's own one-sentence errors about unusable input or settings:
    a ``ValueError`` (``ClipError``, ``DatasetError``, ``BenchError`` and the checks of masks, pose
    logs and settings are ``ValueError``) raised by a ``raise`` statement in :mod:`geocon_core`
    itself. A ``ValueError`` raised inside numpy, OpenCV or another library is an internal bug:
    the command lets it through with its traceback."""
    if not isinstance(exc, ValueError):
        return False
    tb = exc.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    return Path(tb.tb_frame.f_code.co_filename).resolve().is_relative_to(_CORE_DIR)


def _rrd_sink_factory(rrd: Path) -> Callable[[Path], Any]:
    """A sink factory for :func:`~geocon_core.bench.run.score_to_folder` that records the audit into
    ``rrd``; fails before scoring when the viewer extra is missing."""
    if not has_viewer_extra("rerun"):
        raise fail(f"writing a Rerun recording needs the viewer extra: {VIEWER_EXTRA}")
    from ..rerun import RrdSink, quiet_encoder_logs

    quiet_encoder_logs()
    return lambda _folder: RrdSink(rrd)


def score_with_progress(
    clip: Path,
    cfg: ScoreConfig,
    *,
    out_dir: Path,
    pose_log: Path | None = None,
    masks: Path | None = None,
    quiet: bool = False,
    rrd: Path | None = None,
    flow_checkpoint: Path | None = None,
    dense: bool = True,
    sam2_checkpoint: Path | None = None,
    dust3r_checkpoint: Path | None = None,
    dust3r_path: Path | None = None,
) -> ClipRecord:
    """Score a clip with a progress bar on stderr that appears once the clip is readable; write
    the record (with its overlays and, with ``dense``, the dense point clouds) into ``out_dir``
    and, with ``rrd``, a Rerun recording."""
    from geocon_core.bench import score_to_folder
    from geocon_core.reconstruction import DenseCloudConfig

    sinks = [] if rrd is None else [_rrd_sink_factory(rrd)]
    with progress_bar("scoring", "frames", disable=quiet) as bar:
        task = bar.add_task("score", total=None, visible=False)
        try:
            return score_to_folder(
                clip,
                cfg,
                out_dir,
                pose_log=pose_log,
                masks=masks,
                flow_checkpoint=flow_checkpoint,
                sam2_checkpoint=sam2_checkpoint,
                dust3r_checkpoint=dust3r_checkpoint,
                dust3r_path=dust3r_path,
                sinks=sinks,
                dense=DenseCloudConfig() if dense else None,
                progress=lambda done, total: bar.update(task, completed=done, total=total, visible=True),
            )
        except BaseException:
            bar.live.transient = True  # a failed run leaves its error, not a half-filled bar
            raise


def _gate_row(record: ClipRecord) -> str:
    g = record.gate
    if g.pose_present:
        return (
            f"{g.label} -> model {g.model}   t_inf {fmt(g.t_inf, '.4f')}   margin {fmt(g.margin, '+.4f')}   "
            f"({g.backend} pose, {g.pose.method})"
        )
    return f"F (no pose: {g.pose.reason}; fail->F)   backend {g.backend}"


def _verdict_row(record: ClipRecord) -> str:
    f = record.finding()
    colour = {"consistent": "green", "inconsistent": "red"}.get(f.verdict, "yellow")
    score = "" if f.clip_score is None else f"   clip score {f.clip_score:.2f} (0 sound .. 1 broken)"
    return f"[{colour}]{f.verdict}[/]{score}: {f.reason}"


def _regions_row(record: ClipRecord) -> str:
    """The region readings in one cell: what fires (reported; the verdict does not read them), or
    the largest of each, or why they cannot judge."""
    regions = record.regions
    assert regions is not None
    r = regions.readings
    fired = r.fired
    head = f"{r.tracks} tracks over {r.coverage:.0%} of the frame; "
    if fired:
        return head + "; ".join(f.describe() for f in fired) + " (reported, not in the verdict)"
    values = ", ".join(f"{k} {'-' if v is None else format(v, '.2f')}" for k, v in r.values.items())
    if all(v is None for v in r.values.values()):
        return head + "cannot judge: " + next(iter(r.reasons.values()), "no long tracks")
    return head + f"none fires ({values})"


def _why_row(record: ClipRecord) -> str:
    """The clip model's contributions, reading by reading (empty for the background's own score)."""
    from geocon_core.signals import READING_LABELS, load_clip_model

    f = record.finding()
    if not f.parts:
        return ""
    values = record.reading_values()
    cells = []
    for name, part in f.parts:
        value = values.get(name)
        shown = "-" if value is None else f"{value:.3g}"
        colour = "red" if part > 0.005 else ("green" if part < -0.005 else "dim")
        cells.append(f"[{colour}]{part:+.2f}[/] {READING_LABELS.get(name, name)} ({shown})")
    if record.other_model() is not None:  # its own model's base is not here: the contributions it was made with
        return "   ".join(cells)
    signals = record.config.signals
    base = load_clip_model(signals.model, signals.model_sha256).intercept
    total = base + sum(part for _, part in f.parts)
    return f"log-odds {total:+.2f} = base {base:+.2f}   " + "   ".join(cells)


def _object_rows(table: Table, record: ClipRecord) -> None:
    share = max(record.masked_share) if record.masked_share else 0.0
    table.add_row(
        "objects",
        f"{len(record.objects)} from {record.masks_source} masks (masked share up to {share:.1%} of the content); "
        f"AdaDFRC on frame pairs (t, t+{record.config.object_gap}), frames below are t",
    )
    # Long-lived objects first; a clip with dozens of short motion blobs keeps a readable table.
    shown = sorted(record.objects, key=lambda o: (-o.frames, o.object_id))[:MAX_OBJECT_ROWS]
    for o in sorted(shown, key=lambda o: o.object_id):
        table.add_row(
            f"  object {o.object_id}",
            f"frames {o.first_frame}-{o.last_frame} ({o.frames}), AdaDFRC {fmt(o.adadfrc, '.3f')} px², "
            f"W2 {fmt(o.adadfrc_w2, '.3f')} px², AdaP90 {fmt(o.adap90, '.3f')} px², masked {o.masked_share:.1%}",
        )
    if len(record.objects) > len(shown):
        table.add_row(
            "", f"... {len(record.objects) - len(shown)} shorter-lived objects not listed (all are in record.json)"
        )


def print_record(record: ClipRecord, out_dir: Path | None) -> None:
    """The readable summary of a scored clip."""
    bg, cfg = record.background, record.config
    table = Table(title=f"GeoCon: {record.clip}", title_justify="left", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("gate", _gate_row(record))
    tau = f"tau_H {cfg.tau_h:g} px" if bg.model == "H" else f"tau_F {cfg.tau_f:g} (~{fmt(bg.tau_f_px, '.1f')} px)"
    table.add_row("background", f"{bg.model}: IR {fmt(bg.ir, '.3f')}   GE {fmt(bg.ge, '.2f')} px   ({tau})")
    if (resized := record.canvas_note()) is not None:
        table.add_row("canvas", resized)
    if len(bg.chosen.per_gap) > 1:
        table.add_row(
            "per gap",
            "   ".join(
                f"gap {p.gap}: IR {fmt(p.ir, '.3f')} GE {fmt(p.ge, '.2f')}" + ("" if p.judged else " (not judged)")
                for p in bg.chosen.per_gap
            ),
        )
    table.add_row(
        "other family",
        f"{bg.other.family}: IR {fmt(bg.other.ir, '.3f')}   GE {fmt(bg.other.ge, '.2f')} px (best-of, not the score)",
    )
    reasons = ", ".join(f"{k} {v}" for k, v in bg.chosen.invalid_reasons.items()) or "none"
    frames = record.video.num_frames
    coverage = f"{bg.valid_pairs}/{bg.total_pairs} pair-scales valid; {frames} frames; invalid: {reasons}"
    gross = sum(p.n_gross for p in record.pairs)
    if gross:
        kept = sum(p.n_matches for p in record.pairs)
        coverage += f"; {gross} of {gross + kept} matches dropped as gross mismatches (repeated structure)"
    table.add_row("coverage", coverage)
    for shot in record.shots:
        state = {True: "consistent", False: "inconsistent", None: "not judged"}[shot.consistent]
        table.add_row(
            f"  shot {shot.start}-{shot.end}",
            f"gate {shot.label or '-'} (t_inf {fmt(shot.t_inf, '.4f')}) -> {shot.model}: IR {fmt(shot.ir, '.3f')}   "
            f"GE {fmt(shot.ge, '.2f')} px   {state}",
        )
    table.add_row("verdict", _verdict_row(record))
    if record.model_note() is not None:
        table.add_row("clip model", f"[yellow]{escape(str(record.model_note()))}[/]")
    why = _why_row(record)
    if why:
        table.add_row("why this score", why)
    if record.category is not None:
        table.add_row("category", f"{record.category.label}: {record.category.rule}")
    if record.regions is not None:
        table.add_row("regions", escape(_regions_row(record)))
    _object_rows(table, record)
    table.add_row("config", f"{cfg.preset} preset{_changed_settings(cfg)}, hash {record.config_hash}")
    for w in record.warnings:
        table.add_row("[yellow]warning[/]", w)
    if out_dir is not None:
        table.add_row("record", f"{out_dir}/record.json (+ matches.npz)")
    out.print(table)


def _changed_settings(cfg: ScoreConfig) -> str:
    """``" changed by options (matcher orb, ...)"``: the settings of ``cfg`` that differ from those
    of the preset it names (``--preset paper --matcher orb`` is no longer the paper's protocol),
    or ``""``. Masks the clip brings (``--masks DIR``) are an input, not a change of setting."""
    from dataclasses import fields, is_dataclass

    from geocon_core.config import PRESETS

    if cfg.preset not in PRESETS:
        return ""
    own = PRESETS[cfg.preset][1]
    changed = []
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if value == getattr(own, f.name) or (f.name == "masks" and value == "external"):
            continue
        changed.append(f.name if is_dataclass(value) else f"{f.name} {value}")
    return f" changed by options ({', '.join(changed)})" if changed else ""


def _config(
    preset_name: str,
    matcher: str | None,
    fov: float | None,
    masks: Path | None,
    no_masks: bool,
    flow: str | None = None,
    flow_checkpoint: Path | None = None,
    *,
    sam2: bool = False,
    sam2_checkpoint: Path | None = None,
    sam2_config: str | None = None,
    sam2_size: int | None = None,
) -> Any:
    from dataclasses import replace

    from geocon_core.config import preset
    from geocon_core.flow import FLOW_BACKENDS
    from geocon_core.geometry import make_matcher

    cfg = preset(preset_name)
    settings = (("matcher", matcher), ("fov_x_deg", fov), ("flow", flow))
    overrides: dict[str, Any] = {k: v for k, v in settings if v is not None}
    if flow is not None and flow.strip().lower() not in FLOW_BACKENDS:
        raise ValueError(f"unknown flow backend {flow!r}; valid: {', '.join(FLOW_BACKENDS)}")
    if (flow or cfg.flow).strip().lower() == "raft" and flow_checkpoint is None:
        raise ValueError("--flow raft needs --raft-checkpoint PATH (a raft-small.pth; nothing is downloaded)")
    if flow_checkpoint is not None and (flow or cfg.flow).strip().lower() != "raft":
        raise ValueError("--raft-checkpoint is used with --flow raft")
    if no_masks:
        if masks is not None or sam2:
            raise ValueError("--masks and --no-masks exclude each other")
        overrides["masks"] = "none"
    if sam2:
        if sam2_checkpoint is None:
            raise ValueError("--masks sam2 needs --sam2-checkpoint PATH (a SAM-2 .pt file; nothing is downloaded)")
        overrides["masks"] = "sam2"
        sam2_cfg = cfg.sam2
        if sam2_config is not None:
            sam2_cfg = replace(sam2_cfg, model=sam2_config)
        if sam2_size is not None:
            sam2_cfg = replace(sam2_cfg, image_size=sam2_size)
        overrides["sam2"] = sam2_cfg
    elif sam2_checkpoint is not None or sam2_config is not None or sam2_size is not None:
        raise ValueError("--sam2-checkpoint, --sam2-config and --sam2-size are used with --masks sam2")
    if overrides:
        cfg = cfg.with_(**overrides)
    make_matcher(cfg.matcher)
    return cfg


def _pose_settings(
    cfg: ScoreConfig,
    pose: str | None,
    pose_log: Path | None,
    dust3r_checkpoint: Path | None,
    dust3r_path: Path | None,
) -> ScoreConfig:
    """``cfg`` with the pose backend of ``--pose``, its options checked (``ValueError``, one sentence)."""
    name = None if pose is None else pose.strip().lower()
    if name is not None and name not in ("classical", "dust3r"):
        raise ValueError(f"unknown pose backend {pose!r}; valid: classical, dust3r (or --pose-log FILE)")
    if name == "dust3r":
        if pose_log is not None:
            raise ValueError("--pose dust3r and --pose-log exclude each other")
        if dust3r_checkpoint is None:
            raise ValueError("--pose dust3r needs --dust3r-checkpoint PATH (a DUSt3R .pth; nothing is downloaded)")
        if not dust3r_checkpoint.is_file():
            raise ValueError(f"--dust3r-checkpoint {dust3r_checkpoint} does not exist or is not a file")
        if dust3r_path is not None and not dust3r_path.is_dir():
            raise ValueError(f"--dust3r-path {dust3r_path} is not a folder (a checkout of naver/dust3r is expected)")
        return cfg.with_(pose_backend="dust3r")
    if dust3r_checkpoint is not None or dust3r_path is not None:
        raise ValueError("--dust3r-checkpoint and --dust3r-path are used with --pose dust3r")
    return cfg if name is None else cfg.with_(pose_backend=name)


def check_inputs(
    out_dir: Path,
    *,
    pose_log: Path | None = None,
    masks: Path | None = None,
    rrd: Path | None = None,
    clip: Path | None = None,
) -> None:
    """Everything a scoring command names besides the clip, checked before the clip is decoded:
    the output folder (not a results folder of ``geocon bench``, nor inside one), the pose log, the
    masks' layout and the recording's path, and that no output would write over an input or into
    the record's own files (``ValueError`` with one sentence)."""
    from geocon_core.bench import check_output_kind
    from geocon_core.files import check_apart, check_out_dir, check_out_file, claim
    from geocon_core.masks import check_masks_path
    from geocon_core.pose import load_pose_log

    inputs = [(what, p) for what, p in (("clip", clip), ("masks", masks), ("pose log", pose_log)) if p is not None]
    outputs = [("--out", out_dir)] + ([] if rrd is None else [("--rrd", rrd)])
    check_apart(outputs, inputs, records=[out_dir])
    check_out_dir(out_dir, "--out")
    check_output_kind(out_dir, "record")
    claim("--out", out_dir, "record", mine=None if clip is None else record_of(clip))
    if pose_log is not None:
        load_pose_log(pose_log)
    if masks is not None:
        check_masks_path(masks)
    if rrd is not None:
        check_out_file(rrd, "--rrd")
        claim("--rrd", rrd, "recording", own=[out_dir])


def score(
    clip: Annotated[Path, typer.Argument(help="Video (mp4, avi, mov, webm, gif) or a folder of PNG/JPEG frames.")],
    out_dir: Annotated[
        Optional[Path], typer.Option("--out", help="Folder for the record (default: geocon-out/<clip name>).")
    ] = None,
    preset_name: Annotated[
        str,
        typer.Option("--preset", help="Named settings (`paper`: the paper's protocol); see `geocon presets`."),
    ] = DEFAULT_PRESET,
    pose_log: Annotated[
        Optional[Path],
        typer.Option(
            help="External first->last pose (geocon-pose/1 JSON, e.g. from DUSt3R) instead of the classical pose."
        ),
    ] = None,
    masks: Annotated[
        Optional[str],
        typer.Option(
            help="External object masks: a folder of label PNGs, per-object folders, or an .npz (see the README); "
            "or `sam2`: SAM-2 masks prompted by the motion segmentation (needs --sam2-checkpoint)."
        ),
    ] = None,
    no_masks: Annotated[
        bool, typer.Option("--no-masks", help="Do not separate moving objects (score the whole content as background).")
    ] = False,
    matcher: Annotated[
        Optional[str], typer.Option(help="Correspondences: sift, sift_octaves, orb, klt, klt_tracks.")
    ] = None,
    fov: Annotated[
        Optional[float], typer.Option(help="Assumed horizontal field of view in degrees (default 60; 10 to 150).")
    ] = None,
    flow: Annotated[
        Optional[str],
        typer.Option(
            help="Dense flow of the masks and objects: dis (default, no weights) or raft (needs --raft-checkpoint)."
        ),
    ] = None,
    raft_checkpoint: Annotated[
        Optional[Path], typer.Option(help="RAFT-small weights (raft-small.pth from the RAFT authors) for --flow raft.")
    ] = None,
    pose: Annotated[
        Optional[str],
        typer.Option(
            "--pose",
            help="First->last pose of the gate: classical (default, no weights) or dust3r (needs --dust3r-checkpoint).",
        ),
    ] = None,
    dust3r_checkpoint: Annotated[
        Optional[Path], typer.Option(help="DUSt3R weights (a DUSt3R .pth from its authors) for --pose dust3r.")
    ] = None,
    dust3r_path: Annotated[
        Optional[Path],
        typer.Option(help="A checkout of naver/dust3r (with croco) to import instead of the mini-dust3r package."),
    ] = None,
    sam2_checkpoint: Annotated[
        Optional[Path], typer.Option(help="SAM-2 weights (a sam2*.pt from the SAM-2 authors) for --masks sam2.")
    ] = None,
    sam2_config: Annotated[
        Optional[str],
        typer.Option(help="SAM-2 model configuration the checkpoint was made for (default sam2.1_hiera_t)."),
    ] = None,
    sam2_size: Annotated[
        Optional[int],
        typer.Option(
            help="Side (px, a multiple of 32) SAM-2 sees the frames at (default 1024; the fast preset 512); "
            "smaller is faster on a CPU."
        ),
    ] = None,
    dense: Annotated[
        Optional[bool],
        typer.Option(
            "--dense/--no-dense",
            help="Also make the dense point clouds (first/last pair and gate windows, coloured by residual) for "
            "the viewers; no score depends on them (default: with --rrd).",
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the clip summary as JSON on stdout.")] = False,
    rrd: Annotated[
        Optional[Path],
        typer.Option(
            "--rrd",
            help="Also write a Rerun recording (.rrd) of the audit: frames, matches, residual maps, objects, "
            "time series, 3D.",
        ),
    ] = None,
) -> None:
    """Score a clip: translation gate (H/F), background inlier ratio (IR) and geometric error
    (GE) per frame pair and scale, the report verdict; writes the audit record."""
    from geocon_core.signals import configured_model

    target = out_dir or default_out(clip)
    sam2 = masks is not None and masks.strip().lower() == "sam2"
    if masks is not None and sam2 and sam2_checkpoint is None and Path(masks).exists():
        raise fail(
            f"--masks {masks} asks for SAM-2 masks, which need --sam2-checkpoint PATH; to read the masks in the "
            f"folder {masks} instead, give it as ./{masks}"
        )
    mask_path = None if masks is None or sam2 else Path(masks)
    try:
        cfg = _config(
            preset_name,
            matcher,
            fov,
            mask_path,
            no_masks,
            flow,
            raft_checkpoint,
            sam2=sam2,
            sam2_checkpoint=sam2_checkpoint,
            sam2_config=sam2_config,
            sam2_size=sam2_size,
        )
        cfg = _pose_settings(cfg, pose, pose_log, dust3r_checkpoint, dust3r_path)
        configured_model(cfg.signals)  # a clip model file that cannot be used, before any work
        check_inputs(target, pose_log=pose_log, masks=mask_path, rrd=rrd, clip=clip)
    except ValueError as exc:
        raise fail(str(exc)) from None
    try:
        record = score_with_progress(
            clip,
            cfg,
            out_dir=target,
            pose_log=pose_log,
            masks=mask_path,
            quiet=as_json,
            rrd=rrd,
            flow_checkpoint=raft_checkpoint,
            dense=rrd is not None if dense is None else dense,
            sam2_checkpoint=sam2_checkpoint,
            dust3r_checkpoint=dust3r_checkpoint,
            dust3r_path=dust3r_path,
        )
    except ValueError as exc:
        if not is_input_error(exc):
            raise
        raise fail(str(exc)) from None
    if rrd is not None and not as_json:
        err.print(
            f"Rerun recording written to {rrd} (rerun-sdk {rerun_version()}; open it with `geocon view {target}` "
            f"or `rerun {rrd}`)"
        )
    if as_json:
        sys.stdout.write(json.dumps(record.summary(), indent=1) + "\n")
    else:
        print_record(record, target)
