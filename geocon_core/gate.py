"""Translation gate: choosing the homography (H) or fundamental-matrix (F) model for the
background from ``t_inf`` (SPEC section 1)."""

from __future__ import annotations

from typing import Literal

__all__ = [
    "GateLabel",
    "TAU_T_BINARY",
    "TAU_T_LOW",
    "TAU_T_HIGH",
    "binary_gate",
    "hysteresis_gate",
    "gate_margin",
    "gate_decision",
]

GateLabel = Literal["H", "F", "U"]

TAU_T_BINARY = 0.04
"""Binary gate: F if ``t_inf > 0.04`` else H."""
TAU_T_LOW = 0.03
"""Hysteresis gate: H if ``t_inf <= 0.03``."""
TAU_T_HIGH = 0.05
"""Hysteresis gate: F if ``t_inf >= 0.05``; in between the clip is U (gray zone)."""


def binary_gate(t_inf: float, tau_t: float = TAU_T_BINARY) -> GateLabel:
    """``"F"`` if ``t_inf > tau_t`` else ``"H"``."""
    return "F" if t_inf > tau_t else "H"


def hysteresis_gate(t_inf: float, low: float = TAU_T_LOW, high: float = TAU_T_HIGH) -> GateLabel:
    """``"H"`` if ``t_inf <= low``, ``"F"`` if ``t_inf >= high``, else ``"U"`` (gray zone)."""
    if not low <= high:
        raise ValueError(f"hysteresis thresholds must satisfy low <= high, got {low} > {high}")
    if t_inf <= low:
        return "H"
    if t_inf >= high:
        return "F"
    return "U"


def gate_margin(label: GateLabel, t_inf: float, low: float = TAU_T_LOW, high: float = TAU_T_HIGH) -> float:
    """Distance of ``t_inf`` from the threshold its label depends on: ``low - t_inf`` for H,
    ``t_inf - high`` for F; for U, minus the distance to the nearer threshold (negative inside
    the gray zone)."""
    if label == "H":
        return low - t_inf
    if label == "F":
        return t_inf - high
    return -min(t_inf - low, high - t_inf)


def gate_decision(
    t_inf: float | None,
    *,
    pose_present: bool,
    tau_t: float = TAU_T_BINARY,
    low: float = TAU_T_LOW,
    high: float = TAU_T_HIGH,
) -> tuple[GateLabel, GateLabel, float | None]:
    """(hysteresis label, binary label, margin). Without a pose the clip is gated F with no
    margin (the fail->F policy)."""
    if not pose_present or t_inf is None:
        return "F", "F", None
    label = hysteresis_gate(t_inf, low, high)
    return label, binary_gate(t_inf, tau_t), gate_margin(label, t_inf, low, high)
