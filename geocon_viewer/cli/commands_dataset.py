"""``geocon dataset``: how ``geocon bench`` reads a dataset (every clip's metadata and where each
value came from), and the sidecars that spell it out, for people who want to edit them."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer
from rich.markup import escape
from rich.table import Table

from .console import err, fail, out, progress_bar

if TYPE_CHECKING:
    from geocon_core.bench import ClipEntry, Dataset

__all__ = ["dataset"]

_LAYOUT_TEXT = {
    "sidecars": "a folder of clips with sidecars (*.meta.json)",
    "manifest": "a manifest",
    "folder": "a plain folder of clips",
}
_COLUMNS = (("clip id", "clip_id"), ("platform", "model"), ("prompt", "prompt"), ("category", "category"))
SHOWN_CHARS = 200
"""A field longer than this is shown cut, with its length (a long prompt would fill the terminal,
and the table's wrapping takes time that grows faster than the text)."""


def dataset(
    path: Annotated[
        Path,
        typer.Argument(
            help="Dataset folder (clips with sidecars, a manifest.csv / manifest.jsonl, or plain clip files in "
            "platform sub-folders) or the path of a .csv / .jsonl manifest."
        ),
    ],
    write: Annotated[
        bool,
        typer.Option("--write", help="Write each clip's metadata as a <stem>.meta.json sidecar beside its file."),
    ] = False,
    force: Annotated[bool, typer.Option("--force", help="With --write: replace sidecars that exist.")] = False,
    roots: Annotated[
        Optional[list[Path]],
        typer.Option(
            "--root",
            help="A folder the dataset's clip and masks paths may lie in besides the dataset's own folder; "
            "repeatable (as for `geocon bench`).",
        ),
    ] = None,
) -> None:
    """List the clips `geocon bench` finds in a dataset: id, platform, prompt, category (or "from
    scorer" where none is given) and scene, each with where it came from (sidecar, manifest,
    folder, file name, clip file, default); with --write, save them as sidecars to edit by hand."""
    from geocon_core.bench import DatasetError, scan_dataset, write_sidecars

    if force and not write:
        raise fail("--force replaces sidecars that --write would keep; give it with --write")
    bar = progress_bar("checking clips", "clips", transient=True, disable=not err.is_terminal)
    task = bar.add_task("check", total=None)

    def progress(done: int, total: int) -> None:
        if not bar.live.is_started:
            bar.start()
        bar.update(task, completed=done, total=total)

    try:
        try:
            found = scan_dataset(path, progress=progress, roots=roots or ())
        finally:
            if bar.live.is_started:
                bar.stop()
    except DatasetError as exc:
        raise fail(str(exc)) from None
    if write:
        try:
            _check_sidecars(found, force)  # before anything is said: a refusal is its one sentence
        except ValueError as exc:
            raise fail(str(exc)) from None
    out.print(_table(found))
    for sentence in found.notes:
        err.print(f"note: {sentence}", soft_wrap=True, highlight=False, markup=False)
    platforms = sorted({e.model for e in found.entries})
    out.print(
        f"{found.root}: {_LAYOUT_TEXT[found.layout]}, {len(found.entries)} clip(s) on {len(platforms)} platform(s) "
        f"({', '.join(platforms)})",
        soft_wrap=True,
        highlight=False,
        markup=False,
    )
    if not write:
        if found.layout != "sidecars":
            out.print(f"to edit these values: geocon dataset {path} --write", soft_wrap=True, highlight=False)
        return
    try:
        done = write_sidecars(found, force=force)
    except OSError as exc:
        from . import RESOURCE_ERRORS

        if exc.errno in RESOURCE_ERRORS:  # the machine's (a full disk, a read-only folder): one sentence, exit 1
            raise
        raise fail(f"a sidecar could not be written ({exc.strerror or exc}: {exc.filename})") from None
    if done.written:
        out.print(
            f"wrote {len(done.written)} sidecar(s) beside the clips (e.g. {done.written[0]}); `geocon bench` reads "
            "them from now on",
            soft_wrap=True,
            highlight=False,
        )
    if done.kept:
        said = (
            f"kept {len(done.kept)} sidecar(s) that already hold these values (e.g. {done.kept[0]})"
            if force
            else f"kept {len(done.kept)} existing sidecar(s) (e.g. {done.kept[0]}); --force replaces them"
        )
        out.print(
            said,
            soft_wrap=True,
            highlight=False,
        )


def _check_sidecars(found: Dataset, force: bool) -> None:
    """No sidecar ``--write`` would write is its own clip or masks, lies inside them, is a device
    or a FIFO (a sidecar is replaced by renaming), the sidecar of two clips, or lands on another
    output of GeoCon's; with ``force``, one it replaces is a sidecar GeoCon wrote for the same clip
    (:func:`geocon_core.bench.sidecar_owner`), never a file written by hand (``ValueError`` with
    one sentence)."""
    from geocon_core.bench import sidecar_owner
    from geocon_core.files import check_apart, claim, refuse_special

    seen: dict[str, Path] = {}
    for e in found.entries:
        inputs = [("clip", e.video)] + ([] if e.masks is None else [("masks", e.masks)])
        check_apart([("--write", e.sidecar)], inputs)
        refuse_special(e.sidecar, "--write")
        key = os.path.realpath(e.sidecar)
        if key in seen:
            raise ValueError(
                f"{seen[key]} and {e.video} would both have the sidecar {e.sidecar} (one name beside two clips); "
                "rename one of the clips"
            )
        seen[key] = e.video
        if force or not e.sidecar.exists():
            claim("--write", e.sidecar, "json", mine=sidecar_owner(e))


def _cell(entry: ClipEntry, key: str) -> str:
    """A field's value (``from scorer`` for a category not given, ``-`` for no value) over its
    source, dimmed."""
    value: Any = entry.meta.get(key)
    text = ("from scorer" if key == "category" else "-") if value is None else str(value)
    if len(text) > SHOWN_CHARS:
        text = f"{text[:SHOWN_CHARS]}... ({len(text)} characters)"
    return f"{escape(text)}\n[dim]{entry.sources.get(key, '?')}[/]"


def _table(found: Dataset) -> Table:
    """One row per clip: its file (relative to the dataset folder or the manifest's), then each
    field with its source."""
    base = found.root.parent if found.root.is_file() else found.root
    table = Table(show_lines=True)
    table.add_column("file", overflow="fold")
    for title, _ in _COLUMNS:
        table.add_column(title, overflow="fold")
    table.add_column("scene", overflow="fold")
    for e in found.entries:
        rel = os.path.relpath(e.video, base.resolve())
        table.add_row(
            escape(rel if not rel.startswith("..") else str(e.video)),
            *(_cell(e, key) for _, key in _COLUMNS),
            _cell(e, "scene_id"),
        )
    return table
