"""Files on disk, read and written safely.

:mod:`.paths` (output folders checked before work, outputs kept apart from inputs, whole-folder
replacement, signals held during a commit), :mod:`.owner` (what a path holds, and the one rule of
every writer: only its own files, replaced only by its own kind for the same input),
:mod:`.commit` (outputs of several files checked whole and committed together),
:mod:`.lockfile` (one writer per results folder), :mod:`.procs` (worker processes that do not
outlive their parent), :mod:`.alloc` (the C allocator of a long scoring process), :mod:`.jsonin`
(strict JSON for sidecars and pose logs), :mod:`.npz` (the errors a damaged archive raises, and
what a file that is none is) and :mod:`.checkpoint` (the one reader of user-given network weights).
"""

from __future__ import annotations

from .alloc import ARENAS, MMAP_THRESHOLD, tune_allocator
from .checkpoint import (
    read_checkpoint_file,
)
from .commit import check_targets, commit_together
from .jsonin import (
    MAX_NUMBER_CHARS,
    strict_json,
)
from .lockfile import (
    FolderLock,
    LockHeld,
    lock_holder,
)
from .npz import (
    NPZ_ERRORS,
    npz_problem,
)
from .owner import (
    FOLDER_KINDS,
    FORMATS,
    FolderKind,
    Held,
    claim,
    folder_kind,
    folders_above,
    held,
    stamp_png,
)
from .paths import (
    PROTECTED_PARTS,
    OutPathError,
    check_apart,
    check_out_dir,
    check_out_file,
    clear_stale_parts,
    deferred_signals,
    parents_made,
    part_path,
    part_prefix,
    record_parts,
    refuse_special,
    remove_path,
    replace_dir,
    replace_file,
    short_name,
    special_file,
)
from .procs import (
    PARENT_POLL_S,
    die_with_parent,
    pid_alive,
    quiet_resource_tracker,
    quiet_tracker_restarts,
    reap_when_gone,
    start_reaper,
)

__all__ = [
    "ARENAS",
    "MMAP_THRESHOLD",
    "tune_allocator",
    "PARENT_POLL_S",
    "die_with_parent",
    "quiet_resource_tracker",
    "quiet_tracker_restarts",
    "pid_alive",
    "reap_when_gone",
    "start_reaper",
    "OutPathError",
    "PROTECTED_PARTS",
    "check_apart",
    "check_out_dir",
    "check_out_file",
    "clear_stale_parts",
    "deferred_signals",
    "parents_made",
    "part_path",
    "part_prefix",
    "record_parts",
    "remove_path",
    "refuse_special",
    "replace_dir",
    "replace_file",
    "short_name",
    "special_file",
    "FolderLock",
    "LockHeld",
    "lock_holder",
    "MAX_NUMBER_CHARS",
    "strict_json",
    "NPZ_ERRORS",
    "npz_problem",
    "read_checkpoint_file",
    "check_targets",
    "commit_together",
    "FOLDER_KINDS",
    "FORMATS",
    "FolderKind",
    "Held",
    "claim",
    "folder_kind",
    "folders_above",
    "held",
    "stamp_png",
]
