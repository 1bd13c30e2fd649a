"""Region-by-region readings over long baselines (:func:`read_regions`).

Every pair of keyframes (a, b) at least ``min_baseline`` frames apart is read. The clip's one
camera between them is fitted to the background tracks alive at both (a homography; where it
leaves too many tracks unexplained, the camera translates and a fundamental matrix is fitted
instead). Each track's residual against that camera is a vector: the full ``x_b - H x_a``, or for
F its signed distance to its epipolar line along the line's normal. A track is a mover where an
object mask covers it or where its own motion against the camera exceeds ``mover_speed_px`` per
frame between two keyframes (nothing in a real scene that slow moves far over a clip); movers
are left out of the background readings and read on their own.

A region is a track's neighbourhood: the tracks within ``radius`` (share of the frame diagonal)
at frame a, at least ``min_region_tracks`` of them. Readings, each the largest over regions and
pairs, in px of the working canvas:

- ``drift``: the region's median residual length (its tracks move against the camera: together,
  a slide, or each its own way, a melt), minus the frame's median of the same; its direction is
  that of the region's median residual;
- ``deformation``: on a mover, the same around the mover's own best homography (a body that
  does not move as one rigid or planar thing);
- ``appearance``: the region's median patch change ``1 - NCC`` against each track's patch at
  birth, minus the frame's median (a patch redrawn), with the share of its tracks lost;
- ``breathing``: the spread of the regions' median residuals over the frame (90th percentile
  of their lengths), the residual field of a warp that covers everything.

A reading whose evidence is too thin (fewer than ``min_tracks`` background tracks over any long
baseline) is None: "cannot judge", never "consistent".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..config import RegionsConfig
from .tracks import ClipTracks

__all__ = ["RegionFinding", "RegionReadings", "read_regions", "READING_NAMES"]

READING_NAMES: tuple[str, ...] = ("drift", "deformation", "appearance", "breathing")
"""The region readings, in the order the record and the viewers list them."""


@dataclass(frozen=True)
class RegionFinding:
    """Where one reading is largest: ``reading`` (:data:`READING_NAMES`), ``value`` (its size),
    the pair ``(first, last)`` of frames, the region's ``outline`` at the first frame (convex
    hull, (x, y) working px), its ``centre``, ``direction`` (unit (dx, dy); drift only),
    ``course``: (frame, value) over the later keyframes from ``first``, ``tracks`` in the region,
    ``object`` (the mover's id, 0 on the background), ``fires`` whether it reaches its threshold."""

    reading: str
    value: float
    first: int
    last: int
    outline: tuple[tuple[float, float], ...]
    centre: tuple[float, float]
    direction: tuple[float, float] | None
    course: tuple[tuple[int, float], ...]
    tracks: int
    object: int = 0
    fires: bool = False

    def describe(self) -> str:
        where = f"around ({self.centre[0]:.0f}, {self.centre[1]:.0f}) px"
        what = {
            "drift": f"moves {self.value:.1f} px against the camera",
            "deformation": f"deforms {self.value:.1f} px beyond its own best motion",
            "appearance": f"changes its look by {self.value:.2f} (1 - NCC) beyond the frame's",
            "breathing": f"the frame's residual field spreads {self.value:.1f} px",
        }[self.reading]
        on = "the background" if self.object == 0 else f"object {self.object}"
        return f"a region of {on} {where} {what} from frame {self.first} to {self.last} ({self.tracks} tracks)"

    def to_dict(self) -> dict[str, Any]:
        return {
            "reading": self.reading,
            "value": self.value,
            "first": self.first,
            "last": self.last,
            "outline": [list(p) for p in self.outline],
            "centre": list(self.centre),
            "direction": None if self.direction is None else list(self.direction),
            "course": [list(c) for c in self.course],
            "tracks": self.tracks,
            "object": self.object,
            "fires": self.fires,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RegionFinding":
        return cls(
            reading=str(d["reading"]),
            value=float(d["value"]),
            first=int(d["first"]),
            last=int(d["last"]),
            outline=tuple((float(x), float(y)) for x, y in d["outline"]),
            centre=(float(d["centre"][0]), float(d["centre"][1])),
            direction=None if d.get("direction") is None else (float(d["direction"][0]), float(d["direction"][1])),
            course=tuple((int(f), float(v)) for f, v in d["course"]),
            tracks=int(d["tracks"]),
            object=int(d.get("object", 0)),
            fires=bool(d.get("fires", False)),
        )


@dataclass(frozen=True)
class RegionReadings:
    """The readings of one clip: each of :data:`READING_NAMES` (None: cannot judge), the
    finding where each is largest, why a reading cannot judge, the camera model of each pair
    read (``models``: ``H`` or ``F`` counts), the tracks read and the share of the frame they
    cover (``coverage``)."""

    values: dict[str, float | None]
    findings: tuple[RegionFinding, ...]
    reasons: dict[str, str] = field(default_factory=dict)
    models: dict[str, int] = field(default_factory=dict)
    tracks: int = 0
    coverage: float = 0.0

    @property
    def fired(self) -> tuple[RegionFinding, ...]:
        return tuple(f for f in self.findings if f.fires)

    def to_dict(self) -> dict[str, Any]:
        return {
            "values": dict(self.values),
            "findings": [f.to_dict() for f in self.findings],
            "reasons": dict(self.reasons),
            "models": dict(self.models),
            "tracks": self.tracks,
            "coverage": self.coverage,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RegionReadings":
        return cls(
            values={str(k): None if v is None else float(v) for k, v in d["values"].items()},
            findings=tuple(RegionFinding.from_dict(f) for f in d.get("findings", [])),
            reasons={str(k): str(v) for k, v in d.get("reasons", {}).items()},
            models={str(k): int(v) for k, v in d.get("models", {}).items()},
            tracks=int(d.get("tracks", 0)),
            coverage=float(d.get("coverage", 0.0)),
        )


@dataclass
class _Best:
    value: float = -math.inf
    finding: RegionFinding | None = None


def _fitted(fit: Any, *args: Any, **kwargs: Any) -> np.ndarray | None:
    """The model of an OpenCV robust fit (``fit(*args, **kwargs)`` returns (model, mask)), or None
    where there is none: OpenCV's USAC asserts on some degenerate track sets instead of returning
    no model, and one such pair of keyframes must read as "no camera", not end the clip's scoring."""
    try:
        model, _ = fit(*args, **kwargs)
    except cv2.error:
        return None
    return None if model is None or getattr(model, "size", 0) == 0 else model


def _camera(
    pa: np.ndarray, pb: np.ndarray, cfg: RegionsConfig, seed: int, *, h_only: bool = False, model: str | None = None
) -> tuple[str, np.ndarray] | None:
    """(``H`` or ``F``, the (N, 2) residual vectors) of the camera fitted to the background tracks;
    ``h_only``: the homography whatever it explains; ``model``: the family the clip's gate chose
    (None: the homography where it explains ``h_share`` of the tracks, else F)."""
    if model == "H":
        h_only = True
    cv2.setRNGSeed(seed)
    H = None
    if model != "F":
        H = _fitted(
            cv2.findHomography, pa, pb, cv2.USAC_MAGSAC, cfg.ransac_px, maxIters=cfg.ransac_iterations, confidence=0.999
        )
    if H is not None:
        proj = cv2.perspectiveTransform(pa.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
        r = pb - proj
        share = float(np.mean(np.linalg.norm(r, axis=1) <= cfg.ransac_px))
        if share >= cfg.h_share or h_only:
            return "H", r
    if len(pa) < 16 or h_only:
        return None
    F = _fitted(cv2.findFundamentalMat, pa, pb, cv2.USAC_MAGSAC, cfg.ransac_px, 0.999, cfg.ransac_iterations)
    if F is None or F.shape != (3, 3):
        return None
    ones = np.ones((len(pa), 1))
    lines = np.hstack([pa, ones]) @ F.T  # epipolar lines in b
    norm = np.hypot(lines[:, 0], lines[:, 1])
    norm = np.where(norm > 1e-12, norm, 1e-12)
    d = (np.hstack([pb, ones]) * lines).sum(axis=1) / norm
    nvec = lines[:, :2] / norm[:, None]
    return "F", d[:, None] * nvec


def _neighbours(pts: np.ndarray, radius: float, k_min: int) -> list[np.ndarray]:
    """For each point, the indices of the points within ``radius`` (itself included), or an empty
    array where there are fewer than ``k_min``."""
    if len(pts) == 0:
        return []
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2)
    out = []
    r2 = radius * radius
    for row in d2:
        idx = np.flatnonzero(row <= r2)
        out.append(idx if len(idx) >= k_min else idx[:0])
    return out


def _hull(pts: np.ndarray) -> tuple[tuple[float, float], ...]:
    if len(pts) < 3:
        return tuple((float(x), float(y)) for x, y in pts)
    h = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
    return tuple((round(float(x), 1), round(float(y), 1)) for x, y in h)


def _mover_tracks(tr: ClipTracks, cfg: RegionsConfig, seed: int) -> np.ndarray:
    """(N,) bool: tracks that move on their own, by mask or by speed against the camera between
    neighbouring keyframes (a homography: over a few frames parallax is small, and a fundamental
    matrix would let a track run along its epipolar line unseen)."""
    alive = tr.alive()
    mover: np.ndarray = np.asarray((tr.label > 0).any(axis=1), bool)
    for k in range(len(tr.frames) - 1):
        both = alive[:, k] & alive[:, k + 1] & ~(tr.label[:, k] > 0) & ~(tr.label[:, k + 1] > 0)
        idx = np.flatnonzero(both)
        if len(idx) < cfg.min_tracks:
            continue
        pa, pb = tr.xy[idx, k].astype(np.float64), tr.xy[idx, k + 1].astype(np.float64)
        cam = _camera(pa, pb, cfg, seed + k, h_only=True)
        if cam is None:
            continue
        _, r = cam
        gap = max(1, int(tr.frames[k + 1] - tr.frames[k]))
        fast = np.linalg.norm(r, axis=1) / gap > cfg.mover_speed_px
        mover[idx[fast]] = True
    return mover


def _pairs(tr: ClipTracks, cfg: RegionsConfig) -> list[tuple[int, int]]:
    """The keyframe index pairs (ka, kb) read: at least ``min_baseline`` frames apart."""
    K = len(tr.frames)
    return [(ka, kb) for ka in range(K) for kb in range(ka + 1, K) if tr.frames[kb] - tr.frames[ka] >= cfg.min_baseline]


def _local_median(values: np.ndarray, near: list[np.ndarray], k_min: int) -> np.ndarray:
    """Per point, the median of ``values`` (finite ones) over its neighbours; NaN where fewer than
    ``k_min`` are finite."""
    out = np.full(len(near), np.nan)
    for i, idx in enumerate(near):
        if len(idx):
            vals = values[idx]
            vals = vals[np.isfinite(vals)]
            if len(vals) >= k_min:
                out[i] = float(np.median(vals))
    return out


@dataclass
class _Pair:
    """One pair of keyframes read: its frames, background tracks ``bg`` (indices), their
    positions at the first, residual vectors ``r`` and neighbourhoods ``near``."""

    ka: int
    kb: int
    a: int
    b: int
    bg: np.ndarray
    pa: np.ndarray
    r: np.ndarray
    near: list[np.ndarray]

    def finding(self, reading: str, value: float, i: int | None, direction=None) -> RegionFinding:
        """The finding of ``reading`` at track ``i``'s region (None: the whole frame)."""
        idx = np.arange(len(self.bg)) if i is None else self.near[i]
        pts = self.pa[idx]
        centre = (float(pts[:, 0].mean()), float(pts[:, 1].mean()))
        return RegionFinding(
            reading, value, self.a, self.b, _hull(pts), centre, direction, ((self.b, value),), len(idx)
        )


def _drift(p: _Pair, cfg: RegionsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(each region's median residual length minus the frame's median, each region's median
    residual vector, each region's median residual length), or None when too few regions are read."""
    lengths = np.linalg.norm(p.r, axis=1)
    length = _local_median(lengths, p.near, cfg.min_region_tracks)
    ok = np.isfinite(length)
    if ok.sum() < cfg.min_region_tracks:
        return None
    vectors = np.full((len(p.bg), 2), np.nan)
    for i, idx in enumerate(p.near):
        if ok[i]:
            vectors[i] = np.median(p.r[idx], axis=0)
    return np.where(ok, length - float(np.median(length[ok])), -np.inf), vectors, length


def _appearance(p: _Pair, tr: ClipTracks, cfg: RegionsConfig) -> np.ndarray | None:
    """Each region's median patch change at the pair's last keyframe minus the frame's median."""
    change = _local_median(1.0 - tr.ncc[p.bg, p.kb].astype(np.float64), p.near, cfg.min_region_tracks)
    ok = np.isfinite(change)
    if ok.sum() < cfg.min_region_tracks:
        return None
    return np.where(ok, change - float(np.median(change[ok])), -np.inf)


def read_regions(tr: ClipTracks, cfg: RegionsConfig, seed: int = 0, camera: str | None = None) -> RegionReadings:
    """The region readings of one clip's tracks (:class:`RegionReadings`); ``camera``: the model
    family the clip's translation gate chose (``H`` or ``F``), else chosen pair by pair (a
    homography where it explains ``h_share`` of the background tracks)."""
    radius = cfg.radius * math.hypot(*tr.size)
    alive = tr.alive()
    mover = _mover_tracks(tr, cfg, seed)
    best = {name: _Best() for name in READING_NAMES}
    models = {"H": 0, "F": 0}
    used = np.zeros(len(tr), bool)
    fields: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    drift_at: tuple[int, np.ndarray] | None = None
    for ka, kb in _pairs(tr, cfg):
        bg = np.flatnonzero(alive[:, ka] & alive[:, kb] & ~mover)
        if len(bg) < cfg.min_tracks:
            continue
        pa, pb = tr.xy[bg, ka].astype(np.float64), tr.xy[bg, kb].astype(np.float64)
        cam = _camera(pa, pb, cfg, seed + 1000 * ka + kb, model=camera)
        if cam is None:
            continue
        models[cam[0]] += 1
        used[bg] = True
        p = _Pair(
            ka,
            kb,
            int(tr.frames[ka]),
            int(tr.frames[kb]),
            bg,
            pa,
            cam[1],
            _neighbours(pa, radius, cfg.min_region_tracks),
        )
        drift = _drift(p, cfg)
        if drift is not None:
            excess, vectors, length = drift
            fields[(ka, kb)] = (bg, excess)
            i = int(np.argmax(excess))
            if excess[i] > best["drift"].value:
                d = vectors[i] / max(1e-9, float(np.linalg.norm(vectors[i])))
                best["drift"] = _Best(
                    float(excess[i]), p.finding("drift", float(excess[i]), i, (float(d[0]), float(d[1])))
                )
                drift_at = (ka, bg[p.near[i]])
            spread = float(np.percentile(length[np.isfinite(length)], 90))
            if spread > best["breathing"].value:
                best["breathing"] = _Best(spread, p.finding("breathing", spread, None))
        change = _appearance(p, tr, cfg)
        if change is not None:
            j = int(np.argmax(change))
            if change[j] > best["appearance"].value:
                best["appearance"] = _Best(float(change[j]), p.finding("appearance", float(change[j]), j))
    if best["drift"].finding is not None and drift_at is not None:
        best["drift"].finding = _with_course(best["drift"].finding, drift_at, fields, tr)
    _movers(tr, cfg, mover, best, radius, seed)
    values, findings, reasons = _results(best, cfg)
    return RegionReadings(values, findings, reasons, models, int(used.sum()), _coverage(tr, used))


def _results(
    best: dict[str, _Best], cfg: RegionsConfig
) -> tuple[dict[str, float | None], tuple[RegionFinding, ...], dict[str, str]]:
    """Each reading's value, finding (with whether it fires) and, where it cannot judge, why."""
    thresholds = {
        "drift": cfg.drift_px,
        "deformation": cfg.deformation_px,
        "appearance": cfg.appearance_change,
        "breathing": cfg.breathing_px,
    }
    values: dict[str, float | None] = {}
    reasons: dict[str, str] = {}
    findings = []
    for name in READING_NAMES:
        f = best[name].finding
        if f is None:
            values[name] = None
            reasons[name] = (
                "no mover with enough long tracks"
                if name == "deformation"
                else f"fewer than {cfg.min_tracks} background tracks over {cfg.min_baseline} frames or more"
            )
            continue
        value = round(float(best[name].value), 4)
        values[name] = value
        findings.append(
            RegionFinding(
                f.reading,
                value,
                f.first,
                f.last,
                f.outline,
                f.centre,
                f.direction,
                f.course,
                f.tracks,
                f.object,
                bool(value >= thresholds[name]),
            )  # fmt: skip
        )
    return values, tuple(findings), reasons


def _movers(
    tr: ClipTracks, cfg: RegionsConfig, mover: np.ndarray, best: dict[str, _Best], radius: float, seed: int
) -> None:
    """The deformation reading: each mover (a connected group of mover tracks at the first frame
    of a pair) around its own best homography."""
    alive = tr.alive()
    K = len(tr.frames)
    for ka in range(K):
        for kb in range(ka + 1, K):
            a, b = int(tr.frames[ka]), int(tr.frames[kb])
            if b - a < cfg.min_baseline:
                continue
            idx = np.flatnonzero(alive[:, ka] & alive[:, kb] & mover)
            if len(idx) < cfg.min_tracks:
                continue
            labels = tr.label[idx, ka]
            for obj in np.unique(labels):
                sel = idx[labels == obj]
                if len(sel) < cfg.min_tracks:
                    continue
                pa, pb = tr.xy[sel, ka].astype(np.float64), tr.xy[sel, kb].astype(np.float64)
                cv2.setRNGSeed(seed + 7 * ka + kb)
                Hm = _fitted(cv2.findHomography, pa, pb, cv2.USAC_MAGSAC, cfg.ransac_px, maxIters=cfg.ransac_iterations)
                if Hm is None:
                    continue
                r = pb - cv2.perspectiveTransform(pa.reshape(-1, 1, 2), Hm).reshape(-1, 2)
                near = _neighbours(pa, radius * cfg.mover_radius_share, cfg.min_region_tracks)
                length = np.array([np.linalg.norm(np.median(r[n], axis=0)) if len(n) else np.nan for n in near])
                ok = np.isfinite(length)
                if not ok.any():
                    continue
                i = int(np.nanargmax(length))
                v = float(length[i])
                if v > best["deformation"].value:
                    n = near[i]
                    best["deformation"] = _Best(
                        v,
                        RegionFinding("deformation", v, a, b, _hull(pa[n]),
                                      (float(pa[n, 0].mean()), float(pa[n, 1].mean())), None, ((b, v),), len(n),
                                      int(obj)),
                    )  # fmt: skip


def _with_course(
    f: RegionFinding,
    at: tuple[int, np.ndarray],
    fields: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    tr: ClipTracks,
) -> RegionFinding:
    """The drift finding with its course: the region's excess at every keyframe read from its first."""
    ka, ids = at
    course = []
    for (k0, kb), (bg, excess) in sorted(fields.items()):
        if k0 != ka:
            continue
        sel = np.isin(bg, ids) & np.isfinite(excess)
        if sel.sum():
            course.append((int(tr.frames[kb]), round(float(np.median(excess[sel])), 4)))
    return RegionFinding(f.reading, f.value, f.first, f.last, f.outline, f.centre, f.direction, tuple(course), f.tracks)


def _coverage(tr: ClipTracks, used: np.ndarray, cells: int = 8) -> float:
    """Share of an ``cells`` x ``cells`` grid over the frame holding a track read."""
    if not used.any():
        return 0.0
    W, H = tr.size
    first = np.argmax(tr.alive()[used], axis=1)
    pts = tr.xy[used][np.arange(int(used.sum())), first]
    cx = np.clip((pts[:, 0] / W * cells).astype(int), 0, cells - 1)
    cy = np.clip((pts[:, 1] / H * cells).astype(int), 0, cells - 1)
    return round(len(set(zip(cx.tolist(), cy.tolist(), strict=True))) / (cells * cells), 4)
