"""Rerun audit recordings: everything the scorer knows about a clip, on two timelines.

:class:`RerunAudit` writes into an explicit :class:`rerun.RecordingStream` (never the global
one). Frames arrive one at a time (:meth:`RerunAudit.frame`, usable as the scorer's
``on_frame``), then the finished :class:`~geocon_core.record.ClipRecord` adds the matches,
residual maps, object vectors, time series, the point cloud and the audit card
(:meth:`RerunAudit.record`). Nothing here computes a score: every number comes from the
record, and the pictures are drawn from its stored per-match residuals and per-cell vectors.

Timelines: ``frame`` (sequence, frame index t) and ``video_time`` (t / fps). A pair (t, t+k) is
logged at frame t. Entity paths:

=============================  ===============================================================
``frame/image``                the frames (one AV1 video asset with a frame reference per
                               frame, or a JPEG per frame)
``frame/content``              pixels outside the content box (static segmentation)
``frame/objects``              object ids used for masking (segmentation, named by
                               ``frame/objects``' annotation context)
``frame/matches/inliers``      background matches of pair (t, t+1) at x_t, inliers ...
``frame/matches/outliers``     ... and outliers of the chosen family
``frame/matches/lines``        x_t -> x_{t+1}, coloured by residual
``frame/residual_map``         per-match residuals spread over the image (inferno colour map,
                               transparent where there are no matches)
``frame/flow``                 flow-direction hue slices of the objects inside their masks (hue =
                               direction, brightness = magnitude; transparent elsewhere)
``frame/readings/<map>``       where a reading fires over the clip (static; ``failure``,
                               ``movers``, ``unexplained``: :mod:`geocon_core.signals.pictures`),
                               each in a tab beside the residual map
``frame/cells/<id>/observed``  per-cell median flow of object <id> (arrows, exaggerated)
``frame/cells/<id>/predicted`` the affine prediction at the same cells
``series/background/...``      IR and GE per gap and scale, report gates, flagged pairs
``series/objects/<id>``        AdaDFRC ``D_t`` per object
``series/gate/...``            per-window ``t_inf`` with the 0.03 / 0.05 lines and margin
``world/points``               first/last two-view point cloud (sparse; when there is no dense one)
``world/dense``, ``window/...``  the dense clouds (:mod:`geocon_viewer.rerun.dense`)
``world/cam_first``,
``world/cam_last``             both cameras as pinholes
``audit``                      the audit card (markdown)
=============================  ===============================================================
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from geocon_core.files import clear_stale_parts, part_path, replace_file
from geocon_core.media import DEFAULT_FPS
from geocon_core.record import ClipRecord, FlowSlice, FrameDiagnostics, flow_hue
from geocon_core.signals import MAP_NAMES

from .card import RERUN_VERSION, audit_card, evidence, reading_tab, worst_frame
from .images import object_rgba, png_bytes, residual_map
from .layers import ARROW_GAIN, RecordLayers
from .video import FrameVideo, quiet_encoder_logs

__all__ = [
    "RerunAudit",
    "AuditFrame",
    "RrdSink",
    "STREAM_FLUSH_S",
    "ViewerStalled",
    "write_rrd",
    "blueprint",
    "audit_card",
    "worst_frame",
    "residual_map",
    "RERUN_VERSION",
    "ARROW_GAIN",
    "quiet_encoder_logs",
    "frames_from_diagnostics",
]


@dataclass(frozen=True, eq=False)
class AuditFrame:
    """One frame as the recording shows it: (H, W, 3) uint8 RGB, object labels (H, W) uint16 or
    None, and the objects' flow-hue slices on the pair (t, t + g), g the config's ``object_gap``."""

    index: int
    rgb: np.ndarray
    labels: np.ndarray | None
    flows: Sequence[FlowSlice] = ()


def frames_from_diagnostics(fd: FrameDiagnostics) -> AuditFrame:
    """The scorer's live diagnostics as an :class:`AuditFrame` (flow turned into hue slices)."""
    slices = []
    for of in fd.flows:
        rgba, vmax = flow_hue(of.flow, of.reliable & of.mask)
        slices.append(FlowSlice(of.object_id, of.t0, of.t1, of.box, vmax, rgba))
    return AuditFrame(fd.index, fd.frame.rgb, fd.labels, slices)


class RerunAudit:
    """Writes one clip's audit into ``rec``.

    fps: the clip's frame rate (for ``video_time``; the reader's ``DEFAULT_FPS`` when not
    positive); frames: ``"video"`` (AV1, compact, the default) or ``"jpeg"`` (one JPEG per frame,
    ``quality``; also what ``"video"`` falls back to for frames too thin for the encoder,
    :meth:`~geocon_viewer.rerun.video.FrameVideo.encodes`); scale: which scale's matches are drawn
    over the frames (default: the largest).
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        fps: float,
        frames: str = "video",
        quality: int | None = None,
        scale: float | None = None,
    ) -> None:
        if frames not in ("video", "jpeg"):
            raise ValueError(f"frames must be 'video' or 'jpeg', got {frames!r}")
        if not fps > 0:
            fps = DEFAULT_FPS
        self.rec, self.fps, self.scale = rec, float(fps), scale
        self.frames_mode = frames
        self.quality = int(quality if quality is not None else (32 if frames == "video" else 80))
        self.video = FrameVideo(self.fps, self.quality) if frames == "video" else None
        self.n_frames = 0
        self._content_logged = False
        self._flow_shown = False

    def _time(self, t: int) -> None:
        self.rec.set_time("frame", sequence=int(t))
        self.rec.set_time("video_time", duration=t / self.fps)

    # -- per frame ---------------------------------------------------------------------------

    def frame(self, f: AuditFrame | FrameDiagnostics) -> None:
        """Log one frame with its object labels and flow-hue slices."""
        if isinstance(f, FrameDiagnostics):
            if not self._content_logged:
                self._log_content(f.frame.content)
            f = frames_from_diagnostics(f)
        rec = self.rec
        self._time(f.index)
        if self.video is not None and not self.video.indices and not FrameVideo.encodes(*f.rgb.shape[1::-1]):
            self.video, self.frames_mode, self.quality = None, "jpeg", 80  # too thin for the AV1 encoder
        if self.video is not None:
            self.video.add(f.index, f.rgb)
        else:
            ok, jpg = cv2.imencode(
                ".jpg", cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.quality]
            )
            assert ok
            rec.log("frame/image", rr.EncodedImage(contents=jpg.tobytes(), media_type="image/jpeg", draw_order=0.0))
        if f.labels is not None:
            labels = f.labels.astype(np.uint8) if f.labels.max(initial=0) < 256 else f.labels.astype(np.uint16)
            rec.log("frame/objects", rr.SegmentationImage(labels, opacity=0.35, draw_order=1.0))
        # All objects' slices in one image of the frame's size: Rerun needs an image entity to keep
        # its dimensions over time, and a mostly transparent PNG costs a few kB.
        if f.flows:
            h, w = f.rgb.shape[:2]
            hue = np.zeros((h, w, 4), dtype=np.uint8)
            for sl in f.flows:
                x0, y0, x1, y1 = sl.box
                x1, y1 = min(x1, w), min(y1, h)
                patch = sl.image[: y1 - y0, : x1 - x0]
                covered = patch[..., 3] > 0
                hue[y0:y1, x0:x1][covered] = patch[covered]
            rec.log(
                "frame/flow",
                rr.EncodedImage(contents=png_bytes(hue, level=1), media_type="image/png", opacity=0.9, draw_order=2.0),
            )
            self._flow_shown = True
        elif self._flow_shown:
            rec.log("frame/flow", rr.Clear(recursive=False))
            self._flow_shown = False
        self.n_frames = max(self.n_frames, f.index + 1)

    def _log_content(self, content: np.ndarray) -> None:
        outside = (~content).astype(np.uint8)
        self.rec.log(
            "frame/content",
            rr.AnnotationContext([(0, "content", (0, 0, 0, 0)), (1, "outside the content box", (40, 40, 160, 160))]),
            static=True,
        )
        self.rec.log("frame/content", rr.SegmentationImage(outside, opacity=0.5, draw_order=0.5), static=True)
        self._content_logged = True

    # -- from the record ---------------------------------------------------------------------

    def record(self, record: ClipRecord) -> None:
        """Log everything that comes from the finished record."""
        rec = self.rec
        if not self._content_logged:
            self._log_content_box(record)
        if self.video is not None:
            data = self.video.finish()
            if data is not None:
                asset = rr.AssetVideo(contents=data, media_type="video/mp4")
                rec.log("frame/image", asset, static=True)
                # the container's own timestamps, so every reference hits its frame exactly
                ns = asset.read_frame_timestamps_nanos()
                t = np.asarray(self.video.indices, np.int64)
                if len(ns) != len(t):
                    raise RuntimeError(f"the frame video holds {len(ns)} frames, {len(t)} were encoded")
                rec.send_columns(
                    "frame/image",
                    indexes=[rr.TimeColumn("frame", sequence=t), rr.TimeColumn("video_time", duration=t / self.fps)],
                    columns=rr.VideoFrameReference.columns_nanos(ns),
                )
        rec.send_property(
            "geocon",
            rr.AnyValues(
                clip=record.clip,
                config_hash=record.config_hash,
                preset=record.config.preset,
                geocon_version=record.versions.get("geocon", "?"),
                rerun_version=RERUN_VERSION,
            ),
        )
        ids = [o.object_id for o in record.objects]
        rec.log(
            "frame/objects",
            rr.AnnotationContext([(0, "background", (0, 0, 0, 0))] + [(i, f"object {i}", object_rgba(i)) for i in ids]),
            static=True,
        )
        RecordLayers(rec, self.fps, self.scale).log_all(record)
        rec.log("audit", rr.TextDocument(audit_card(record), media_type=rr.MediaType.MARKDOWN), static=True)

    def _log_content_box(self, record: ClipRecord) -> None:
        w, h = record.video.working_size
        x0, y0, x1, y1 = record.video.content_box
        content = np.zeros((h, w), bool)
        content[y0:y1, x0:x1] = True
        self._log_content(content)


def blueprint(reading_map: str | None = None) -> rrb.Blueprint:
    """The default layout: frame with matches, residual map and object flow on top; 3D, the
    time series and the audit card below. The residual map shares its place with the reading maps
    (tabs); ``reading_map`` names the one shown first (none: the residual map)."""
    frame_view = rrb.Spatial2DView(
        name="Frame + background matches",
        origin="frame",
        contents=["+ frame/image", "+ frame/content", "+ frame/objects", "+ frame/matches/**", "+ frame/multiview"],
    )
    residual_view = rrb.Spatial2DView(
        name="Residual map", origin="frame", contents=["+ frame/image", "+ frame/residual_map/**"]
    )
    reading_views = [
        rrb.Spatial2DView(
            name=reading_tab(name), origin="frame", contents=["+ frame/image", f"+ frame/readings/{name}"]
        )
        for name in MAP_NAMES
    ]
    object_view = rrb.Spatial2DView(
        name="Object flow + AdaDFRC cells",
        origin="frame",
        contents=["+ frame/image", "+ frame/objects", "+ frame/flow", "+ frame/cells/**"],
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                frame_view,
                rrb.Tabs(
                    residual_view,
                    *reading_views,
                    active_tab=0 if reading_map is None else 1 + MAP_NAMES.index(reading_map),
                ),
                object_view,
            ),
            rrb.Horizontal(
                rrb.Tabs(
                    rrb.Spatial3DView(name="One camera for the clip", origin="clip3d"),
                    rrb.Spatial3DView(name="First/last two-view geometry", origin="world"),
                    rrb.Spatial3DView(name="Gate window: dense cloud", origin="window"),
                ),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="Background IR", origin="series/background/ir"),
                    rrb.TimeSeriesView(name="Background GE (px)", origin="series/background/ge"),
                ),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="Gate t_inf", origin="series/gate"),
                    rrb.TimeSeriesView(name="AdaDFRC per object (px^2)", origin="series/objects"),
                ),
                rrb.TextDocumentView(name="Audit card", origin="audit"),
                column_shares=[3, 3, 3, 2],
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="frame", play_state="paused", state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


class _PipedFile:
    """Rerun's file sink writes into a pipe; a thread copies the pipe into ``part`` with Python's
    own file I/O. A write that fails (a full disk, ``ulimit -f``, an I/O error) is kept as
    :attr:`error` and raised, naming ``name``, by :meth:`check` and :meth:`close`; the pipe is
    drained to its end regardless, so Rerun never waits on a writer that stopped (its own file
    writer, on such an error, leaves the recording's flush waiting for ever). The pipe holds at
    most a few pages: memory does not grow with the recording."""

    CHUNK = 1 << 20
    """Bytes read from the pipe at a time."""
    CLOSE_TIMEOUT_S = 120.0
    """Seconds Rerun may take, once the recording is disconnected, to write its last bytes."""

    def __init__(self, part: Path, name: Path) -> None:
        self.part, self.name = part, name
        self.error: Exception | None = None
        try:
            self._file = open(part, "wb")  # closed by close() or discard()
        except OSError as exc:
            raise self._named(exc) from None
        try:
            self._read, self._write = os.pipe()
        except OSError:
            self._file.close()
            part.unlink(missing_ok=True)
            raise
        self.sink_path = f"/dev/fd/{self._write}"
        """Where Rerun's file sink opens its own descriptor of the pipe (:meth:`attached` then
        closes this one, so the pipe ends when Rerun closes it)."""
        self._thread = threading.Thread(target=self._pump, name="geocon-rrd-writer", daemon=True)
        self._thread.start()

    def _named(self, exc: OSError) -> OSError:
        """``exc`` naming the recording's path rather than its temporary file."""
        return OSError(exc.errno, exc.strerror or str(exc), str(self.name))

    def _pump(self) -> None:
        try:
            while chunk := os.read(self._read, self.CHUNK):
                if self.error is None:
                    try:
                        self._file.write(chunk)
                    except Exception as exc:  # kept; raised in the main thread
                        self.error = exc
        except OSError as exc:
            self.error = self.error or exc
        finally:
            os.close(self._read)

    def attached(self) -> None:
        """Rerun holds the pipe now: close this process's copy of its writing end."""
        if self._write >= 0:
            os.close(self._write)
            self._write = -1

    def check(self) -> None:
        """Raise the first failed write (an ``OSError`` naming the recording's path)."""
        exc = self.error
        if exc is None:
            return
        if isinstance(exc, OSError):
            raise self._named(exc) from None
        raise exc

    def close(self) -> None:
        """Once Rerun has closed the pipe: copy the rest, close the file, raise a failed write."""
        self.attached()
        self._thread.join(self.CLOSE_TIMEOUT_S)
        if self._thread.is_alive() and self.error is None:
            self.error = OSError(errno.EIO, "Rerun did not finish writing the recording")
        try:
            self._file.close()
        except OSError as exc:
            self.error = self.error or exc
        self.check()

    DISCARD_WAIT_S = 5.0
    """Seconds an abandoned recording waits for Rerun to close the pipe; past them the thread goes
    on draining it (writes to the closed file are dropped), so Rerun never waits on it."""

    def discard(self) -> None:
        """Close everything and remove the partial file, waiting at most :attr:`DISCARD_WAIT_S`
        for Rerun (a run that failed must not wait on the recording it abandons)."""
        self.attached()
        self._thread.join(self.DISCARD_WAIT_S)
        with contextlib.suppress(OSError, ValueError):
            self._file.close()
        self.part.unlink(missing_ok=True)


STREAM_FLUSH_S = 30.0
"""Seconds a viewer streamed to (``--connect``) may take, once every frame is logged, to take the
rest of the recording; a viewer that has stopped taking it by then (it answered when the command
began, then hung) is given up (:class:`ViewerStalled`)."""


class ViewerStalled(RuntimeError):
    """The viewer streamed to did not take the recording within :data:`STREAM_FLUSH_S`. Rerun's
    client then waits for it for ever, in its disconnect and again when the process exits, so the
    process must end without that clean-up (the command line's call, ``os._exit``)."""


class _StreamLogger:
    """Logs into a recording that streams to a viewer, on a thread of its own, so that a viewer
    which stops taking the recording can never hold the caller: Rerun's gRPC sink may block inside
    any ``log`` call once its buffer is full, not only in the final flush. Jobs run in order; the
    caller waits only while the logger makes progress, and gives up (:class:`ViewerStalled`) when
    no job has finished for :data:`STREAM_FLUSH_S`. The queue is short, so frames decoded faster
    than the viewer takes them wait here instead of piling up in memory."""

    QUEUE = 8

    def __init__(self) -> None:
        import queue

        self._jobs: queue.Queue = queue.Queue(self.QUEUE)
        self._error: BaseException | None = None
        self._done = threading.Event()
        self._beat = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="geocon-rerun-stream", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                self._done.set()
                return
            if self._error is None:
                try:
                    job()
                except BaseException as exc:  # handed to the caller at its next call
                    self._error = exc
            self._beat = time.monotonic()

    def _stalled(self) -> bool:
        return time.monotonic() - self._beat > STREAM_FLUSH_S

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def submit(self, job) -> None:
        """Queue ``job`` (a callable); waits while the queue is full and the logger moves."""
        import queue

        self._raise()
        while True:
            try:
                self._jobs.put(job, timeout=0.2)
                return
            except queue.Full:
                if self._stalled():
                    raise ViewerStalled(
                        f"it took no more of the recording within {STREAM_FLUSH_S:g} s while it streamed"
                    ) from None

    def close(self) -> None:
        """Wait until every queued job has run; :class:`ViewerStalled` when the logger stops
        moving for :data:`STREAM_FLUSH_S`, else the first error a job raised."""
        self.submit(None)
        while not self._done.wait(0.2):
            if self._stalled():
                raise ViewerStalled(f"it took not all of the recording within {STREAM_FLUSH_S:g} s of the last frame")
        self._raise()


class RrdSink:
    """Streams a clip into a recording while it is scored: pass it as the scorer's ``on_frame``,
    then call :meth:`finish` with the record. Writes ``path`` (a ``.rrd`` file) and/or streams to
    a running viewer at ``connect`` (a ``rerun+http://.../proxy`` URL). The file is written
    beside ``path`` under a temporary name and moved into place by :meth:`finish`, so a run that
    fails or is killed leaves an earlier recording at ``path`` as it was (:meth:`abort` removes
    the partial file). The file's bytes are written by this process (:class:`_PipedFile`): a full
    disk or a file-size limit raises ``OSError`` naming ``path`` at the next frame or at
    :meth:`finish`, never a wait."""

    def __init__(
        self,
        path: str | Path | None,
        *,
        connect: str | None = None,
        frames: str = "video",
        reading_map: str | None = None,
    ) -> None:
        if path is None and connect is None:
            raise ValueError("RrdSink needs a file path, a viewer URL to connect to, or both")
        self.path = None if path is None else Path(path)
        self.part: Path | None = None
        self.file: _PipedFile | None = None
        self.rec = rr.RecordingStream("geocon")
        self.connect = connect
        self.stalled = False
        """The viewer at ``connect`` stopped taking the recording (:class:`ViewerStalled`)."""
        sinks: list = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            clear_stale_parts(self.path)
            self.part = part_path(self.path)
            self.file = _PipedFile(self.part, self.path)
            sinks.append(rr.FileSink(self.file.sink_path))
        if connect is not None:
            sinks.append(rr.GrpcSink(connect))
        try:
            self.rec.set_sinks(*sinks, default_blueprint=blueprint(reading_map))
        except BaseException:
            self.abort()
            raise
        if self.file is not None:
            self.file.attached()
        self.frames = frames
        self.audit: RerunAudit | None = None
        self._stream = _StreamLogger() if connect is not None else None
        """Where logging runs while a viewer is streamed to (:class:`_StreamLogger`)."""

    def _audit(self, fps: float) -> RerunAudit:
        if self.audit is None:
            self.audit = RerunAudit(self.rec, fps=fps, frames=self.frames)
        return self.audit

    def _check(self) -> None:
        if self.file is not None:
            self.file.check()

    def _log(self, job) -> None:
        if self._stream is None:
            job()
            return
        try:
            self._stream.submit(job)
        except ViewerStalled:
            self.stalled = True
            raise

    def __call__(self, fd: FrameDiagnostics) -> None:
        self._log(lambda: self._audit(fd.fps).frame(fd))
        self._check()

    def frame(self, f: AuditFrame, fps: float) -> None:
        self._log(lambda: self._audit(fps).frame(f))
        self._check()

    def finish(self, record: ClipRecord, *, commit: bool = True) -> Path | None:
        """Log the record and close the recording; with ``commit`` move it into place at once,
        else leave that to :meth:`commit` (a caller committing it together with the record)."""
        if self._stream is None:
            self._audit(record.video.fps).record(record)
            self.rec.flush()
        else:

            def last() -> None:
                try:
                    self.rec.flush(timeout_sec=STREAM_FLUSH_S)
                except RuntimeError:  # Rerun's "Flush timed out"
                    raise ViewerStalled(
                        f"it took not all of the recording within {STREAM_FLUSH_S:g} s of the last frame"
                    ) from None

            try:
                self._log(lambda: self._audit(record.video.fps).record(record))
                self._log(last)
                self._stream.close()
            except ViewerStalled:
                self.stalled = True
                raise
        self.rec.disconnect()
        if self.file is not None:
            self.file.close()
        if commit:
            self.commit()
        return self.path

    def commit(self) -> None:
        """Move the finished recording into place (one rename; never onto a device or a FIFO)."""
        if self.part is not None and self.path is not None:
            replace_file(self.part, self.path)

    def abort(self) -> None:
        """Stop recording and remove the partial file; an earlier recording at ``path`` stays. A
        stalled viewer is not disconnected (that would wait for it for ever)."""
        if not self.stalled:
            with contextlib.suppress(Exception):
                self.rec.disconnect()
        if self.file is not None:
            self.file.discard()
        elif self.part is not None:
            self.part.unlink(missing_ok=True)


def write_rrd(
    record_dir: str | Path, path: str | Path | None, *, connect: str | None = None, progress=None
) -> Path | None:
    """Re-render the recording of a saved record (``record.json`` + ``matches.npz`` + ``overlays/``)
    without re-scoring: frames are decoded again from the clip the record names."""
    from geocon_core.media import ClipError, ClipInfo, iter_frames, locate_clip, probe_clip
    from geocon_core.record import read_overlays, read_record

    record = read_record(record_dir)
    overlays = read_overlays(record_dir, record)
    sink = RrdSink(path, connect=connect, reading_map=evidence(record)[0])  # a flagged clip opens on its evidence
    fps = record.video.fps
    try:
        found: ClipInfo | None = locate_clip(record.video, record_dir)
    except ClipError as exc:
        found, missing = None, str(exc)
    try:
        if found is not None:
            info = probe_clip(found.path, record.config)
            if (info.num_frames, info.source_size) != (record.video.num_frames, record.video.source_size):
                raise ValueError(
                    f"{found.path} decodes to {info.num_frames} frames of {info.source_size[0]}x{info.source_size[1]} "
                    f"but {Path(record_dir) / 'record.json'} says {record.video.num_frames} of "
                    f"{record.video.source_size[0]}x{record.video.source_size[1]}: score the clip again"
                )
            for frame in iter_frames(info):
                labels = flows = None
                if overlays is not None:
                    labels, flows = overlays.labels(frame.index), overlays.flows(frame.index)
                sink.frame(AuditFrame(frame.index, frame.rgb, labels, flows or ()), fps)
                if progress is not None:
                    progress(frame.index + 1, info.num_frames)
        else:
            sink.rec.log(
                "audit/missing_clip",
                rr.TextDocument(f"{missing}: frames are not shown"),
                static=True,
            )
        return sink.finish(record)
    except BaseException:
        sink.abort()
        raise
