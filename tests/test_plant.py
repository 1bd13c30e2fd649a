"""``geocon plant``: failures planted into real footage, recovered by the project's own optical flow.

A RealEstate10K clip (384x256, read from ``../shared/data``, cut to its first 10 frames) gets each
planted failure at severity ``middle``. The flow (DIS, the default classical backend) from the clean
clip's frame t to the planted clip's frame t must match the ground truth's displacement (median
error at most 0.5 px inside the region, 0.1 px outside); ``redraw`` moves nothing and must change
the region only. The clean clip must score like the source (preset ``audit``), the same seed must
give the same bytes, and bad inputs get one sentence each."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.flow import make_flow_backend
from geocon_core.media import open_video
from geocon_core.plant import (
    LEVELS,
    PLANT_KINDS,
    Planting,
    plant_clip,
    planted_displacement,
    read_plant_truth,
)

from . import test_bad_input as catalogue
from .bad_inputs import pan_frames, snapshot, write_pngs, write_video
from .test_bad_input import Case, Ctx, Outcome, judge

assets = catalogue.assets
ctx = catalogue.ctx
"""The catalogue's fixtures, visible to the tests here: the shared inputs, the case's folder."""

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "realestate10k"
CLIP = DATA / "0bf152ef84195293.mp4"
FRAMES = 10
LEVEL = "middle"
INSIDE_PX = 0.5
OUTSIDE_PX = 0.1

pytestmark = pytest.mark.skipif(not CLIP.is_file(), reason=f"shared footage {CLIP} is not here")


def _grays(path: Path) -> list[np.ndarray]:
    """The frames of ``path`` as the project decodes them, in grey."""
    _fps, frames = open_video(str(path))
    return [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]


@pytest.fixture(scope="module")
def planted(tmp_path_factory: pytest.TempPathFactory):
    """``planted(kind)`` -> the :class:`~geocon_core.plant.PlantResult` of ``kind`` at ``middle``,
    seed 0, in the first 10 frames of the clip; each kind is planted once per module."""
    out = tmp_path_factory.mktemp("plant")
    done = {}

    def get(kind: str):
        if kind not in done:
            done[kind] = plant_clip(CLIP, kind, LEVEL, 0, out, frames=FRAMES)
        return done[kind]

    return get


def _in_view(planting: Planting, t: int) -> np.ndarray:
    """Pixels whose content stays in the frame (content that leaves it has no flow to recover)."""
    w, h = planting.size
    d = planting.displacement(t)
    gy, gx = np.mgrid[0:h, 0:w]
    x, y = gx + d[..., 0], gy + d[..., 1]
    return (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)


def recovery_errors(result) -> list[tuple[int, float, float | None]]:
    """Per affected frame: (t, median flow error inside the region, outside it or None)."""
    clean, planted = _grays(result.clean), _grays(result.planted)
    flow = make_flow_backend("dis")
    rows = []
    for t in result.planting.frames_affected():
        truth = planted_displacement(result.ground_truth, t)
        err = np.linalg.norm(flow.compute(clean[t], planted[t]).flow - truth, axis=2)
        region = result.planting.mask(t)
        inside = region & _in_view(result.planting, t)
        rows.append((t, float(np.median(err[inside])), float(np.median(err[~region])) if (~region).any() else None))
    return rows


@pytest.mark.parametrize("kind", ["morph", "breathing", "slide"])
def test_the_flow_recovers_the_planted_displacement(planted, kind):
    result = planted(kind)
    rows = recovery_errors(result)
    assert len(rows) == FRAMES - 1, rows  # every frame but the first
    for t, inside, outside in rows:
        assert inside <= INSIDE_PX, f"frame {t}: median error {inside:.3f} px inside the region"
        assert outside is None or outside <= OUTSIDE_PX, f"frame {t}: median error {outside:.3f} px outside"
    last = planted_displacement(result.truth, FRAMES - 1)
    peak = float(np.linalg.norm(last, axis=2).max())
    amplitude = PLANT_KINDS[kind].amplitudes[LEVELS.index(LEVEL)]
    if kind == "breathing":  # sin(2 pi t / 24) at the last frame
        assert peak == pytest.approx(amplitude * np.sin(2 * np.pi * (FRAMES - 1) / 24), rel=1e-6)
    else:
        assert peak == pytest.approx(amplitude, abs=0.05)


def test_redraw_changes_the_region_only(planted):
    result = planted("redraw")
    clean, damaged = _grays(result.clean), _grays(result.planted)
    assert np.array_equal(clean[0], damaged[0])  # frame 0 is never changed
    inside_means = []
    for t in result.planting.frames_affected():
        region = result.planting.mask(t)
        diff = np.abs(clean[t].astype(np.int16) - damaged[t])
        inside_means.append(float(diff[region].mean()))
        outside = diff[~region]
        # outside, the two encodes differ only by the codec's rounding where a block looked at the region
        assert np.median(outside) == 0 and outside.mean() < 1.5, (t, np.median(outside), outside.mean())
    assert inside_means[-1] > 10 * max(1.0, float(np.abs(clean[-1].astype(np.int16) - damaged[-1])[~region].mean()))
    assert inside_means[-1] > inside_means[0]  # it grows over the clip
    assert np.all(planted_displacement(result.truth, FRAMES - 1) == 0)


@pytest.mark.parametrize("kind", list(PLANT_KINDS))
def test_planting_leaves_every_pixel_outside_its_region_exactly(planted, kind):
    """Before encoding: the planted planes equal the clean ones outside the region, in every plane."""
    from geocon_core.plant.encode import decode_planes

    result = planted(kind)
    planting = result.planting
    t = FRAMES - 1
    planes = list(decode_planes(CLIP, "yuv420p", FRAMES))[t]
    out = planting.apply(t, planes, [(1, 1), (2, 2), (2, 2)])
    changed = out[0] != planes[0]
    assert changed.sum() > 1000, "the failure changed almost nothing"
    assert not (changed & ~planting.mask(t)).any()
    h, w = planes[1].shape  # 4:2:0: a chroma sample covers 2x2 frame pixels
    near = planting.mask(t).reshape(h, 2, w, 2).any(axis=(1, 3)).astype(np.uint8)
    near = cv2.dilate(near, np.ones((3, 3), np.uint8)).astype(bool)
    for plane, new in zip(planes[1:], out[1:], strict=True):
        assert (new != plane).any()
        assert not ((new != plane) & ~near).any()


def test_the_ground_truth_describes_the_planting(planted):
    result = planted("morph")
    truth = read_plant_truth(result.ground_truth)
    assert truth == result.truth
    assert truth["scene_id"] == CLIP.stem and truth["kind"] == "morph" and truth["severity"] == LEVEL
    assert truth["source"]["name"] == CLIP.name
    assert truth["source"]["sha256"] == __import__("hashlib").sha256(CLIP.read_bytes()).hexdigest()
    assert truth["frames_affected"] == list(range(1, FRAMES))
    assert len(truth["region"]["polygons"]) == FRAMES and len(truth["region"]["centres"]) == FRAMES
    rebuilt = Planting.from_dict(truth)
    for t in (3, FRAMES - 1):
        assert np.array_equal(rebuilt.displacement(t), result.planting.displacement(t))
    # the region follows the content: the camera pans, and so does the region's centre
    (x0, y0), (x1, y1) = truth["region"]["centres"][0], truth["region"]["centres"][-1]
    assert abs(x1 - x0) + abs(y1 - y0) > 5
    metas = {p.name: json.loads(p.read_text()) for p in result.planted.parent.glob("*.meta.json")}
    assert {m["scene_id"] for m in metas.values()} == {CLIP.stem}
    assert metas[f"{CLIP.stem}.clean.meta.json"]["video"] == result.clean.name


def test_both_clips_are_encoded_like_the_source(planted):
    import av

    result = planted("slide")
    with av.open(str(CLIP)) as src:
        s = src.streams.video[0]
        want = (s.codec_context.name, s.codec_context.pix_fmt, s.average_rate, s.width, s.height)
    for path in (result.clean, result.planted):
        with av.open(str(path)) as clip:
            v = clip.streams.video[0]
            assert (v.codec_context.name, v.codec_context.pix_fmt, v.average_rate, v.width, v.height) == want
            assert sum(1 for _ in clip.decode(v)) == FRAMES
    enc, source = result.truth["encoding"], result.truth["source"]
    assert enc["same_family_as_source"] and enc["encoder"] == "libx264" and enc["quality"]["option"] == "qp"
    ratio = result.truth["clean"]["bits_per_pixel"] / source["bits_per_pixel"]
    assert 0.8 < ratio < 1.25, ratio


@pytest.mark.full
def test_the_clean_clip_scores_like_the_source(tmp_path):
    """Preset ``audit`` on the whole 16-frame clip and on its clean re-encode: the same verdict and a
    background IR within 0.01."""
    from geocon_core import preset, score_clip

    result = plant_clip(CLIP, "slide", LEVEL, 0, tmp_path)
    config = preset("audit")
    original, clean = score_clip(CLIP, config), score_clip(result.clean, config)
    assert clean.video.num_frames == original.video.num_frames == 16
    assert clean.finding().verdict == original.finding().verdict
    assert original.background.ir is not None and clean.background.ir is not None
    assert abs(clean.background.ir - original.background.ir) <= 0.01


@pytest.mark.full
def test_the_same_seed_gives_the_same_bytes(tmp_path):
    first = plant_clip(CLIP, "morph", "high", 7, tmp_path / "a", frames=6)
    again = plant_clip(CLIP, "morph", "high", 7, tmp_path / "b", frames=6)
    other = plant_clip(CLIP, "morph", "high", 8, tmp_path / "c", frames=6)
    a, b = snapshot(tmp_path / "a"), snapshot(tmp_path / "b")
    assert a == b and len(a) == 5
    assert first.truth == again.truth
    assert other.clean.read_bytes() == first.clean.read_bytes()
    assert other.planted.read_bytes() != first.planted.read_bytes()
    assert other.truth["region"]["centres"][0] != first.truth["region"]["centres"][0]


@pytest.mark.parametrize(("codec", "name", "family"), [("libx265", "h.mp4", "hevc"), ("mpeg4", "m.avi", "h264")])
def test_other_codecs_are_written_in_their_family_or_as_h264(tmp_path, codec, name, family):
    pytest.importorskip("av")
    clip = write_video(tmp_path / name, pan_frames(192, 128, 6, seed=2), codec=codec, fps=12)
    result = plant_clip(clip, "slide", "low", 0, tmp_path / "out")
    import av

    with av.open(str(result.planted)) as c:
        assert c.streams.video[0].codec_context.name == family
    assert result.truth["encoding"]["same_family_as_source"] == (family != "h264")
    assert result.truth["source"]["codec"] == ("hevc" if codec == "libx265" else "mpeg4")


# --- bad inputs: one sentence each, nothing left behind ---------------------------------------------


def plant(clip: str, *more: str, failure: str = "morph", severity: str = "low", out: str = "out") -> tuple[str, ...]:
    return ("plant", clip, "--failure", failure, "--severity", severity, "--out", out, *more)


def frames_folder(c: Ctx) -> None:
    write_pngs(c.tmp / "frames", pan_frames(160, 90, 4, seed=1))


def output_link_to_clip(c: Ctx) -> None:
    """``clip.mp4`` and a link ``clip.clean.mp4`` to it: the name of the clean output."""
    c.pan()
    os.symlink("clip.mp4", c.tmp / "clip.clean.mp4")


def written_beside(c: Ctx, _res: Outcome) -> None:
    names = {p.name for p in c.tmp.iterdir()}
    assert {"clip.morph-low-s0.mp4", "clip.clean.mp4", "clip.morph-low-s0.gt.json"} <= names, names


CASES = [
    Case("unknown failure", lambda c: c.pan(), plant("clip.mp4", failure="melt"), says=("--failure", "melt", "morph")),
    Case("severity not a level", lambda c: c.pan(), plant("clip.mp4", severity="5"), says=("--severity", "low")),
    Case("severity of another case", lambda c: c.pan(), plant("clip.mp4", severity="Middle"), says=("--severity",)),
    Case("missing clip", lambda c: None, plant("nothere.mp4"), says=("nothere.mp4",)),
    Case("junk bytes", lambda c: c.write("junk.mp4", b"not a video" * 50), plant("junk.mp4"), says=("junk.mp4",)),
    Case("a folder of frames", frames_folder, plant("frames"), says=("frames", "video file")),
    Case("--out is the clip itself", lambda c: c.pan(), plant("clip.mp4", out="clip.mp4"), says=("--out", "clip.mp4")),
    Case("an output is the clip", output_link_to_clip, plant("clip.mp4", out="."), says=("clip.clean.mp4", "clip")),
    Case(
        "a clip too small for the severity",
        lambda c: c.pan(),
        plant("clip.mp4", failure="slide", severity="high"),
        says=("high", "160x90", "severity"),
    ),
    Case("--out is the clip's folder", lambda c: c.pan(), plant("clip.mp4", out="."), code=0, check=written_beside),
]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_plant_input(case: Case, ctx: Ctx):
    case.build(ctx)
    before = snapshot(ctx.tmp)
    res = ctx.invoke(list(case.argv))
    problems = judge(case, ctx, res, before)
    assert not problems, f"{case.name}: {res.describe()}\n  - " + "\n  - ".join(problems)
