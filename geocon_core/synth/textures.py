"""Procedural textures for synthetic planes: multi-octave value noise plus drawn shapes, rich
in corners and blobs at several scales so that feature matchers find plenty of
correspondences. Every texture is a pure function of its random generator."""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["procedural_texture", "shape_alpha", "object_texture"]


def _value_noise(rng: np.random.Generator, height: int, width: int, cells: int) -> np.ndarray:
    """Smooth noise in [0, 1], (height, width, 3), with about ``cells`` cells along the longer side."""
    gw = max(2, round(cells * width / max(width, height)))
    gh = max(2, round(cells * height / max(width, height)))
    grid = rng.random((gh, gw, 3)).astype(np.float32)
    return cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)


def procedural_texture(rng: np.random.Generator, height: int, width: int, *, contrast: float = 1.0) -> np.ndarray:
    """A textured RGB image, (height, width, 3) uint8.

    ``contrast`` scales the deviation from the mean colour: 1 is a richly textured surface,
    values near 0.05 make the low-texture surfaces of the stress family.
    """
    if height < 1 or width < 1:
        raise ValueError(f"texture size must be positive, got {width}x{height}")
    base = rng.uniform(0.25, 0.75, size=3).astype(np.float32)
    img = np.zeros((height, width, 3), np.float32)
    longest = max(height, width)
    weight_sum = 0.0
    for cells, weight in ((4, 0.5), (longest / 48, 0.35), (longest / 12, 0.25), (longest / 4, 0.15)):
        img += weight * (_value_noise(rng, height, width, max(2, int(cells))) - 0.5)
        weight_sum += weight
    img = img / weight_sum * 0.9
    canvas = np.clip(img + base, 0.0, 1.0)
    canvas = (canvas * 255).astype(np.uint8)

    # Shapes: circles, rectangles, strokes of random colour and size (3..40 texels).
    n_shapes = int(width * height / 350)
    kinds = rng.integers(0, 3, n_shapes)
    centers = rng.uniform(0, 1, (n_shapes, 2)) * (width, height)
    sizes = np.exp(rng.uniform(math.log(3), math.log(40), n_shapes))
    colours = rng.integers(0, 256, (n_shapes, 3))
    angles = rng.uniform(0, 2 * math.pi, n_shapes)
    for kind, (cx, cy), size, colour, ang in zip(kinds, centers, sizes, colours, angles, strict=True):
        c = tuple(int(v) for v in colour)
        p = (int(cx), int(cy))
        if kind == 0:
            cv2.circle(canvas, p, max(1, int(size / 2)), c, -1, cv2.LINE_AA)
        elif kind == 1:
            d = int(size / 2)
            cv2.rectangle(canvas, (p[0] - d, p[1] - d // 2), (p[0] + d, p[1] + d // 2), c, -1, cv2.LINE_AA)
        else:
            q = (int(cx + size * math.cos(ang)), int(cy + size * math.sin(ang)))
            cv2.line(canvas, p, q, c, max(1, int(size / 10)), cv2.LINE_AA)

    out = canvas.astype(np.float32)
    if contrast != 1.0:
        mean = out.reshape(-1, 3).mean(axis=0)
        out = mean + contrast * (out - mean)
    out = cv2.GaussianBlur(out, (0, 0), 0.6)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def shape_alpha(height: int, width: int, shape: str) -> np.ndarray:
    """Opacity mask (height, width) uint8 (255 = opaque) for an object's silhouette:
    ``"disc"`` (inscribed ellipse), ``"card"`` (rounded rectangle) or ``"rect"`` (full)."""
    alpha = np.zeros((height, width), np.uint8)
    if shape == "rect":
        alpha[:] = 255
    elif shape == "disc":
        cv2.ellipse(
            alpha, (width // 2, height // 2), (width // 2 - 1, height // 2 - 1), 0, 0, 360, 255, -1, cv2.LINE_AA
        )
    elif shape == "card":
        r = max(2, min(height, width) // 5)
        cv2.rectangle(alpha, (r, 0), (width - 1 - r, height - 1), 255, -1)
        cv2.rectangle(alpha, (0, r), (width - 1, height - 1 - r), 255, -1)
        for cx, cy in ((r, r), (width - 1 - r, r), (r, height - 1 - r), (width - 1 - r, height - 1 - r)):
            cv2.circle(alpha, (cx, cy), r, 255, -1, cv2.LINE_AA)
    else:
        raise ValueError(f"unknown shape {shape!r}; valid: 'card', 'disc', 'rect'")
    return alpha


def object_texture(rng: np.random.Generator, alpha: np.ndarray) -> np.ndarray:
    """Texture for a moving object: a lighter, textured fill with a dark outline along its
    silhouette, so that objects stand out from the background for a human viewer."""
    h, w = alpha.shape
    tex = procedural_texture(rng, h, w).astype(np.float32)
    tex = 0.75 * tex + 0.25 * 255
    width = max(2, round(min(h, w) / 40))
    inner = cv2.erode(alpha, np.ones((2 * width + 1, 2 * width + 1), np.uint8))
    tex[(alpha >= 128) & (inner < 128)] = (25, 25, 35)
    return tex.astype(np.uint8)
