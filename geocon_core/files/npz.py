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

__all__ = ["NPZ_ERRORS"]

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
