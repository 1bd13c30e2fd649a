"""Post-hoc scene family C1-C6 (SPEC section 5), decided from measured quantities.

The rule, in order (the first that fires wins):

1. **C6 stress** when the geometry cannot be measured well: no first-last pose, fewer than
   half of the background (pair, scale) entries valid, fewer than ``MIN_MATCHES`` background
   correspondences per valid pair at the largest scale (low texture), or a translating camera
   whose background IR stays below ``STRESS_IR`` (thin structures and occlusions defeat every
   single model).
2. **Static camera** when the gate is H, the median background motion between adjacent frames
   is below ``STATIC_MOTION_PX`` and the first-last rotation below ``STATIC_ROTATION_DEG``:
   **C4** if a moving object was tracked for at least ``MIN_OBJECT_FRAMES`` frames, else **C1**.
3. **C2 rotation-dominant** when the gate is H (or U resolved to H).
4. **C5 complex** when the gate is F and the camera also rotates by at least
   ``COMPLEX_ROTATION_DEG`` between the first and last frame; otherwise **C3
   translation-dominant**.

Every input is logged with the label so that the decision can be audited and re-derived.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .record import Category, ClipRecord

__all__ = [
    "categorize",
    "categorize_record",
    "STATIC_MOTION_PX",
    "STATIC_ROTATION_DEG",
    "COMPLEX_ROTATION_DEG",
    "MIN_OBJECT_FRAMES",
    "MIN_MATCHES",
    "STRESS_IR",
]

STATIC_MOTION_PX = 0.5
"""Median background displacement between adjacent frames (working px, scale 1) below which
the camera counts as static."""
STATIC_ROTATION_DEG = 1.0
COMPLEX_ROTATION_DEG = 3.0
MIN_OBJECT_FRAMES = 3
MIN_MATCHES = 50
STRESS_IR = 0.8


def categorize(
    *,
    gate_model: str,
    pose_present: bool,
    t_inf: float | None,
    rotation_deg: float | None,
    background_motion_px: float | None,
    valid_share: float,
    median_matches: float | None,
    background_ir: float | None,
    object_frames: list[int],
) -> Category:
    """The category with its inputs and the rule that fired (see the module docstring)."""
    inputs: dict[str, Any] = {
        "gate_model": gate_model,
        "pose_present": pose_present,
        "t_inf": t_inf,
        "rotation_deg": rotation_deg,
        "background_motion_px": background_motion_px,
        "valid_share": valid_share,
        "median_matches": median_matches,
        "background_ir": background_ir,
        "object_frames": object_frames,
    }
    rot = rotation_deg or 0.0
    if not pose_present:
        return Category("C6", "stress: no first-last pose", inputs)
    if valid_share < 0.5:
        return Category("C6", "stress: fewer than half of the background pairs are valid", inputs)
    if median_matches is not None and median_matches < MIN_MATCHES:
        return Category("C6", f"stress: fewer than {MIN_MATCHES} background matches per pair (low texture)", inputs)
    if gate_model == "F" and background_ir is not None and background_ir < STRESS_IR:
        return Category("C6", f"stress: translating camera and background IR below {STRESS_IR}", inputs)
    has_objects = any(n >= MIN_OBJECT_FRAMES for n in object_frames)
    if gate_model == "H" and (background_motion_px or 0.0) < STATIC_MOTION_PX and rot < STATIC_ROTATION_DEG:
        if has_objects:
            return Category("C4", "static camera with moving objects", inputs)
        return Category("C1", "static camera, no moving objects", inputs)
    if gate_model == "H":
        return Category("C2", "rotation-dominant camera (H gate, moving background)", inputs)
    if rot >= COMPLEX_ROTATION_DEG:
        return Category("C5", f"translation with rotation >= {COMPLEX_ROTATION_DEG} deg", inputs)
    return Category("C3", "translation-dominant camera", inputs)


def categorize_record(record: ClipRecord, object_frames: list[int]) -> Category:
    """:func:`categorize` with its inputs measured from a scored record: the gate and first-last
    pose, the background's valid share and IR, and over the valid gap-1 pairs of the largest scale
    the median displacement of the H inliers (``background_motion_px``) and the median number of
    matches; ``object_frames`` is the number of frames each object was seen."""
    s_max = max(record.config.scales)
    motions, matches = [], []
    for p in record.pairs:
        if p.gap != 1 or p.scale != s_max or p.skip is not None or p.h is None or not p.h.valid:
            continue
        arr = record.matches.pair(p.index)
        inl = arr["h_inl"]
        motions.append(float(np.median(np.linalg.norm(arr["x2"][inl] - arr["x1"][inl], axis=1))))
        matches.append(p.n_matches)
    bg = record.background
    return categorize(
        gate_model=record.gate.model,
        pose_present=record.gate.pose_present,
        t_inf=record.gate.t_inf,
        rotation_deg=record.gate.pose.get("rotation_deg"),
        background_motion_px=float(np.median(motions)) if motions else None,
        valid_share=bg.valid_pairs / bg.total_pairs if bg.total_pairs else 0.0,
        median_matches=float(np.median(matches)) if matches else None,
        background_ir=bg.ir,
        object_frames=object_frames,
    )
