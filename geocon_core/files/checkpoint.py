"""Reading the weights a user gives (RAFT, SAM-2, DUSt3R): one rule for every neural backend.

A checkpoint is an untrusted file. It is read with ``torch.load(..., weights_only=True)``, which
unpickles tensors and plain containers only, plus the classes a backend names explicitly (DUSt3R's
``argparse.Namespace``); nothing in it is executed. Every failure is one sentence naming the
backend, the file and what to pass instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["read_checkpoint_file"]


def read_checkpoint_file(path: str | Path, what: str, hint: str, *, allow: Sequence[type] = ()) -> Any:
    """The object stored in the checkpoint ``path`` of ``what`` (e.g. ``"RAFT checkpoint"``),
    read on the CPU with ``weights_only=True`` and the classes ``allow`` besides tensors and
    containers. ``ValueError`` for a missing file (with ``hint``, e.g. the option to pass), a file
    torch cannot read, and one that holds a class outside the allow-list (named, never built)."""
    import torch

    p = Path(path)
    where = f"{what} {p}"
    if not p.is_file():
        raise ValueError(f"{where} does not exist or is not a file ({hint})")
    try:
        with torch.serialization.safe_globals(list(allow)):
            return torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        text = str(exc)
        if "Unsupported global" in text:
            name = text.split("Unsupported global:", 1)[1].split()[1] if "GLOBAL" in text else "an object"
            allowed = " and ".join(["tensors", *(f"{c.__module__}.{c.__qualname__}" for c in allow)])
            raise ValueError(f"{where} holds {name}, which GeoCon does not unpickle (only {allowed})") from None
        raise ValueError(f"{where} cannot be read as a PyTorch checkpoint ({type(exc).__name__})") from None
