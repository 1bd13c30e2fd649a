"""Record folders that change all at once: a record (``record.json``, ``matches.npz``,
``overlays/``) is written into a temporary sibling folder and its parts are moved into the target
folder only when all of them are complete, so a run that fails or is killed leaves the previous
record there exactly as it was.

The parts are moved one by one with ``rename`` (atomic on one filesystem), ``record.json`` last,
so the folder holds the old ``record.json`` until every other part of the new record is in place
(for the instant of the moves its overlays may already be the new ones). Other files in the target folder
are left alone, except a Rerun recording of the old record (``audit.rrd``), which no longer
matches and is removed. Staging folders of killed runs (``.<name>.part-<pid>``, pid no longer
running) are removed by the next run into the same folder.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from ..files import clear_stale_parts, deferred_signals, parents_made, part_path, refuse_special, remove_path
from ..record import OVERLAYS_DIR
from .layout import RRD_NAME

__all__ = ["RECORD_PARTS", "staged_record"]

RECORD_PARTS = (OVERLAYS_DIR, "matches.npz", RRD_NAME, "record.json")
"""What a record folder holds, in the order a commit moves them (``record.json`` last)."""


def _commit(stage: Path, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    for part in RECORD_PARTS:  # a device or a FIFO in a part's place is refused before anything moves
        refuse_special(out_dir / part)
    for part in RECORD_PARTS:
        new, old = stage / part, out_dir / part
        if new.exists():
            if old.is_dir() and not old.is_symlink():
                trash = stage / f".old-{part}"
                old.rename(trash)  # a folder cannot be replaced by rename while it holds files
            new.replace(old)
        elif old.exists() or old.is_symlink():
            remove_path(old)  # a part of the previous record that this one does not have


@contextlib.contextmanager
def staged_record(out_dir: str | Path, then: Sequence[Callable[[], object]] = ()) -> Iterator[Path]:
    """A temporary folder beside ``out_dir`` to write a record into; when the block ends without
    an exception the record's parts replace those of ``out_dir`` (created if needed), otherwise
    the temporary folder is removed and ``out_dir`` is untouched. ``then``: further commits of the
    same unit (a recording's rename), run right after the record's; Ctrl-C or ``kill`` during the
    commits is held until all of them are done (:func:`~geocon_core.files.paths.deferred_signals`), so
    a signal leaves either the old record with its old recording or the new pair."""
    out_dir = Path(out_dir)
    with parents_made(out_dir.parent):  # a failed run leaves no empty parent behind
        clear_stale_parts(out_dir)
        stage = part_path(out_dir)
        remove_path(stage)
        stage.mkdir()
        try:
            yield stage
            with deferred_signals():
                _commit(stage, out_dir)
                for commit in then:
                    commit()
        finally:
            remove_path(stage)
