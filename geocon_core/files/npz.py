"""What reading an ``.npz`` (or ``.npy``) that nobody vouches for can raise.

``np.load(..., allow_pickle=False)`` never runs code, but a damaged archive fails in many ways:
the zip layer (``BadZipFile``, ``zlib.error``, ``EOFError``), numpy's header parser (``ValueError``,
``SyntaxError``, ``tokenize.TokenError``, ``RecursionError`` on a nested header) and a header that
claims a huge array (``MemoryError``). Readers catch :data:`NPZ_ERRORS` and answer with one
sentence naming the file.
"""

from __future__ import annotations

import tokenize
import zipfile
import zlib
from pathlib import Path

__all__ = ["NPZ_ERRORS", "npz_problem"]

NPZ_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    EOFError,
    ValueError,
    SyntaxError,
    tokenize.TokenError,
    RecursionError,
    MemoryError,
    zipfile.BadZipFile,
    zlib.error,
)
"""Exceptions of a damaged ``.npz``/``.npy`` file (see the module docstring)."""


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
"""How a zip archive (an ``.npz``) starts: a first entry, or the end record of an empty archive."""
_NPY_MAGIC = b"\x93NUMPY"


def npz_problem(path: str | Path) -> str | None:
    """Why the file at ``path`` is no ``.npz`` archive, in a few words, judged from its first
    bytes as ``np.load`` would (which takes anything else for a pickle, and says so with a hint to
    unpickle it): ``"a single .npy array"``, ``"a Python pickle, which GeoCon never loads"`` or
    ``"not a zip archive"``; None when it starts as an archive (or cannot be read: the reader's own
    error says so)."""
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except OSError:
        return None
    if head[:4] in _ZIP_MAGIC:
        return None
    if head == _NPY_MAGIC:
        return "a single .npy array"
    if head[:1] == b"\x80" and head[1:2] in (b"\x02", b"\x03", b"\x04", b"\x05"):
        return "a Python pickle, which GeoCon never loads"
    return "not a zip archive"
