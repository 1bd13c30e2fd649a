"""``geocon serve``: the Viser audit app over a results folder (:mod:`.app`), its panels (:mod:`.gui`),
the side panel's texts (:mod:`.triage`), what it draws for the selected clip (:mod:`.views`) and
where the Viser apps are served (:mod:`.served`)."""

from __future__ import annotations

from .app import AuditApp
from .served import ServedApp
from .views import INLIER, OUTLIER, thumb

__all__ = [
    "AuditApp",
    "INLIER",
    "OUTLIER",
    "ServedApp",
    "thumb",
]
