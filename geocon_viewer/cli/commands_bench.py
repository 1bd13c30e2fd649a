"""``geocon bench``, ``geocon report`` and ``geocon presets``: many clips at once, their tables and
report, and the named settings."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape
from rich.table import Table

from geocon_core.config import DEFAULT_PRESET

from .console import VIEWER_EXTRA, err, fail, has_viewer_extra, out, parse_size, progress_bar

__all__ = ["bench", "report", "presets", "render_audit_rrd"]


def render_audit_rrd(record_dir: Path, rrd_path: Path) -> Path | None:
    """Write the Rerun recording of a saved record (the renderer ``geocon bench`` gives its worker
    processes for flagged clips: a module-level function, so it pickles by name)."""
    from ..rerun import quiet_encoder_logs, write_rrd

    quiet_encoder_logs()
    return write_rrd(record_dir, rrd_path)


def bench(
    dataset: Annotated[
        Path,
        typer.Argument(
            help="Dataset folder (clips with <name>.meta.json sidecars, a manifest.csv / manifest.jsonl, or plain clip "
            "files in one sub-folder per platform) or the path of a .csv / .jsonl manifest; `geocon dataset` shows "
            "what is read."
        ),
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Results folder (created; rerun the same command to resume).")],
    preset_name: Annotated[
        str,
        typer.Option("--preset", help="Named settings (`paper`: the paper's protocol); see `geocon presets`."),
    ] = DEFAULT_PRESET,
    workers: Annotated[
        int,
        typer.Option(min=1, help="Worker processes scoring clips in parallel (with --executor ray: the local CPUs)."),
    ] = 1,
    executor: Annotated[
        str,
        typer.Option(
            "--executor",
            help="pool: worker processes on this machine; ray: one Ray task per clip, on this machine or a cluster "
            "(--ray-address; needs the distributed extra). Either can resume the other's run.",
        ),
    ] = "pool",
    ray_address: Annotated[
        Optional[str],
        typer.Option(
            "--ray-address",
            help="Ray cluster to run on (the address `ray start --head` prints); default: a private local "
            "instance on 127.0.0.1. Every node must read the clips at the dataset's paths.",
        ),
    ] = None,
    ray_cpus: Annotated[
        float, typer.Option("--ray-cpus-per-clip", help="CPUs each clip's Ray task asks for (more than 0).")
    ] = 1.0,
    ray_gpus: Annotated[
        Optional[float],
        typer.Option(
            "--ray-gpus-per-clip",
            help="GPUs each clip's Ray task asks for (default: 1 when a neural backend is selected and the "
            "cluster has a GPU, else 0).",
        ),
    ] = None,
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
    roots: Annotated[
        Optional[list[Path]],
        typer.Option(
            "--root",
            help="A folder the dataset's clip and masks paths may lie in besides the dataset's own folder (e.g. where "
            "a manifest's absolute paths point); repeatable. Paths anywhere else are refused.",
        ),
    ] = None,
) -> None:
    """Score every clip of a dataset (in parallel, resumable) and write per-clip records plus flat
    Parquet tables (clip, pair, object level) into the results folder."""
    from geocon_core.bench import BenchError, DatasetError, run_bench
    from geocon_core.config import preset

    try:
        cfg = preset(preset_name)
        if working_size is not None:
            cfg = cfg.with_(working_size=parse_size(working_size, "--working-size"))
        ray_options = _ray_options(executor, ray_address, workers, ray_cpus, ray_gpus)
        _check_bench_out(dataset, out_dir)
    except ValueError as exc:
        raise fail(str(exc)) from None
    renderer = render_audit_rrd if rrd and has_viewer_extra("rerun") else None
    if rrd and renderer is None:
        err.print(
            f"note: Rerun recordings of flagged clips need the viewer extra ({VIEWER_EXTRA}); scoring without them"
        )
    # started when scoring starts, so a refusal (bad --out, bad dataset, a busy folder) prints its sentence alone
    bar = progress_bar("{task.description}", "clips", failed=True, transient=False)
    task = bar.add_task("benchmark", total=None, failed=0, visible=False)

    def on_start(todo: int, skipped: int) -> None:
        if skipped:
            err.print(f"resuming: {skipped} clip(s) already finished in {out_dir}, {todo} to score")
        bar.start()
        bar.update(task, total=todo + skipped, completed=skipped, visible=True)

    def on_clip(status: dict[str, Any], done: int, total: int, failed: int) -> None:
        if status["status"] == "failed":
            bar.console.print(
                f"[red]failed[/] {status['clip_id']}: {status['error']}",
                soft_wrap=True,
                markup=True,
                highlight=False,
            )
        bar.update(task, completed=done, failed=failed)

    def on_note(sentence: str) -> None:
        (bar.console if bar.live.is_started else err).print(f"note: {sentence}", soft_wrap=True, highlight=False)

    try:
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
                executor=executor,
                ray=ray_options,
                on_note=on_note,
                roots=roots or (),
            )
        finally:
            if bar.live.is_started:
                bar.stop()
    except (DatasetError, BenchError, ImportError) as exc:
        raise fail(str(exc)) from None
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
    if summary.total and summary.failed == summary.total:
        err.print(
            f"[bold red]error:[/] every clip failed ({summary.failed} of {summary.total}), so the results say nothing "
            f"about the dataset; the reasons are above and in {escape(str(out_dir))}/clips/<clip_id>/status.json",
            soft_wrap=True,
            highlight=False,
        )
        raise typer.Exit(code=1)


def _check_bench_out(dataset: Path, out_dir: Path) -> None:
    """The results folder is not the dataset folder itself (its records would sit among the clips),
    nor a record folder of ``geocon score`` or inside one; a manifest file given as the dataset is
    never the results folder either (:func:`~geocon_core.files.check_apart`)."""
    from geocon_core.bench import check_output_kind
    from geocon_core.files import OutPathError, check_apart, claim

    if dataset.is_file():
        check_apart([("--out", out_dir)], [("dataset manifest", dataset)])
    if out_dir.exists() and dataset.exists() and os.path.samefile(out_dir, dataset):
        raise OutPathError(
            f"--out {out_dir} is the dataset folder; the results go into a folder of their own (e.g. {dataset}/results)"
        )
    check_output_kind(out_dir, "results")
    claim("--out", out_dir, "results")  # results moved with their dataset, or of another, are taken over (and said)


def _ray_options(executor: str, address: str | None, workers: int, cpus: float, gpus: float | None) -> Any:
    """The Ray settings of ``geocon bench`` (None for the process pool, which takes none of them)."""
    from geocon_core.bench import EXECUTORS

    if executor not in EXECUTORS:
        raise ValueError(f"--executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    from geocon_core.bench import RayOptions

    options = RayOptions(address=address, local_cpus=workers, cpus_per_clip=cpus, gpus_per_clip=gpus)  # checked
    if executor != "ray":
        if address is not None:
            raise ValueError("--ray-address needs --executor ray")
        return None
    return options


def _check_report_out(results: Path, out_dir: Path | None) -> None:
    """The report folder is replaced whole: it must not be the results folder, hold it, or lie in
    its records or tables."""
    from geocon_core.files import OutPathError, check_apart

    if out_dir is None:
        return
    if out_dir.exists() and results.exists():
        if os.path.samefile(out_dir, results):
            raise OutPathError(
                f"--out {out_dir} is the results folder, and a report folder is replaced whole; "
                "choose another folder (default: RESULTS/report)"
            )
        if Path(os.path.realpath(out_dir)) in Path(os.path.realpath(results)).parents:
            raise OutPathError(
                f"--out {out_dir} holds the results folder {results}, and a report folder is replaced whole; "
                "choose another folder (default: RESULTS/report)"
            )
    for part in ("clips", "tables"):
        check_apart([("--out", out_dir)], [(f"results' {part} folder", results / part)])


def report(
    results: Annotated[Path, typer.Argument(help="Results folder written by `geocon bench`.")],
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="Report folder (default: RESULTS/report).")] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the bootstrap resampling (0 or more).")] = 0,
    bootstrap: Annotated[
        int,
        typer.Option(min=100, help="Bootstrap resamples behind every confidence interval (fewer: faster, coarser)."),
    ] = 10_000,
) -> None:
    """The paper's tables and figures from benchmark results: PNG/SVG figures and one
    self-contained HTML report that opens offline."""
    try:
        from geocon_core.report import build_report
    except ImportError as exc:
        raise fail(f"the report needs the bench extra: pip install 'geocon[bench]' ({exc})") from None
    try:
        _check_report_out(results, out_dir)
        result = build_report(
            results,
            out_dir,
            seed=seed,
            bootstrap=bootstrap,
            progress=lambda what: err.print(f"report: {what}", highlight=False),
        )
    except ValueError as exc:
        raise fail(str(exc)) from None
    except OSError as exc:  # a folder vanished: the previous report is kept
        from . import RESOURCE_ERRORS

        if exc.errno in RESOURCE_ERRORS:  # the machine's (a full disk): one sentence, exit 1
            raise
        where = f": {exc.filename}" if exc.filename else ""
        why = f"{exc.strerror or exc}{where}"
        raise fail(f"the report could not be written ({why}); a previous report is unchanged") from None
    for warning in result.warnings:
        err.print(f"note: {warning}", soft_wrap=True, highlight=False)
    out.print(f"report: {result.html} ({len(result.figures)} figure files in {result.out})", soft_wrap=True)


def presets() -> None:
    """List the named scoring presets and every setting, stage settings as dotted names (``motion.min_area``)."""
    from geocon_core.config import PRESETS, config_hash, config_items

    for name, (text, cfg) in PRESETS.items():
        table = Table(title=f"{name}: {text} (hash {config_hash(cfg)})", title_justify="left", show_header=False)
        table.add_column(style="bold", no_wrap=True)
        table.add_column()
        for key, value in config_items(cfg):
            table.add_row(key, str(list(value) if isinstance(value, tuple) else value))
        out.print(table)
