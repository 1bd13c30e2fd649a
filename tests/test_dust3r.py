"""The DUSt3R pose backend: the pose from point maps recovers a known pose, the checkpoint loader
never unpickles or evaluates anything but literals and says in one sentence what is wrong, and
``geocon score --pose dust3r`` writes a record with the pose and the point maps (random-weight
tiny checkpoint; DUSt3R itself comes from the ``mini-dust3r`` package or a checkout)."""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.geometry import make_pose, rotation_xyz
from geocon_core.pose import make_pose_backend
from geocon_core.pose.dust3r import (
    Dust3rPose,
    network_input,
    parse_model_string,
    pose_from_pointmaps,
    similarity_align,
)

TINY = (
    "AsymmetricCroCo3DStereo(pos_embed='RoPE100', img_size=(224, 224), head_type='linear', "
    "output_mode='pts3d', depth_mode=('exp', -inf, inf), conf_mode=('exp', 1, inf), enc_embed_dim=32, "
    "enc_depth=1, enc_num_heads=2, dec_embed_dim=32, dec_depth=1, dec_num_heads=2)"
)
"""A DUSt3R model string in the released checkpoints' form, with tiny dimensions."""


# --- the pose from point maps ------------------------------------------------------------------


def _scene(seed: int, T_cam0_camT: np.ndarray, h: int = 24, w: int = 32):
    """Point maps of a random scene seen by two cameras: the first frame's points in camera 0,
    the last frame's in camera 0 and (on another scale, as DUSt3R's second pass) in its own."""
    rng = np.random.default_rng(seed)
    n = h * w
    rays = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.4, 0.4, n), np.ones(n)])
    X0 = rays * rng.uniform(2.0, 6.0, (n, 1))  # first frame's points, camera 0
    Y = rays[::-1] * rng.uniform(2.0, 6.0, (n, 1))  # last frame's points, its own camera
    Y_in0 = Y @ T_cam0_camT[:3, :3].T + T_cam0_camT[:3, 3]
    return X0.reshape(h, w, 3), Y_in0.reshape(h, w, 3), Y.reshape(h, w, 3)


def test_similarity_align_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    R = rotation_xyz(20.0, -7.0, 3.0)
    dst = 2.5 * src @ R.T + [0.3, -1.0, 4.0]
    s, R_fit, t = similarity_align(src, dst, rng.uniform(0.5, 2.0, 50))
    assert s == pytest.approx(2.5, abs=1e-9)
    assert np.abs(R_fit - R).max() < 1e-9 and np.abs(t - [0.3, -1.0, 4.0]).max() < 1e-9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pose_from_pointmaps_recovers_the_true_pose(seed: int):
    rng = np.random.default_rng(100 + seed)
    T = make_pose(rotation_xyz(*rng.uniform(-15, 15, 3)), rng.uniform(-0.5, 0.5, 3))
    X0, Y_in0, Y = _scene(seed, T)
    h, w = X0.shape[:2]
    conf = rng.uniform(3.5, 20.0, (3, h, w))
    # DUSt3R's two passes have unrelated scales: pass 1 scaled by 0.7, pass 2 by 0.23
    fit = pose_from_pointmaps(0.7 * X0, conf[0], 0.7 * Y_in0, conf[1], 0.23 * Y, conf[2], min_conf=3.0, min_points=100)
    assert fit and fit.reason is None and fit.n_points == h * w
    dist = float(np.linalg.norm(X0.reshape(-1, 3), axis=1).mean())
    assert fit.T_cam0_camT is not None
    assert np.abs(fit.T_cam0_camT[:3, :3] - T[:3, :3]).max() < 1e-6
    assert np.abs(fit.T_cam0_camT[:3, 3] - T[:3, 3] / dist).max() < 1e-6
    assert fit.mean_distance == pytest.approx(0.7 * dist) and fit.rms < 1e-9


def test_low_confidence_pixels_are_left_out_and_too_few_fail():
    T = make_pose(rotation_xyz(5.0, 0.0, 0.0), np.array([0.2, 0.0, 0.1]))
    X0, Y_in0, Y = _scene(7, T)
    h, w = X0.shape[:2]
    rng = np.random.default_rng(7)
    conf = np.full((h, w), 10.0)
    bad = rng.random((h, w)) < 0.3
    garbage = Y_in0.copy()
    garbage[bad] = rng.normal(scale=50.0, size=(int(bad.sum()), 3))  # wrong predictions...
    low = np.where(bad, 1.5, 10.0)  # ...that DUSt3R is unsure of
    fit = pose_from_pointmaps(X0, conf, garbage, low, Y, conf, min_conf=3.0, min_points=100)
    assert fit and fit.n_points == int((~bad).sum())
    dist = float(np.linalg.norm(X0.reshape(-1, 3), axis=1).mean())
    assert np.abs(fit.T_cam0_camT[:3, 3] - T[:3, 3] / dist).max() < 1e-6
    few = pose_from_pointmaps(X0, conf, Y_in0, np.full((h, w), 2.0), Y, conf, min_conf=3.0, min_points=100)
    assert not few and few.reason == "too_few_points" and few.T_cam0_camT is None
    flat = np.zeros_like(Y)
    flat[..., 2] = 1.0  # every point the same: no rotation can be found
    degenerate = pose_from_pointmaps(X0, conf, Y_in0, conf, flat, conf, min_conf=3.0, min_points=100)
    assert not degenerate and degenerate.reason == "degenerate"


def test_network_input_follows_dust3r_image_loader():
    rgb = np.zeros((180, 320, 3), np.uint8)
    img, box = network_input(rgb, (0, 0, 320, 180), 224)
    assert img.shape == (224, 224, 3) and box == (70, 0, 250, 180)  # centred square
    img, box = network_input(rgb, (10, 0, 310, 180), 512)
    assert img.shape == (304, 512, 3) and box[2] - box[0] == 300  # long side 512, sides cut to 16
    img, box = network_input(np.zeros((720, 1280, 3), np.uint8), (0, 0, 1280, 720), 512)
    assert img.shape == (288, 512, 3) and box == (0, 0, 1280, 720)


# --- the model string and the checkpoint --------------------------------------------------------


def test_the_model_string_is_parsed_not_evaluated():
    spec = parse_model_string(TINY)
    assert spec.class_name == "AsymmetricCroCo3DStereo" and spec.img_size == 224
    assert spec.kwargs["depth_mode"] == ("exp", -math.inf, math.inf)
    assert spec.kwargs["landscape_only"] is False and spec.kwargs["patch_embed_cls"] == "PatchEmbedDust3R"
    many = parse_model_string(TINY.replace("pos_embed=", "patch_embed_cls='ManyAR_PatchEmbed', pos_embed="))
    assert many.kwargs["patch_embed_cls"] == "PatchEmbedDust3R"  # as DUSt3R's loader does


@pytest.mark.parametrize(
    "model, says",
    [
        ("__import__('os').system('touch PWNED')", "must call AsymmetricCroCo3DStereo"),
        ("os.system('touch PWNED')", "must call AsymmetricCroCo3DStereo"),
        ("Evil(img_size=(224, 224))", "must call AsymmetricCroCo3DStereo"),
        ("AsymmetricCroCo3DStereo(enc_depth=__import__('os').system('touch PWNED'))", "not a literal value"),
        ("AsymmetricCroCo3DStereo(img_size=os.sep)", "not a literal value"),
        ("AsymmetricCroCo3DStereo(img_size=size)", "not a literal value"),
        ("AsymmetricCroCo3DStereo(norm_layer=1)", "not a DUSt3R model setting"),
        ("AsymmetricCroCo3DStereo(**{'a': 1})", "only pass keyword arguments"),
        ("AsymmetricCroCo3DStereo(1)", "only pass keyword arguments"),
        ("AsymmetricCroCo3DStereo(", "not a constructor call"),
    ],
)
def test_a_model_string_beyond_literals_is_refused(model: str, says: str, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=says) as info:
        parse_model_string(model, "ckpt")
    assert "\n" not in str(info.value)
    assert not (tmp_path / "PWNED").exists()


@pytest.fixture(scope="module")
def torch():
    """torch and DUSt3R (the ``mini-dust3r`` package), or the test is skipped."""
    module = pytest.importorskip("torch")
    pytest.importorskip("mini_dust3r")
    return module


def _tiny_checkpoint(path: Path, model: str = TINY, *, drop: str | None = None, seed: int = 0) -> Path:
    """A random-weight DUSt3R checkpoint in the released format (seeded; the confidence channel's
    bias raised so that the random network is confident about most pixels)."""
    import warnings

    import torch

    with warnings.catch_warnings():  # DUSt3R's type hints and its import notice are not under test
        warnings.simplefilter("ignore")
        from mini_dust3r.model import AsymmetricCroCo3DStereo

    torch.manual_seed(seed)
    net = AsymmetricCroCo3DStereo(**parse_model_string(TINY).kwargs)
    with torch.no_grad():
        for head in (net.downstream_head1, net.downstream_head2):
            head.proj.bias[3 * 16 * 16 :] += 3.0  # conf = 1 + exp(x): about 21 on average
    state = net.state_dict()
    if drop is not None:
        state = {k: v for k, v in state.items() if not k.startswith(drop)}
    torch.save({"args": argparse.Namespace(model=model, lr=1e-4), "model": state}, path)
    return path


@pytest.fixture(scope="module")
def tiny(torch, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _tiny_checkpoint(tmp_path_factory.mktemp("dust3r") / "tiny.pth")


def test_a_tiny_checkpoint_loads_and_poses_two_frames(tiny: Path):
    backend = make_pose_backend("dust3r", checkpoint=tiny)
    assert isinstance(backend, Dust3rPose) and backend.spec.img_size == 224 and not backend.model.training
    assert backend.source.startswith("mini_dust3r ")
    rng = np.random.default_rng(1)
    rgb0 = rng.integers(0, 255, (180, 320, 3), dtype=np.uint8)
    rgb1 = np.roll(rgb0, 4, axis=1)
    K = np.array([[277.0, 0, 159.5], [0, 277.0, 89.5], [0, 0, 1]])
    est, maps = backend.estimate_frames(rgb0, rgb1, (0, 0, 320, 180), K, (0, 11))
    assert est.method == "dust3r" and est.pose_present and est.n_matches == 224 * 224
    assert est.t_inf == pytest.approx(float(np.abs(est.T_cam0_camT[:3, 3]).max()))
    R = est.T_cam0_camT[:3, :3]
    assert np.abs(R.T @ R - np.eye(3)).max() < 1e-9 and np.linalg.det(R) == pytest.approx(1.0)
    assert maps is not None and maps.xyz0.shape == (112, 112, 3) and maps.xyz0.dtype == np.float16
    assert maps.frames == (0, 11) and maps.box == (70, 0, 250, 180) and maps.step == 2
    seen = maps.conf0.astype(float) >= backend.config.min_conf  # the unit-distance convention, subsampled
    assert np.linalg.norm(maps.xyz0[seen].astype(float), axis=1).mean() == pytest.approx(1.0, rel=0.05)
    again, _ = backend.estimate_frames(rgb0, rgb1, (0, 0, 320, 180), K, (0, 11))
    assert np.array_equal(again.T_cam0_camT, est.T_cam0_camT)  # deterministic
    assert not backend.estimate(np.zeros((5, 2)), np.zeros((5, 2)), K).pose_present  # needs frames


def _one_sentence(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text and text.count(". ") == 0, text
    return text


def test_a_checkpoint_with_code_in_its_model_string_is_refused_unexecuted(torch, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = _tiny_checkpoint(tmp_path / "bad.pth", "__import__('os').system('touch PWNED') or AsymmetricCroCo3DStereo()")
    with pytest.raises(ValueError) as info:
        Dust3rPose(checkpoint=bad)
    assert "never evaluates" in _one_sentence(info) and str(bad) in str(info.value)
    attr = _tiny_checkpoint(tmp_path / "attr.pth", TINY.replace("enc_depth=1", "enc_depth=os.sep"))
    with pytest.raises(ValueError, match="not a literal value"):
        Dust3rPose(checkpoint=attr)
    assert not (tmp_path / "PWNED").exists()


class _Gadget:
    """Not on the loader's allow-list; unpickling it would set ``ran``."""

    ran = False

    def __init__(self) -> None:
        self.payload = 1

    def __setstate__(self, state: dict) -> None:
        _Gadget.ran = True


def test_bad_checkpoints_give_one_sentence(torch, tmp_path: Path):
    cases = {}
    cases["missing"] = (tmp_path / "nope.pth", "does not exist")
    corrupt = tmp_path / "corrupt.pth"
    corrupt.write_bytes(np.random.default_rng(0).bytes(4096))
    cases["corrupt"] = (corrupt, "cannot be read as a PyTorch checkpoint")
    gadget = tmp_path / "gadget.pth"
    torch.save({"args": argparse.Namespace(model=TINY, extra=_Gadget()), "model": {}}, gadget)
    cases["gadget"] = (gadget, "does not unpickle")
    plain = tmp_path / "plain.pth"
    torch.save({"w": torch.zeros(2)}, plain)
    cases["foreign"] = (plain, "is not a DUSt3R checkpoint")
    cases["lacking"] = (_tiny_checkpoint(tmp_path / "lacking.pth", drop="downstream_head2"), "lack")
    wrong = _tiny_checkpoint(tmp_path / "wrong.pth", TINY.replace("enc_embed_dim=32", "enc_embed_dim=64"))
    cases["shapes"] = (wrong, "do not fit the model")
    unbuildable = _tiny_checkpoint(tmp_path / "unbuildable.pth", TINY.replace("head_type='linear'", "head_type='x'"))
    cases["unbuildable"] = (unbuildable, "cannot build the model")
    for name, (path, says) in cases.items():
        with pytest.raises(ValueError) as info:
            Dust3rPose(checkpoint=path)
        assert says in _one_sentence(info), name
        assert str(path) in str(info.value), name
    assert not _Gadget.ran
    with pytest.raises(ValueError, match="needs --dust3r-checkpoint"):
        Dust3rPose()


def test_a_missing_package_or_a_bad_clone_names_what_to_do(tiny: Path, tmp_path: Path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "mini_dust3r", None)  # import fails as if not installed
    with pytest.raises(ValueError) as info:
        Dust3rPose(checkpoint=tiny)
    assert "pip install --no-deps mini-dust3r==0.1.2" in _one_sentence(info) and "--dust3r-path" in str(info.value)
    monkeypatch.undo()
    with pytest.raises(ValueError, match="not a DUSt3R checkout") as info:
        Dust3rPose(checkpoint=tiny, clone=tmp_path)
    _one_sentence(info)
    (tmp_path / "dust3r").mkdir()
    (tmp_path / "dust3r" / "model.py").write_text("raise SystemExit('must not be imported')\n")
    with pytest.raises(ValueError, match="lacks its croco submodule") as info:
        Dust3rPose(checkpoint=tiny, clone=tmp_path)
    _one_sentence(info)


@pytest.mark.skipif(
    not os.environ.get("GEOCON_DUST3R_PATH"), reason="set GEOCON_DUST3R_PATH to a naver/dust3r checkout"
)
def test_a_dust3r_checkout_poses_like_the_package(tiny: Path):
    clone = Path(os.environ["GEOCON_DUST3R_PATH"])
    backend = Dust3rPose(checkpoint=tiny, clone=clone)
    assert backend.source.startswith("dust3r at ")
    packaged = Dust3rPose(checkpoint=tiny)
    rng = np.random.default_rng(2)
    rgb0 = rng.integers(0, 255, (180, 320, 3), dtype=np.uint8)
    rgb1 = np.roll(rgb0, 6, axis=0)
    K = np.eye(3)
    a, _ = backend.estimate_frames(rgb0, rgb1, (0, 0, 320, 180), K, (0, 1))
    b, _ = packaged.estimate_frames(rgb0, rgb1, (0, 0, 320, 180), K, (0, 1))
    assert a.pose_present and np.abs(a.T_cam0_camT - b.T_cam0_camT).max() < 1e-4


# --- end to end ---------------------------------------------------------------------------------


def test_geocon_score_with_dust3r_writes_the_pose_and_point_maps(tiny: Path, synth_clips, tmp_path: Path):
    from geocon_core.record import read_record
    from geocon_core.synth import ClipPlan
    from geocon_viewer.cli import app

    clip = synth_clips([ClipPlan("C3")], seed=5, width=320, height=180, num_frames=12) / "c3_translation.mp4"
    out = tmp_path / "rec"
    args = ["score", str(clip), "--pose", "dust3r", "--dust3r-checkpoint", str(tiny), "--out", str(out)]
    res = CliRunner().invoke(app, [*args, "--preset", "fast", "--no-masks", "--no-dense", "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)  # nothing of DUSt3R's own printing reaches stdout
    assert summary["gate"]["backend"] == "dust3r" and summary["gate"]["pose_present"]
    record = read_record(out)
    gate = record.gate
    assert gate.backend == "dust3r" and gate.pose.method == "dust3r" and gate.pose_present
    assert gate.t_inf == pytest.approx(float(np.abs(gate.pose.T_cam0_camT[:3, 3]).max()))
    assert gate.label in ("H", "F", "U") and gate.margin is not None
    assert record.config.pose_backend == "dust3r"
    maps = record.pointmaps
    assert maps is not None and maps.frames == (0, record.video.num_frames - 1)
    assert maps.xyz0.shape == maps.xyz1.shape == (112, 112, 3) and maps.rgb1.dtype == np.uint8
    assert np.isfinite(maps.xyz0.astype(float)).all() and float(maps.conf1.min()) >= 1.0
    assert [w.start for w in gate.timeline] == [0]  # the first-last pose only, as with a pose log
    # the recording shows the confident points of both maps
    from rerun.chunk import RrdReader

    from geocon_viewer.rerun.log import write_rrd

    write_rrd(out, tmp_path / "audit.rrd")
    reader = RrdReader(tmp_path / "audit.rrd")
    (store,) = reader.recordings()
    counts = {}
    for chunk in reader.stream(store=store):
        if chunk.entity_path.startswith("/world/dust3r/"):
            counts[chunk.entity_path] = len(chunk.to_record_batch().to_pydict()["Points3D:positions"][0])
    least = record.config.dust3r.min_conf
    assert counts == {
        "/world/dust3r/first": int((maps.conf0.astype(np.float32) >= least).sum()),
        "/world/dust3r/last": int((maps.conf1.astype(np.float32) >= least).sum()),
    }


def test_the_cli_checks_dust3r_options_before_decoding(tiny: Path, tmp_path: Path):
    from geocon_viewer.cli import app

    missing_clip = str(tmp_path / "no-such-clip.mp4")
    cases = [
        (["--pose", "dust3r"], "needs --dust3r-checkpoint"),
        (["--dust3r-checkpoint", str(tiny)], "used with --pose dust3r"),
        (["--pose", "dust3r", "--dust3r-checkpoint", str(tmp_path / "x.pth")], "does not exist"),
        (["--pose", "dust3r", "--dust3r-checkpoint", str(tiny), "--pose-log", str(tiny)], "exclude each other"),
        (["--pose", "dust3r", "--dust3r-checkpoint", str(tiny), "--dust3r-path", str(tmp_path / "n")], "not a folder"),
        (["--pose", "magic"], "unknown pose backend"),
    ]
    for extra, says in cases:
        res = CliRunner().invoke(app, ["score", missing_clip, "--out", str(tmp_path / "o"), *extra])
        assert res.exit_code != 0 and says in res.output, (extra, res.output)
