"""RAFT-small (``geocon_core.flow.raft``) against the authors' implementation.

The fixture ``tests/data/raft_small_reference.npz`` was made once, outside the project, with the
reference code (github.com/princeton-vl/RAFT at 2888e15, ``core/``; ``RAFT(small=True,
mixed_precision=False, alternate_corr=False)``, eval mode, ``test_mode=True``, 12 iterations,
torch 2.13.0 on CPU). Its weights are not stored: every parameter, in sorted key order, is drawn
from ``numpy.random.default_rng(0)`` as ``uniform(-1, 1, shape) / sqrt(fan_in)`` in float32
(``fan_in`` = the product of the shape without its first axis, or its length for a vector),
which :func:`_weights` repeats here. The file holds the released checkpoint's key names and
shapes, the two frames (128x160 RGB: a smooth random texture and the same texture moved by
(2.5, -1.25) px) and the reference's upsampled flow. With such weights the flow is meaningless
(its values reach 67 px) but fully determined, which is what an equivalence check needs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geocon_core.flow.raft import RaftSmall, load_raft_small  # noqa: E402

FIXTURE = Path(__file__).parent / "data" / "raft_small_reference.npz"


def _weights(keys: list[str], shapes: list[tuple[int, ...]], seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {}
    for key, shape in sorted(zip(keys, shapes, strict=True)):
        fan_in = int(np.prod(shape[1:])) if len(shape) > 1 else int(shape[0])
        out[key] = (rng.uniform(-1.0, 1.0, size=shape) / np.sqrt(fan_in)).astype(np.float32)
    return out


@pytest.fixture(scope="module")
def reference():
    with np.load(FIXTURE, allow_pickle=False) as z:
        keys = [str(k) for k in z["keys"]]
        shapes = [tuple(int(v) for v in s.split(",")) for s in z["shapes"]]
        return keys, shapes, z["frame0"], z["frame1"], z["flow_up"]


def _image(frame: np.ndarray):
    return torch.from_numpy(frame).permute(2, 0, 1)[None].float()


def test_parameters_have_the_released_names_and_shapes(reference):
    keys, shapes, *_ = reference
    mine = {k: tuple(v.shape) for k, v in RaftSmall().state_dict().items()}
    assert mine == dict(zip(keys, shapes, strict=True))


@pytest.mark.full
@pytest.mark.parametrize("prefix", ["", "module."])
def test_flow_equals_the_reference_implementation(reference, tmp_path, prefix):
    keys, shapes, f0, f1, expected = reference
    state = {prefix + k: torch.from_numpy(v) for k, v in _weights(keys, shapes).items()}
    torch.save(state, tmp_path / "raft-small.pth")
    model = load_raft_small(tmp_path / "raft-small.pth")
    with torch.no_grad():
        flow = model(_image(f0), _image(f1), iters=12)[0].numpy()
    assert flow.shape == expected.shape == (2, 128, 160)
    assert np.abs(expected).max() > 10  # the comparison is not between two near-zero fields
    assert np.abs(flow - expected).max() <= 1e-4


def test_bad_checkpoints_are_one_sentence(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_raft_small(tmp_path / "nope.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="cannot be read as a PyTorch checkpoint"):
        load_raft_small(tmp_path / "junk.pth")
    torch.save({"conv.weight": torch.zeros(3)}, tmp_path / "other.pth")
    with pytest.raises(ValueError, match="not a RAFT-small checkpoint"):
        load_raft_small(tmp_path / "other.pth")
    with pytest.raises(ValueError, match="multiples of 8 and at least 128"):
        RaftSmall()(torch.zeros(1, 3, 64, 96), torch.zeros(1, 3, 64, 96))


def _random_checkpoint(reference, path: Path) -> Path:
    keys, shapes, *_ = reference
    torch.save({"module." + k: torch.from_numpy(v) for k, v in _weights(keys, shapes).items()}, path)
    return path


@pytest.mark.full
def test_scoring_with_raft_runs_end_to_end(reference, tmp_path):
    """Plumbing only: with random weights the flow means nothing, so this checks that the raft
    backend carries the objects' rigidity through to a valid record (shapes, ids, values), not
    that rigid objects score below elastic ones; that needs the released weights."""
    from geocon_core.config import preset
    from geocon_core.record import read_record, write_record
    from geocon_core.scoring import score_clip
    from geocon_core.synth import ClipPlan, write_clip

    gt = write_clip(ClipPlan("C4"), tmp_path, width=192, height=128, num_frames=6)
    clip = tmp_path / f"{gt.clip_id}.mp4"
    ckpt = _random_checkpoint(reference, tmp_path / "raft-small.pth")
    cfg = preset("fast").with_(flow="raft")
    record = score_clip(clip, cfg, masks=tmp_path / gt.masks_path, flow_checkpoint=ckpt)
    assert record.config.flow == "raft" and record.masks_source.startswith("external")
    assert sorted(o.object_id for o in record.objects) == [1, 2]
    for o in record.objects:  # every frame pair of every object was measured or skipped with a reason
        (summary,) = o.per_scale
        assert summary.valid_frames + sum(summary.skipped.values()) == o.frames - 1 > 0
        assert (o.adadfrc is None) == (summary.valid_frames == 0)
        assert o.adadfrc is None or np.isfinite(o.adadfrc)
    assert record.background.ir is not None
    write_record(record, tmp_path / "rec")
    assert read_record(tmp_path / "rec").config.flow == "raft"


def test_cli_raft_options_are_checked_before_decoding(reference, tmp_path):
    from typer.testing import CliRunner

    from geocon_viewer.cli import app

    clip = tmp_path / "missing.mp4"  # never reached: the options are refused first
    runner = CliRunner()
    res = runner.invoke(app, ["score", str(clip), "--flow", "raft"])
    assert res.exit_code == 2 and "--flow raft needs --raft-checkpoint PATH" in res.stderr
    res = runner.invoke(app, ["score", str(clip), "--raft-checkpoint", str(tmp_path / "x.pth")])
    assert res.exit_code == 2 and "--raft-checkpoint is used with --flow raft" in res.stderr
    res = runner.invoke(app, ["score", str(clip), "--flow", "farneback"])
    assert res.exit_code == 2 and "unknown flow backend 'farneback'; valid: dis, raft" in res.stderr


@pytest.mark.full
def test_batched_pairs_give_the_per_pair_fields(reference, tmp_path):
    """``RaftFlow.compute_both_many`` (several pairs per network call, a last batch that is not
    full) equals ``compute_both`` pair by pair: flow to 1e-4 px, the same reliability where the
    forward-backward error is not within 1e-3 px of its threshold."""
    from geocon_core.flow import RaftFlow

    ckpt = _random_checkpoint(reference, tmp_path / "raft-small.pth")
    backend = RaftFlow(checkpoint=ckpt, device="cpu")
    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, (128, 136), dtype=np.uint8)
    frames = [np.roll(base, (k, 2 * k), axis=(0, 1)) for k in range(4)]
    pairs = list(zip(frames[:-1], frames[1:], strict=True))
    box = (4, 2, 134, 122)  # grown by the margin to the whole frame
    many = backend.compute_both_many(pairs, box, batch=2)
    assert len(many) == len(pairs)
    for (g0, g1), got in zip(pairs, many, strict=True):
        for one, batched in zip(backend.compute_both(g0, g1, box), got, strict=True):
            assert batched.box == one.box == box and batched.flow.shape == (120, 130, 2)
            assert np.abs(one.flow).max() > 1  # not two near-zero fields
            assert np.abs(batched.flow - one.flow).max() <= 1e-4
            finite = np.isfinite(one.fb_error)
            assert np.array_equal(finite, np.isfinite(batched.fb_error))
            assert np.abs(batched.fb_error[finite] - one.fb_error[finite]).max() <= 1e-3
            mag = np.linalg.norm(one.flow, axis=-1)
            margin = np.abs(one.fb_error - (backend.config.fb_abs + backend.config.fb_rel * mag))
            clear = ~finite | (margin > 1e-3)
            assert np.array_equal(batched.reliable[clear], one.reliable[clear])
    with pytest.raises(ValueError, match="one size"):
        backend.compute_both_many([pairs[0], (frames[0][:120], frames[1][:120])])
    with pytest.raises(ValueError, match="batch must be at least 1"):
        backend.compute_both_many(pairs, batch=0)
