"""The clip reader: layout of the working canvas, burned-in bars, duplicates, hard cuts, every
input format, and one-sentence errors. Synthetic clips come from the project's renderer (known
bars and frame counts); real footage is read from ../shared/data."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.config import ScoreConfig, preset
from geocon_core.media import ClipError, ClipInfo, Frame, Mp4Writer, iter_frames, probe_clip
from geocon_core.synth import ClipPlan, load_ground_truth, write_clip

from .conftest import SHARED_DATA, read_video

W, H = 320, 180  # source size of the synthetic clips; smaller than the 1024x720 canvas: read as is


def shared(relative: str) -> Path:
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared data missing: {path}")
    return path


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Synthetic clips, 320x180, 8 frames, with the renderer's default sensor noise (sigma 2; at
    sigma 1, H.264 at CRF 12 removes the noise of a static scene, consecutive decoded frames
    differ by 0.01-0.04 grey levels and correctly read as duplicates, <= 0.05)."""
    out = tmp_path_factory.mktemp("reader_synth")
    paths = {}
    for key, plan, seed in [
        ("C1", ClipPlan("C1"), 0),
        ("C2", ClipPlan("C2"), 0),
        ("C3", ClipPlan("C3"), 1),
        ("C4", ClipPlan("C4"), 0),
        ("C5", ClipPlan("C5"), 0),
        ("letterbox", ClipPlan("C5", "letterbox", 0.15), 0),
    ]:
        gt = write_clip(plan, out / key, seed=seed, width=W, height=H, num_frames=8)
        paths[key] = out / key / gt.video_path
    return paths


def write_folder(folder: Path, frames: list[np.ndarray], names: list[str] | None = None) -> Path:
    """Write frames (BGR, grey or BGRA arrays) as image files; names default to frame_<t>.png."""
    folder.mkdir(parents=True, exist_ok=True)
    names = names or [f"frame_{t}.png" for t in range(len(frames))]
    for img, name in zip(frames, names, strict=True):
        assert cv2.imwrite(str(folder / name), img)
    return folder


def textured(seed: int, h: int, w: int) -> np.ndarray:
    """(h, w, 3) uint8 smooth random texture (BGR), bright enough never to read as a bar."""
    rng = np.random.default_rng(seed)
    small = rng.integers(40, 255, (max(2, h // 8), max(2, w // 8), 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def assert_one_sentence(err: pytest.ExceptionInfo[ClipError], name: str, phrase: str) -> None:
    msg = str(err.value)
    assert msg.startswith(f"{name}: "), msg
    assert phrase in msg, msg
    assert "\n" not in msg and ". " not in msg and "Traceback" not in msg and "cv2" not in msg, msg
    assert err.value.__cause__ is None


# --- layout and frames ------------------------------------------------------------------------


def test_synthetic_clip_layout(clips):
    info = probe_clip(clips["C2"])
    assert info.path == str(clips["C2"]) and info.kind == "video"
    assert info.num_frames == 8 and info.source_size == (W, H) and info.fps == 24.0
    assert info.working_size == (W, H)  # never upscaled
    assert info.scale == 1.0 and info.offset == (0, 0)
    assert info.bars == (0, 0, 0, 0)
    assert info.content_box == (0, 0, W, H)
    assert info.duplicates == () and info.cuts == ()


def test_iter_frames_yields_the_decoded_frames_unscaled(clips):
    info = probe_clip(clips["C2"])
    it = iter_frames(info)
    assert inspect.isgenerator(it)
    first = next(it)
    assert inspect.isgenerator(it) and first.index == 0  # still a lazy generator after one frame
    frames = [first, *it]
    decoded = read_video(clips["C2"])
    assert [f.index for f in frames] == list(range(8)) == list(range(len(decoded)))
    for f, src in zip(frames, decoded, strict=True):
        assert isinstance(f, Frame)
        assert f.rgb.shape == (H, W, 3) and f.rgb.dtype == np.uint8
        assert f.gray.shape == (H, W) and f.gray.dtype == np.uint8
        assert f.content.shape == (H, W) and f.content.dtype == bool
        np.testing.assert_array_equal(f.rgb, src)  # the decoded pixels, not interpolated
        np.testing.assert_array_equal(f.gray, cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY))
        assert f.content is frames[0].content
    assert frames[0].content.all()


def test_downscaling_uses_area_interpolation_and_never_upscales(tmp_path):
    # 1600x600 -> scale 0.64 (shrinking to fit 1024 wide): 1024x384, no padding
    wide = [textured(t, 600, 1600) for t in range(3)]
    info = probe_clip(write_folder(tmp_path / "wide", wide))
    assert info.scale == pytest.approx(0.64) and info.offset == (0, 0) and info.working_size == (1024, 384)
    assert info.content_box == (0, 0, 1024, 384)
    for f, src in zip(iter_frames(info), wide, strict=True):
        expected = cv2.cvtColor(cv2.resize(src, (1024, 384), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(f.rgb, expected)
    # portrait 1080x1920 -> height-bound scale 0.375: 405x720
    tall = [textured(10 + t, 1920, 1080) for t in range(2)]
    info = probe_clip(write_folder(tmp_path / "tall", tall))
    assert info.scale == pytest.approx(0.375) and info.working_size == (405, 720)
    # a portrait clip inside the canvas is read at its own size
    small = [textured(10 + t, 640, 360) for t in range(2)]
    info = probe_clip(write_folder(tmp_path / "small", small))
    assert info.scale == 1.0 and info.working_size == (360, 640) and info.content_box == (0, 0, 360, 640)
    f = next(iter_frames(info))
    np.testing.assert_array_equal(f.rgb, cv2.cvtColor(small[0], cv2.COLOR_BGR2RGB))


# --- burned-in bars ---------------------------------------------------------------------------


def test_letterbox_bars_found_and_excluded_from_content(clips):
    path = clips["letterbox"]
    gt = load_ground_truth(path.with_name(path.name.replace(".mp4", ".gt.json")))
    bar = round(0.15 * H)
    assert gt.content_box == (0, bar, W, H - bar)
    info = probe_clip(path)
    top, bottom, left, right = info.bars
    assert abs(top - bar) <= 2 and abs(bottom - bar) <= 2 and (left, right) == (0, 0)
    x0, y0, x1, y1 = info.content_box
    assert (x0, x1) == (0, W)
    # exactly the source minus bars, shrunk by the 2 px ringing margin
    assert y0 == top + 2 and y1 == H - bottom - 2
    # inside the true content, losing at most ~2 source rows per side
    assert bar <= y0 <= bar + 4 and H - bar - 4 <= y1 <= H - bar
    for f in iter_frames(info):
        rows = f.gray[y0:y1].mean(axis=1)
        assert rows.min() > ScoreConfig().bar_luma  # no bar row inside the content box
        assert f.gray[: bar - 2].max() <= 20  # the burned-in bar is black


@pytest.mark.parametrize("key", ["C1", "C2", "C3", "C4", "C5"])
def test_clean_clips_have_no_bars(clips, key):
    info = probe_clip(clips[key])
    assert info.bars == (0, 0, 0, 0) and info.content_box == (0, 0, W, H)


def test_pillarbox_bars_in_an_image_folder(tmp_path):
    frames = []
    for t in range(3):
        img = textured(t, 100, 200)
        img[:, :30] = 0
        img[:, 170:] = 5  # dark but not zero: still at most bar_luma
        frames.append(img)
    info = probe_clip(write_folder(tmp_path / "pillar", frames))
    assert info.bars == (0, 0, 30, 30)
    # read at its own 200x100; x0 = 30 + 2, x1 = 170 - 2 (2 px ringing margin beside each bar)
    assert info.scale == 1.0 and info.offset == (0, 0)
    assert info.content_box == (32, 0, 168, 100)


def test_dark_clip_has_no_bars(tmp_path):
    frames = []
    for t in range(3):
        img = np.full((100, 200, 3), 6, np.uint8)
        img[40:60, 90:110] = 200 + t  # bright patch narrower and shorter than 30% of the frame
        frames.append(img)
    info = probe_clip(write_folder(tmp_path / "dark", frames))
    assert info.bars == (0, 0, 0, 0) and info.content_box == (0, 0, 200, 100)


# --- image folders ----------------------------------------------------------------------------


def test_image_folder_natural_order_grey_and_alpha(tmp_path):
    # frame t has brightness 20 + 15 t; names need natural sort (frame_2 < frame_10)
    base = textured(0, 60, 80)
    frames: list[np.ndarray] = []
    for t in range(12):
        img = np.clip(base.astype(int) // 3 + 20 + 15 * t, 0, 255).astype(np.uint8)
        if t % 3 == 1:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)  # grey PNG
        elif t % 3 == 2:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)  # PNG with alpha
        frames.append(img)
    folder = write_folder(tmp_path / "seq", frames)
    (folder / "notes.txt").write_text("not a frame")
    (folder / "sub").mkdir()
    info = probe_clip(folder)
    assert info.kind == "images" and info.num_frames == 12 and info.fps == 24.0
    assert info.source_size == (80, 60)
    means = [float(f.gray[info.content_box[1] : info.content_box[3]].mean()) for f in iter_frames(info)]
    assert all(b > a + 5 for a, b in zip(means[:-1], means[1:], strict=True)), means  # frame_0 .. frame_11 in order


def test_jpeg_folder(tmp_path):
    frames = [np.roll(textured(1, 90, 160), 4 * t, axis=1) for t in range(5)]
    folder = write_folder(tmp_path / "jpg", frames, [f"img{t:02d}.JPG" for t in range(5)])
    info = probe_clip(folder)
    assert info.kind == "images" and info.num_frames == 5 and info.source_size == (160, 90)
    assert info.duplicates == () and info.cuts == ()
    assert sum(1 for _ in iter_frames(info)) == 5


def test_iter_frames_notices_a_changed_folder(tmp_path):
    folder = write_folder(tmp_path / "seq", [textured(t, 40, 60) for t in range(4)])
    info = probe_clip(folder)
    (folder / "frame_3.png").unlink()
    with pytest.raises(ClipError, match="when it was probed"):
        list(iter_frames(info))


# --- GIFs -------------------------------------------------------------------------------------


def test_animatediff_gif():
    path = shared("aigc/animatediff/motionlora_m01_01_zoomin.gif")
    info = probe_clip(path)
    assert info.kind == "gif" and info.num_frames == 16 and info.source_size == (256, 256)
    assert info.fps == pytest.approx(1 / 0.13)  # 13 cs per GIF frame
    assert info.scale == 1.0 and info.offset == (0, 0) and info.working_size == (256, 256)
    assert info.content_box == (0, 0, 256, 256)
    assert info.duplicates == () and info.cuts == () and info.bars == (0, 0, 0, 0)
    frames = list(iter_frames(info))
    assert len(frames) == 16 and frames[0].rgb.shape == (256, 256, 3)


@pytest.mark.parametrize(
    "name", ["svdxt_mountain_lake_0f47577ab3441480.gif", "svdxt_rocky_coastline_0bf152ef84195293.gif"]
)
def test_svd_gifs_repeat_a_frame(name):
    # The data README says these GIFs repeat their first frame. Decoded, it is the final frame
    # (25) that repeats frame 24 exactly; frame 0 differs from frame 1 and from frame 25.
    info = probe_clip(shared(f"aigc/cameractrl/{name}"))
    assert info.kind == "gif" and info.num_frames == 26 and info.source_size == (576, 320)
    assert info.duplicates == (25,) and info.cuts == ()
    assert info.pair_skip_reason(24, 25) == "duplicate_frame"
    assert info.pair_skip_reason(23, 25) is None and info.pair_skip_reason(0, 1) is None


def test_opensora_gif_holds_every_fifth_frame():
    info = probe_clip(shared("aigc/opensora/readme_sample_1.gif"))
    assert info.num_frames == 20 and info.fps == 10.0
    assert info.duplicates == (2, 7, 12, 17) and info.cuts == ()


# --- duplicates -------------------------------------------------------------------------------


def test_exact_duplicates_in_a_folder(tmp_path):
    a, b, c, d = (textured(s, 48, 64) for s in range(4))
    info = probe_clip(write_folder(tmp_path / "dups", [a, a, b, c, c, c, d]))
    assert info.num_frames == 7 and info.duplicates == (1, 4, 5) and info.cuts == ()
    assert info.pair_skip_reason(0, 1) == "duplicate_frame"
    assert info.pair_skip_reason(3, 5) == "duplicate_frame"  # frames 3, 4, 5 identical
    assert info.pair_skip_reason(3, 4) == "duplicate_frame"
    assert info.pair_skip_reason(3, 6) is None
    assert info.pair_skip_reason(1, 2) is None and info.pair_skip_reason(0, 2) is None
    with pytest.raises(ValueError):
        info.pair_skip_reason(2, 2)
    with pytest.raises(ValueError):
        info.pair_skip_reason(5, 7)


def test_static_scene_with_sensor_noise_has_no_duplicates(clips):
    info = probe_clip(clips["C1"])
    assert info.num_frames == 8 and info.duplicates == () and info.cuts == ()


def test_duplicate_threshold_comes_from_the_config(tmp_path):
    a = textured(0, 48, 64)
    b = a.copy()
    b[:, :32] += 1  # mean absolute grey difference ~0.5
    folder = write_folder(tmp_path / "near", [a, b, a])
    assert probe_clip(folder).duplicates == ()
    assert probe_clip(folder, ScoreConfig(duplicate_mad=1.0)).duplicates == (1, 2)


# --- hard cuts --------------------------------------------------------------------------------


def test_hard_cut_at_the_junction_of_two_clips(clips, tmp_path):
    frames = read_video(clips["C2"]) + read_video(clips["C3"])  # different scenes and seeds, both moving
    path = tmp_path / "two_shots.mp4"
    with Mp4Writer(path, W, H, 24) as writer:
        for rgb in frames:
            writer.write(rgb)
    info = probe_clip(path)
    assert info.num_frames == 16 and info.cuts == (8,)
    assert info.pair_skip_reason(7, 8) == "hard_cut" and info.pair_skip_reason(5, 10) == "hard_cut"
    assert info.pair_skip_reason(6, 7) is None and info.pair_skip_reason(8, 15) is None


def _first_frames(path: Path, n: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while len(frames) < n:
        ok, bgr = cap.read()
        assert ok, f"{path} has fewer than {n} frames"
        frames.append(bgr)
    cap.release()
    return frames


def test_a_cut_after_a_change_of_exposure_is_found(tmp_path):
    """Two RealEstate10K walk-throughs joined: the last pair of the first shot changes exposure, so
    the histogram distance of the cut is not twice its neighbour's; the picture difference is."""
    first = _first_frames(shared("real/realestate10k/0f47577ab3441480.mp4"), 16)
    second = _first_frames(shared("real/realestate10k/0bf152ef84195293.mp4"), 16)
    folder = tmp_path / "joined"
    folder.mkdir()
    for i, bgr in enumerate(first + second):
        cv2.imwrite(str(folder / f"{i:05d}.png"), bgr)
    for cfg in (ScoreConfig(), preset("audit")):
        info = probe_clip(folder, cfg)
        assert info.cuts == (16,), info.cuts
        assert info.shots == ((0, 15), (16, 31))


@pytest.mark.parametrize("key", ["C2", "C3", "C4"])
def test_pans_translation_and_moving_objects_are_not_cuts(clips, key):
    assert probe_clip(clips[key]).cuts == ()


@pytest.mark.parametrize(
    "relative",
    [
        "real/realestate10k/0c9b371cc6225682.mp4",  # camera sweeps past a near door frame
        "real/realestate10k/0c9b371cc6225682_svdxt_ref.mp4",
        "aigc/fastvideo/gen3c_cosmos7b_baseline.mp4",  # a sudden exposure flicker at frame 6
        "aigc/cameractrl/animatediff_realestatelora_kitchen_0bf152ef84195293.gif",
    ],
)
def test_fast_motion_and_flicker_are_not_cuts(relative):
    assert probe_clip(shared(relative)).cuts == ()


def test_real_footage_vtest():
    info = probe_clip(shared("real/opencv/vtest.avi"))
    assert info.kind == "video" and info.num_frames == 795 and info.source_size == (768, 576)
    assert info.cuts == () and info.duplicates == () and info.bars == (0, 0, 0, 0)
    assert info.scale == 1.0 and info.offset == (0, 0) and info.working_size == (768, 576)


# --- records ----------------------------------------------------------------------------------


def test_clip_info_round_trips_and_is_deterministic(clips):
    info = probe_clip(clips["letterbox"])
    assert probe_clip(clips["letterbox"]) == info
    d = json.loads(json.dumps(info.to_dict()))
    assert isinstance(d["bars"], list) and isinstance(d["duplicates"], list)
    assert ClipInfo.from_dict(d) == info
    with pytest.raises(ValueError, match="unknown"):
        ClipInfo.from_dict({**d, "extra": 1})


def test_clip_info_checks_its_fields(clips):
    d = probe_clip(clips["C2"]).to_dict()
    for bad in (
        {"cuts": [0]},
        {"duplicates": [8]},
        {"num_frames": 1},
        {"kind": "film"},
        {"content_box": [0, 0, 2000, 10]},
    ):
        with pytest.raises(ValueError):
            ClipInfo.from_dict({**d, **bad})


# --- errors -----------------------------------------------------------------------------------


def test_missing_path(tmp_path):
    path = tmp_path / "clip.mp4"
    with pytest.raises(ClipError) as err:
        probe_clip(path)
    assert_one_sentence(err, str(path), "no such file")


def test_folder_without_images(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("hello")
    with pytest.raises(ClipError) as err:
        probe_clip(tmp_path / "empty")
    assert_one_sentence(err, str(tmp_path / "empty"), "no PNG or JPEG frames")


@pytest.mark.parametrize("name", ["notes.txt", "notes.mp4"])
def test_text_file(tmp_path, name):
    (tmp_path / name).write_text("this is not a video\n" * 20)
    with pytest.raises(ClipError) as err:
        probe_clip(tmp_path / name)
    assert_one_sentence(err, str(tmp_path / name), "cannot be decoded as a video or image sequence")


def test_single_image_and_single_frame(tmp_path):
    img = textured(0, 40, 60)
    cv2.imwrite(str(tmp_path / "one.png"), img)
    with pytest.raises(ClipError) as err:
        probe_clip(tmp_path / "one.png")
    assert_one_sentence(err, str(tmp_path / "one.png"), "has 1 frame; at least 2 are needed")
    folder = write_folder(tmp_path / "onefolder", [img])
    with pytest.raises(ClipError) as err:
        probe_clip(folder)
    assert_one_sentence(err, str(folder), "has 1 frame")
    with Mp4Writer(tmp_path / "one.mp4", 64, 64, 24) as writer:
        writer.write(np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(ClipError) as err:
        probe_clip(tmp_path / "one.mp4")
    assert_one_sentence(err, str(tmp_path / "one.mp4"), "has 1 frame")


def test_broken_bytes(clips, tmp_path):
    data = clips["C2"].read_bytes()
    mdat = data.find(b"mdat")
    assert 0 < mdat < data.find(b"moov")  # H.264 payload first, index at the end
    cases = {
        "truncated.mp4": data[: len(data) // 2],  # index lost
        "zeroed.mp4": data[: mdat + 4] + bytes(len(data) // 2) + data[mdat + 4 + len(data) // 2 :],  # payload lost
    }
    for name, blob in cases.items():
        (tmp_path / name).write_bytes(blob)
        with pytest.raises(ClipError) as err:
            probe_clip(tmp_path / name)
        assert_one_sentence(err, str(tmp_path / name), "unreadable bytes (")


def test_corrupt_image_in_a_folder(tmp_path):
    folder = write_folder(tmp_path / "seq", [textured(t, 40, 60) for t in range(3)])
    (folder / "frame_1.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(ClipError) as err:
        probe_clip(folder)
    assert_one_sentence(err, str(folder / "frame_1.png"), "cannot be decoded as an image")


def test_frames_of_different_sizes(tmp_path):
    folder = write_folder(tmp_path / "mixed", [textured(0, 40, 60), textured(1, 40, 60), textured(2, 42, 60)])
    with pytest.raises(ClipError) as err:
        probe_clip(folder)
    assert_one_sentence(err, str(folder), "frame 2 (frame_2.png) is 60x42 but frame 0 is 60x40")


def test_a_record_finds_its_clip_where_it_moved_and_refuses_another(tmp_path):
    from dataclasses import replace

    from geocon_core.media import OtherClipError, clip_fingerprint, locate_clip

    from .bad_inputs import pan_frames, write_video

    clip = write_video(tmp_path / "a.mp4", pan_frames(96, 64, 6, seed=1))
    info = probe_clip(clip)
    assert info.abs_path == str(clip) and info.fingerprint == clip_fingerprint(clip) is not None
    assert locate_clip(info, tmp_path / "rec").path == str(clip)
    moved = tmp_path / "x" / "a.mp4"
    moved.parent.mkdir()
    clip.rename(moved)
    gone = replace(info, path="a.mp4", abs_path=str(clip), from_record="x/a.mp4")  # record at tmp_path/rec
    assert locate_clip(gone, tmp_path / "rec").path == str(moved)
    write_video(moved, pan_frames(96, 64, 6, seed=2))  # the same name, another clip
    with pytest.raises(OtherClipError, match="not the clip this record was scored on"):
        locate_clip(gone, tmp_path / "rec")
    assert locate_clip(replace(gone, fingerprint=None), tmp_path / "rec").path == str(moved)  # an old record
    moved.unlink()
    with pytest.raises(ClipError, match="the clip of this record is gone"):
        locate_clip(gone, tmp_path / "rec")
    folder = tmp_path / "frames"
    folder.mkdir()
    for t, f in enumerate(pan_frames(96, 64, 3, seed=1)):
        cv2.imwrite(str(folder / f"{t:03d}.png"), f)
    first = clip_fingerprint(folder)
    cv2.imwrite(str(folder / "001.png"), pan_frames(96, 64, 3, seed=5)[1])  # a middle frame replaced
    assert first is not None and clip_fingerprint(folder) not in (None, first)
