"""Per-frame diagnostics the scorer streams to the viewers, and their files beside a record.

:func:`~geocon_core.scoring.scorer.score_clip` calls ``on_frame(FrameDiagnostics)`` once per frame, in
frame order, as soon as everything about the frame is known: the decoded frame, the object
labels the scorer used (built-in segmentation or external masks) and, per object, the optical
flow to the next frame at the working resolution. These are the pictures behind the numbers;
the numbers themselves live in the :class:`~geocon_core.record.ClipRecord`.

:class:`OverlayWriter` keeps the parts a viewer cannot rebuild without re-scoring in a folder
``overlays/`` next to ``record.json``:

- ``labels-NNNNN.png``: (H, W) uint16 object ids of frame N (0 = background), only for frames
  with at least one object;
- ``flow-NNNNN-III.png``: the flow-direction hue slice of object III on the pair it is scored on,
  (N, N + ``object_gap``), inside its box (RGBA: hue = direction, brightness = magnitude up to
  ``max_magnitude``, alpha = reliable object pixels);
- ``index.json``: format ``geocon-overlays/1``; per frame the masked share, the labels file and
  the flow slices with their boxes (x0, y0, x1, y1, working pixels, half-open); and the
  ``record_id`` of the record they belong to (absent from overlays written before records had
  ids).

Frames themselves are not copied: they are decoded again from the clip.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..files import OVERLAY_IMAGE, OVERLAYS_INDEX, ReadRefused, read_bytes, regular_file
from ..media import Frame, imread_any, imwrite_any

if TYPE_CHECKING:
    from .clip import ClipRecord

__all__ = [
    "ObjectFlow",
    "FrameDiagnostics",
    "flow_hue",
    "OverlayWriter",
    "OverlayFlow",
    "OverlayFrame",
    "Overlays",
    "read_overlays",
    "OVERLAYS_FORMAT",
]

OVERLAYS_FORMAT = "geocon-overlays/1"
"""The ``format`` field of the overlays index."""
OVERLAYS_DIR = "overlays"
"""The sub-folder of a record folder that holds the per-frame overlays."""


@dataclass(frozen=True, eq=False)
class ObjectFlow:
    """Optical flow of one object from frame ``t0`` to ``t1`` at the working resolution.

    box: (x0, y0, x1, y1) working pixels, half-open; flow: (h, w, 2) float32 pixels inside the
    box; reliable: (h, w) bool pixels AdaDFRC may use (forward-backward consistent, and farther
    than ``object_edge_px`` from the mask's edge); mask: (h, w) bool object pixels at ``t0``.
    """

    object_id: int
    t0: int
    t1: int
    box: tuple[int, int, int, int]
    flow: np.ndarray
    reliable: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True, eq=False)
class FrameDiagnostics:
    """What the scorer knows about frame ``index`` beyond the record.

    frame: the decoded frame (working canvas); fps: the clip's frame rate; labels: (H, W) uint16 object ids used for
    masking (None when masks are off); masked_share: share of content pixels inside objects;
    flows: per object, the flow on the pair (index, index + 1) (empty on the last frame, across
    cuts and without masks).
    """

    index: int
    frame: Frame
    fps: float
    labels: np.ndarray | None
    masked_share: float
    flows: tuple[ObjectFlow, ...] = ()


def flow_hue(flow: np.ndarray, valid: np.ndarray, max_magnitude: float | None = None) -> tuple[np.ndarray, float]:
    """RGBA picture of a flow field (h, w, 2): hue = direction (0 deg = +x, red), brightness =
    magnitude / ``max_magnitude`` (default: the 99th percentile over ``valid``), alpha = 255 on
    ``valid`` pixels. Returns the (h, w, 4) uint8 image and the magnitude used for full
    brightness."""
    fx, fy = flow[..., 0].astype(np.float32), flow[..., 1].astype(np.float32)
    mag, ang = cv2.cartToPolar(fx, fy, angleInDegrees=True)
    if max_magnitude is None:
        vals = mag[valid]
        max_magnitude = float(np.percentile(vals, 99)) if vals.size else 0.0
    max_magnitude = max(float(max_magnitude), 1e-6)
    hsv = np.zeros(flow.shape[:2] + (3,), np.uint8)
    hsv[..., 0] = np.round(ang / 2.0).astype(np.uint16) % 180
    hsv[..., 1] = 255
    hsv[..., 2] = np.clip(mag / max_magnitude * 255.0, 0, 255).astype(np.uint8)
    rgba = np.empty(flow.shape[:2] + (4,), np.uint8)
    rgba[..., :3] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    rgba[..., 3] = np.where(valid, 255, 0)
    return rgba, max_magnitude


@dataclass(frozen=True)
class OverlayFlow:
    """An entry of ``index.json``: the flow-hue slice file of object ``object_id`` on the pair
    (t0, t1), covering ``box`` (x0, y0, x1, y1, working px, half-open); ``max_magnitude`` (px) is
    the flow magnitude shown at full brightness."""

    object_id: int
    t0: int
    t1: int
    box: tuple[int, int, int, int]
    file: str
    max_magnitude: float

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "object_id": self.object_id,
            "t0": self.t0,
            "t1": self.t1,
            "box": list(self.box),
            "file": self.file,
            "max_magnitude": self.max_magnitude,
        }

    @classmethod
    def from_json_dict(cls, d: dict[str, Any]) -> "OverlayFlow":
        x0, y0, x1, y1 = (int(v) for v in d["box"])
        return cls(int(d["object_id"]), int(d["t0"]), int(d["t1"]), (x0, y0, x1, y1), d["file"], d["max_magnitude"])


@dataclass(frozen=True)
class OverlayFrame:
    """The ``index.json`` entry of one frame: the masked share of the content (0..1), the labels
    file (None for a frame without objects) and the flow slices of its objects."""

    masked_share: float
    labels: str | None
    flows: tuple[OverlayFlow, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "masked_share": self.masked_share,
            "labels": self.labels,
            "flows": [f.to_json_dict() for f in self.flows],
        }

    @classmethod
    def from_json_dict(cls, d: dict[str, Any]) -> "OverlayFrame":
        return cls(d["masked_share"], d["labels"], tuple(OverlayFlow.from_json_dict(f) for f in d["flows"]))


class OverlayWriter:
    """Writes the ``overlays/`` folder of a record as frames stream in (use as ``on_frame``)."""

    def __init__(self, record_dir: str | Path) -> None:
        self.dir = Path(record_dir) / OVERLAYS_DIR
        self.dir.mkdir(parents=True, exist_ok=True)
        for old in self.dir.glob("*.png"):
            old.unlink()
        self.frames: dict[int, OverlayFrame] = {}

    def __call__(self, fd: FrameDiagnostics) -> None:
        labels = None
        if fd.labels is not None and fd.labels.any():
            labels = f"labels-{fd.index:05d}.png"
            _imwrite(self.dir / labels, fd.labels.astype(np.uint16))
        flows = []
        for of in fd.flows:
            rgba, vmax = flow_hue(of.flow, of.reliable & of.mask)
            name = f"flow-{fd.index:05d}-{of.object_id:03d}.png"
            _imwrite(self.dir / name, cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
            flows.append(OverlayFlow(of.object_id, of.t0, of.t1, of.box, name, vmax))
        self.frames[fd.index] = OverlayFrame(float(fd.masked_share), labels, tuple(flows))

    def close(self, record_id: str | None = None) -> Path:
        """Write ``index.json``, naming the record the overlays belong to
        (:func:`~geocon_core.record.clip.record_id`)."""
        path = self.dir / "index.json"
        tmp = self.dir / ".index.json.part"
        frames = {str(t): entry.to_json_dict() for t, entry in self.frames.items()}
        doc: dict[str, Any] = {"format": OVERLAYS_FORMAT}
        if record_id is not None:
            doc["record_id"] = record_id
        doc["frames"] = frames
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
        tmp.replace(path)
        return path


def _imwrite(path: Path, image: np.ndarray) -> None:
    if not imwrite_any(path, image):
        raise OSError(f"could not write {path}")


@dataclass(frozen=True)
class FlowSlice:
    """A stored flow-hue slice: (h, w, 4) RGBA ``image`` for ``box`` on the pair (t0, t1)."""

    object_id: int
    t0: int
    t1: int
    box: tuple[int, int, int, int]
    max_magnitude: float
    image: np.ndarray


class Overlays:
    """Read access to a record's ``overlays/`` folder (files are loaded on demand). ``size``: the
    record's working (W, H); when given, a PNG whose header states another size than its entry's
    is refused before it is decoded."""

    def __init__(self, folder: Path, index: dict[str, Any], size: tuple[int, int] | None = None) -> None:
        self.folder = folder
        self.size = size
        self.entries: dict[int, OverlayFrame] = {
            int(t): OverlayFrame.from_json_dict(e) for t, e in index["frames"].items()
        }

    @property
    def frames(self) -> list[int]:
        return sorted(self.entries)

    def masked_share(self, t: int) -> float | None:
        e = self.entries.get(t)
        return None if e is None else e.masked_share

    def labels(self, t: int) -> np.ndarray | None:
        """(H, W) uint16 object ids of frame t, or None when the frame has no object."""
        e = self.entries.get(t)
        if e is None or e.labels is None:
            return None
        self._check_size(self.folder / e.labels, self.size)
        labels = imread_any(self.folder / e.labels, cv2.IMREAD_UNCHANGED)
        if labels is None:
            raise _missing(self.folder / e.labels)
        return np.asarray(labels)

    def flows(self, t: int) -> list[FlowSlice]:
        e = self.entries.get(t)
        out = []
        for f in () if e is None else e.flows:
            x0, y0, x1, y1 = f.box
            self._check_size(self.folder / f.file, None if self.size is None else (x1 - x0, y1 - y0))
            bgra = imread_any(self.folder / f.file, cv2.IMREAD_UNCHANGED)
            if bgra is None or bgra.ndim != 3 or bgra.shape[2] != 4:
                raise _missing(self.folder / f.file)
            img = cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA)
            out.append(FlowSlice(f.object_id, f.t0, f.t1, f.box, f.max_magnitude, img))
        return out

    @staticmethod
    def _check_size(path: Path, size: tuple[int, int] | None) -> None:
        """An overlay that is not a regular file (a FIFO would block its reader) or is past
        :data:`~geocon_core.files.bounded.OVERLAY_IMAGE`'s bound, and a PNG whose header states
        another (w, h) than ``size``, are refused unread (its pixels would be allocated at the stated
        size)."""
        try:
            regular_file(path, OVERLAY_IMAGE)
        except ReadRefused as exc:
            if exc.reason == "missing":
                raise _missing(path) from None
            raise ValueError(f"{path} is {exc.why}: the record was edited or damaged; score the clip again") from None
        if size is None:
            return
        try:
            with open(path, "rb") as f:
                head = f.read(24)
        except OSError:
            return  # the reading that follows says it is missing
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            stated = (int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big"))
            if stated != size:
                raise ValueError(
                    f"{path}: an overlay of {stated[0]}x{stated[1]} px where the record's is {size[0]}x{size[1]}; "
                    "score the clip again"
                )


def _missing(path: Path) -> ValueError:
    return ValueError(f"{path}: an overlay of this record is missing or unreadable; score the clip again")


MAX_INDEX_BYTES = OVERLAYS_INDEX.limit
"""An overlays index larger than this is refused unread (a long clip's index is a few MB)."""


def read_overlays(record_dir: str | Path, record: ClipRecord | None = None) -> Overlays | None:
    """The overlays stored beside a record, or None when the record has none; ``ValueError``
    naming the file when the index is unreadable or not GeoCon's. With the ``record`` read from
    the same folder, the overlays must be that record's: the same ``record_id`` (both none for a
    record written before ids), frames and boxes inside its frames and canvas."""
    folder = Path(record_dir)
    folder = (folder if folder.is_dir() else folder.parent) / OVERLAYS_DIR
    index = folder / "index.json"
    if not index.exists():
        return None
    try:
        try:
            raw = read_bytes(index, OVERLAYS_INDEX)  # a regular file within its bound, or refused unread
        except ReadRefused as exc:
            if exc.reason == "size":
                raise ValueError(
                    f"{index}: larger than {MAX_INDEX_BYTES >> 20} MB; not a GeoCon overlays index"
                ) from None
            raise ValueError(f"{index}: {exc.why}; score the clip again") from None
        d = json.loads(raw.decode("utf-8"))
        if not isinstance(d, dict) or d.get("format") != OVERLAYS_FORMAT:
            fmt = d.get("format") if isinstance(d, dict) else None
            raise ValueError(f"{index}: not GeoCon overlays (format {fmt!r}, expected {OVERLAYS_FORMAT!r})")
        if record is None:
            return Overlays(folder, d)
        if d.get("record_id") != record.record_id:
            raise ValueError(
                f"{index}: the overlays of another record (record id {d.get('record_id') or 'missing'}, the record's "
                f"is {record.record_id or 'none'}): copy a record folder whole, or score the clip again"
            )
        overlays = Overlays(folder, d, record.video.working_size)
        _check_within(overlays, record, index)
        return overlays
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:  # JSON and Unicode errors too
        if isinstance(exc, ValueError) and str(exc).startswith(str(index)):
            raise
        raise ValueError(f"{index}: cannot be read as GeoCon overlays ({type(exc).__name__}: {exc})") from None


def _check_within(overlays: Overlays, record: ClipRecord, index: Path) -> None:
    """Every frame and flow box of ``overlays`` lies inside the record's frames and canvas."""
    n, (W, H) = record.video.num_frames, record.video.working_size
    for t, entry in overlays.entries.items():
        if not 0 <= t < n:
            raise ValueError(f"{index}: an overlay of frame {t}, outside the record's {n} frames; score the clip again")
        for f in entry.flows:
            x0, y0, x1, y1 = f.box
            if not (0 <= f.t0 < f.t1 < n and 0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H):
                raise ValueError(
                    f"{index}: a flow overlay on frames ({f.t0}, {f.t1}) in box {list(f.box)}, outside the record's "
                    f"{n} frames or {W}x{H} canvas; score the clip again"
                )
