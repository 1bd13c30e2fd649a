"""Object regions of one frame's motion score map (step 4 of
:class:`~geocon_core.masks.MotionSegmenter`): a local half-maximum boundary, morphology, and
connected components kept when they are compact and sharply bounded."""

from __future__ import annotations

import cv2
import numpy as np

from ..config import MotionConfig

__all__ = ["RegionFinder"]

_ELLIPSE3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
_ELLIPSE5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_ELLIPSE13 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))


class RegionFinder:
    """Accepted object regions of score maps on a reduced canvas of ``area`` pixels."""

    def __init__(self, config: MotionConfig, area: int) -> None:
        self.config = config
        self._halo_kernel = cv2.getStructuringElement(
            cv2.MORPH_ELLIPSE, (2 * config.halo_px + 1, 2 * config.halo_px + 1)
        )
        self._min_area_px = max(16, round(config.min_area * area))
        self._max_area_px = config.max_area * area

    def objects(self, score: np.ndarray) -> list[np.ndarray]:
        """Accepted object masks ((rh, rw) bool) of one frame's score map, in raster order of
        their first pixel.

        Flow is smoothed across object edges, so the residual falls off gradually around an
        object (a halo of a few pixels). A pixel is kept only where its score reaches
        ``refine`` of the highest score within ``halo_px`` (a local half-maximum boundary):
        this trims the halo and separates objects whose halos touch, while a smooth change of
        score inside an object (a turning card) keeps the object whole."""
        level = cv2.dilate(score, self._halo_kernel)
        keep = (score >= 1.0) & (score >= self.config.refine * level)
        binary = cv2.morphologyEx(keep.astype(np.uint8), cv2.MORPH_OPEN, _ELLIPSE3)
        binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, _ELLIPSE5)
        binary[(score >= 1.0) & ~keep] = 0  # closing fills holes, never a trimmed halo
        n, cc, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
        rh, rw = score.shape
        out: list[np.ndarray] = []
        pad = 8
        for k in range(1, n):
            area = int(stats[k, cv2.CC_STAT_AREA])
            if not self._min_area_px <= area <= self._max_area_px:
                continue
            x, y, bw, bh = (
                int(stats[k, i]) for i in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT)
            )
            X0, Y0, X1, Y1 = max(0, x - pad), max(0, y - pad), min(rw, x + bw + pad), min(rh, y + bh + pad)
            piece = cc[Y0:Y1, X0:X1] == k
            if self._accept(piece, score[Y0:Y1, X0:X1], area):
                full = np.zeros((rh, rw), bool)
                full[Y0:Y1, X0:X1] = piece
                out.append(full)
        return out

    def _accept(self, piece: np.ndarray, sc: np.ndarray, area: int) -> bool:
        """Compact (solidity, thickness) and sharply bounded (ring vs inside score)."""
        cfg = self.config
        m = piece.astype(np.uint8)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        hull = cv2.convexHull(np.concatenate(contours))
        if area / max(float(cv2.contourArea(hull)), 1.0) < cfg.min_solidity:
            return False
        core = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)
        if float(core.max()) < cfg.min_thickness:
            return False
        near = cv2.dilate(m, _ELLIPSE5)
        far = cv2.dilate(m, _ELLIPSE13)
        ring = (far > 0) & (near == 0)
        if np.count_nonzero(ring) < 8:
            return True
        return float(np.median(sc[ring])) <= cfg.edge_ratio * float(np.median(sc[piece]))
