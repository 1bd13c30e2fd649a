"""``geocon teach``: the Viser app for teaching two-view geometry (:mod:`.app`), the synthetic clip its
sliders set (:mod:`.scene`) and what it shows for one update (:mod:`.views`)."""

from __future__ import annotations

from .app import TeachApp
from .scene import TeachParams
from .views import TeachUpdate

__all__ = [
    "TeachApp",
    "TeachParams",
    "TeachUpdate",
]
