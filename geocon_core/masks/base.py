"""The mask source protocol, masked shares, label mapping into the working canvas, and the
per-frame coverage shared by the sources."""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np

from ..media import ClipInfo, Frame, layout_of

__all__ = ["IMPLAUSIBLE_SHARE", "MAX_ID", "MaskSource", "masked_share", "labels_to_canvas", "Coverage"]

IMPLAUSIBLE_SHARE = 0.5
"""Masks covering more than this share of a frame's content are reported in ``warnings``."""

MAX_ID = 255


class MaskSource(Protocol):
    """Object label images, streamed (see the module docstring for the contract)."""

    name: str
    lookahead: int

    @property
    def warnings(self) -> list[str]:
        """Problems found so far, one sentence each."""
        ...

    def push(self, frame: Frame) -> None: ...

    def finish(self) -> None: ...

    def labels(self, t: int) -> np.ndarray: ...

    def release(self, t: int) -> None: ...


def masked_share(labels: np.ndarray, content: np.ndarray) -> float:
    """Share of the ``content`` pixels ((H, W) bool) that ``labels`` ((H, W), 0 = background)
    marks as object; 0.0 for an empty content mask."""
    if labels.shape != content.shape:
        raise ValueError(f"labels {labels.shape} and content {content.shape} differ in size")
    n = int(np.count_nonzero(content))
    return 0.0 if n == 0 else int(np.count_nonzero((labels != 0) & content)) / n


def labels_to_canvas(src: np.ndarray, info: ClipInfo) -> np.ndarray:
    """A source-resolution label image (h, w) -> (H, W) uint8 in the working canvas: resized
    like the reader resizes frames (nearest neighbour, pixel centres aligned), placed at
    ``info.offset`` and zeroed outside ``info.content_box``."""
    w, h = info.source_size
    if src.shape != (h, w):
        raise ValueError(f"mask is {src.shape[1]}x{src.shape[0]} but the clip's frames are {w}x{h}")
    layout = layout_of(info)
    sw, sh = layout.scaled_size
    ox, oy = info.offset
    lab = src if src.dtype == np.uint8 else src.astype(np.uint8)
    if (sw, sh) != (w, h):
        lab = cv2.resize(lab, (sw, sh), interpolation=cv2.INTER_NEAREST_EXACT)
    W, H = info.working_size
    out = np.zeros((H, W), np.uint8)
    x0, y0, x1, y1 = info.content_box
    out[y0:y1, x0:x1] = lab[y0 - oy : y1 - oy, x0 - ox : x1 - ox]
    return out


class Coverage:
    """Per-frame masked share and the implausible-share warning (shared by the sources)."""

    name: str

    def __init__(self, info: ClipInfo) -> None:
        self.info = info
        self.coverage: dict[int, float] = {}
        self._content = info.content_mask
        self._extra_warnings: list[str] = []

    def _record(self, t: int, labels: np.ndarray) -> None:
        if t not in self.coverage:
            self.coverage[t] = masked_share(labels, self._content)

    @property
    def warnings(self) -> list[str]:
        out = list(self._extra_warnings)
        bad = sorted(t for t, s in self.coverage.items() if s > IMPLAUSIBLE_SHARE)
        if bad:
            worst = max(self.coverage[t] for t in bad)
            out.append(
                f"{self.name} masks cover more than {IMPLAUSIBLE_SHARE:.0%} of the content in {len(bad)} "
                f"frame(s) (t={bad[0]}..{bad[-1]}, up to {worst:.0%}): implausible for moving objects"
            )
        return out
