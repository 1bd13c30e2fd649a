"""One camera for the whole clip: long tracks, one bundle adjustment, and the layers that drift.

The paper's protocol fits one model per frame pair, and a background layer that drifts slowly
against the rest (the "sliding wallpaper" of generated walk-throughs) is a valid static scene
at another depth in any two views. Over the whole clip it is not: the clip must agree with one
camera path and one set of 3D points. The check, one stage a module:

1. :mod:`.tracks` follows corners through every frame with pyramidal Lucas-Kanade
   (:class:`~.tracks.LongTracks`, the object masks applied as for the pair fits) and keeps their
   positions at up to ``max_views`` evenly spread keyframes;
2. :mod:`.solve` and this module build one reconstruction (:func:`reconstruct`): for a clip
   the gate calls F, an essential matrix between the first keyframe and the farthest one that shares enough tracks, then
   every other keyframe by PnP, points triangulated as they become visible; for a clip the gate
   calls H, rotations (and a focal length per keyframe, so zooms are judged) chained from
   keyframe to keyframe, every point at infinity. Both are refined by **pycolmap's bundle
   adjuster** (Ceres; a Cauchy loss): poses, points and the focal length (shared and with one
   radial term for F; per keyframe for H, whose camera centres stay at one point through a
   pose prior);
3. this module measures each track's reprojection residual over its life (source px), the share of tracks
   consistent with the reconstruction (MV-IR, residual at most ``tau_px``) and their median
   residual (MV-GE), and groups the inconsistent tracks into spatially coherent layers whose
   residuals drift the same way (:class:`~.result.DriftLayer`: "this region drifts ~N px against
   the camera path between frames a and b"), reported as a :class:`~.result.MultiViewResult`
   (:mod:`.result`).

A reconstruction that leaves most tracks inconsistent, registers too few keyframes or has too
few tracks cannot judge the clip (``MultiViewResult.reason``); it never flags one.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..config import MultiViewConfig
from .result import ARRAY_NAMES, DriftLayer, MultiViewResult
from .solve import (
    ba_subset,
    bundle_adjust,
    far_directions,
    init_general,
    init_rotation,
    project,
    triangulated,
    undistort,
    with_focal,
)
from .tracks import LongTracks, TrackObservations, TrackTable, keyframes

__all__ = [
    "ARRAY_NAMES",
    "LongTracks",
    "TrackObservations",
    "DriftLayer",
    "MultiViewResult",
    "keyframes",
    "reconstruct",
]


def reconstruct(
    obs: TrackObservations,
    K: np.ndarray,
    size: tuple[int, int],
    model: str,
    config: MultiViewConfig,
    *,
    px_scale: float = 1.0,
    seed: int = 0,
) -> MultiViewResult:
    """One reconstruction of the tracks ``obs`` (working px, frame size ``size`` = (W, H), prior
    intrinsics ``K``) under ``model`` (the gate's ``F`` or ``H``), and what it measures.
    ``px_scale`` is working px per source px (residuals and drifts are reported in source px)."""
    cfg = config
    frames = tuple(obs.frames)
    table = TrackTable.of(obs, cfg.min_views)

    def cannot(reason: str, registered: tuple[int, ...] = ()) -> MultiViewResult:
        return MultiViewResult(model, frames, registered, None, None, 0, reason=reason)

    if len(frames) < cfg.min_views:
        return cannot(f"{len(frames)} keyframes, fewer than {cfg.min_views}")
    if len(table.ids) < cfg.min_tracks:
        return cannot(f"{len(table.ids)} tracks seen at {cfg.min_views} keyframes or more, fewer than {cfg.min_tracks}")
    loss_px = cfg.loss_px * px_scale
    need = max(cfg.min_views, math.ceil(cfg.min_registered * len(frames)))
    if model == "H":
        rot, focal, keep = init_rotation(table, K, seed, cfg.min_init_tracks)
        if len(rot) < need:
            return cannot(f"{len(rot)} of {len(frames)} keyframes chained", tuple(frames[k] for k in sorted(rot)))
        poses = {k: np.c_[R, np.zeros(3)] for k, R in rot.items()}
        zoom = max(abs(f / float(K[0, 0]) - 1) for f in focal.values()) > cfg.zoom_share
        params = {k: np.array([focal[k] if zoom else float(K[0, 0]), K[0, 2], K[1, 2]]) for k in rot}
        for _ in range(cfg.rotation_rounds):  # alternate: cameras with the points held, then the points
            poses, params, pts, keep = _rotation_round(table, K, size, poses, params, keep, zoom, cfg, px_scale)
        result = _measure(table, poses, pts, params, model, cfg, px_scale)
        if result.layers:  # once more without the layers: the cameras judge them from the rest
            keep &= ~np.isin(table.ids, _layer_ids(result))
            poses, params, pts, _ = _rotation_round(table, K, size, poses, params, keep, zoom, cfg, px_scale)
            result = _measure(table, poses, pts, params, model, cfg, px_scale)
        return result
    init = init_general(table, K, cfg)
    if init is None:
        return cannot("no keyframe pair has the baseline to start a reconstruction")
    poses, points = init
    if len(poses) < need:
        return cannot(f"{len(poses)} of {len(frames)} keyframes registered", tuple(frames[k] for k in sorted(poses)))
    rows = ba_subset(table, sorted(points), cfg.ba_tracks, size)
    poses, sub, params = bundle_adjust(table, K, size, poses, {r: points[r] for r in rows}, cfg, loss_px)
    # the tracks that agree with the first adjustment make the second (a drifting layer is
    # left out of the cameras that judge it), which may refine the intrinsics
    X = _stack({**points, **sub}, len(table.ids))
    rms = _rms(table, poses, params, X, px_scale)
    keep = rms <= min(cfg.tau_px, cfg.keep_factor * float(np.median(rms[np.isfinite(rms)])))
    rows = ba_subset(table, [r for r in sorted(points) if keep[r]], cfg.ba_tracks, size)
    poses, sub, params = bundle_adjust(table, K, size, poses, {r: sub.get(r, points[r]) for r in rows}, cfg, loss_px)
    if cfg.refine_intrinsics:  # kept only where the clip pins them down (see MultiViewConfig)
        refined = bundle_adjust(table, K, size, poses, sub, cfg, loss_px, refine_intrinsics=True)
        f = float(next(iter(refined[2].values()))[0]) / float(K[0, 0])
        before, after = (
            float(np.median(_rms(table, p, c, _stack(pts, len(table.ids)), px_scale)[rows]))
            for p, pts, c in ((poses, sub, params), refined)
        )
        if 1 / cfg.max_focal_ratio <= f <= cfg.max_focal_ratio and after <= (1 - cfg.refine_gain) * before:
            poses, sub, params = refined
    result = _measure(table, poses, _all_points(table, K, poses, params, sub), params, model, cfg, px_scale)
    if result.layers:  # once more without the layers: the cameras judge them from the rest
        out = np.isin(table.ids, _layer_ids(result))
        rows = [r for r in rows if not out[r]]
        poses, sub, params = bundle_adjust(
            table, K, size, poses, {r: sub[r] for r in rows if r in sub}, cfg, loss_px, k1=_k1(params)
        )
        result = _measure(table, poses, _all_points(table, K, poses, params, sub), params, model, cfg, px_scale)
    return result


def _k1(params: dict[int, np.ndarray]) -> float:
    cam = next(iter(params.values()))
    return float(cam[3]) if len(cam) > 3 else 0.0


def _layer_ids(result: MultiViewResult) -> np.ndarray:
    """The ids of the tracks in any of ``result``'s layers."""
    if result.track_ids is None or result.layer_of is None:
        return np.zeros(0, np.int64)
    return result.track_ids[result.layer_of >= 0]


def _all_points(
    table: TrackTable,
    K: np.ndarray,
    poses: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    adjusted: dict[int, np.ndarray],
) -> dict[int, np.ndarray]:
    """Every track's point: the adjusted ones as adjusted, the others triangulated with the
    adjusted cameras (their pixels undistorted)."""
    cam = next(iter(params.values()))
    undistorted = TrackTable(table.frames, table.ids, undistort(table.xy, cam))
    pts = triangulated(undistorted, with_focal(K, float(cam[0])), poses, np.arange(len(table.ids)), 0.0, refine=True)
    pts.update(adjusted)
    return pts


def _rotation_round(
    table: TrackTable,
    K: np.ndarray,
    size: tuple[int, int],
    poses: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    keep: np.ndarray,
    zoom: bool,
    cfg: MultiViewConfig,
    px_scale: float,
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], dict[int, np.ndarray], np.ndarray]:
    """One round of the rotation-only model: the cameras adjusted to the far points of the
    ``keep`` tracks (held), then every point again from its rays. Returns the cameras, their
    parameters, the points and the tracks to keep in the next round."""
    far = far_directions(table, poses, params, K)
    rows = ba_subset(table, [int(r) for r in np.flatnonzero(keep & np.isfinite(far[:, 0]))], cfg.ba_tracks, size)
    focal = {k: float(p[0]) for k, p in params.items()} if zoom else None
    poses, _, params = bundle_adjust(
        table, K, size, poses, {r: far[r] for r in rows}, cfg, cfg.loss_px * px_scale, focal=focal, fixed_points=True
    )
    far = far_directions(table, poses, params, K)
    rms = _rms(table, poses, params, far, px_scale)
    keep = keep & (rms <= min(cfg.tau_px, cfg.keep_factor * float(np.median(rms[np.isfinite(rms)]))))
    pts = {int(r): far[r] for r in np.flatnonzero(np.isfinite(far[:, 0]))}
    return poses, params, pts, keep


def _stack(points: dict[int, np.ndarray], n: int) -> np.ndarray:
    """(n, 3) the points of rows ``points`` (NaN for the others)."""
    X = np.full((n, 3), np.nan)
    for r, x in points.items():
        X[r] = x
    return X


def _rms(
    table: TrackTable, poses: dict[int, np.ndarray], params: dict[int, np.ndarray], X: np.ndarray, px_scale: float
) -> np.ndarray:
    """(T,) RMS reprojection residual (source px) of each track's point ``X`` (T, 3) over the
    posed keyframes that see it; inf where it has no point."""
    seen = table.seen()
    sq = np.zeros(len(table.ids))
    count = np.zeros(len(table.ids))
    for k in poses:
        d = table.xy[:, k] - project(poses[k], params[k], np.nan_to_num(X))
        e = np.sum(d * d, axis=1)
        ok = seen[:, k] & np.isfinite(e)
        sq[ok] += e[ok]
        count[ok] += 1
    out = np.sqrt(sq / np.maximum(count, 1)) / px_scale
    out[(count < 2) | ~np.all(np.isfinite(X), axis=1)] = np.inf
    return out


def _measure(
    table: TrackTable,
    poses: dict[int, np.ndarray],
    points: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    model: str,
    cfg: MultiViewConfig,
    px_scale: float,
) -> MultiViewResult:
    frames = table.frames
    reg = sorted(poses)
    seen = table.seen()
    rows = [r for r in sorted(points) if sum(seen[r, k] for k in reg) >= cfg.min_views]
    nk = len(frames)
    err = np.full((len(rows), nk, 2), np.nan)
    X = np.array([points[r] for r in rows]) if rows else np.zeros((0, 3))
    for k in reg:
        proj = project(poses[k], params[k], X)
        err[:, k] = np.where(seen[rows, k][:, None], table.xy[rows, k] - proj, np.nan)
    err /= px_scale  # working -> source px
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rms = np.sqrt(np.nanmean(np.sum(err**2, axis=2), axis=1))
    good = np.isfinite(rms)
    rows = [r for r, g in zip(rows, good, strict=True) if g]
    err, rms, X = err[good], rms[good], X[good]
    registered = tuple(frames[k] for k in reg)
    focal_px = float(params[reg[0]][0]) if reg else None
    if len(rows) < cfg.min_tracks:
        return MultiViewResult(
            model,
            frames,
            registered,
            None,
            None,
            len(rows),
            reason=f"{len(rows)} tracks judged, fewer than {cfg.min_tracks}",
        )
    inlier = rms <= cfg.tau_px
    mv_ir, mv_ge = float(inlier.mean()), float(np.median(rms))
    # each track's middle keyframe position, and the drift of its residual: a line fitted to the
    # residual over the frames it was seen at (a drifting layer's tracks share its slope,
    # however long each of them lives)
    mid = np.zeros((len(rows), 2))
    mid_frame = np.zeros(len(rows), np.int64)
    slope = np.zeros((len(rows), 2))
    sig = np.zeros(len(rows), bool)
    span = np.zeros((len(rows), 2), int)
    fr = np.asarray(frames, dtype=float)
    for i, r in enumerate(rows):
        ks = [k for k in reg if seen[r, k]]
        mid[i] = table.xy[r, ks[len(ks) // 2]] / px_scale
        mid_frame[i] = frames[ks[len(ks) // 2]]
        span[i] = (frames[ks[0]], frames[ks[-1]])
        t = fr[ks] - fr[ks].mean()
        e = err[i, ks]
        tt = float(t @ t)
        if tt <= 0:
            continue
        slope[i] = t @ (e - e.mean(axis=0)) / tt
        fit = e.mean(axis=0) + t[:, None] * slope[i]
        dof = max(1, len(ks) - 2)
        stderr = math.sqrt(float(np.sum((e - fit) ** 2)) / (2 * dof) / tt)
        drift = float(np.linalg.norm(slope[i])) * (span[i, 1] - span[i, 0])
        sig[i] = drift >= cfg.track_drift_px and float(np.linalg.norm(slope[i])) >= cfg.slope_sigmas * stderr
    layers, layer_of = _layers(mid, slope, span, sig, cfg, table.ids[rows])
    floor = float(np.median(rms[layer_of < 0])) if np.any(layer_of < 0) else None
    reason = None
    if floor is not None and floor > cfg.max_floor_px:
        reason = (
            f"the tracks fit one camera path to within {floor:.2f} px only (median outside any layer; "
            f"more than {cfg.max_floor_px:g} px): a slow drift cannot be told from that noise"
        )
        layers, layer_of = (), np.full(len(rows), -1)
    elif 1 - mv_ir > cfg.max_outlier_share:
        reason = (
            f"{100 * (1 - mv_ir):.0f}% of the tracks disagree with the reconstruction "
            f"(more than {100 * cfg.max_outlier_share:.0f}%)"
        )
        layers, layer_of = (), np.full(len(rows), -1)
    return MultiViewResult(
        model,
        frames,
        registered,
        mv_ir,
        mv_ge,
        len(rows),
        layers,
        reason,
        focal_px,
        floor,
        np.stack([poses[k] for k in reg]),
        X / np.linalg.norm(X, axis=1, keepdims=True) if model == "H" else X,
        rms,
        table.ids[rows],
        mid,
        mid_frame,
        layer_of,
    )


def _layers(
    mid: np.ndarray,
    slope: np.ndarray,
    span: np.ndarray,
    drifting: np.ndarray,
    cfg: MultiViewConfig,
    ids: np.ndarray,
) -> tuple[tuple[DriftLayer, ...], np.ndarray]:
    """Group the drifting tracks into layers: neighbours closer than ``layer_radius`` of the
    tracks' extent whose drifts (``slope``, source px per frame) point the same way (cosine >=
    ``layer_cosine``) are joined; a group is a layer when it holds ``layer_min_tracks`` and
    ``layer_min_share`` of the tracks and its median slope carries it ``drift_px`` or more over
    the frames its tracks span."""
    n = len(mid)
    layer_of = np.full(n, -1)
    if drifting.sum() < cfg.layer_min_tracks:
        return (), layer_of
    extent = mid.max(axis=0) - mid.min(axis=0)
    radius = cfg.layer_radius * float(np.hypot(*extent))
    mag = np.linalg.norm(slope, axis=1)
    unit = slope / np.maximum(mag, 1e-12)[:, None]
    near = np.linalg.norm(mid[:, None] - mid[None], axis=2) <= radius
    np.fill_diagonal(near, False)
    agree = near & drifting[None, :] & drifting[:, None] & ((unit @ unit.T) >= cfg.layer_cosine)
    # a core track drifts with most of its neighbours (a region that slides, not stray tracks)
    core = drifting & (agree.sum(axis=1) >= np.maximum(3, cfg.layer_core_share * near.sum(axis=1)))
    idx = np.flatnonzero(core)
    parent = np.arange(len(idx))
    pos = {int(t): i for i, t in enumerate(idx)}
    d = slope[idx]
    p = mid[idx]
    mag = mag[idx]

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return int(i)

    for i, j in zip(*np.nonzero(np.triu(agree[np.ix_(idx, idx)], 1)), strict=True):
        ri, rj = root(int(i)), root(int(j))
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    members_of: dict[int, list[int]] = {}
    for i in range(len(idx)):
        members_of.setdefault(root(i), []).append(int(idx[i]))
    # a drifting track beside a core track of a layer joins it
    for t in np.flatnonzero(drifting & ~core):
        cores = [pos[int(j)] for j in np.flatnonzero(agree[t] & core)]
        if cores:
            members_of[root(cores[0])].append(int(t))
    idx = np.arange(n)
    d, p, mag = slope, mid, np.linalg.norm(slope, axis=1)
    groups = {g: m for g, m in members_of.items()}
    found = []
    for members in groups.values():
        m = np.asarray(members)
        if len(m) < cfg.layer_min_tracks or len(m) / n < cfg.layer_min_share:
            continue
        vec = np.median(d[m], axis=0)
        frames_spanned = int(span[idx[m], 1].max() - span[idx[m], 0].min())
        size = float(np.linalg.norm(vec)) * frames_spanned
        if size < cfg.drift_px:
            continue
        box = (*p[m].min(axis=0), *p[m].max(axis=0))
        found.append((len(m), m, vec, size, box))
    found.sort(key=lambda f: -f[0])
    layers = []
    for li, (count, m, vec, size, box) in enumerate(found):
        layer_of[idx[m]] = li
        direction = vec / max(1e-9, float(np.linalg.norm(vec)))
        layers.append(
            DriftLayer(
                count,
                count / n,
                size,
                (float(direction[0]), float(direction[1])),
                tuple(float(v) for v in box),  # type: ignore[arg-type]
                (int(span[idx[m], 0].min()), int(span[idx[m], 1].max())),
                tuple(int(v) for v in ids[idx[m]]),
            )
        )
    return tuple(layers), layer_of
