"""The bad-media catalogue: valid containers that look damaged (an audio track longer than the
video, timestamps that start late, two video tracks), files that are no clip (a Rerun recording,
a folder of videos, bytes given as a pose source) and records whose counts or parts were edited or
mixed up, each run through the ``geocon`` command line with the conventions of
``test_bad_input.py`` (:func:`~tests.test_bad_input.judge`): a refusal is exit code 2 with one
``error:`` line naming the file, nothing is left behind, inputs are unchanged.

To add a case, append a ``Case`` to one of the tables (``CONTAINERS``, ``NOT_CLIPS``, ``RECORDS``,
``POSE_SOURCES``)."""

from __future__ import annotations

import json
import os
import pickle
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from . import test_bad_input as catalogue
from .bad_inputs import pan_frames
from .test_bad_input import Case, Ctx, H, N, Outcome, W, build_all_checks, frames_of, record, run_case, score

assets = catalogue.assets
"""The catalogue's session inputs (a fixture), shared with ``test_bad_input.py``."""
ctx = catalogue.ctx
"""A case's working folder as the current directory (a fixture of the catalogue)."""

REFUSAL_LIMIT_S = 10.0
"""An edited record is refused within this many seconds (it is refused before anything is
allocated or rendered; a run that allocates by the edited count takes minutes or is killed)."""


# --- containers PyAV writes -----------------------------------------------------------------------


def _video_stream(c, size: tuple[int, int], intra: bool):
    """An H.264 stream of ``size`` at 24 frames/s, timestamps in frames."""
    options = {"preset": "ultrafast", **({"g": "1"} if intra else {})}
    stream = c.add_stream("libx264", rate=24, options=options)
    stream.width, stream.height, stream.pix_fmt = *size, "yuv420p"
    stream.thread_count = 1
    stream.codec_context.time_base = Fraction(1, 24)
    return stream


def _mux(c, stream, frame) -> None:
    """Encode ``frame`` (None: flush) into ``stream`` and mux its packets."""
    for packet in stream.encode(frame) if frame is not None else stream.encode():
        c.mux(packet)


def _audio(c, audio, seconds: float) -> None:
    """A ``seconds`` long tone into the AAC stream ``audio`` (16 kHz mono)."""
    import av

    samples = (np.sin(np.arange(int(16000 * seconds)) * 0.17) * 0.3).astype(np.float32)
    for at in range(0, len(samples), 1024):
        chunk = av.AudioFrame.from_ndarray(samples[None, at : at + 1024], format="fltp", layout="mono")
        chunk.sample_rate, chunk.pts = 16000, at
        _mux(c, audio, chunk)
    _mux(c, audio, None)


def write_av(
    path: Path,
    frames: list[np.ndarray],
    *,
    audio_s: float = 0.0,
    start_s: float = 0.0,
    second: list[np.ndarray] | None = None,
    intra: bool = False,
) -> Path:
    """H.264 ``frames`` at 24 frames/s in the container the suffix of ``path`` names (``.mp4``,
    ``.mkv``), with an AAC track of ``audio_s`` seconds (0: none), the video's timestamps starting
    at ``start_s`` seconds, and ``second`` as a second video track. Skips the test where PyAV
    cannot encode AAC."""
    import av

    fmt = {".mp4": "mp4", ".mkv": "matroska"}[path.suffix]
    tracks = [frames] if second is None else [frames, second]
    try:
        with av.open(str(path), mode="w", format=fmt) as c:
            streams = [_video_stream(c, (fs[0].shape[1], fs[0].shape[0]), intra) for fs in tracks]
            audio = c.add_stream("aac", rate=16000) if audio_s else None  # every stream before the first packet
            if audio is not None:
                audio.layout = "mono"
            for t in range(max(len(fs) for fs in tracks)):
                for stream, fs in zip(streams, tracks, strict=True):
                    if t < len(fs):
                        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(fs[t]), format="rgb24")
                        frame.pts, frame.time_base = round(start_s * 24) + t, Fraction(1, 24)
                        _mux(c, stream, frame)
            for stream in streams:
                _mux(c, stream, None)
            if audio is not None:
                _audio(c, audio, audio_s)
    except (av.FFmpegError, ValueError) as exc:
        pytest.skip(f"PyAV cannot write this container here: {exc}")
    return path


def av_clip(name: str, **options) -> Callable[[Ctx], None]:
    """``name``: the pan (``N`` frames of ``W`` x ``H``) written by :func:`write_av`."""
    return lambda ctx: write_av(ctx.tmp / name, frames_of("pan"), **options)


def two_tracks(name: str) -> Callable[[Ctx], None]:
    """``name``: the pan as its first video track, a longer clip of another size as its second."""
    return lambda ctx: write_av(ctx.tmp / name, frames_of("pan"), second=pan_frames(96, 64, 2 * N, seed=8))


def truncated_with_audio(name: str) -> Callable[[Ctx], None]:
    """``full.mkv`` (key frames only, 2 s of audio) and ``name``: its first half."""

    def build(ctx: Ctx) -> None:
        full = write_av(ctx.tmp / "full.mkv", frames_of("pan"), audio_s=2.0, intra=True)
        data = full.read_bytes()
        ctx.write(name, data[: len(data) // 2])

    return build


def all_frames_unwarned(ctx: Ctx, res: Outcome) -> None:
    """Every frame scored, and no word of truncation or damage in the record or the terminal."""
    rec = record(ctx)
    assert rec["video"]["num_frames"] == N, rec["video"]
    damage = [w for w in rec["warnings"] if "truncated" in w or "damaged" in w]
    assert not damage, damage
    assert "truncated" not in res.stdout and "damaged" not in res.stdout, res.stdout


def shown(text: str) -> str:
    """The terminal text with the table's borders and line breaks taken out."""
    return re.sub(r"[\s│┃|]+", " ", text)


def first_track_named(ctx: Ctx, res: Outcome) -> None:
    """The first track (the pan) is scored, and the record and the terminal say which of how many."""
    rec = record(ctx)
    assert rec["video"]["num_frames"] == N and rec["video"]["source_size"] == [W, H], rec["video"]
    said = [w for w in rec["warnings"] if "2 video tracks" in w]
    assert said and "track 1 of 2" in said[0] and f"{W}x{H}" in said[0], rec["warnings"]
    assert "2 video tracks" in shown(res.stdout) and "track 1 of 2" in shown(res.stdout), res.stdout


def truncation_still_warned(ctx: Ctx, res: Outcome) -> None:
    rec = record(ctx)
    assert 2 <= rec["video"]["num_frames"] < N, rec["video"]
    assert any("truncated" in w for w in rec["warnings"]), rec["warnings"]


CONTAINERS = [
    Case("audio-longer-than-video-mp4", av_clip("av.mp4", audio_s=3.0), score("av.mp4"), 0, check=all_frames_unwarned),
    Case("audio-longer-than-video-mkv", av_clip("av.mkv", audio_s=3.0), score("av.mkv"), 0, check=all_frames_unwarned),
    Case("start-at-1e6-s-mp4", av_clip("late.mp4", start_s=1e6), score("late.mp4"), 0, check=all_frames_unwarned),
    Case("start-at-1e6-s-mkv", av_clip("late.mkv", start_s=1e6), score("late.mkv"), 0, check=all_frames_unwarned),
    Case("two-video-tracks-mp4", two_tracks("two.mp4"), score("two.mp4"), 0, check=first_track_named),
    Case("two-video-tracks-mkv", two_tracks("two.mkv"), score("two.mkv"), 0, check=first_track_named),
    Case("truncated-mkv-with-audio", truncated_with_audio("cut.mkv"), score("cut.mkv"), 0,
         check=truncation_still_warned),
]  # fmt: skip


# --- files that are no clip -----------------------------------------------------------------------


def rerun_recording(ctx: Ctx) -> None:
    """``clip.mp4`` scored into ``rec`` with its Rerun recording ``audit.rrd`` beside it."""
    ctx.pan()
    res = ctx.invoke(list(score("clip.mp4", "--rrd", "audit.rrd", out="rec")))
    assert res.code == 0 and (ctx.tmp / "audit.rrd").is_file(), res.describe()


def renamed_recording(ctx: Ctx) -> None:
    """A Rerun recording named like a clip (``audit.mp4``): told by its first bytes."""
    ctx.write("audit.mp4", b"RRF2" + np.random.default_rng(4).bytes(400))


def folder_of_videos(ctx: Ctx) -> None:
    ctx.pan("vids/a.mp4")
    ctx.pan("vids/b.mp4")


def folder_of_platforms(ctx: Ctx) -> None:
    """A dataset's layout: a folder per platform, each holding videos."""
    ctx.pan("ds/sora/a.mp4")
    ctx.pan("ds/veo/a.mp4")


def folder_of_notes(ctx: Ctx) -> None:
    ctx.write("notes/a.txt", "no frames here\n")


def nothing_made(ctx: Ctx, _res: Outcome) -> None:
    assert not (ctx.tmp / "geocon-out").exists(), "a refused view left a geocon-out folder"


RRD_SAYS = ("audit.rrd", "Rerun recording", "rerun")
NOT_CLIPS = [
    Case("view-rerun-recording", rerun_recording, ("view", "audit.rrd", "--headless"), 2, RRD_SAYS,
         forbids=("cannot be decoded",), check=nothing_made, needs=("rerun",)),
    Case("score-rerun-recording", rerun_recording, score("audit.rrd"), 2, RRD_SAYS, forbids=("cannot be decoded",),
         needs=("rerun",)),
    Case("score-recording-named-mp4", renamed_recording, score("audit.mp4"), 2, ("audit.mp4", "Rerun recording")),
    Case("view-not-a-clip", lambda c: c.write("junk.bin", np.random.default_rng(6).bytes(3000)),
         ("view", "junk.bin", "--headless"), 2, ("junk.bin",), check=nothing_made, needs=("rerun",)),
    Case("score-folder-of-videos", folder_of_videos, score("vids"), 2, ("vids", "2 video files", "geocon bench vids")),
    Case("score-folder-of-platform-folders", folder_of_platforms, score("ds"), 2, ("ds", "geocon bench ds")),
    Case("score-folder-of-notes", folder_of_notes, score("notes"), 2, ("notes", "no PNG or JPEG"), forbids=("bench",)),
]  # fmt: skip


# --- records whose counts or parts were edited or mixed up ----------------------------------------


def edited(change: Callable[[dict], object]) -> Callable[[Ctx], None]:
    """The C4 record as ``rec`` with ``change`` applied to its parsed ``record.json``."""

    def build(ctx: Ctx) -> None:
        ctx.record()
        path = ctx.tmp / "rec" / "record.json"
        doc = json.loads(path.read_text(encoding="utf-8"))
        change(doc)
        path.write_text(json.dumps(doc, indent=1), encoding="utf-8")

    return build


def set_in(*keys: str, value: object) -> Callable[[dict], None]:
    def change(doc: dict) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        doc[keys[-1]] = value

    return change


def rewrite_npz(path: Path, change: Callable[[dict[str, np.ndarray]], object]) -> None:
    """Rewrite the ``.npz`` at ``path`` with ``change`` applied to its arrays."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    change(arrays)
    np.savez_compressed(path, **arrays)


def huge_offsets(ctx: Ctx) -> None:
    """The C4 record with the last row offset of ``matches.npz`` at 10^12."""
    ctx.record()

    def change(arrays: dict[str, np.ndarray]) -> None:
        arrays["offsets"] = arrays["offsets"].copy()
        arrays["offsets"][-1] = 10**12

    rewrite_npz(ctx.tmp / "rec" / "matches.npz", change)


def edited_index(change: Callable[[dict], object]) -> Callable[[Ctx], None]:
    """The C4 record with ``change`` applied to its ``overlays/index.json``."""

    def build(ctx: Ctx) -> None:
        ctx.record()
        path = ctx.tmp / "rec" / "overlays" / "index.json"
        doc = json.loads(path.read_text(encoding="utf-8"))
        change(doc)
        path.write_text(json.dumps(doc, indent=1), encoding="utf-8")

    return build


def frame_far_away(doc: dict) -> None:
    doc["frames"]["999999999"] = next(iter(doc["frames"].values()))


def huge_label_png(ctx: Ctx) -> None:
    """The C4 record with a labels PNG whose header states 100000 x 100000 pixels."""
    ctx.record()
    folder = ctx.tmp / "rec" / "overlays"
    first = sorted(folder.glob("labels-*.png"))[0]
    data = bytearray(first.read_bytes())
    data[16:24] = (100_000).to_bytes(4, "big") * 2
    first.write_bytes(bytes(data))


def other_record(ctx: Ctx) -> None:
    """``other``: the record of another clip (the pan, scored with the C4 clip's masks off)."""
    ctx.pan()
    res = ctx.invoke(list(score("clip.mp4", out="other")))
    assert res.code == 0, res.describe()


def mixed(part: str) -> Callable[[Ctx], None]:
    """The C4 record as ``rec`` with ``part`` (a path inside a record) copied from ``other``."""

    def build(ctx: Ctx) -> None:
        ctx.record()
        other_record(ctx)
        (ctx.tmp / "rec" / part).write_bytes((ctx.tmp / "other" / part).read_bytes())

    return build


def written_before_ids(ctx: Ctx) -> None:
    """The C4 record as a record written before records had ids: no ``record_id`` anywhere."""
    ctx.record()
    rec = ctx.tmp / "rec"
    for path in (rec / "record.json", rec / "overlays" / "index.json"):
        doc = json.loads(path.read_text(encoding="utf-8"))
        assert doc.pop("record_id"), f"{path} names no record"
        path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    rewrite_npz(rec / "matches.npz", lambda arrays: arrays.pop("record_id"))


def fast(ctx: Ctx, res: Outcome) -> None:
    assert res.seconds < REFUSAL_LIMIT_S, f"refused after {res.seconds:.1f} s"


def rendered(ctx: Ctx, _res: Outcome) -> None:
    assert (ctx.tmp / "rec" / "audit.rrd").is_file(), "the old record was not rendered"


VIEW = ("view", "rec", "--headless")
ANOTHER = ("another record",)
RECORDS = [
    Case("view-num-frames-1e9", edited(set_in("video", "num_frames", value=10**9)), VIEW, 2,
         ("record.json", "num_frames", "1000000000"), check=fast, needs=("rerun",)),
    Case("view-num-frames-not-a-count", edited(set_in("video", "num_frames", value=1.5)), VIEW, 2,
         ("record.json", "num_frames"), needs=("rerun",)),
    Case("view-masked-share-short", edited(lambda d: d["masked_share"].pop()), VIEW, 2,
         ("record.json", "masked_share"), needs=("rerun",)),
    Case("view-working-size-huge", edited(set_in("video", "working_size", value=[100_000, 100_000])), VIEW, 2,
         ("record.json", "working_size"), check=fast, needs=("rerun",)),
    Case("view-pair-past-the-clip", edited(lambda d: d["pairs"][0].update(t0=10**9, t1=10**9 + 1)), VIEW, 2,
         ("record.json",), check=fast, needs=("rerun",)),
    Case("view-offsets-1e12", huge_offsets, VIEW, 2, ("matches.npz", "offsets"), check=fast, needs=("rerun",)),
    Case("view-overlay-frame-1e9", edited_index(frame_far_away), VIEW, 2, ("index.json", "999999999"), check=fast,
         needs=("rerun",)),
    Case("view-overlay-png-100000-px", huge_label_png, VIEW, 2, ("labels-", "100000x100000"), check=fast,
         needs=("rerun",)),
    Case("view-matches-of-another-record", mixed("matches.npz"), VIEW, 2, ("matches.npz", *ANOTHER),
         needs=("rerun",)),
    Case("view-record-json-of-another-record", mixed("record.json"), VIEW, 2, ("matches.npz", *ANOTHER),
         needs=("rerun",)),
    Case("view-overlays-of-another-record", mixed("overlays/index.json"), VIEW, 2, ("index.json", *ANOTHER),
         needs=("rerun",)),
    Case("view-record-written-before-ids", written_before_ids, VIEW, 0, check=rendered, needs=("rerun",)),
]  # fmt: skip


# --- what `geocon pose-log` is given --------------------------------------------------------------


def object_scene(ctx: Ctx) -> None:
    poses = np.empty(2, dtype=object)
    poses[:] = [np.eye(4), np.eye(4)]
    ctx.npz("objects.npz", poses=poses, pts3d=np.zeros((4, 4, 3)))


NUMPY_HINTS = ("allow_pickle", "If you trust", "pickle.load", "unsafely")
POSE_SOURCES = [
    Case("pose-log-random-bytes", lambda c: c.write("junk.npz", np.random.default_rng(7).bytes(3000)),
         ("pose-log", "junk.npz", "--out", "p.json"), 2, ("junk.npz", ".npz", "not a zip archive"), NUMPY_HINTS),
    Case("pose-log-text", lambda c: c.write("notes.npz", "poses: none\n"), ("pose-log", "notes.npz", "--out", "p.json"),
         2, ("notes.npz", "not a zip archive"), NUMPY_HINTS),
    Case("pose-log-single-npy", lambda c: np.save(c.tmp / "poses.npy", np.stack([np.eye(4)] * 2)),
         ("pose-log", "poses.npy", "--out", "p.json"), 2, ("poses.npy", ".npy"), NUMPY_HINTS),
    Case("pose-log-pickle", lambda c: c.write("scene.npz", pickle.dumps({"poses": [1, 2]})),
         ("pose-log", "scene.npz", "--out", "p.json"), 2, ("scene.npz", "pickle"), NUMPY_HINTS),
    Case("pose-log-object-arrays", object_scene, ("pose-log", "objects.npz", "--out", "p.json"), 2,
         ("objects.npz", "poses"), NUMPY_HINTS),
]  # fmt: skip

CASES = CONTAINERS + NOT_CLIPS + RECORDS + POSE_SOURCES


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_media(case: Case, ctx: Ctx):
    run_case(case, ctx)


def test_record_ids_round_trip_and_older_records_still_read(assets, tmp_path):
    """The reader itself: a record's id is its content's (a rewrite keeps it), a record written
    before ids reads as before (``record_id`` None, its overlays too), and a ``matches.npz`` that
    holds another id is refused naming the file."""
    from geocon_core.record import RecordError, read_overlays, read_record, record_id, write_record

    ctx = Ctx(tmp_path, assets)
    rec = ctx.record("rec")
    now = read_record(rec)
    assert now.record_id == record_id(now) and len(now.record_id) == 16
    assert read_overlays(rec, now) is not None
    write_record(now, tmp_path / "again")
    assert read_record(tmp_path / "again").record_id == now.record_id

    (tmp_path / "old").mkdir()
    written_before_ids(Ctx(tmp_path / "old", assets))
    old = read_record(tmp_path / "old" / "rec")
    assert old.record_id is None and read_overlays(tmp_path / "old" / "rec", old) is not None

    rewrite_npz(rec / "matches.npz", lambda arrays: arrays.update(record_id=np.array(["0123456789abcdef"])))
    with pytest.raises(RecordError, match=r"matches\.npz belongs to another record"):
        read_record(rec)


def test_an_overlay_png_of_another_size_is_refused_from_its_header(assets, tmp_path):
    """A labels PNG whose header states 2^30 x 2^30 pixels is refused from its first 24 bytes:
    its pixels (here none) are never decoded or allocated."""
    from geocon_core.record import read_overlays, read_record

    rec = Ctx(tmp_path, assets).record("rec")
    overlays = read_overlays(rec, read_record(rec))
    assert overlays is not None
    t, entry = next((t, e) for t, e in sorted(overlays.entries.items()) if e.labels is not None)
    assert overlays.labels(t) is not None  # readable as written
    png = rec / "overlays" / str(entry.labels)
    header = bytearray(png.read_bytes()[:33])
    header[16:24] = (1 << 30).to_bytes(4, "big") * 2
    png.write_bytes(bytes(header))
    with pytest.raises(ValueError, match="1073741824x1073741824"):
        overlays.labels(t)


# --- odd sizes, rates, names, frame folders; records from elsewhere; the viewers' inputs ----------
#
# Run by ``test_odd_media`` below: a case that could crash the process (a native library) or hang
# runs as a subprocess of its own, through ``geocon``'s own entry point (so the terminal's lines are
# judged as a user sees them), with a limit that leaves room for a loaded machine.

ODD_SUBPROCESS_LIMIT_S = 60.0
"""A subprocess case of ``ODD`` still running after this long hangs (it is killed and fails)."""


def clip_of(name: str, width: int = W, height: int = H, **options) -> Callable[[Ctx], None]:
    """``name``: ``N`` frames of the pan at ``width`` x ``height``, written by ``write_video``."""
    return lambda ctx: ctx.video(name, pan_frames(width, height, N, seed=3), **options)


def turned_90(ctx: Ctx) -> None:
    """``turned.mp4``: the pan whose track header turns it by 90 degrees (a phone held upright)."""
    import struct

    data = bytearray(ctx.video("turned.mp4", frames_of("pan")).read_bytes())
    at = data.find(b"tkhd") + 4 + 40  # version 0: the matrix follows 40 bytes of fields
    data[at : at + 36] = struct.pack(">9i", 0, 0x10000, 0, -0x10000, 0, 0, 0, 0, 0x40000000)
    (ctx.tmp / "turned.mp4").write_bytes(bytes(data))


def other_clip_beside(name: str, beside: str) -> Callable[[Ctx], None]:
    """``name`` (the pan, ``N`` frames) with another clip of 4 frames as ``beside``."""

    def build(ctx: Ctx) -> None:
        ctx.pan(name)
        ctx.video(beside, pan_frames(W, H, 4, seed=9))

    return build


def frame_folder(extra: Callable[[Path, list[np.ndarray]], object]) -> Callable[[Ctx], None]:
    """``frames/``: the pan as ``00000.png, ...``, then ``extra(folder, frames)``."""

    def build(ctx: Ctx) -> None:
        from .bad_inputs import write_pngs

        frames = frames_of("pan")
        folder = write_pngs(ctx.tmp / "frames", frames)
        extra(folder, frames)

    return build


def _bgr(rgb: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(rgb[..., ::-1])


def jpeg_of_each(folder: Path, frames: list[np.ndarray]) -> None:
    import cv2

    for t, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{t:05d}.jpg"), _bgr(f))


def copy_named(folder: Path, frames: list[np.ndarray]) -> None:
    """A file manager's copy of frame 3 that holds frame 4: ``00003 (1).png``."""
    import cv2

    cv2.imwrite(str(folder / "00003 (1).png"), _bgr(frames[4]))


def upper_case_twin(folder: Path, frames: list[np.ndarray]) -> None:
    import cv2

    cv2.imwrite(str(folder / "00003.PNG"), _bgr(frames[6]))


def apple_double(folder: Path, frames: list[np.ndarray]) -> None:
    """``._00000.png, ...``: the metadata macOS writes beside each file it copies to a foreign disk."""
    for t in range(len(frames)):
        (folder / f"._{t:05d}.png").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        " + bytes(200))


def exif_turned(ctx: Ctx) -> None:
    """``frames/``: the pan as JPEGs, frame 5 tagged with EXIF orientation 6 (turn by 90 degrees)."""
    from PIL import Image

    (ctx.tmp / "frames").mkdir()
    for t, f in enumerate(frames_of("pan")):
        image = Image.fromarray(f)
        exif = image.getexif()
        if t == 5:
            exif[0x0112] = 6
        image.save(ctx.tmp / "frames" / f"{t:05d}.jpg", exif=exif)


def truncated_png_frame(folder: Path, _frames: list[np.ndarray]) -> None:
    data = (folder / "00002.png").read_bytes()
    (folder / "00002.png").write_bytes(data[: len(data) // 2])


def multipage_tiff(ctx: Ctx) -> None:
    from PIL import Image

    pages = [Image.fromarray(f) for f in frames_of("pan")]
    pages[0].save(ctx.tmp / "pages.tif", save_all=True, append_images=pages[1:])


def damaged_h264(ctx: Ctx) -> None:
    """``flip.mp4``: key frames only, 40 bytes of its later two thirds inverted (frames decode, with
    errors the decoder would print)."""
    data = bytearray(ctx.video("flip.mp4", frames_of("pan"), intra=True, faststart=True).read_bytes())
    for at in np.random.default_rng(1).integers(len(data) // 3, len(data), 40):
        data[at] ^= 0xFF
    (ctx.tmp / "flip.mp4").write_bytes(bytes(data))


def masks_folder_named_sam2(ctx: Ctx) -> None:
    ctx.c4()
    shutil.copytree(ctx.tmp / "c4.masks", ctx.tmp / "sam2")


def record_and_clip(ctx: Ctx) -> None:
    """The C4 clip (``c4.mp4``) and its record ``rec``."""
    ctx.c4()
    ctx.record()


def warns(words: str) -> Callable[[Ctx, Outcome], None]:
    """A check: every frame scored, and the record warns with ``words``."""

    def check(ctx: Ctx, _res: Outcome) -> None:
        rec = record(ctx)
        assert any(words in w for w in rec["warnings"]), rec["warnings"]

    return check


def frames_scored(n: int = N, **video: object) -> Callable[[Ctx, Outcome], None]:
    """A check: ``n`` frames scored, and ``record.json``'s ``video`` block holds ``video``."""

    def check(ctx: Ctx, _res: Outcome) -> None:
        got = record(ctx)["video"]
        assert got["num_frames"] == n, f"{got['num_frames']} frames scored, expected {n}"
        for key, want in video.items():
            assert got[key] == want, f"video.{key} = {got[key]!r}, expected {want!r}"

    return check


def with_rrd(name: str) -> Callable[[Ctx, Outcome], None]:
    """A check: every frame scored and the recording ``name`` written."""

    def check(ctx: Ctx, res: Outcome) -> None:
        frames_scored()(ctx, res)
        assert (ctx.tmp / name).is_file() and (ctx.tmp / name).stat().st_size > 0, f"no recording {name}"

    return check


def no_decoder_lines(_ctx: Ctx, res: Outcome) -> None:
    """No line of FFmpeg's (``[h264 @ 0x...]``) or OpenCV's (``[ WARN:...]``) own on the terminal."""
    noise = [line for line in res.stderr.splitlines() if " @ 0x" in line or "WARN:" in line or "libpng" in line]
    assert not noise, noise[:3]


def nothing_served(_ctx: Ctx, res: Outcome) -> None:
    assert "http://" not in res.stdout, f"the server started before the refusal: {res.stdout[:200]!r}"


STRIP = ("score", "strip.mp4", *catalogue.FAST, "--out", "out")
ODD = [
    # sizes: OpenCV's DIS flow crashed the process on a strip (its pyramid chosen from the width
    # alone); SVT-AV1 never returned from a frame under 32 px high and 128 px wide or more
    Case("score-2048x16-strip", clip_of("strip.mp4", 2048, 16), STRIP, 0,
         check=frames_scored(source_size=[2048, 16]), runner="subprocess"),
    Case("score-4096x2-strip", clip_of("strip.mp4", 4096, 2, pix_fmt="yuv444p"), STRIP, 0,
         check=frames_scored(source_size=[4096, 2]), runner="subprocess"),
    Case("score-rrd-of-a-2048x16-strip", clip_of("strip.mp4", 2048, 16), (*STRIP, "--rrd", "a.rrd"), 0,
         check=with_rrd("a.rrd"), runner="subprocess", needs=("rerun",)),
    Case("score-rrd-of-a-16x16-clip", clip_of("tiny.mp4", 16, 16), score("tiny.mp4", "--rrd", "a.rrd"), 0,
         check=with_rrd("a.rrd"), needs=("rerun",)),
    Case("score-161x91-yuv444", clip_of("odd.mp4", 161, 91, pix_fmt="yuv444p"), score("odd.mp4"), 0,
         check=frames_scored(source_size=[161, 91])),
    Case("score-turned-90-degrees", turned_90, score("turned.mp4"), 0, check=frames_scored(source_size=[H, W])),
    # frame rates
    Case("score-rrd-at-999-fps", clip_of("fast.mp4", fps=999), score("fast.mp4", "--rrd", "a.rrd"), 0,
         check=with_rrd("a.rrd"), needs=("rerun",)),
    Case("score-1000-fps-says-so", clip_of("fast.mp4", fps=1000), score("fast.mp4"), 0,
         check=build_all_checks(frames_scored(fps=24.0), warns("states 1000 frames/s"))),
    Case("score-bare-h264-stream", clip_of("bare.h264", container="h264"), score("bare.h264"), 0,
         check=warns("no timestamps")),
    # names FFmpeg would read as a protocol
    Case("score-iso-time-name", lambda c: c.pan("2024-05-01T12:30:00.mp4"), score("2024-05-01T12:30:00.mp4"), 0,
         check=frames_scored()),
    Case("score-name-file-colon", other_clip_beside("file:b.mp4", "b.mp4"), score("file:b.mp4"), 0,
         check=frames_scored()),
    Case("score-name-pipe-colon", lambda c: c.pan("pipe:0.mp4"), score("pipe:0.mp4"), 0, check=frames_scored(),
         runner="subprocess"),
    Case("score-fifo-says-save-to-a-file", lambda c: os.mkfifo(c.tmp / "pipe.mp4"), score("pipe.mp4"), 2,
         ("pipe.mp4", "FIFO", "save the clip"), runner="subprocess"),
    # files and folders of pictures
    Case("score-multipage-tiff", multipage_tiff, score("pages.tif"), 0, check=frames_scored(), needs=("PIL",)),
    Case("score-frames-png-and-jpeg-of-each", frame_folder(jpeg_of_each), score("frames"), 2,
         ("00000.jpg", "00000.png", "one frame stored twice")),
    Case("score-frames-with-a-copy-name", frame_folder(copy_named), score("frames"), 2,
         ("00003.png", "00003 (1).png")),
    Case("score-frames-png-and-PNG", frame_folder(upper_case_twin), score("frames"), 2, ("00003.PNG", "00003.png")),
    Case("score-frames-with-appledouble-files", frame_folder(apple_double), score("frames"), 0,
         check=build_all_checks(frames_scored(), warns("left out 12 hidden files"))),
    Case("score-frames-exif-turned", exif_turned, score("frames"), 2, ("00005.jpg", "EXIF orientation"),
         needs=("PIL",)),
    # the terminal as a user sees it: one line, none of the decoders' own
    Case("score-junk-one-line", lambda c: c.write("junk.bin", b"no video here\n" * 40), score("junk.bin"), 2,
         ("junk.bin",), runner="subprocess"),
    Case("score-truncated-png-frame-one-line", frame_folder(truncated_png_frame), score("frames"), 2,
         ("00002.png",), runner="subprocess"),
    Case("score-damaged-h264-quietly", damaged_h264, score("flip.mp4"), 0, check=no_decoder_lines,
         runner="subprocess"),
    # masks
    Case("masks-sam2-is-also-a-folder", masks_folder_named_sam2, score("c4.mp4", "--masks", "sam2"), 2,
         ("--masks sam2", "./sam2")),
    # records from elsewhere
    Case("view-record-format-2", edited(set_in("format", value="geocon-record/2")), VIEW, 2,
         ("record.json", "geocon-record/2", "score the clip again"), ("not a GeoCon record",), needs=("rerun",)),
    Case("view-fps-infinite", edited(set_in("video", "fps", value=float("inf"))), VIEW, 2,
         ("record.json", "video.fps"), check=fast, needs=("rerun",)),
    Case("view-fps-1e300", edited(set_in("video", "fps", value=1e300)), VIEW, 2, ("record.json", "video.fps"),
         needs=("rerun",)),
    Case("view-record-reformatted", edited(lambda d: None), VIEW, 0, check=rendered, needs=("rerun",)),
    Case("view-matches-npz-of-a-record", record_and_clip, ("view", "rec/matches.npz", "--headless"), 2,
         ("rec/matches.npz", "part of the record", "geocon view rec"), check=nothing_made, needs=("rerun",)),
    # the servers' inputs (127.0.0.1 only)
    Case("serve-a-clip-file", lambda c: c.pan(), ("serve", "clip.mp4", "--port", "0"), 2,
         ("clip.mp4", "is a file", "geocon view clip.mp4"), runner="subprocess", needs=("viser",)),
    Case("serve-clip-not-in-the-results", record_and_clip, ("serve", "rec", "--port", "0", "--clip", "nope"), 2,
         ("--clip", "nope", "rec"), check=nothing_served, runner="subprocess", needs=("viser",)),
    Case("serve-screenshot-onto-a-folder", record_and_clip,
         ("serve", "rec", "--port", "0", "--screenshot", "rec"), 2, ("--screenshot", "rec/screenshot.png"),
         check=nothing_served, runner="subprocess", needs=("viser",)),
    Case("teach-screenshot-onto-a-folder", lambda c: (c.tmp / "shots").mkdir(),
         ("teach", "--port", "0", "--screenshot", "shots"), 2, ("--screenshot", "shots/screenshot.png"),
         check=nothing_served, runner="subprocess", needs=("viser",)),
]  # fmt: skip


def test_the_odd_catalogue_is_complete():
    names = [c.name for c in CASES + ODD]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.full
@pytest.mark.parametrize("case", ODD, ids=[c.name for c in ODD])
def test_odd_media(case: Case, ctx: Ctx, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(catalogue, "SUBPROCESS_TIMEOUT_S", ODD_SUBPROCESS_LIMIT_S)
    run_case(case, ctx)


def test_dis_flow_of_thin_regions_does_not_crash():
    """Every region shape DIS is given, down to 1 px on a side and up to 4096 px long, gives a flow
    of its own size with each preset (run in a child process: a crash there fails the test, not the
    run); regions of ordinary shape are computed unpadded, as before."""
    code = """
import cv2, numpy as np
from geocon_core.flow.dense import DisFlow, _dis_safe_padding
cv2.setNumThreads(1)
rng = np.random.default_rng(0)
big = rng.integers(0, 255, (4100, 4100), dtype=np.uint8)
for preset in ("ultrafast", "fast", "medium"):
    flow = DisFlow(preset=preset)
    for h, w in [(16, 256), (16, 100), (24, 1000), (2, 4096), (1, 50), (31, 91), (16, 2048), (5, 512)]:
        for hh, ww in ((h, w), (w, h)):
            f = flow._calc(np.ascontiguousarray(big[:hh, :ww]), np.ascontiguousarray(big[1:hh + 1, 1:ww + 1]))
            assert f.shape == (hh, ww, 2), (preset, hh, ww, f.shape)
assert _dis_safe_padding(90, 160, 8, 1, 0, 0) == (0, 0)  # a frame of an ordinary clip: as it is
assert _dis_safe_padding(40, 60, 8, 2, 0, 0) == (0, 0)  # a small object's region DIS reads as it is
assert _dis_safe_padding(16, 256, 8, 2, 0, 0) == (16, 0)  # the strip: 32 rows for the fast presets
print("ok")
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.strip() == "ok", (res.returncode, res.stderr[-2000:])


def test_frames_too_thin_for_the_av1_encoder_are_logged_as_images():
    pytest.importorskip("rerun")
    from geocon_viewer.rerun.video import FrameVideo

    assert FrameVideo.encodes(160, 90) and FrameVideo.encodes(33, 4096)
    assert not FrameVideo.encodes(2048, 16) and not FrameVideo.encodes(16, 16) and not FrameVideo.encodes(2, 360)


def test_pycolmap_keeps_the_process_signal_handlers():
    """Importing pycolmap installs glog's failure handler, which answers ``kill`` with a native stack
    trace and the process's end; imported through GeoCon (here from a worker thread, as ``geocon
    teach`` does), ``kill`` still reaches Python's own handler."""
    pytest.importorskip("pycolmap")
    code = """
import os, signal, threading, time
ran = []
signal.signal(signal.SIGTERM, lambda *_: ran.append(1))
from geocon_core.reconstruction.solve import load_pycolmap
worker = threading.Thread(target=load_pycolmap)
worker.start()
worker.join()
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(0.2)
print("handled" if ran else "not handled")
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "handled", (res.returncode, res.stderr[-1500:])
    assert "Aborted at" not in res.stderr


def test_served_urls_put_ipv6_addresses_in_brackets():
    from geocon_viewer.audit.served import ServedApp

    class Server:
        def __init__(self, host: str) -> None:
            self.host = host

        def get_host(self) -> str:
            return self.host

        def get_port(self) -> int:
            return 8080

    app = ServedApp()
    for host, url in (("::1", "http://[::1]:8080"), ("127.0.0.1", "http://127.0.0.1:8080")):
        app.server = Server(host)  # type: ignore[assignment]
        assert app.url == url
