"""Truncated and partially damaged input: a clip is scored on the frames that decode, and a record
of a clip that lost frames says so in one warning sentence (never ``warnings: []``); a clip of which
fewer than 2 frames decode is a one-sentence :class:`ClipError`.

Every clip is rendered here: a camera panning over a flat texture, 160x90, 24 frames, encoded with
PyAV (single-threaded, so the bytes and the cut points are reproducible), then cut or damaged."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from geocon_core.config import preset
from geocon_core.media import ClipError, ClipInfo, FrameCount, iter_frames, probe_clip
from geocon_core.scoring import score_clip

from .conftest import read_video

W, H, T = 160, 90, 24


def pan(num_frames: int = T) -> list[np.ndarray]:
    """``num_frames`` RGB frames panning 3 px right and 1 px down per frame over a smooth texture."""
    rng = np.random.default_rng(0)
    big_w, big_h = W + 3 * num_frames + 8, H + num_frames + 8
    small = rng.integers(30, 256, (big_h // 4, big_w // 4, 3), dtype=np.uint8)
    big = cv2.resize(small, (big_w, big_h), interpolation=cv2.INTER_CUBIC)
    return [np.ascontiguousarray(big[t : t + H, 3 * t : 3 * t + W]) for t in range(num_frames)]


def encode(
    path: Path,
    frames: list[np.ndarray],
    *,
    container: str = "mp4",
    codec: str = "libx264",
    faststart: bool = False,
    intra: bool = True,
    pts_ms: list[int] | None = None,
) -> Path:
    """Encode RGB frames; ``intra``: every frame a key frame (frames of similar size, so a cut at a
    share of the bytes loses about that share of the frames). ``pts_ms``: one timestamp per frame."""
    import av

    options = ({"g": "1"} if intra else {}) | ({"preset": "ultrafast"} if codec == "libx264" else {})
    with av.open(str(path), "w", format=container, options={"movflags": "faststart"} if faststart else {}) as c:
        stream = c.add_stream(codec, rate=24, options=options)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.thread_count = 1
        if pts_ms is not None:
            stream.codec_context.time_base = stream.time_base = Fraction(1, 1000)
        for t, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            if pts_ms is not None:
                frame.pts, frame.time_base = pts_ms[t], Fraction(1, 1000)
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def write_gif(path: Path, frames: list[np.ndarray]) -> Path:
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=40, loop=0)
    return path


def cut(src: Path, dst: Path, keep: int) -> Path:
    """``dst``: the first ``keep`` bytes of ``src``."""
    dst.write_bytes(src.read_bytes()[:keep])
    return dst


def one_sentence(msg: str) -> None:
    assert "\n" not in msg and ". " not in msg and "Traceback" not in msg and "cv2" not in msg, msg


def promised(n: int, total: int = T) -> str:
    return f"the container promises {total} frames but only {n} decoded (truncated or damaged file); scored on those"


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("truncated")
    frames = pan()
    return {
        "faststart": encode(out / "faststart.mp4", frames, faststart=True),
        "plain": encode(out / "plain.mp4", frames, intra=False),  # one key frame, then P frames
        "webm": encode(out / "clip.webm", frames, container="webm", codec="libvpx-vp9"),
        "gif": write_gif(out / "clip.gif", frames),
    }


# --- what the container promises -------------------------------------------------------------


def test_intact_clips_have_no_warnings(clips):
    for key in ("faststart", "plain", "webm", "gif"):
        info = probe_clip(clips[key])
        assert info.num_frames == T and info.warnings == (), key


def test_truncated_faststart_mp4_is_scored_on_what_decodes_with_a_warning(clips, tmp_path):
    # the user's report: moov first, cut at 50% of the bytes -> 11 of 24 frames, warnings: []
    data = clips["faststart"].read_bytes()
    path = cut(clips["faststart"], tmp_path / "half.mp4", len(data) // 2)
    info = probe_clip(path)
    n = len(read_video(path))
    assert 2 <= n < T // 2 + 2 and info.num_frames == n
    assert info.warnings == (promised(n),)
    assert len(list(iter_frames(info))) == n
    assert ClipInfo.from_dict(info.to_dict()) == info


def test_corrupt_bytes_in_the_middle_of_an_mp4(clips, tmp_path):
    # moov last; 2000 zero bytes in the middle of the media data break a P frame, and the decoder
    # stops (in an all-intra stream it conceals the damage and outputs every frame, which no frame
    # count can reveal)
    data = clips["plain"].read_bytes()
    mid = data.find(b"mdat") + (data.find(b"moov") - data.find(b"mdat")) // 2
    path = tmp_path / "holed.mp4"
    path.write_bytes(data[:mid] + bytes(2000) + data[mid + 2000 :])
    info = probe_clip(path)
    assert 2 <= info.num_frames < T - 2
    assert info.warnings == (promised(info.num_frames),)


def test_truncated_webm_warns_against_its_duration(clips, tmp_path):
    # webm stores no frame count: the promise is duration x frame rate, an estimate
    data = clips["webm"].read_bytes()
    path = cut(clips["webm"], tmp_path / "half.webm", len(data) // 2)
    info = probe_clip(path)
    assert info.num_frames < T * 2 / 3
    assert info.warnings == (
        f"the container's duration implies about {T} frames but only {info.num_frames} decoded"
        " (truncated or damaged file); scored on those",
    )


def test_variable_frame_rate_estimate_is_not_a_truncation(tmp_path):
    # 12 frames at 33 ms then 12 at 80 ms: duration x average rate would say 32 frames; the packets
    # of a variable rate are counted instead, and cover the duration: 24, as decode
    pts = [33 * t if t < 12 else 33 * 12 + 80 * (t - 12) for t in range(T)]
    path = encode(tmp_path / "vfr.mkv", pan(), container="matroska", pts_ms=pts)
    from geocon_core.media import container_frame_count

    assert container_frame_count(str(path)) == FrameCount(T, exact=False)
    info = probe_clip(path)
    assert info.num_frames == T and len(info.warnings) == 1  # no truncation: the variable rate is named
    assert info.warnings[0].startswith("variable frame rate: frames are 33 to 80 ms apart")


PAUSING_MS = [33 * t + (500 if t >= 8 else 0) + (900 if t >= 16 else 0) for t in range(T)]
"""A screen recording that stops twice (for 0.5 s, then 0.9 s): duration x its stated rate
promises 53 frames of the 24 it holds."""


@pytest.mark.parametrize(
    ("container", "codec", "name"),
    [("matroska", "libx264", "pausing.mkv"), ("webm", "libvpx-vp9", "pausing.webm")],
)
def test_a_complete_clip_that_pauses_is_not_taken_for_a_truncation(tmp_path, container, codec, name):
    path = encode(tmp_path / name, pan(), container=container, codec=codec, pts_ms=PAUSING_MS)
    from geocon_core.media import container_frame_count

    assert container_frame_count(str(path)) == FrameCount(T, exact=False)
    info = probe_clip(path)
    assert info.num_frames == T and len(info.warnings) == 1, info.warnings  # the variable rate, no truncation
    assert info.warnings[0].startswith("variable frame rate: frames are 33 to 933 ms apart")


def test_a_complete_clip_that_slows_to_one_frame_a_second_is_not_truncated(tmp_path):
    pts = [33 * t if t < 12 else 33 * 12 + 1000 * (t - 11) for t in range(T)]
    path = encode(tmp_path / "slow.mkv", pan(), container="matroska", pts_ms=pts)
    info = probe_clip(path)
    assert info.num_frames == T and not any("truncated" in w for w in info.warnings), info.warnings


def test_a_truncated_clip_of_variable_rate_is_still_warned(tmp_path):
    # variable from its first frames on (33 and 66 ms apart in turn); the second half cut off: the
    # packets left cover half the duration, so the estimate doubles them
    pts = list(np.cumsum([0] + [33 if t % 2 else 66 for t in range(T - 1)]))
    full = encode(tmp_path / "vfr.mkv", pan(), container="matroska", pts_ms=[int(v) for v in pts])
    half = cut(full, tmp_path / "half.mkv", len(full.read_bytes()) // 2)
    from geocon_core.media import container_frame_count

    promise = container_frame_count(str(half))
    assert promise is not None and not promise.exact and promise.frames >= T - 1, promise
    info = probe_clip(half)
    assert info.num_frames < T * 2 / 3
    assert any(w.startswith("the container's duration implies about") and "truncated" in w for w in info.warnings)


def test_a_steady_matroska_keeps_its_duration_estimate(tmp_path):
    path = encode(tmp_path / "steady.mkv", pan(), container="matroska")
    from geocon_core.media import container_frame_count

    assert container_frame_count(str(path)) == FrameCount(T, exact=False)
    half = cut(path, tmp_path / "half.mkv", len(path.read_bytes()) // 2)
    info = probe_clip(half)
    assert any("implies about 24 frames" in w for w in info.warnings), info.warnings


def test_edit_list_hiding_frames_is_not_a_truncation(clips, tmp_path):
    # remuxed with the first 5 frames before time 0: the mp4 index still counts 24 samples, the
    # edit list plays 19; the promise is capped by the stream's duration
    import av

    path = tmp_path / "edit.mp4"
    with av.open(str(clips["plain"])) as src, av.open(str(path), "w", format="mp4") as dst:
        ist = src.streams.video[0]
        ost = dst.add_stream_from_template(ist)
        shift = round(5 / (24 * ist.time_base))
        for packet in src.demux(ist):
            if packet.dts is None:
                continue
            packet.pts -= shift
            packet.dts -= shift
            packet.stream = ost
            dst.mux(packet)
    with av.open(str(path)) as c:
        assert c.streams.video[0].frames == T
    info = probe_clip(path)
    assert info.num_frames == T - 5 and info.warnings == ()


def test_small_shortfall_of_an_exact_count_is_tolerated():
    count = FrameCount(24, exact=True)
    assert not count.falls_short(24) and not count.falls_short(23)  # one frame: an index off by one
    assert count.falls_short(22) and count.falls_short(10)
    estimate = FrameCount(24, exact=False)
    assert not estimate.falls_short(17) and estimate.falls_short(15)
    assert not FrameCount(200, exact=True).falls_short(191) and FrameCount(200, exact=True).falls_short(189)


# --- a decoder error or a cut GIF -------------------------------------------------------------


def test_decoder_error_mid_stream_is_a_warning(clips, monkeypatch):
    real = cv2.VideoCapture

    class Failing:
        """A capture whose decoder raises at frame 9."""

        def __init__(self, *args):
            self._cap, self._t = real(*args), 0

        def read(self):
            if self._t == 9:
                raise cv2.error("OpenCV(5.0) decoder.cpp:1: error: (-2:Unspecified error) broken NAL unit")
            self._t += 1
            return self._cap.read()

        def __getattr__(self, name):
            return getattr(self._cap, name)

    monkeypatch.setattr(cv2, "VideoCapture", Failing)
    info = probe_clip(clips["plain"])
    assert info.num_frames == 9
    (warning,) = info.warnings
    assert warning.startswith("decoding stopped with an error at frame 9 of the 24 the container promises (")
    assert warning.endswith("); scored on the 9 frames before it")
    one_sentence(warning)
    assert len(list(iter_frames(info))) == 9


def test_gif_cut_short(clips, tmp_path):
    data = clips["gif"].read_bytes()
    assert data.endswith(b";")
    path = cut(clips["gif"], tmp_path / "cut.gif", len(data) * 3 // 4)
    info = probe_clip(path)
    assert 2 <= info.num_frames < T
    (warning,) = info.warnings
    assert warning.startswith("the GIF is cut short inside frame ")
    assert warning.endswith(f"(truncated or damaged file); scored on the {info.num_frames} frames that decoded")
    # only the trailer lost: every frame decodes, but the file may have held more
    info = probe_clip(cut(clips["gif"], tmp_path / "no_trailer.gif", len(data) - 1))
    assert info.num_frames == T
    assert info.warnings == (
        "the GIF ends without its trailer block, so later frames may be missing;"
        f" scored on the {T} frames that decoded",
    )


# --- nothing (or one frame) decodes: an error, not an empty record ------------------------------


def test_truncation_leaving_one_frame_is_an_error(clips, tmp_path):
    data = clips["faststart"].read_bytes()
    mdat = data.find(b"mdat")
    for keep in range(mdat + 4, len(data), 200):  # the shortest cut that decodes a frame
        path = cut(clips["faststart"], tmp_path / "one.mp4", keep)
        cap = cv2.VideoCapture(str(path))
        n = 0
        while cap.read()[0]:
            n += 1
        cap.release()
        if n:
            break
    assert n == 1
    with pytest.raises(ClipError) as err:
        probe_clip(path)
    assert str(err.value) == (
        f"{path}: only 1 of the {T} frames the container promises decoded (truncated or damaged file);"
        " at least 2 are needed"
    )


@pytest.mark.parametrize("case", ["no_media", "no_moov"])
def test_nothing_decodes_is_one_sentence(clips, tmp_path, case):
    if case == "no_media":  # moov first, the media data cut away
        data = clips["faststart"].read_bytes()
        path = cut(clips["faststart"], tmp_path / "empty.mp4", data.find(b"mdat") + 4)
    else:  # moov last, lost with the second half
        data = clips["plain"].read_bytes()
        path = cut(clips["plain"], tmp_path / "no_moov.mp4", len(data) // 2)
    with pytest.raises(ClipError) as err:
        probe_clip(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: unreadable bytes ("), msg
    one_sentence(msg)


# --- image folders: a broken frame file is an error naming it -----------------------------------


@pytest.mark.parametrize("damage", ["garbage", "cut_short"])
def test_broken_png_in_a_folder_is_named(tmp_path, damage):
    folder = tmp_path / "seq"
    folder.mkdir()
    for t, rgb in enumerate(pan(5)):
        assert cv2.imwrite(str(folder / f"{t:03d}.png"), rgb[..., ::-1])
    bad = folder / "002.png"
    data = bad.read_bytes()
    bad.write_bytes(b"\x89PNG\r\n\x1a\n garbage" if damage == "garbage" else data[: len(data) // 2])
    with pytest.raises(ClipError) as err:
        probe_clip(folder)
    assert str(err.value) == f"{bad}: cannot be decoded as an image (frame 2 of {folder})"
    assert err.value.__cause__ is None


# --- the record -------------------------------------------------------------------------------


def test_record_of_a_truncated_clip_carries_the_warning(clips, tmp_path):
    data = clips["faststart"].read_bytes()
    path = cut(clips["faststart"], tmp_path / "half.mp4", len(data) // 2)
    record = score_clip(path, preset("fast").with_(masks="none"), workers=1)
    n = record.video.num_frames
    assert n < T
    assert record.warnings[0] == promised(n)
    assert record.summary()["warnings"][0] == promised(n)


def test_clip_info_of_an_older_record_has_no_warnings(clips):
    d = probe_clip(clips["plain"]).to_dict()
    assert d["warnings"] == []
    del d["warnings"]
    assert ClipInfo.from_dict(d).warnings == ()
    with pytest.raises(ValueError):
        ClipInfo.from_dict({**d, "warnings": "one"})
