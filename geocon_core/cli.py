"""The ``geocon`` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

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

RECORD_RENDERERS: dict[str, str] = {}
"""Renderers of saved records other packages contribute, as ``"module:function"`` called with
``(record_dir, output_path)`` (``geocon_viewer`` registers ``"rrd"``); ``geocon bench`` uses it in
its worker processes to write recordings of flagged clips."""
FRAME_SINKS: dict[str, Callable[..., Any]] = {}
"""Recorders other packages contribute (``geocon_viewer`` registers ``"rrd"``: a factory
``(path) -> sink`` where ``sink(FrameDiagnostics)`` is called per frame and
``sink.finish(record)`` at the end). The core never imports them."""
MAX_OBJECT_ROWS = 12
"""The summary table lists at most this many objects (the longest-lived ones)."""


def _fail(message: str) -> typer.Exit:
    from rich.markup import escape

    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
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
    version: Annotated[
        bool, typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """GeoCon: is a generated video geometrically real?"""


def _render_plans(
    plans,
    out_dir: Path,
    *,
    seed: int,
    width: int,
    height: int,
    frames: int,
    fps: float,
    quiet: bool,
    noise: float = 2.0,
):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from .synth import write_clip

    results = []
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("frames"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=err, disable=quiet, transient=False) as progress:
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


def _summary_rows(gts) -> list[dict]:
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


def _print_table(gts, out_dir: Path) -> None:
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


@app.command()
def synth(
    family: Annotated[
        str,
        typer.Argument(
            help="Scene family: C1..C6 (or c1_static, c2_rotation, c3_translation, c4_objects, c5_complex, c6_stress), or 'all'."
        ),
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Output folder (created if missing).")],
    frames: Annotated[int, typer.Option(min=2, help="Frames per clip.")] = 48,
    size: Annotated[str, typer.Option(help="Frame size WxH (even numbers).")] = "640x360",
    fps: Annotated[float, typer.Option(min=0.1, help="Frames per second.")] = 24.0,
    seed: Annotated[int, typer.Option(help="Random seed; the same seed gives identical files.")] = 0,
    failure: Annotated[
        Optional[str],
        typer.Option(help="Inject a failure: breathing, slide, missing_parallax, elastic, boiling, letterbox."),
    ] = None,
    severity: Annotated[
        Optional[float], typer.Option(help="Failure severity in the failure's unit (see `geocon synth-failures`).")
    ] = None,
    noise: Annotated[float, typer.Option(min=0.0, help="Sensor noise, standard deviation in grey levels.")] = 2.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout instead of a table.")] = False,
) -> None:
    """Render synthetic clips with exact ground truth: video (mp4), object masks, ground truth
    (.gt.json) and benchmark metadata (.meta.json) per clip.

    'all' renders one clip per family plus one variant per failure kind."""
    from .synth import plan_clips

    width, height = _parse_size(size)
    try:
        plans = plan_clips(family, failure, severity)
        gts = _render_plans(
            plans, out_dir, seed=seed, width=width, height=height, frames=frames, fps=fps, quiet=as_json, noise=noise
        )
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
    which deforms non-rigidly, print what the clip contains, then score it."""
    from .config import ScoreConfig
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
    table.add_row(
        "translation gate", f"t_inf = {gt.t_inf:.3f} -> expected model {gt.expected_gate} (hysteresis 0.03 / 0.05)"
    )
    for o in gt.objects:
        table.add_row(
            f"object {o.object_id}",
            f"{o.name}, {'rigid' if o.rigid else 'NON-RIGID (injected elastic warp)'}, visible in {len(o.visible_frames)}/{gt.num_frames} frames",
        )
    table.add_row("masked share", f"{gt.masked_share.mean():.1%} of the frame on average")
    out.print(table)
    clip = out_dir / gt.video_path
    # the clip ships its object masks (as a benchmark dataset does through masks_path)
    target, rrd = out_dir / "record", (out_dir / "demo.rrd" if "rrd" in FRAME_SINKS else None)
    record = _score_with_progress(clip, ScoreConfig(), out_dir=target, masks=out_dir / gt.masks_path, rrd=rrd)
    _print_record(record, target)
    truth = {o.object_id: o for o in gt.objects}
    for o in record.objects:
        t = truth.get(o.object_id)
        if t is not None:
            out.print(
                f"object {o.object_id} ({t.name}, {'rigid' if t.rigid else 'non-rigid by construction'}): "
                f"AdaDFRC {_fmt(o.adadfrc, '.3f')} px²",
                soft_wrap=True,
            )
    out.print(
        "Higher AdaDFRC means less rigid motion. Score any clip: geocon score CLIP (built-in masks) or "
        "geocon score CLIP --masks DIR.",
        soft_wrap=True,
    )
    if rrd is not None:
        out.print(
            f"Rerun recording: {rrd}. Browse it with `geocon view {target}` (web viewer on 127.0.0.1 when there is no display), "
            f"or `rerun {rrd}` with rerun-sdk {_rerun_version()}.",
            soft_wrap=True,
        )


def _rerun_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rerun-sdk")
    except PackageNotFoundError:
        return "?"


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def _print_record(record, out_dir: Path | None) -> None:
    """The readable summary of a scored clip."""
    g, bg = record.gate, record.background
    table = Table(title=f"GeoCon: {record.clip}", title_justify="left", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    if g.pose_present:
        gate = f"{g.label} -> model {g.model}   t_inf {g.t_inf:.4f}   margin {g.margin:+.4f}   ({g.backend} pose, {g.pose['method']})"
    else:
        gate = f"F (no pose: {g.pose.reason}; fail->F)   backend {g.backend}"
    table.add_row("gate", gate)
    tau = (
        f"tau_H {record.config.tau_h:g} px"
        if bg.model == "H"
        else f"tau_F {record.config.tau_f:g} (~{_fmt(bg.tau_f_px, '.1f')} px)"
    )
    table.add_row("background", f"{bg.model}: IR {_fmt(bg.ir, '.3f')}   GE {_fmt(bg.ge, '.2f')} px   ({tau})")
    if len(bg.chosen.per_gap) > 1:
        table.add_row(
            "per gap",
            "   ".join(f"gap {p.gap}: IR {_fmt(p.ir, '.3f')} GE {_fmt(p.ge, '.2f')}" for p in bg.chosen.per_gap),
        )
    table.add_row(
        "other family",
        f"{bg.other.family}: IR {_fmt(bg.other.ir, '.3f')}   GE {_fmt(bg.other.ge, '.2f')} px (best-of, not the score)",
    )
    reasons = ", ".join(f"{k} {v}" for k, v in bg.chosen.invalid_reasons.items()) or "none"
    table.add_row(
        "coverage",
        f"{bg.valid_pairs}/{bg.total_pairs} pair-scales valid; {record.video['num_frames']} frames; invalid: {reasons}",
    )
    if bg.consistent is None:
        verdict = "[yellow]not judged[/] (no valid pair)"
    elif bg.consistent:
        verdict = f"[green]consistent[/] (IR >= {record.config.ir_gate:g} and GE <= {record.config.ge_gate:g} px)"
    else:
        verdict = f"[red]inconsistent[/] (needs IR >= {record.config.ir_gate:g} and GE <= {record.config.ge_gate:g} px)"
    table.add_row("verdict", verdict)
    if record.category is not None:
        table.add_row("category", f"{record.category.label}: {record.category.rule}")
    share = max(record.masked_share) if record.masked_share else 0.0
    table.add_row(
        "objects",
        f"{len(record.objects)} from {record.masks_source} masks (masked share up to {share:.1%} of the content)",
    )
    # Long-lived objects first; a clip with dozens of short motion blobs keeps a readable table.
    shown = sorted(record.objects, key=lambda o: (-o.frames, o.object_id))[:MAX_OBJECT_ROWS]
    for o in sorted(shown, key=lambda o: o.object_id):
        table.add_row(
            f"  object {o.object_id}",
            f"frames {o.first_frame}-{o.last_frame} ({o.frames}), AdaDFRC {_fmt(o.adadfrc, '.3f')} px², "
            f"W2 {_fmt(o.adadfrc_w2, '.3f')} px², AdaP90 {_fmt(o.adap90, '.3f')} px², masked {o.masked_share:.1%}",
        )
    if len(record.objects) > len(shown):
        table.add_row(
            "", f"... {len(record.objects) - len(shown)} shorter-lived objects not listed (all are in record.json)"
        )
    table.add_row("config", f"{record.config.preset} preset, hash {record.config_hash}")
    for w in record.warnings:
        table.add_row("[yellow]warning[/]", w)
    if out_dir is not None:
        table.add_row("record", f"{out_dir}/record.json (+ matches.npz)")
    out.print(table)


def _rrd_factory() -> Callable[[Path], Any]:
    factory = FRAME_SINKS.get("rrd")
    if factory is None:
        raise _fail(
            "writing a Rerun recording needs the viewer extra: pip install 'geocon[viewer]' (or run bash scripts/bootstrap.sh viewer)"
        )
    return factory


def _score_with_progress(
    clip: Path,
    cfg,
    *,
    out_dir: Path,
    pose_log: Path | None = None,
    masks: Path | None = None,
    quiet: bool = False,
    rrd: Path | None = None,
):
    """Score a clip with a progress bar on stderr that appears once the clip is readable; write
    the record (with its overlays) into ``out_dir`` and, with ``rrd``, a Rerun recording."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from .bench import score_to_folder

    factory = None if rrd is None else _rrd_factory()  # fails before scoring when the viewer extra is missing
    sinks = [] if factory is None else [lambda _folder: factory(rrd)]
    columns = (
        TextColumn("scoring"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("frames"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=err, disable=quiet) as bar:
        task = bar.add_task("score", total=None, visible=False)
        return score_to_folder(
            clip,
            cfg,
            out_dir,
            pose_log=pose_log,
            masks=masks,
            sinks=sinks,
            progress=lambda done, total: bar.update(task, completed=done, total=total, visible=True),
        )


def _default_out(clip: Path) -> Path:
    return Path("geocon-out") / (clip.name if clip.is_dir() else clip.stem)


@app.command()
def score(
    clip: Annotated[Path, typer.Argument(help="Video (mp4, avi, mov, webm, gif) or a folder of PNG/JPEG frames.")],
    out_dir: Annotated[
        Optional[Path], typer.Option("--out", help="Folder for the record (default: geocon-out/<clip name>).")
    ] = None,
    preset_name: Annotated[str, typer.Option("--preset", help="Named settings; see `geocon presets`.")] = "paper",
    pose_log: Annotated[
        Optional[Path],
        typer.Option(
            help="External first->last pose (geocon-pose/1 JSON, e.g. from DUSt3R) instead of the classical pose."
        ),
    ] = None,
    masks: Annotated[
        Optional[Path],
        typer.Option(
            help="External object masks: a folder of label PNGs, per-object folders, or an .npz (see the README)."
        ),
    ] = None,
    no_masks: Annotated[
        bool, typer.Option("--no-masks", help="Do not separate moving objects (score the whole content as background).")
    ] = False,
    matcher: Annotated[Optional[str], typer.Option(help="Correspondences: sift (default), orb, klt.")] = None,
    fov: Annotated[
        Optional[float], typer.Option(help="Assumed horizontal field of view in degrees (default 60).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the clip summary as JSON on stdout.")] = False,
    rrd: Annotated[
        Optional[Path],
        typer.Option(
            "--rrd",
            help="Also write a Rerun recording (.rrd) of the audit: frames, matches, residual maps, objects, time series, 3D.",
        ),
    ] = None,
) -> None:
    """Score a clip: translation gate (H/F), background inlier ratio (IR) and geometric error
    (GE) per frame pair and scale, the report verdict; writes the audit record."""
    from .config import preset
    from .reader import ClipError

    try:
        cfg = preset(preset_name)
        overrides = {k: v for k, v in (("matcher", matcher), ("fov_x_deg", fov)) if v is not None}
        if no_masks:
            if masks is not None:
                raise ValueError("--masks and --no-masks exclude each other")
            overrides["masks"] = "none"
        if overrides:
            cfg = cfg.with_(**overrides)
        from .features import make_matcher

        make_matcher(cfg.matcher)
        target = out_dir or _default_out(clip)
        record = _score_with_progress(clip, cfg, out_dir=target, pose_log=pose_log, masks=masks, quiet=as_json, rrd=rrd)
    except (ClipError, ValueError) as exc:
        raise _fail(str(exc)) from None
    if rrd is not None and not as_json:
        err.print(
            f"Rerun recording written to {rrd} (rerun-sdk {_rerun_version()}; open it with `geocon view {target}` or `rerun {rrd}`)"
        )
    if as_json:
        sys.stdout.write(json.dumps(record.summary(), indent=1) + "\n")
    else:
        _print_record(record, target)


@app.command("synth-bench")
def synth_bench(
    out_dir: Annotated[Path, typer.Option("--out", help="Dataset folder (created).")],
    scenes: Annotated[int, typer.Option(min=1, help="Scenes (seeds) per family; every platform renders each.")] = 3,
    families: Annotated[str, typer.Option(help="Comma-separated families.")] = "C1,C2,C3,C4,C5",
    frames: Annotated[int, typer.Option(min=2, help="Frames per clip.")] = 24,
    size: Annotated[str, typer.Option(help="Frame size WxH (even numbers).")] = "320x180",
) -> None:
    """Render a synthetic benchmark dataset for `geocon bench`: the same scenes from three
    "platforms" (clean, breathing background, elastic objects), with sidecar metadata."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from .synth.benchmark import plan_benchmark, write_benchmark

    width, height = _parse_size(size)
    try:
        clips = plan_benchmark(families=[f.strip() for f in families.split(",") if f.strip()], scenes=scenes)
    except ValueError as exc:
        raise _fail(str(exc)) from None
    with Progress(
        TextColumn("rendering"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("frames"),
        TimeElapsedColumn(),
        console=err,
    ) as bar:
        task = bar.add_task("render", total=len(clips) * frames)
        write_benchmark(
            out_dir, clips, width=width, height=height, num_frames=frames, on_frame=lambda _t: bar.advance(task)
        )
    out.print(
        f"{len(clips)} clips in {out_dir} (platforms clean, breathing, elastic). Next: geocon bench {out_dir} --out RESULTS",
        soft_wrap=True,
    )


@app.command()
def bench(
    dataset: Annotated[
        Path, typer.Argument(help="Dataset folder: clips with sidecar <name>.meta.json files (see the README).")
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Results folder (created; rerun the same command to resume).")],
    preset_name: Annotated[str, typer.Option("--preset", help="Named settings; see `geocon presets`.")] = "paper",
    workers: Annotated[int, typer.Option(min=1, help="Worker processes scoring clips in parallel.")] = 1,
    retry_failed: Annotated[
        bool, typer.Option("--retry-failed", help="Score clips that failed in an earlier run again.")
    ] = False,
    rrd: Annotated[
        bool,
        typer.Option(
            "--rrd/--no-rrd", help="Write a Rerun recording (audit.rrd) for each flagged clip (needs the viewer extra)."
        ),
    ] = True,
    working_size: Annotated[
        Optional[str],
        typer.Option(
            "--working-size", help="Working resolution WxH clips are fitted into (default: the preset's, 1024x720)."
        ),
    ] = None,
) -> None:
    """Score every clip of a dataset (in parallel, resumable) and write per-clip records plus flat
    Parquet tables (clip, pair, object level) into the results folder."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from .bench import BenchError, run_bench
    from .config import preset
    from .dataset import DatasetError

    try:
        cfg = preset(preset_name)
        if working_size is not None:
            cfg = cfg.with_(working_size=_parse_size(working_size))
    except ValueError as exc:
        raise _fail(str(exc)) from None
    renderer = RECORD_RENDERERS.get("rrd") if rrd else None
    if rrd and renderer is None:
        err.print(
            "note: Rerun recordings of flagged clips need the viewer extra (pip install 'geocon[viewer]'); scoring without them"
        )
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("clips"),
        TextColumn("[red]{task.fields[failed]} failed"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=err, transient=False) as bar:
        task = bar.add_task("benchmark", total=None, failed=0, visible=False)

        def on_start(todo: int, skipped: int) -> None:
            if skipped:
                err.print(f"resuming: {skipped} clip(s) already finished in {out_dir}, {todo} to score")
            bar.update(task, total=todo + skipped, completed=skipped, visible=True)

        def on_clip(status: dict, done: int, total: int, failed: int) -> None:
            if status["status"] == "failed":
                bar.console.print(
                    f"[red]failed[/] {status['clip_id']}: {status['error']}",
                    soft_wrap=True,
                    markup=True,
                    highlight=False,
                )
            bar.update(task, completed=done, failed=failed)

        try:
            summary = run_bench(
                dataset,
                out_dir,
                cfg,
                workers=workers,
                rrd_renderer=renderer,
                retry_failed=retry_failed,
                on_start=on_start,
                on_clip=on_clip,
            )
        except DatasetError as exc:
            raise _fail(str(exc)) from None
        except (BenchError, ImportError) as exc:
            raise _fail(str(exc)) from None
        except KeyboardInterrupt:
            err.print(f"interrupted: finished clips are kept in {out_dir}; run the same command again to resume")
            raise typer.Exit(code=130) from None
    ok = summary.total - summary.failed
    out.print(
        f"{summary.total} clips: {ok} scored, {summary.failed} failed ({summary.scored} in this run, "
        f"{summary.skipped} finished earlier) in {summary.seconds:.1f} s",
        soft_wrap=True,
    )
    out.print(
        f"records: {out_dir}/clips/<clip_id>/   tables: {out_dir}/tables/*.parquet   report: geocon report {out_dir}",
        soft_wrap=True,
    )


@app.command()
def report(
    results: Annotated[Path, typer.Argument(help="Results folder written by `geocon bench`.")],
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="Report folder (default: RESULTS/report).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the bootstrap resampling.")] = 0,
) -> None:
    """The paper's tables and figures from benchmark results: PNG/SVG figures and one
    self-contained HTML report that opens offline."""
    try:
        from .report import build_report
    except ImportError as exc:
        raise _fail(f"the report needs the bench extra: pip install 'geocon[bench]' ({exc})") from None
    try:
        result = build_report(
            results, out_dir, seed=seed, progress=lambda what: err.print(f"report: {what}", highlight=False)
        )
    except (ValueError, FileNotFoundError) as exc:
        raise _fail(str(exc)) from None
    for warning in result.warnings:
        err.print(f"note: {warning}", soft_wrap=True, highlight=False)
    out.print(f"report: {result.html} ({len(result.figures)} figure files in {result.out})", soft_wrap=True)


@app.command()
def presets() -> None:
    """List the named scoring presets and their settings."""
    from .config import PRESETS, config_hash

    for name, (text, cfg) in PRESETS.items():
        table = Table(title=f"{name}: {text} (hash {config_hash(cfg)})", title_justify="left", show_header=False)
        table.add_column(style="bold")
        table.add_column()
        for key, value in cfg.to_dict().items():
            table.add_row(key, str(value))
        out.print(table)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
