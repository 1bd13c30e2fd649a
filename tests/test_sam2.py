"""SAM-2 masks: prompts from the motion segmentation's movers, sessions per shot, the errors, and
``geocon score --masks sam2`` end to end with a random-weight checkpoint (plumbing, not quality)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.config import Sam2Config, preset
from geocon_core.masks import make_mask_source
from geocon_core.masks.sam2 import Sam2Masks, load_sam2, prompt_box, resolve_sam2_config
from geocon_core.media import Frame
from tests.conftest import clip_info

# -- fakes for our own logic: a motion segmentation with planted movers, and a "SAM-2" that
# -- segments exactly the box it was prompted with and keeps it


class FakeMotion:
    """Motion labels given per frame: ``movers[id] = (first, last, (x0, y0, x1, y1))``."""

    def __init__(self, info, movers: dict[int, tuple[int, int, tuple[int, int, int, int]]], lookahead: int = 2):
        self.info, self.movers, self.lookahead = info, movers, lookahead
        self.pushed, self.released = 0, 0

    def push(self, frame: Frame) -> None:
        self.pushed = frame.index + 1

    def finish(self) -> None:
        self.pushed = self.info.num_frames

    def labels(self, t: int) -> np.ndarray:
        assert t + self.lookahead < self.pushed or self.pushed == self.info.num_frames, "asked before final"
        W, H = self.info.working_size
        out = np.zeros((H, W), np.uint8)
        for k, (first, last, (x0, y0, x1, y1)) in sorted(self.movers.items()):
            if first <= t <= last:
                out[y0:y1, x0:x1] = k
        return out

    def release(self, t: int) -> None:
        self.released = max(self.released, t)


class FakeSession:
    def __init__(self, size: int, n: int) -> None:
        self.size, self.n = size, n
        self.boxes: dict[int, tuple[float, ...]] = {}
        self.tracked: list[int] = []

    def _logits(self, box) -> np.ndarray:
        s = self.size
        out = np.full((s, s), -8.0, np.float32)
        x0, y0, x1, y1 = (round(v * s) for v in box)
        out[y0:y1, x0:x1] = 8.0
        return out

    def track(self, t: int, image: np.ndarray) -> dict[int, np.ndarray]:
        assert image.shape == (self.size * 4, self.size * 4, 3) and image.dtype == np.uint8
        assert 0 <= t < self.n and (not self.tracked or t == self.tracked[-1] + 1)
        self.tracked.append(t)
        return {k: self._logits(b) for k, b in self.boxes.items()}

    def prompt(self, t: int, image: np.ndarray, obj_id: int, box) -> np.ndarray:
        assert self.tracked[-1] == t and obj_id not in self.boxes and all(0 <= v <= 1 for v in box)
        self.boxes[obj_id] = box
        return self._logits(box)


class FakeSam2:
    image_size = 256

    def __init__(self) -> None:
        self.sessions: list[FakeSession] = []

    def session(self, n: int) -> FakeSession:
        self.sessions.append(FakeSession(self.image_size // 4, n))
        return self.sessions[-1]


def _frames(info):
    W, H = info.working_size
    rng = np.random.default_rng(0)
    content = info.content_mask
    for t in range(info.num_frames):
        rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        yield Frame(t, rgb, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), content)


def _run(src, info) -> list[np.ndarray]:
    """Labels of every frame, asked as the scorer asks them (as soon as final), then released."""
    out: list[np.ndarray] = []
    for frame in _frames(info):
        src.push(frame)
        while len(out) <= frame.index - src.lookahead:
            out.append(src.labels(len(out)).copy())
            src.release(len(out))
    src.finish()
    while len(out) < info.num_frames:
        out.append(src.labels(len(out)).copy())
        src.release(len(out))
    return out


def _source(info, movers, config: Sam2Config | None = None, model=None):
    model = model or FakeSam2()
    return Sam2Masks(info, model, FakeMotion(info, movers), config or Sam2Config(box_margin=0.0)), model


def test_prompt_box_grows_by_the_margin_and_stays_inside() -> None:
    mask = np.zeros((100, 200), bool)
    mask[10:30, 150:190] = True
    assert prompt_box(mask, 0.0) == (150.0, 10.0, 190.0, 30.0)
    assert prompt_box(mask, 0.1) == (146.0, 8.0, 194.0, 32.0)
    assert prompt_box(mask, 0.5) == (130.0, 0.0, 200.0, 40.0)  # clipped to the image


def test_each_new_mover_prompts_on_its_first_frame() -> None:
    info = clip_info(num_frames=10)
    src, model = _source(info, {1: (2, 9, (40, 52, 80, 92)), 2: (5, 9, (200, 100, 240, 140))})
    labels = _run(src, info)
    assert [(p.t, p.obj_id, p.box) for p in src.prompts] == [
        (2, 1, (40.0, 52.0, 80.0, 92.0)),
        (5, 2, (200.0, 100.0, 240.0, 140.0)),
    ]
    (session,) = model.sessions
    assert session.tracked == list(range(10)) and session.n == 10
    for t, lab in enumerate(labels):
        assert lab.shape == (180, 320) and lab.dtype == np.uint8
        assert set(np.unique(lab)) == ({0} if t < 2 else {0, 1} if t < 5 else {0, 1, 2})
    # the fake tracks the prompted box: the labels are that box at the content's resolution
    inside = labels[7][56:88, 44:76]
    assert (inside == 1).all() and (labels[7][104:136, 204:236] == 2).all()
    assert not labels[7][:40].any() and not labels[7][:, 90:190].any()
    assert src.coverage[7] == pytest.approx(2 * 40 * 40 / (320 * 180), rel=0.15)
    assert src.lookahead == 2 and src.motion.released == 10


def test_a_redetected_mover_adds_no_prompt_but_a_new_one_does() -> None:
    info = clip_info(num_frames=8)
    movers = {
        1: (0, 7, (40, 40, 120, 120)),
        2: (3, 7, (60, 60, 140, 100)),  # 3/4 inside object 1: the motion segmentation re-found a part
        3: (4, 7, (100, 40, 180, 120)),  # 1/4 inside object 1: a new mover
    }
    src, model = _source(info, movers)
    labels = _run(src, info)
    assert [(p.t, p.obj_id) for p in src.prompts] == [(0, 1), (4, 3)]
    assert set(np.unique(labels[2])) == {0, 1} and set(np.unique(labels[6])) == {0, 1, 3}
    assert 2 not in np.unique(np.stack(labels))
    # with a stricter cover rule the part becomes its own prompt
    src, _ = _source(info, movers, Sam2Config(box_margin=0.0, prompt_cover=0.9))
    _run(src, info)
    assert [(p.t, p.obj_id) for p in src.prompts] == [(0, 1), (3, 2), (4, 3)]


def test_a_hard_cut_starts_a_new_session_and_prompts_again() -> None:
    info = clip_info(num_frames=9, cuts=(5,))
    src, model = _source(info, {1: (0, 8, (40, 40, 80, 80))})
    _run(src, info)
    assert [(p.t, p.obj_id) for p in src.prompts] == [(0, 1), (5, 1)]
    assert [(s.n, s.tracked) for s in model.sessions] == [(5, [0, 1, 2, 3, 4]), (4, [0, 1, 2, 3])]


def test_boxes_are_relative_to_the_content_box_and_labels_stay_inside_it() -> None:
    info = clip_info(num_frames=6, content_box=(0, 30, 320, 150))
    src, model = _source(info, {4: (1, 5, (160, 60, 200, 100))})
    labels = _run(src, info)
    (prompt,) = src.prompts
    assert prompt.box == (160.0, 60.0, 200.0, 100.0)  # working px
    assert model.sessions[0].boxes[4] == pytest.approx((0.5, 0.25, 0.625, 7 / 12))  # of the content box
    assert (labels[3][64:96, 164:196] == 4).all()
    assert not labels[3][:30].any() and not labels[3][150:].any()


def test_the_highest_logit_wins_where_objects_overlap() -> None:
    info = clip_info(num_frames=4)
    src, _ = _source(info, {1: (0, 3, (40, 40, 120, 120))}, Sam2Config(box_margin=0.0, prompt_cover=1.0))
    logits = {1: np.full((8, 8), 2.0, np.float32), 2: np.full((8, 8), -1.0, np.float32)}
    logits[2][:4] = 5.0
    lab = src._content_labels(logits)
    assert (lab[:80] == 2).all() and (lab[100:] == 1).all()
    logits[1][:] = -0.5  # below mask_threshold: background
    assert not src._content_labels(logits)[100:].any()


def test_labels_follow_the_streaming_contract() -> None:
    info = clip_info(num_frames=6)
    src, _ = _source(info, {1: (0, 5, (40, 40, 80, 80))})
    frames = list(_frames(info))
    src.push(frames[0])
    src.push(frames[1])
    with pytest.raises(ValueError, match="not final before frame 2"):
        src.labels(0)
    src.push(frames[2])
    first = src.labels(0)
    assert src.labels(0) is first and not first.flags.writeable
    src.release(1)
    with pytest.raises(ValueError, match="released"):
        src.labels(0)
    for f in frames[3:]:
        src.push(f)
    src.finish()
    assert src.labels(5).shape == (180, 320)
    with pytest.raises(ValueError, match="push"):
        src.push(frames[0])


# -- errors: one sentence each ------------------------------------------------------------------


def test_a_missing_package_names_the_install_command(monkeypatch, tmp_path) -> None:
    import importlib.util

    from geocon_core.masks import sam2 as module

    real = importlib.util.find_spec
    monkeypatch.setattr(module.importlib.util, "find_spec", lambda m, *a: None if m == "sam2" else real(m, *a))
    ck = tmp_path / "x.pt"
    ck.write_bytes(b"x")
    with pytest.raises(ValueError) as exc:
        load_sam2(ck)
    msg = str(exc.value)
    assert msg.startswith("SAM-2 masks need sam2: pip install 'geocon[neural]' && SAM2_BUILD_CUDA=0 pip install")
    assert "\n" not in msg and msg.count(". ") == 0


def test_settings_errors_are_one_sentence(tmp_path) -> None:
    info = clip_info()
    with pytest.raises(ValueError, match=r"^SAM-2 masks need a checkpoint: pass --sam2-checkpoint PATH"):
        make_mask_source("sam2", info)
    with pytest.raises(ValueError, match=r"does not exist \(pass --sam2-checkpoint"):
        load_sam2(tmp_path / "missing.pt")
    with pytest.raises(ValueError, match="sam2.image_size must be a multiple of 32"):
        Sam2Config(image_size=500)
    with pytest.raises(ValueError, match="a SAM-2 checkpoint was given but the masks are 'motion'"):
        from geocon_core.scoring import score_clip

        score_clip(tmp_path / "clip.mp4", preset("fast"), sam2_checkpoint=tmp_path / "x.pt")


def test_the_cli_checks_its_sam2_options(tmp_path) -> None:
    from geocon_viewer.cli import app

    clip = tmp_path / "clip.mp4"
    runner = CliRunner()
    res = runner.invoke(app, ["score", str(clip), "--masks", "sam2", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "--masks sam2 needs --sam2-checkpoint PATH" in res.output
    said = "--sam2-checkpoint, --sam2-config and --sam2-size are used with --masks sam2"
    for extra in (["--sam2-checkpoint", str(clip)], ["--sam2-size", "256"]):
        res = runner.invoke(app, ["score", str(clip), *extra, "--out", str(tmp_path / "o")])
        assert res.exit_code != 0 and said in res.output
    res = runner.invoke(
        app, ["score", str(clip), "--masks", "sam2", "--sam2-checkpoint", str(clip), "--sam2-size", "100"]
    )
    assert res.exit_code != 0 and "multiple of 32" in res.output
    res = runner.invoke(app, ["score", str(clip), "--masks", "sam2", "--no-masks", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "exclude each other" in res.output


# -- the real predictor (random weights: plumbing, not quality) --------------------------------


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A random-weight SAM-2.1 tiny checkpoint in the released layout ``{"model": state_dict}``."""
    pytest.importorskip("sam2")
    torch = pytest.importorskip("torch")
    from sam2.build_sam import build_sam2_video_predictor

    path = tmp_path_factory.mktemp("sam2") / "random_hiera_t.pt"
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = build_sam2_video_predictor(resolve_sam2_config("sam2.1_hiera_t"), None, device="cpu")
        torch.save({"model": model.state_dict()}, path)
    return path


def test_config_names_resolve_in_every_spelling() -> None:
    pytest.importorskip("sam2")
    for name in ("sam2.1_hiera_t", "sam2.1_hiera_t.yaml", "configs/sam2.1/sam2.1_hiera_t.yaml"):
        assert resolve_sam2_config(name) == "configs/sam2.1/sam2.1_hiera_t.yaml"
    assert resolve_sam2_config("sam2_hiera_s") == "configs/sam2/sam2_hiera_s.yaml"
    with pytest.raises(ValueError, match=r"^unknown SAM-2 model configuration 'hiera_xl'; valid: .*sam2.1_hiera_t"):
        resolve_sam2_config("hiera_xl")


def test_bad_checkpoints_are_one_sentence(checkpoint, tmp_path) -> None:
    import torch

    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(ValueError, match=r"cannot be read as a PyTorch checkpoint \("):
        load_sam2(junk)
    empty = tmp_path / "empty.pt"
    torch.save({"model": {"step": 3}}, empty)
    with pytest.raises(ValueError, match=r"holds no state dict of tensors"):
        load_sam2(empty)
    other = tmp_path / "other.pt"
    torch.save({"model": {"encoder.weight": torch.zeros(2)}}, other)
    with pytest.raises(ValueError, match=r"does not fit the model sam2.1_hiera_t \(missing .*--sam2-config it was"):
        load_sam2(other)
    with pytest.raises(ValueError, match=r"does not fit the model sam2.1_hiera_s"):  # tiny weights, small model
        load_sam2(checkpoint, Sam2Config(model="sam2.1_hiera_s"))
    with pytest.raises(ValueError, match=r"unknown SAM-2 model configuration 'nope'"):
        load_sam2(checkpoint, Sam2Config(model="nope"))


def _real_run(checkpoint, info, movers) -> tuple[np.ndarray, Sam2Masks]:
    model = load_sam2(checkpoint, Sam2Config(image_size=128))
    assert model.image_size == 128 and model.device == "cpu"
    src = Sam2Masks(info, model, FakeMotion(info, movers), Sam2Config(image_size=128))
    labels = np.stack(_run(src, info))
    assert labels.shape == (info.num_frames, 180, 320) and labels.dtype == np.uint8
    return labels, src


@pytest.mark.full
def test_the_real_predictor_tracks_prompted_movers_per_shot(checkpoint) -> None:
    info = clip_info(num_frames=7, cuts=(4,))
    movers = {1: (1, 6, (40, 40, 90, 90)), 2: (2, 3, (200, 60, 260, 120)), 3: (5, 6, (220, 40, 260, 100))}
    labels, src = _real_run(checkpoint, info, movers)
    prompts = [(p.t, p.obj_id) for p in src.prompts]
    # the first mover of each shot is always prompted; the others unless random masks cover them
    assert prompts[0] == (1, 1) and (4, 1) in prompts and set(prompts) <= {(1, 1), (2, 2), (4, 1), (5, 3)}
    assert not labels[0].any()  # nothing prompted yet
    assert set(np.unique(labels[:4])) <= {0} | {k for t, k in prompts if t < 4}
    assert set(np.unique(labels[4:])) <= {0} | {k for t, k in prompts if t >= 4}
    again, _ = _real_run(checkpoint, info, movers)
    assert np.array_equal(labels, again)  # deterministic


@pytest.mark.slow
def test_the_real_predictor_keeps_only_the_memory_it_can_reach(checkpoint) -> None:
    info = clip_info(num_frames=24)
    _, src = _real_run(checkpoint, info, {1: (0, 23, (40, 40, 90, 90))})
    session = src._session
    kept = [sorted(o["non_cond_frame_outputs"]) for o in session.state["output_dict_per_obj"].values()]  # type: ignore[union-attr]
    assert kept == [list(range(23 - session.keep, 24))]  # type: ignore[union-attr]


@pytest.mark.full
def test_score_masks_sam2_end_to_end(checkpoint, synth_clips, tmp_path) -> None:
    from geocon_core.record import read_record
    from geocon_core.synth import ClipPlan
    from geocon_viewer.cli import app

    clip = synth_clips([ClipPlan("C4")], seed=0, width=320, height=180, num_frames=12) / "c4_objects.mp4"
    out = tmp_path / "out"
    args = ["score", str(clip), "--preset", "fast", "--no-dense", "--out", str(out), "--json"]
    sam2 = ["--masks", "sam2", "--sam2-checkpoint", str(checkpoint), "--sam2-size", "256"]
    res = CliRunner().invoke(app, [*args, *sam2])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    record = read_record(out)
    assert record.masks_source == "sam2" and summary["masks"] == "sam2"
    assert record.config.masks == "sam2" and record.config.sam2 == Sam2Config(image_size=256)
    assert len(record.masked_share) == 12
    ids = {o.object_id for o in record.objects}
    assert ids and ids <= {1, 2}  # ids of the motion segmentation's movers (C4: a disc and a card)
    seen: set[int] = set()
    for t in range(12):
        lab = cv2.imread(str(out / "overlays" / f"labels-{t:05d}.png"), cv2.IMREAD_UNCHANGED)
        assert lab.shape == (180, 320)
        seen |= set(np.unique(lab).tolist()) - {0}
        share = np.count_nonzero(lab) / lab.size
        assert record.masked_share[t] == pytest.approx(share, abs=1e-6)
    assert seen == ids
