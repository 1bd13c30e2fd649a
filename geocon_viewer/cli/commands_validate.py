"""``geocon validate``: the validation report (synthetic grid + annotated real clips), printed as
one table and written as markdown and JSON."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer
from rich.markup import escape
from rich.table import Table

from .console import MAX_FRAMES, fail, out, progress_bar

if TYPE_CHECKING:
    from geocon_core.config import ScoreConfig
    from geocon_core.validation import Annotation, ValidationPlan, ValidationReport

__all__ = ["validate", "footage", "print_report"]

_DEFAULT_DATA = Path("../shared/data")
_DEFAULT_REAL2 = Path("../shared/real2")


def _ints(text: str | None, name: str) -> tuple[int, ...] | None:
    if text is None:
        return None
    try:
        return _once(tuple(int(v) for v in text.split(",") if v.strip()), name)
    except ValueError:
        raise fail(f"--{name} takes comma-separated whole numbers, got {text!r}") from None


def _names(text: str | None, name: str) -> tuple[str, ...] | None:
    if text is None:
        return None
    return _once(tuple(v.strip() for v in text.split(",") if v.strip() and v.strip().lower() != "none"), name)


def _once(values: tuple[Any, ...], name: str) -> tuple[Any, ...]:
    """``values`` of the list option ``--name``, refused when one is given twice (its cases would
    be planned, and counted, twice)."""
    seen: set[str] = set()
    for v in values:
        key = str(v).lower()
        if key in seen:
            raise fail(f"--{name} lists {v} twice; give each once")
        seen.add(key)
    return values


def print_report(report: ValidationReport) -> None:
    """The validation table on the terminal."""
    from geocon_core.validation import INTERVALS_NOTE, metric_cells

    p = report.plan
    table = Table(
        title=f"GeoCon validation: preset {report.preset}, heights {','.join(map(str, p.heights))}, codecs "
        f"{','.join(p.codecs)}, {len(report.cases)} of {report.planned} cases, {report.seconds:.0f} s",
        title_justify="left",
        caption=INTERVALS_NOTE,
        caption_justify="left",
    )
    for col in ("measure", "set", "value", "target", "met", "detail"):
        table.add_column(col, justify="right" if col == "value" else "left", overflow="fold")
    for row in report.metrics:
        cells = metric_cells(row)
        cells[4] = {"yes": "[green]yes[/]", "NO": "[red]NO[/]"}.get(cells[4], cells[4])
        table.add_row(*cells)
    out.print(table)
    if report.planted is not None:
        _print_planted(report)


def _print_planted(report: ValidationReport) -> None:
    """The planted failures' table on the terminal, with how its clips were made."""
    from geocon_core.validation import PLANTED_COLUMNS, PLANTED_NOTE, cache_line, planted_cells

    summary = report.planted
    assert summary is not None
    table = Table(title="Planted failures", title_justify="left", caption=PLANTED_NOTE, caption_justify="left")
    for col in PLANTED_COLUMNS:
        table.add_column(col, overflow="fold")
    for row in summary.rows:
        table.add_row(*planted_cells(row))
    out.print(table)
    for line in summary.reencodes:
        out.print(f"clean re-encodes against the originals, {line.subset}: {line.detail}", soft_wrap=True)
    out.print(cache_line(summary.cache), soft_wrap=True)


def validate(
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for the records and the report (created).")] = Path(
        "geocon-validation"
    ),
    cache: Annotated[
        Optional[Path], typer.Option(help="Folder for rendered and cut clips (default: OUT/cache); reused across runs.")
    ] = None,
    preset_name: Annotated[
        Optional[str], typer.Option("--preset", help="Named settings (default: the default of `geocon score`).")
    ] = None,
    data: Annotated[Path, typer.Option(help="Folder of real clips.")] = _DEFAULT_DATA,
    annotations: Annotated[
        Optional[Path], typer.Option(help="Annotation CSV (default: assets/validation/annotations.csv).")
    ] = None,
    quick: Annotated[
        bool,
        typer.Option(
            "--quick", help="A smoke run: heights 256,720, codecs png,crf28, 24 frames, real clips cut to 16."
        ),
    ] = False,
    heights: Annotated[Optional[str], typer.Option(help="Comma-separated synthetic heights, px.")] = None,
    codecs: Annotated[Optional[str], typer.Option(help="Comma-separated codecs: png, crf18, crf28.")] = None,
    families: Annotated[Optional[str], typer.Option(help="Comma-separated clean families (C1..C6, or none).")] = None,
    failures: Annotated[
        Optional[str], typer.Option(help="Comma-separated failures: breathing, slide, elastic (or none).")
    ] = None,
    levels: Annotated[Optional[str], typer.Option(help="Comma-separated severities: low, middle, high.")] = None,
    frames: Annotated[
        Optional[int], typer.Option(min=2, max=MAX_FRAMES, help="Frames per synthetic clip (default 24).")
    ] = None,
    max_frames: Annotated[
        Optional[int],
        typer.Option(min=2, max=MAX_FRAMES, help="Real clips are cut to their first frames (default 48)."),
    ] = None,
    seed: Annotated[
        int,
        typer.Option(
            min=0,
            help="Seed of the synthetic scenes (layout, textures, failure fields). The thresholds were "
            "chosen at seed 0; another seed shows them on scenes they were not tuned on.",
        ),
    ] = 0,
    real2: Annotated[
        Path, typer.Option(help="Folder of further real-camera clips (the annotated rows of root real2).")
    ] = _DEFAULT_REAL2,
    footage_dir: Annotated[
        Optional[Path],
        typer.Option(
            "--footage",
            help="The footage cache (annotated rows of root footage; default $GEOCON_FOOTAGE or "
            "~/.cache/geocon/footage). Clips missing from it are listed, not scored.",
        ),
    ] = None,
    footage_from: Annotated[
        Optional[Path],
        typer.Option(
            "--footage-from",
            help="Fill the footage cache first from the clones of the annotated repositories in this folder "
            "(owner+name, bare or not); nothing is downloaded.",
        ),
    ] = None,
    split: Annotated[
        str,
        typer.Option(
            help="all, tune or check: score only that half of the annotated clips of real2 and the footage cache "
            "(the clips of --data and the synthetic grid are not split). Rules are chosen on the tune half.",
        ),
    ] = "all",
    planted: Annotated[
        bool,
        typer.Option(
            "--planted",
            help="Also plant failures (geocon plant) into every annotated real-camera clip of --data, real2 and the "
            "footage cache (in --split), cut to --max-frames, from --seed, beside one clean re-encode of each; "
            "rendered once into --cache. With --no-real the clips themselves are not scored.",
        ),
    ] = False,
    plant_kinds: Annotated[
        Optional[str],
        typer.Option(
            "--plant-kinds",
            help="With --planted: comma-separated kinds, morph, redraw, breathing, slide (default all).",
        ),
    ] = None,
    plant_severity: Annotated[
        Optional[str],
        typer.Option("--severity", help="With --planted: comma-separated severities, low, middle, high (default all)."),
    ] = None,
    real: Annotated[
        bool, typer.Option("--real/--no-real", help="Score the real clips of --data, real2 and the footage cache.")
    ] = True,
    synthetic: Annotated[bool, typer.Option("--synthetic/--no-synthetic", help="Score the synthetic grid.")] = True,
    peer: Annotated[
        bool,
        typer.Option(
            "--peer/--no-peer",
            help="Also score every annotated clip with the peer (GVGC keep rate) for the AUC rows; once per clip.",
        ),
    ] = True,
    jobs: Annotated[int, typer.Option(min=1, help="Worker processes.")] = 1,
    report_only: Annotated[
        bool,
        typer.Option("--report-only", help="Score nothing: the table of the cases already scored in --out."),
    ] = False,
    fit: Annotated[
        bool,
        typer.Option(
            "--fit",
            help="Score nothing: fit the clip model on the tune half of the annotated clips scored in --out "
            "(their readings are read from the clips where the records lack them) and report both halves; "
            "writes clip_model.json and fit.md into --out.",
        ),
    ] = False,
    fit_l2: Annotated[
        float, typer.Option("--fit-l2", min=0.0, help="The fit's L2 penalty on the readings' weights.")
    ] = 1.0,
    fit_with: Annotated[
        Optional[list[Path]],
        typer.Option(
            "--fit-with",
            help="With --fit: also the cases of another validation's --out (planted cases of a --planted run, say); "
            "repeatable.",
        ),
    ] = None,
) -> None:
    """Validate the default settings: synthetic scenes at several heights and codecs, clean and
    with injected failures, and the real clips in --data against the project's annotations; prints
    one table and writes validation.md and validation.json into --out."""
    from geocon_core.config import DEFAULT_PRESET, preset
    from geocon_core.signals import configured_model
    from geocon_core.validation import DEFAULT_FOOTAGE, QUICK, ValidationPlan, read_annotations

    try:
        cfg = preset(preset_name or DEFAULT_PRESET)  # the validation measures the default
        given = {
            "heights": _ints(heights, "heights") if heights is not None else (QUICK.heights if quick else None),
            "codecs": _names(codecs, "codecs") if codecs is not None else (QUICK.codecs if quick else None),
            "families": _names(families, "families"),
            "failures": _names(failures, "failures"),
            "levels": _names(levels, "levels"),
            "frames": frames or (QUICK.frames if quick else None),
            "max_frames": max_frames or (QUICK.max_frames if quick else None),
        }
        if not planted and (plant_kinds is not None or plant_severity is not None):
            option = "--plant-kinds" if plant_kinds is not None else "--severity"
            raise fail(f"{option} chooses the planted cases; add --planted (the synthetic severities are --levels)")
        given["plant_kinds"] = _names(plant_kinds, "plant-kinds")
        given["plant_levels"] = _names(plant_severity, "severity")
        chosen: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
        cache_dir = footage_dir or DEFAULT_FOOTAGE
        roots = real or planted  # the planted cases' sources are the real clips
        plan = replace(
            ValidationPlan(),
            **chosen,
            seed=seed,
            data=data if roots else None,
            synthetic=synthetic,
            real2=real2 if roots and real2.is_dir() else None,
            footage=cache_dir if roots else None,
            split=split,
            real=real,
            planted=planted,
        )
        notes = read_annotations(annotations) if annotations is not None else read_annotations()
        _check_outputs(out_dir, cache, plan, annotations, footage_from, fit=fit)
        configured_model(cfg.signals)  # the clip model that decides the verdicts, before any work
    except (ValueError, OSError) as exc:
        raise fail(str(exc)) from None
    if roots and not data.is_dir():
        leave = "--no-real without --planted" if planted else "--no-real"
        raise fail(f"{data}: no such folder of real clips (give --data, or {leave})")
    if roots:
        from geocon_core.validation import real_clips

        try:
            real_clips(data)  # a FIFO or a device among the clips: refused before any work
        except ValueError as exc:
            raise fail(str(exc)) from None
    if roots and footage_from is not None:
        _fill(notes, cache_dir, footage_from)
    if fit:
        _fit([out_dir, *(fit_with or [])], cfg, notes, annotations, fit_l2)
        return
    if fit_with:
        raise fail("--fit-with adds cases to a fit; add --fit")
    started = time.monotonic()
    report = _run(plan, cfg, out_dir, cache or out_dir / "cache", jobs, notes, not report_only, peer)
    took = time.monotonic() - started
    if report_only and len(report.cases) < report.planned:
        out.print(
            f"[yellow]{report.planned - len(report.cases)} of {report.planned} planned cases have no record in "
            f"{out_dir} scored with these settings from these clips[/] (a case counts when its preset, "
            "--cache, --seed and grid match the run that scored it)"
        )
    print_report(report)
    for sentence in report.notes:
        out.print(f"[yellow]note:[/] {escape(sentence)}", soft_wrap=True, highlight=False)
    out.print(f"report: {out_dir / 'validation.md'} and {out_dir / 'validation.json'}; records in {out_dir / 'cases'}")
    out.print(f"this run took {_minutes(took)} with {jobs} worker process{'es' if jobs > 1 else ''}")


def _fit(
    folders: list[Path], cfg: ScoreConfig, notes: dict[str, Annotation], annotations: Path | None, l2: float
) -> None:
    """``--fit``: the clip model fitted on the tune half of the clips scored in ``folders`` (the
    first is --out, where the model and its report are written)."""
    import datetime

    from rich.progress import TaskID

    from geocon_core.files import commit_together, part_path
    from geocon_core.validation import ANNOTATIONS_PATH, FitCase, fit_cases, fit_markdown, fit_model, model_json

    out_dir = folders[0]
    for folder in folders:
        if not (folder / "cases").is_dir():
            raise fail(f"{folder}: no scored cases to fit on (run `geocon validate --out {folder}` first)")
    rows: list[FitCase] = []
    problems: list[str] = []
    with progress_bar("readings", "clips") as bar:
        for folder in folders:
            task = bar.add_task(f"readings of {folder}", total=None)

            def advance(done: int, total: int, task: TaskID = task) -> None:
                bar.update(task, completed=done, total=total)

            more, trouble = fit_cases(folder / "cases", notes, cfg, advance)
            rows += more
            problems += trouble
    for line in problems:
        out.print(f"[yellow]left out[/] {line}")
    halves = {(c.split, c.broken) for c in rows}
    if ("tune", True) not in halves or ("tune", False) not in halves:
        raise fail(f"{out_dir}: the tune half needs clips with a geometric artifact and sound clips to fit on")
    version = datetime.date.today().isoformat()
    try:
        report = fit_model(
            rows,
            l2=l2,
            version=version,
            annotations_path=annotations or ANNOTATIONS_PATH,
            decisive_shortfall=cfg.signals.decisive_shortfall,
            drift_fails_with_background=cfg.signals.drift_fails_with_background,
        )
    except ValueError as exc:
        raise fail(str(exc)) from None
    moves = []
    try:
        for name, text in (("clip_model.json", model_json(report.model)), ("fit.md", fit_markdown(report))):
            moves.append((part_path(out_dir / name), out_dir / name))
            moves[-1][0].write_text(text)
    except BaseException:
        for part, _ in moves:
            part.unlink(missing_ok=True)
        raise
    commit_together(moves)  # the model and the page that reports it: both or neither
    out.print(fit_markdown(report))
    out.print(
        f"model: {out_dir / 'clip_model.json'} (digest {report.model.digest()}); report: {out_dir / 'fit.md'}; "
        f"{report.cases} clips"
    )


def _minutes(seconds: float) -> str:
    """A wall time in words: ``42 s``, ``12 min 03 s``."""
    whole = int(round(seconds))
    return f"{whole} s" if whole < 60 else f"{whole // 60} min {whole % 60:02d} s"


def _check_outputs(
    out_dir: Path,
    cache: Path | None,
    plan: ValidationPlan,
    annotations: Path | None,
    footage_from: Path | None,
    *,
    fit: bool = False,
) -> None:
    """``--out`` and ``--cache`` are folders that can be written and lie apart from everything the
    run reads: the real clips' folders, the footage cache, the annotations and the clones the
    footage cache is filled from; ``--out`` is a validation folder (or a new one), and the files
    this run writes at its top (the report, or with ``fit`` the model and its page) replace only
    GeoCon's own (``ValueError`` with one sentence)."""
    from geocon_core.files import check_apart, check_out_dir, claim

    outputs = [("--out", out_dir)] + ([] if cache is None else [("--cache", cache)])
    read = [("--data folder", plan.data), ("--real2 folder", plan.real2), ("footage cache", plan.footage)]
    read += [("annotation file", annotations), ("--footage-from folder", footage_from)]
    inputs = [(what, path) for what, path in read if path is not None]
    check_apart(outputs, inputs)
    if footage_from is not None and plan.footage is not None:
        check_apart([("--footage", plan.footage)], [("--footage-from folder", footage_from)])
    for option, path in outputs:
        check_out_dir(path, option)
    claim("--out", out_dir, "validation")  # never a record, results or report folder, nor a user's cases/
    for name, kind in _FIT_FILES if fit else _REPORT_FILES:
        claim("--out", out_dir / name, kind, own=[out_dir])
    if cache is not None:
        claim("--cache", cache, "folder", own=[out_dir])
    if footage_from is not None and plan.footage is not None:
        claim("--footage", plan.footage, "folder")


_REPORT_FILES = (("validation.md", "markdown"), ("validation.json", "json:geocon-validation"))
"""The files ``geocon validate`` writes at the top of ``--out``, and their kinds: each replaces only
GeoCon's own earlier one (:func:`geocon_core.files.claim`)."""
_FIT_FILES = (("clip_model.json", "json:geocon-clip-model"), ("fit.md", "markdown"))
"""The files ``geocon validate --fit`` writes at the top of ``--out`` (instead of the report)."""


def _fill(notes: dict[str, Annotation], cache: Path, sources: Path, option: str = "--footage-from") -> None:
    from geocon_core.validation import fill_footage

    if not sources.is_dir():
        kind = "is a file, not a folder" if sources.exists() else "does not exist"
        raise fail(f"{option} {sources} {kind}; give the folder that holds the clones of the annotated repositories")
    items = fill_footage(notes, cache, sources)
    filled = sum(i.state == "filled" for i in items)
    bad = [i for i in items if i.state not in ("present", "filled")]
    out.print(f"footage cache {cache}: {filled} clips filled, {len(items) - len(bad)} of {len(items)} present")
    for item in bad[:20]:
        out.print(f"  [yellow]{item.annotation.clip}[/]: {item.state}: {item.detail}")
    if len(bad) > 20:
        out.print(f"  ... and {len(bad) - 20} more (`geocon footage status`)")


def footage(
    action: Annotated[str, typer.Argument(help="status (what the cache holds) or fill (copy what is missing).")],
    cache: Annotated[
        Optional[Path],
        typer.Option("--footage", help="The footage cache (default $GEOCON_FOOTAGE or ~/.cache/geocon/footage)."),
    ] = None,
    sources: Annotated[
        Optional[Path],
        typer.Option("--from", help="fill: folder of clones of the annotated repositories (owner+name, bare or not)."),
    ] = None,
    annotations: Annotated[
        Optional[Path], typer.Option(help="Annotation CSV (default: assets/validation/annotations.csv).")
    ] = None,
) -> None:
    """The footage cache of `geocon validate`: clips of public repositories that the annotation file
    names and the project never commits. `status` checks each one against its annotated SHA-256;
    `fill --from DIR` copies the missing ones out of local clones of their repositories (git show
    COMMIT:PATH; nothing is downloaded) and prints the `git clone` line for a repository with no
    clone."""
    from geocon_core.validation import DEFAULT_FOOTAGE, footage_status, read_annotations

    if action not in ("status", "fill"):
        raise fail(f"unknown action {action!r}; valid: status, fill")
    if action == "status" and sources is not None:
        raise fail("--from is used with fill (the clones to copy from); status only reads the cache")
    try:
        notes = read_annotations(annotations) if annotations is not None else read_annotations()
    except (ValueError, OSError) as exc:
        raise fail(str(exc)) from None
    cache_dir = cache or DEFAULT_FOOTAGE
    if action == "fill":
        if sources is None:
            raise fail("fill needs --from DIR: a folder of clones of the annotated repositories")
        from geocon_core.files import check_apart, check_out_dir, claim

        read = [("--from folder", sources)] + ([] if annotations is None else [("annotation file", annotations)])
        try:
            check_apart([("--footage", cache_dir)], read)
            check_out_dir(cache_dir, "--footage")
            claim("--footage", cache_dir, "folder")
        except ValueError as exc:
            raise fail(str(exc)) from None
        _fill(notes, cache_dir, sources, "--from")
        return
    if cache_dir.exists() and not cache_dir.is_dir():
        raise fail(f"--footage {cache_dir} is a file, not a folder; give the footage cache folder")
    items = footage_status(notes, cache_dir)
    present = sum(i.state == "present" for i in items)
    out.print(f"footage cache {cache_dir}: {present} of {len(items)} annotated clips present")
    for item in items:
        if item.state != "present":
            out.print(f"  [yellow]{item.annotation.clip}[/]: {item.detail}")


def _run(
    plan: ValidationPlan,
    cfg: ScoreConfig,
    out_dir: Path,
    cache: Path,
    jobs: int,
    notes: dict[str, Annotation],
    score: bool,
    peer: bool = True,
) -> ValidationReport:
    from rich.progress import TaskID

    from geocon_core.validation import run_validation

    with progress_bar("{task.description}", "clips") as bar:
        tasks: dict[str, TaskID] = {}

        def progress(phase: str, done: int, total: int) -> None:
            if phase not in tasks:
                words = {"prepare": "preparing clips", "score": "scoring", "peer": "peer (GVGC keep rate)"}
                tasks[phase] = bar.add_task(words.get(phase, phase), total=total)
            bar.update(tasks[phase], completed=done, total=total)

        return run_validation(
            plan, cfg, out_dir, cache, jobs=jobs, annotations=notes, progress=progress, score=score, peer=peer
        )
