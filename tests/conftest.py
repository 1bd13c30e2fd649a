"""Shared test helpers: decoding clips and matching features independently of the code under test."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def read_video(path: Path) -> list[np.ndarray]:
    """All frames of a video as RGB uint8 arrays (OpenCV's decoder, not GeoCon's)."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    ok, frame = cap.read()
    while ok:
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
        ok, frame = cap.read()
    cap.release()
    assert frames, f"could not decode {path}"
    return frames


def sift_matches(
    img1: np.ndarray, img2: np.ndarray, *, ratio: float = 0.7, mask1: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest-neighbour SIFT matches passing Lowe's ratio test: (N, 2) pixel arrays."""
    sift = cv2.SIFT_create(nfeatures=4000)
    g1, g2 = (cv2.cvtColor(i, cv2.COLOR_RGB2GRAY) for i in (img1, img2))
    m1 = None if mask1 is None else mask1.astype(np.uint8) * 255
    k1, d1 = sift.detectAndCompute(g1, m1)
    k2, d2 = sift.detectAndCompute(g2, None)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    fwd = matcher.knnMatch(d1, d2, k=2)
    bwd = {m.queryIdx: m.trainIdx for m in matcher.match(d2, d1)}
    pairs = [
        (m.queryIdx, m.trainIdx)
        for m, n in (p for p in fwd if len(p) == 2)
        if m.distance < ratio * n.distance and bwd.get(m.trainIdx) == m.queryIdx
    ]
    x1 = np.array([k1[i].pt for i, _ in pairs], dtype=float).reshape(-1, 2)
    x2 = np.array([k2[j].pt for _, j in pairs], dtype=float).reshape(-1, 2)
    return x1, x2


@pytest.fixture(scope="session")
def synth_dir(synth_clips) -> Path:
    """Clips rendered once per session (640x360, 24 frames, seed 3) by the public API."""
    from geocon_core.synth import ClipPlan

    plans = [
        ClipPlan("C1"),
        ClipPlan("C2"),
        ClipPlan("C3"),
        ClipPlan("C4"),
        ClipPlan("C1", "breathing", 3.0),
        ClipPlan("C5", "letterbox", 0.1),
    ]
    return synth_clips(plans, seed=3, width=640, height=360, num_frames=24)


def _score_clip():
    """The public scoring entry point (the package's top level where it exports it)."""
    try:
        from geocon_core import score_clip
    except ImportError:
        from geocon_core.scoring import score_clip
    return score_clip


@pytest.fixture(scope="session")
def synth_clips(tmp_path_factory: pytest.TempPathFactory):
    """``synth_clips(plans, seed=, width=, height=, num_frames=)`` -> folder holding those clips.

    One folder per (seed, size, length); each clip is rendered at most once per test session,
    however many modules ask for it, so modules that use the same settings share the files."""
    from geocon_core.synth import write_clip

    folders: dict[tuple[int, int, int, int], Path] = {}
    done: set[tuple] = set()

    def get(plans, *, seed: int = 0, width: int = 640, height: int = 360, num_frames: int = 48) -> Path:
        key = (seed, width, height, num_frames)
        if key not in folders:
            folders[key] = tmp_path_factory.mktemp(f"synth-s{seed}-{width}x{height}-{num_frames}")
        for plan in plans:
            if (key, plan) not in done:
                write_clip(plan, folders[key], seed=seed, width=width, height=height, num_frames=num_frames)
                done.add((key, plan))
        return folders[key]

    return get


@pytest.fixture(scope="session")
def scored_clip():
    """``scored_clip(path, config, masks=None)`` -> ClipRecord, scored once per session.

    For tests that only read a record: those scoring the same clip with the same configuration
    share one run. Tests about scoring itself (determinism, callbacks) call ``score_clip``."""
    score_clip = _score_clip()
    cache: dict[tuple, object] = {}

    def get(path: Path, config, masks: Path | None = None):
        key = (str(path), config, None if masks is None else str(masks))
        if key not in cache:
            cache[key] = score_clip(path, config, masks=masks)
        return cache[key]

    return get


def clip_info(**fields: object):
    """A :class:`~geocon_core.media.reader.ClipInfo` of a small clip without bars; ``fields`` override."""
    from geocon_core.media import ClipInfo

    base: dict[str, object] = dict(
        path="x.mp4",
        kind="video",
        source_size=(320, 180),
        fps=24.0,
        num_frames=4,
        working_size=(320, 180),
        scale=1.0,
        offset=(0, 0),
        bars=(0, 0, 0, 0),
        content_box=(0, 0, 320, 180),
    )
    return ClipInfo(**{**base, **fields})  # type: ignore[arg-type]
