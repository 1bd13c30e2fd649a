"""The keep reading: how many of a clip's background matches one fundamental matrix keeps.

The GVGC study scores a generated clip by the share of SIFT matches between neighbouring frames
that one fundamental matrix keeps at 1 px (854 px wide frames). The same evidence is read here from
the matches the background fit already made, at no extra cost: for each pair of neighbouring
frames at the largest scale, the share of its background matches whose distance to the pair's
fitted F (Sampson, px) exceeds ``keep_px`` scaled to the pair's width; the reading is the mean over
pairs (larger = more broken). Moving objects are already masked out, so it reads the background.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..config import SignalsConfig

__all__ = ["unkept_share"]


def unkept_share(
    pairs: Iterable[tuple[int, float, int, int]], f_res_px: np.ndarray, width: int, cfg: SignalsConfig
) -> float | None:
    """The mean unkept share over ``pairs`` given as (gap, scale, first row, end row) into
    ``f_res_px`` (the matches' Sampson distances to their pair's F, px of the pair's scale) of a
    clip scored on a canvas ``width`` px wide. Only neighbouring frames (gap 1) at the largest
    scale read; None when no pair has ``cfg.keep_min_matches`` matches."""
    rows = [p for p in pairs if p[0] == 1]
    if not rows:
        return None
    top = max(scale for _, scale, _, _ in rows)
    shares = []
    for _, scale, a, b in rows:
        if scale != top or b - a < cfg.keep_min_matches:
            continue
        limit = cfg.keep_px * width * scale / cfg.keep_width
        shares.append(float(np.count_nonzero(f_res_px[a:b] > limit)) / (b - a))
    return float(np.mean(shares)) if shares else None
