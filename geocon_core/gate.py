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
