"""Rerun audit recordings: the recorder (:mod:`.log`), the parts drawn from a finished record
(:mod:`.layers`, :mod:`.dense`, :mod:`.multiview`, :mod:`.images`), the audit card (:mod:`.card`),
the frames as one AV1 video (:mod:`.video`) and opening a recording in Rerun's viewer (:mod:`.serve`)."""

from __future__ import annotations

from .card import evidence, why_lines, worst_frame
from .log import STREAM_FLUSH_S, RerunAudit, RrdSink, ViewerStalled, write_rrd
from .serve import open_native, serve_web
from .video import quiet_encoder_logs

__all__ = [
    "RerunAudit",
    "RrdSink",
    "STREAM_FLUSH_S",
    "ViewerStalled",
    "evidence",
    "open_native",
    "quiet_encoder_logs",
    "serve_web",
    "why_lines",
    "worst_frame",
    "write_rrd",
]
