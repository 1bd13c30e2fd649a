"""Thumbnails of the flagged clips in ``geocon report`` (:mod:`geocon_core.report`): per clip, its
first frame, its worst pair (the lowest IR under the family the clip was judged with) with the
pair's inlier matches drawn green and its outliers red, and its last frame, as small JPEGs for
the self-contained page. Where the clip model's score leans on a reading with a picture, the map
of where that reading fires (:mod:`geocon_core.signals.pictures`) is shown on the middle frame;
where the multi-view check found a drifting layer, the layer.

Frames are read again from the clip the record names, at the working resolution the clip was
scored at (the record's :class:`~geocon_core.media.reader.ClipInfo`; no new probe pass), and only the
frames shown are converted: the others are stepped over without being turned into images. The
matches and inliers come from the record (:func:`geocon_core.scoring.regate.pair_inliers` at the
recorded threshold), exactly as the audit viewer draws them. A clip whose record or video can no
longer be read gets a one-sentence note instead (:attr:`ClipThumbs.note`): thumbnails never fail
a report.
"""

from __future__ import annotations

import base64
import html
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import cv2
import numpy as np

from ..media import ClipError, ClipInfo, image_frames, layout_of, locate_clip, native_path, resolve_clip, to_working
from ..record import ClipRecord, PairRecord, read_record
from ..scoring import Family, Thresholds, pair_inliers
from ..signals import MAP_VIEWS, READING_LABELS, blend_heat, leading_picture, map_on_frame

__all__ = [
    "THUMB_WIDTH",
    "ClipThumbs",
    "Thumb",
    "WorstPair",
    "clip_thumbs",
    "draw_matches",
    "many_clip_thumbs",
    "read_frames",
    "thumbs_html",
    "worst_pair",
    "LAYER_RGB",
]

THUMB_WIDTH = 200
"""Width of a thumbnail, px (the height keeps the clip's aspect)."""
JPEG_QUALITY = 80
INLIER_RGB = (40, 210, 60)
OUTLIER_RGB = (255, 40, 40)
LAYER_RGB = (230, 60, 220)
"""Colour of a drifting layer's tracks, in the report and both viewers."""


@dataclass(frozen=True)
class Thumb:
    """One picture of a clip: a short ``label`` under it, a longer ``title`` (tooltip) and its JPEG."""

    label: str
    title: str
    jpeg: bytes
    size: tuple[int, int]
    """(width, height), px."""


@dataclass(frozen=True)
class ClipThumbs:
    """The thumbnails of one clip, or none and a ``note`` saying why (one sentence); a note may
    also come with thumbnails (the clip has frames but no scored pair to draw)."""

    clip_id: str
    thumbs: tuple[Thumb, ...] = ()
    note: str | None = None


@dataclass(frozen=True)
class WorstPair:
    """The pair a clip scores worst on: its record, the family it was judged with and that
    family's IR (share, 0..1) on the pair."""

    pair: PairRecord
    family: Family
    ir: float


def worst_pair(record: ClipRecord) -> WorstPair | None:
    """The scored pair with the lowest IR under the record's background family, among the valid
    pairs (those counted in the clip's IR; any pair with a fitted model when none is valid) at the
    largest scale that has one; ties go to the earliest pair. None when no pair has a fit."""
    fam = record.background.model
    scored = []
    for p in record.pairs:
        fit = p.fit(fam)
        if p.skip is None and fit is not None and fit.model is not None and fit.ir is not None:
            scored.append((p, fit))
    pool = [(p, f) for p, f in scored if f.valid] or scored
    if not pool:
        return None
    top = max(p.scale for p, _ in pool)
    p, f = min(((p, f) for p, f in pool if p.scale == top), key=lambda pf: (pf[1].ir, pf[0].t0, pf[0].t1))
    assert f.ir is not None
    return WorstPair(p, fam, float(f.ir))


def read_frames(info: ClipInfo, wanted: Iterable[int]) -> dict[int, np.ndarray]:
    """The frames ``wanted`` of the clip ``info`` describes, (H, W, 3) uint8 RGB at its working
    resolution (as :func:`geocon_core.media.reader.iter_frames` yields them). A video is decoded in order
    up to the last frame wanted, converting only the wanted ones; an image folder reads only
    their files. Raises :class:`~geocon_core.media.decode.ClipError` (one sentence naming the file) when
    the clip is gone or no longer decodes as it did when it was scored."""
    want = sorted({int(t) for t in wanted})
    if want and (want[0] < 0 or want[-1] >= info.num_frames):
        raise ValueError(f"frames {want} outside 0..{info.num_frames - 1}")
    layout = layout_of(info)
    W, H = info.working_size
    source = _image_files(info, want) if info.kind == "images" else _video_frames(info, want)
    got = {}
    for t, bgr in source:
        if (bgr.shape[1], bgr.shape[0]) != info.source_size:
            raise ClipError(f"{info.path}: decodes differently than when it was scored (changed since?)")
        got[t] = to_working(bgr, layout, W, H)
    return got


def _image_files(info: ClipInfo, want: list[int]) -> Iterator[tuple[int, np.ndarray]]:
    """(t, BGR) of the frames ``want`` of an image folder, reading only their files."""
    name = info.path
    _, files = resolve_clip(Path(name), name)
    assert files is not None
    if len(files) != info.num_frames:
        raise ClipError(f"{name}: holds {len(files)} frames, {info.num_frames} when it was scored (changed since?)")
    for t in want:
        yield t, next(image_frames([files[t]], name))


def _video_frames(info: ClipInfo, want: list[int]) -> Iterator[tuple[int, np.ndarray]]:
    """(t, BGR) of the frames ``want`` of a video or GIF: decoded in order up to the last one,
    the frames in between stepped over (``grab``) without being converted to images."""
    name = info.path
    if not want:
        return
    if not Path(name).is_file():
        raise ClipError(f"{name}: no such file")
    with native_path(name) as safe:
        cap = cv2.VideoCapture(safe, cv2.CAP_FFMPEG)
    try:
        if not cap.isOpened():
            raise ClipError(f"{name}: cannot be decoded any more")
        todo = set(want)
        for t in range(want[-1] + 1):
            if not cap.grab():
                raise ClipError(f"{name}: ends after {t} frames but had {info.num_frames} when it was scored")
            if t in todo:
                ok, frame = cap.retrieve()
                if not ok or frame is None:
                    raise ClipError(f"{name}: frame {t} no longer decodes")
                yield t, (cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame[..., :3])
    except cv2.error as exc:
        raise ClipError(f"{name}: no longer decodes ({str(exc).strip().splitlines()[-1]})") from None
    finally:
        cap.release()


def _resize(rgb: np.ndarray, width: int) -> np.ndarray:
    h, w = rgb.shape[:2]
    height = max(1, round(h * width / w))
    return cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if width < w else cv2.INTER_LINEAR)


def draw_matches(rgb: np.ndarray, x1: np.ndarray, x2: np.ndarray, inliers: np.ndarray, width: int) -> np.ndarray:
    """A ``width``-px-wide picture of the frame ``rgb`` (working px) with each match drawn as a
    dot at ``x1`` (N, 2; working px of this frame) and a line to ``x2`` (its place in the pair's
    other frame): inliers green, outliers red and on top, over the frame in muted grey. Drawn at
    twice the size and reduced, so that thin lines stay smooth."""
    big = _resize(rgb, 2 * width)
    gray = cv2.cvtColor(big, cv2.COLOR_RGB2GRAY)
    big = cv2.cvtColor((gray * 0.55 + 70).astype(np.uint8), cv2.COLOR_GRAY2RGB)  # quiet: the matches stand out
    k = big.shape[1] / rgb.shape[1]
    shift = 4  # sub-pixel precision of cv2's drawing (coordinates x 16)
    a = np.round(np.asarray(x1, float) * k * (1 << shift)).astype(np.int64)
    b = np.round(np.asarray(x2, float) * k * (1 << shift)).astype(np.int64)
    mask = np.asarray(inliers, bool)
    for sel, col in ((mask, INLIER_RGB), (~mask, OUTLIER_RGB)):
        for (ax, ay), (bx, by) in zip(a[sel], b[sel], strict=True):
            cv2.line(big, (int(ax), int(ay)), (int(bx), int(by)), col, 2, cv2.LINE_AA, shift)
        for ax, ay in a[sel]:
            cv2.circle(big, (int(ax), int(ay)), 4 << shift, (0, 0, 0), -1, cv2.LINE_AA, shift)
            cv2.circle(big, (int(ax), int(ay)), 3 << shift, col, -1, cv2.LINE_AA, shift)
    return _resize(big, width)


def _drift_frame(record: ClipRecord) -> int | None:
    """The keyframe to draw a drifting layer on (the middle keyframe most of its tracks were
    placed at), or None when the multi-view check failed no layer."""
    mv = record.multiview
    if record.drift_finding() is None or mv is None or mv.layer_of is None or mv.track_frame is None:
        return None
    frames = mv.track_frame[mv.layer_of == 0]
    values, counts = np.unique(frames, return_counts=True)
    return int(values[np.argmax(counts)]) if len(values) else None


def _drift_thumb(record: ClipRecord, rgb: np.ndarray, t: int, width: int) -> Thumb:
    """The drifting layer on frame ``t``: the judged tracks placed there as dots (the layer's in
    magenta, the others green), the layer's box and an arrow of its drift (drawn 5 times longer)."""
    mv = record.multiview
    assert mv is not None and mv.layer_of is not None and mv.track_frame is not None and mv.track_xy is not None
    layer = mv.layers[0]
    big = _resize(rgb, 2 * width)
    gray = cv2.cvtColor(big, cv2.COLOR_RGB2GRAY)
    big = cv2.cvtColor((gray * 0.55 + 70).astype(np.uint8), cv2.COLOR_GRAY2RGB)
    kw, s = big.shape[1] / rgb.shape[1], record.video.scale  # working -> picture px; source -> working px
    ox, oy = record.video.offset

    def pic(x: float, y: float) -> tuple[int, int]:
        return round((x * s + ox) * kw), round((y * s + oy) * kw)

    at = mv.track_frame == t
    for sel, col in ((at & (mv.layer_of != 0), INLIER_RGB), (at & (mv.layer_of == 0), LAYER_RGB)):
        for x, y in mv.track_xy[sel]:
            cv2.circle(big, pic(x, y), 2, col, -1, cv2.LINE_AA)
    x0, y0, x1, y1 = layer.box
    cv2.rectangle(big, pic(x0, y0), pic(x1, y1), LAYER_RGB, 2, cv2.LINE_AA)
    cx, cy = pic((x0 + x1) / 2, (y0 + y1) / 2)
    dx, dy = (5 * layer.drift_px * s * kw * d for d in layer.direction)
    cv2.arrowedLine(big, (cx, cy), (round(cx + dx), round(cy + dy)), (255, 255, 255), 3, cv2.LINE_AA, tipLength=0.25)
    return _thumb(
        f"drifting layer: ~{layer.drift_px:.1f} px",
        f"the multi-view check: {layer.describe()} (tracks of frame {t}: magenta in the layer; arrow 5x its drift)",
        _resize(big, width),
    )


def _readings_picture(record: ClipRecord) -> tuple[str, str] | None:
    """(reading, map) the clip model's verdict leans on most among the readings with a picture
    (:func:`~geocon_core.signals.leading_picture`), or None."""
    a = record.readings.appearance if record.readings is not None else None
    if a is None or a.maps is None or not record.config.signals.enabled:
        return None
    return leading_picture(record.finding().parts)


def _readings_thumb(record: ClipRecord, rgb: np.ndarray, t: int, reading: str, name: str, width: int) -> Thumb:
    """Where ``reading`` fires over the clip (its map, :mod:`geocon_core.signals.pictures`) on frame ``t``."""
    a = record.readings.appearance if record.readings is not None else None
    assert a is not None and a.maps is not None
    view = MAP_VIEWS[name]
    shares = map_on_frame(a.maps, name, record.video.content_box, (rgb.shape[1], rgb.shape[0]))
    value = record.reading_values().get(reading)
    shown = "?" if value is None else f"{value:.3g}"
    return _thumb(
        f"{READING_LABELS[reading]}: {shown}",
        f"{view.title} over the clip, on frame {t} ({view.unit}; full colour at {view.vmax:g}): the reading the "
        f"clip score leans on most",
        _resize(blend_heat(rgb, shares, view.vmax), width),
    )


def _jpeg(rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def _thumb(label: str, title: str, rgb: np.ndarray) -> Thumb:
    return Thumb(label, title, _jpeg(rgb), (rgb.shape[1], rgb.shape[0]))


def clip_thumbs(folder: str | Path, clip_id: str | None = None, *, width: int = THUMB_WIDTH) -> ClipThumbs:
    """The thumbnails of the clip whose record is in ``folder``: first frame, worst pair
    (:func:`worst_pair`, matches drawn) and last frame, each ``width`` px wide. Never raises: a
    record or clip that cannot be read gives a :class:`ClipThumbs` with a note instead."""
    folder = Path(folder)
    cid = clip_id or folder.name
    try:
        record = read_record(folder)
    except Exception as exc:  # a report must not fail on one clip: any reason becomes the note
        return ClipThumbs(cid, note=f"No thumbnails: the record cannot be read ({_one_line(exc)}).")
    try:
        info = locate_clip(record.video, folder)
        last = info.num_frames - 1
        worst = worst_pair(record)
        drift_at = _drift_frame(record)
        picture = _readings_picture(record)
        middle = last // 2
        wanted = (
            {0, last}
            | ({worst.pair.t0} if worst is not None else set())
            | ({drift_at} if drift_at is not None else set())
            | ({middle} if picture is not None else set())
        )
        frames = read_frames(info, wanted)
        thumbs = [_thumb("first frame", f"frame 0 of {info.num_frames}", _resize(frames[0], width))]
        if picture is not None:
            thumbs.append(_readings_thumb(record, frames[middle], middle, *picture, width))
        if drift_at is not None:
            thumbs.append(_drift_thumb(record, frames[drift_at], drift_at, width))
        note = None
        if worst is not None:
            p = worst.pair
            rows = record.matches.rows(p.index)
            tau = Thresholds.of(record.config).tau(worst.family)
            inl = pair_inliers(record, p.index, worst.family, tau)
            x1 = record.matches.x1[rows] / p.scale
            x2 = record.matches.x2[rows] / p.scale
            k = int(inl.sum())
            thumbs.append(
                _thumb(
                    f"worst pair {p.t0}\u2192{p.t1}: IR {worst.ir:.2f}",
                    f"worst pair: frames {p.t0}\u2192{p.t1} (gap {p.gap}, scale {p.scale:g}), IR {worst.ir:.3f} "
                    f"under {worst.family} at tau {tau:g}; {k} inliers (green), {inl.size - k} outliers (red)",
                    draw_matches(frames[p.t0], x1, x2, inl, width),
                )
            )
        else:
            note = f"No scored pair under {record.background.model} to draw."
        thumbs.append(_thumb("last frame", f"frame {last} of {info.num_frames}", _resize(frames[last], width)))
    except Exception as exc:  # a moved, changed or unreadable clip: the note says which and why
        return ClipThumbs(cid, note=f"No thumbnails: {_one_line(exc)}.")
    return ClipThumbs(cid, tuple(thumbs), note)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text.rstrip(".")


def many_clip_thumbs(
    folders: Mapping[str, str | Path], *, width: int = THUMB_WIDTH, workers: int = 4
) -> dict[str, ClipThumbs]:
    """:func:`clip_thumbs` of each ``clip_id -> record folder``, on up to ``workers`` threads
    (decoding releases the interpreter lock)."""
    if not folders:
        return {}
    with ThreadPoolExecutor(max_workers=max(1, min(workers, len(folders)))) as pool:
        futures = {cid: pool.submit(clip_thumbs, folder, cid, width=width) for cid, folder in folders.items()}
        return {cid: f.result() for cid, f in futures.items()}


def thumbs_html(ct: ClipThumbs) -> str:
    """The strip of ``ct``'s thumbnails (a ``div.thumbs``), or its one-line note
    (``p.nothumbs``) when it has none."""
    note = f'<p class="nothumbs">{html.escape(ct.note)}</p>' if ct.note else ""
    if not ct.thumbs:
        return note
    figs = "".join(
        f'<figure><img src="data:image/jpeg;base64,{base64.b64encode(t.jpeg).decode()}" width="{t.size[0]}" '
        f'height="{t.size[1]}" alt="{html.escape(ct.clip_id)}: {html.escape(t.label)}" title="{html.escape(t.title)}">'
        f"<figcaption>{html.escape(t.label)}</figcaption></figure>"
        for t in ct.thumbs
    )
    return f'<div class="thumbs">{figs}</div>{note}'
