"""What runs beside the viewers: child processes and loopback ports (:mod:`.processes`), headless
Chromium over the DevTools pipe (:mod:`.chromium`) and screenshots of recordings and pages
(:mod:`.screenshot`)."""

from __future__ import annotations

from .chromium import find_chromium
from .processes import (
    BindError,
    ScreenshotError,
    ViewerUnreachable,
    ViewerUrlError,
    check_bind,
    check_viewer_url,
    find_rerun_binary,
    free_port,
    kill_group,
    start_rerun,
)
from .screenshot import screenshot_rrd, screenshot_url

__all__ = [
    "BindError",
    "ScreenshotError",
    "ViewerUnreachable",
    "ViewerUrlError",
    "check_bind",
    "check_viewer_url",
    "find_chromium",
    "find_rerun_binary",
    "free_port",
    "kill_group",
    "screenshot_rrd",
    "screenshot_url",
    "start_rerun",
]
