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
import pickle
import re
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from . import test_bad_input as catalogue
from .bad_inputs import pan_frames, snapshot
from .test_bad_input import Case, Ctx, H, N, Outcome, W, frames_of, judge, record, score

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
    for module in case.needs:
        pytest.importorskip(module)
    case.build(ctx)
    before = snapshot(ctx.tmp)
    res = ctx.invoke(list(case.argv)) if case.runner == "cli" else ctx.spawn(list(case.argv))
    problems = judge(case, ctx, res, before)
    assert not problems, f"{case.name}: {res.describe()}\n  - " + "\n  - ".join(problems)


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
