"""The gate's pose from a chain of short hops, when the first and last frames share too little.

Generated clips often change so much between their first and last frame that the two frames
keep a few dozen matches and no pose (``too_few_matches`` / ``too_few_inliers``); the paper's
convention then gates the clip F without evidence. The frames in between carry that evidence:
the clip is cut into consecutive hops ``(0, h), (h, 2h), ..., (., n - 1)`` (:func:`chain_hops`),
each hop gets its own relative pose, and :func:`compose_chain` composes them.

Rotations compose exactly. Translations compose in the first camera's frame,
``c_0k = c_0a + R_0a c_ak``; each hop's translation is on its own unit-mean-scene-distance scale,
so the sum is on the clip's scale as long as the scene distance changes slowly along the clip
(a camera that moves a large share of the scene distance makes the later hops' units smaller,
and the composed ``t_inf`` is then an under-estimate). A rotation-only hop contributes no
translation (its translation is below the noise) and its first-order bound ``parallax / f``.

Hops of one frame see the least parallax: a camera that trucks while it turns moves a pixel or
less between adjacent frames, every hop is then explained by a rotation, and the chain reads a
translation near zero. With several hop lengths (:func:`chain_lengths`), :func:`select_hops`
walks the clip taking at each frame the longest hop that has a pose, so the chain keeps the
parallax of hops several frames long and falls back to shorter ones only where the longer ones
share too little.

When some hops have no pose, the chain is cut there: every unbroken run of hops is composed on
its own and the clip's ``t_inf`` is the largest run's, a lower bound of the translation over the
clip; it is used only when the hops with a pose span at least ``min_share`` of the clip.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry import rotation_angle_deg
from .base import ZOOM_NOTE_LOG, PoseEstimate

__all__ = ["chain_hops", "chain_lengths", "select_hops", "compose_chain"]


def chain_hops(n: int, hop: int) -> list[tuple[int, int]]:
    """Consecutive hops ``(start, end)`` of ``hop`` frames covering frames ``0 .. n - 1``; a last
    hop shorter than half a hop is merged into the one before. Empty when the clip is not longer
    than one hop (the first-last pair is then itself a short hop)."""
    if hop < 1:
        raise ValueError(f"hop must be a positive number of frames, got {hop}")
    if n - 1 <= hop:
        return []
    ends = list(range(hop, n - 1, hop)) + [n - 1]
    if len(ends) > 1 and ends[-1] - ends[-2] < (hop + 1) // 2:
        ends.pop(-2)
    starts = [0] + ends[:-1]
    return list(zip(starts, ends, strict=True))


def chain_lengths(shortest: int, longest: int) -> list[int]:
    """Hop lengths from ``longest`` down to ``shortest``, halving (``8, 4, 2, 1``); just
    ``[shortest]`` when ``longest <= shortest``."""
    if shortest < 1:
        raise ValueError(f"hop must be a positive number of frames, got {shortest}")
    lengths = [shortest]
    while lengths[-1] * 2 <= longest:
        lengths.append(lengths[-1] * 2)
    return lengths[::-1]


def select_hops(hops: dict[tuple[int, int], PoseEstimate], n: int) -> list[tuple[tuple[int, int], PoseEstimate]]:
    """Consecutive hops over frames ``0 .. n - 1`` for :func:`compose_chain`: from each frame the
    longest hop of ``hops`` (windows ``(start, end)`` of several lengths, :func:`chain_hops` of
    each) that has a pose; where none has, the shortest hop from there (without a pose, so the
    chain is cut) or, where no hop starts, one step on."""
    out: list[tuple[tuple[int, int], PoseEstimate]] = []
    by_start: dict[int, list[tuple[tuple[int, int], PoseEstimate]]] = {}
    for w, est in hops.items():
        by_start.setdefault(w[0], []).append((w, est))
    pos = 0
    while pos < n - 1:
        here = sorted(by_start.get(pos, []), key=lambda h: h[0][1] - h[0][0], reverse=True)
        good = [h for h in here if h[1].pose_present]
        if good:
            out.append(good[0])
            pos = good[0][0][1]
            continue
        if here:  # the shortest hop from here, without a pose: the chain is cut there
            out.append(here[-1])
            pos = here[-1][0][1]
        else:
            pos += 1
    return out


def _compose_run(run: Sequence[PoseEstimate]) -> tuple[np.ndarray, float]:
    """(T_first_last (4, 4), t_inf) of an unbroken run of present hop poses."""
    T = np.eye(4)
    bound = 0.0
    for est in run:
        assert est.T_cam0_camT is not None and est.t_inf is not None
        T = T @ est.T_cam0_camT
        if est.method == "rotation":
            bound = max(bound, est.t_inf)
    return T, max(float(np.abs(T[:3, 3]).max()), bound)


def compose_chain(
    hops: Sequence[tuple[tuple[int, int], PoseEstimate]], n: int, first_last: PoseEstimate, *, min_share: float
) -> PoseEstimate | None:
    """The clip's pose composed from its hop poses (see the module text), or None when the hops
    with a pose span less than ``min_share`` of the clip's ``n - 1`` frame steps. ``first_last``
    is the failed first-last estimate whose reason the result's note keeps. With a broken chain,
    ``T_cam0_camT`` is the relative pose across the chosen run (not first to last frame)."""
    if not hops or n < 2:
        return None
    present = [(w, e) for w, e in hops if e.pose_present]
    spanned = sum(e - s for (s, e), _ in present)
    if not present or spanned < min_share * (n - 1):
        return None
    runs: list[list[PoseEstimate]] = [[]]
    for _, est in hops:
        if est.pose_present:
            runs[-1].append(est)
        elif runs[-1]:
            runs.append([])
    composed = [_compose_run(r) for r in runs if r]
    T, t_inf = max(composed, key=lambda c: c[1])
    whole = len(present) == len(hops)
    note = (
        f"first-last pose failed ({first_last.reason}); "
        + (f"composed from {len(hops)} hops" if whole else f"largest unbroken run of {len(present)}/{len(hops)} hops")
        + f" spanning {spanned} of {n - 1} frame steps"
    )
    ests = [e for _, e in present]
    zoom = float(np.prod([e.zoom for e in ests]))
    if abs(np.log(zoom)) >= ZOOM_NOTE_LOG:
        note += f"; the camera zooms x{zoom:.2f} (a focal change, not a translation)"
    return PoseEstimate(
        pose_present=True,
        t_inf=t_inf,
        T_cam0_camT=T,
        method="chain",
        reason=None,
        n_matches=int(sum(e.n_matches for e in ests)),
        n_inliers=int(sum(e.n_inliers for e in ests)),
        rotation_deg=rotation_angle_deg(T[:3, :3]),
        parallax_px=None,
        focal_px=first_last.focal_px,
        note=note,
        zoom=zoom,
    )
