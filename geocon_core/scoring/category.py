"""Post-hoc scene family C1-C6 (SPEC section 5), decided from measured quantities.

The rule, in order (the first that fires wins):

1. **C6 stress** when the geometry cannot be measured well: no first-last pose, fewer than
   ``min_valid_share`` of the judgeable adjacent pairs (the smallest frame gap, not across
   duplicated frames or cuts) with a valid background fit at the largest scale (longer gaps and
   smaller scales are left out: a fast camera's pairs 8 frames apart share few matches, and a
   small clip's half-size image has few features, which says nothing of the scene), fewer than
   ``min_matches`` background correspondences per valid pair at the largest scale (low texture), or a
   translating camera whose background IR stays below ``stress_ir`` (thin structures and
   occlusions defeat every single model).
2. **Static camera** when the gate is H, the median background motion between adjacent frames
   is below ``static_motion_px`` and the first-last rotation below ``static_rotation_deg``:
   **C4** if a moving object was tracked for at least ``min_object_frames`` frames, else **C1**.
3. **C2 rotation-dominant** when the gate is H (or U resolved to H).
4. **C5 complex** when the gate is F and the camera also rotates by at least
   ``complex_rotation_deg`` between the first and last frame; otherwise **C3
   translation-dominant**.

The thresholds are the fields of :class:`~geocon_core.config.stages.CategoryConfig`
(``ScoreConfig.category``).

Every input is logged with the label so that the decision can be audited and re-derived.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import CategoryConfig
from ..record import Category, ClipRecord

__all__ = ["categorize", "categorize_record"]


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
    config: CategoryConfig | None = None,
) -> Category:
    """The category with its inputs and the rule that fired (see the module docstring);
    ``config`` holds the thresholds (defaults when None)."""
    c = config or CategoryConfig()
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
    if valid_share < c.min_valid_share:
        share = "half" if c.min_valid_share == 0.5 else f"{c.min_valid_share:.0%}"
        return Category("C6", f"stress: fewer than {share} of the background pairs are valid", inputs)
    if median_matches is not None and median_matches < c.min_matches:
        return Category("C6", f"stress: fewer than {c.min_matches} background matches per pair (low texture)", inputs)
    if gate_model == "F" and background_ir is not None and background_ir < c.stress_ir:
        return Category("C6", f"stress: translating camera and background IR below {c.stress_ir}", inputs)
    has_objects = any(n >= c.min_object_frames for n in object_frames)
    if gate_model == "H" and (background_motion_px or 0.0) < c.static_motion_px and rot < c.static_rotation_deg:
        if has_objects:
            return Category("C4", "static camera with moving objects", inputs)
        return Category("C1", "static camera, no moving objects", inputs)
    if gate_model == "H":
        return Category("C2", "rotation-dominant camera (H gate, moving background)", inputs)
    if rot >= c.complex_rotation_deg:
        return Category("C5", f"translation with rotation >= {c.complex_rotation_deg} deg", inputs)
    return Category("C3", "translation-dominant camera", inputs)


def categorize_record(record: ClipRecord, object_frames: list[int]) -> Category:
    """:func:`categorize` with its inputs measured from a scored record: the gate and first-last
    pose, the background IR, the share of the judgeable adjacent pairs of the largest scale whose
    fit of the chosen family is valid, and over those whose H fit is valid the median displacement
    of the H inliers (``background_motion_px``) and the median number of matches;
    ``object_frames`` is the number of frames each object was seen."""
    s_max = max(record.config.scales)
    base = min(record.config.gaps)
    adjacent = [p for p in record.pairs if p.gap == base and p.scale == s_max and p.skip is None]
    fits = [p.fit(record.background.model) for p in adjacent]
    valid = sum(1 for fit in fits if fit is not None and fit.valid)
    motions, matches = [], []
    for p in adjacent:
        if p.h is None or not p.h.valid:
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
        rotation_deg=record.gate.pose.rotation_deg,
        background_motion_px=float(np.median(motions)) if motions else None,
        valid_share=valid / len(adjacent) if adjacent else 0.0,
        median_matches=float(np.median(matches)) if matches else None,
        background_ir=bg.ir,
        object_frames=object_frames,
        config=record.config.category,
    )
