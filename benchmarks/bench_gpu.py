"""Speed and memory of the neural backends on a GPU: RAFT-small flow, SAM-2 video masks, DUSt3R.

    python3 benchmarks/bench_gpu.py --out DIR                            # the default run, a few minutes
    python3 benchmarks/bench_gpu.py --out DIR --only raft,dis            # some sections only
    .venv/bin/python benchmarks/bench_gpu.py --quick --device cpu --out /tmp/bg   # tiny sizes: a CPU check

Every model has seeded random weights built as the tests build them (no checkpoint is
downloaded or needed), so the numbers are speed and memory only, never quality. Frames: a
rendered ``--size`` clip of ``--frames`` frames (a smooth random texture sliding 2 px per frame
at 1024 px wide and a textured square crossing it), no video file.

- **raft**: :class:`geocon_core.flow.RaftFlow` (RAFT-small, 12 iterations, float32 tensors;
  cuDNN's TF32 setting as torch leaves it, shown in the header) on every consecutive pair:
  milliseconds per pair of ``compute_both`` alone (forward and backward flow as one batch of
  two, the forward-backward check on the CPU, what the scorer calls), of ``compute_both_many``
  with ``--batches`` pairs per network call, and of the network call alone at each batch size,
  with the peak GPU memory (``torch.cuda.max_memory_allocated``) of each batch size.
- **dis**: :class:`geocon_core.flow.DisFlow` (OpenCV DIS, medium preset) ``compute_both`` on
  the same pairs, on the CPU with one OpenCV thread and with all of them: the default flow
  backend, for comparison with RAFT.
- **sam2**: the SAM-2 video predictor of :mod:`geocon_core.masks.sam2` (``--sam2-model``, at
  ``--sam2-size`` px, the configured default): one box prompt on the square at frame 0, then
  tracked through the remaining frames; frames per second of the tracking, milliseconds of the
  prompted first frame, peak GPU memory. Skipped, saying so, when SAM-2 does not import.
- **dust3r**: :class:`geocon_core.pose.dust3r.Dust3rPose` on the first and last frame:
  milliseconds of the network's forward pass (both orders, one batch of two) and of
  ``estimate_frames`` (input resize, forward and the point-map alignment), peak GPU memory.
  Two models: the tests' tiny one (224 px, one 32-wide block each side) and, unless
  ``--quick``, one of the released checkpoints' size (``DUSt3R_ViTLarge_BaseDecoder_512_dpt``:
  ViT-L encoder, ViT-B decoder, DPT heads, 512 px; 2.3 GB of float32 weights written to a
  temporary file and read back as a user's checkpoint would be). Skipped, saying so, when
  ``mini_dust3r`` does not import.

Each section runs on its own: an error is printed and recorded and the next section runs. The
table goes to stdout and, after every section, to ``--out``/bench_gpu.json (header, one row per
measurement, the errors). Timings are the median of ``--repeats`` runs after a warm-up, with
``torch.cuda.synchronize`` around each.

On a machine with torch but not this project's other dependencies this script imports only
numpy, OpenCV, torch and the modules of ``geocon_core`` it measures (not PyAV, POT, pycolmap,
rerun or viser); SAM-2 and DUSt3R come from wheels (sam2, hydra-core, omegaconf,
antlr4-python3-runtime, iopath, portalocker; mini-dust3r, einops, beartype, huggingface_hub
and its imports).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import platform
import statistics
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # geocon_core from this checkout, installed or not

SECTIONS = ("raft", "dis", "sam2", "dust3r")
SPEED_PX = (2.0, 0.5)
"""Background motion per frame at 1024 px wide (px, x and y; scaled with the width)."""
SQUARE_PX = (9.0, 4.0)
"""The square's motion per frame at 1024 px wide (px)."""
DUST3R_TINY = (
    "AsymmetricCroCo3DStereo(pos_embed='RoPE100', img_size=(224, 224), head_type='linear', "
    "output_mode='pts3d', depth_mode=('exp', -inf, inf), conf_mode=('exp', 1, inf), enc_embed_dim=32, "
    "enc_depth=1, enc_num_heads=2, dec_embed_dim=32, dec_depth=1, dec_num_heads=2)"
)
"""The tests' tiny DUSt3R (``tests/test_dust3r.py``, ``TINY``)."""
DUST3R_LARGE = (
    "AsymmetricCroCo3DStereo(pos_embed='RoPE100', patch_embed_cls='ManyAR_PatchEmbed', img_size=(512, 512), "
    "head_type='dpt', output_mode='pts3d', depth_mode=('exp', -inf, inf), conf_mode=('exp', 1, inf), "
    "enc_embed_dim=1024, enc_depth=24, enc_num_heads=16, dec_embed_dim=768, dec_depth=12, dec_num_heads=12)"
)
"""The model string of the released ``DUSt3R_ViTLarge_BaseDecoder_512_dpt`` checkpoint."""


@dataclass(frozen=True)
class Row:
    """One measurement: ``value`` in ``unit`` (None when it does not apply, e.g. GPU memory on a CPU)."""

    section: str
    name: str
    value: float | None
    unit: str
    note: str = ""


@dataclass
class Results:
    """The header, the measurements and the errors of a run; printed and written as they come."""

    out: Path
    meta: dict[str, Any]
    rows: list[Row] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def add(self, section: str, name: str, value: float | None, unit: str, note: str = "") -> None:
        row = Row(section, name, None if value is None else round(float(value), 3), unit, note)
        self.rows.append(row)
        print(f"  {_line(row)}", flush=True)

    @contextmanager
    def section(self, name: str) -> Iterator[None]:
        """Run one section: an exception is printed and recorded, and the run goes on."""
        print(f"\n[{name}]", flush=True)
        t0 = time.perf_counter()
        try:
            yield
        except Exception as exc:  # one section's failure must not lose the others
            traceback.print_exc()
            self.errors.append(f"{name}: {type(exc).__name__}: {exc}")
            print(f"{name}: failed ({type(exc).__name__}: {exc}); going on", flush=True)
        finally:
            _release("cuda" if "torch" in sys.modules and sys.modules["torch"].cuda.is_available() else "cpu")
            print(f"[{name}] {time.perf_counter() - t0:.1f} s", flush=True)
            self.write()

    def write(self) -> None:
        rows = [asdict(r) | {"name": r.name.strip()} for r in self.rows]  # the table's indent left out
        payload = {"meta": self.meta, "rows": rows, "errors": self.errors}
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "bench_gpu.json").write_text(json.dumps(payload, indent=1) + "\n")

    def table(self) -> str:
        width = max([len(r.section) + len(r.name) + 3 for r in self.rows] + [20])
        keys = max(len(k) for k in self.meta)
        lines = [f"{k:>{keys}}: {v}" for k, v in self.meta.items() if k != "args"]
        lines += ["", f"{'measurement':<{width}} {'value':>10}  unit       note", "-" * (width + 40)]
        lines += [_line(r, width) for r in self.rows]
        lines += [f"ERROR {e}" for e in self.errors]
        return "\n".join(lines)


def _line(row: Row, width: int = 48) -> str:
    value = "-" if row.value is None else f"{row.value:.3f}" if abs(row.value) < 10 else f"{row.value:.1f}"
    return f"{row.section + ' | ' + row.name:<{width}} {value:>10}  {row.unit:<10} {row.note}".rstrip()


# -- the clip -------------------------------------------------------------------------------------


def _texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """(h, w, 3) uint8: smooth colour blobs plus fine grain (corners and gradients at every scale)."""
    coarse = cv2.resize(rng.uniform(0, 255, (max(2, h // 24), max(2, w // 24), 3)).astype(np.float32), (w, h))
    mid = cv2.resize(rng.uniform(-60, 60, (max(2, h // 6), max(2, w // 6), 3)).astype(np.float32), (w, h))
    fine = rng.normal(0, 12, (h, w, 1)).astype(np.float32)
    return np.clip(coarse + mid + fine, 0, 255).astype(np.uint8)


def render_clip(size: tuple[int, int], frames: int, seed: int = 0) -> tuple[list[np.ndarray], list[tuple]]:
    """``frames`` (H, W, 3) uint8 RGB frames of ``size`` (W, H) and the square's box (x0, y0, x1,
    y1, px) in each: the background slides by :data:`SPEED_PX` per frame (sub-pixel, reflected at
    the borders), a textured square of a sixth of the height moves by :data:`SQUARE_PX`."""
    w, h = size
    rng = np.random.default_rng(seed)
    background = _texture(rng, h, w)
    side = max(16, h // 6)
    square = _texture(rng, side, side)
    scale = w / 1024
    out, boxes = [], []
    for t in range(frames):
        shift = np.array([[1, 0, SPEED_PX[0] * scale * t], [0, 1, SPEED_PX[1] * scale * t]], dtype=np.float32)
        frame = cv2.warpAffine(background, shift, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT101)
        x0 = int(round(0.15 * w + SQUARE_PX[0] * scale * t)) % (w - side)
        y0 = int(round(0.3 * h + SQUARE_PX[1] * scale * t)) % (h - side)
        frame[y0 : y0 + side, x0 : x0 + side] = square
        out.append(frame)
        boxes.append((x0, y0, x0 + side, y0 + side))
    return out, boxes


# -- timing ---------------------------------------------------------------------------------------


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()


def timed(fn: Callable[[], Any], device: str, repeats: int, warmup: int = 1) -> float:
    """Median wall time (s) of ``fn()`` over ``repeats`` runs after ``warmup`` runs, synchronised."""
    for _ in range(warmup):
        fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _reset_peak(device: str) -> None:
    if device.startswith("cuda"):
        import torch

        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()


def _peak_gib(device: str) -> float | None:
    if not device.startswith("cuda"):
        return None
    import torch

    return torch.cuda.max_memory_allocated() / 2**30


def _release(device: str) -> None:
    import gc

    gc.collect()
    if device.startswith("cuda"):
        import torch

        torch.cuda.empty_cache()


# -- RAFT-small and DIS ----------------------------------------------------------------------------


def raft_checkpoint(path: Path, seed: int = 0) -> Path:
    """A random RAFT-small checkpoint as ``tests/test_raft.py`` builds it (``_weights``,
    ``_random_checkpoint``): every parameter, in sorted key order, ``uniform(-1, 1, shape) /
    sqrt(fan_in)`` from ``default_rng(seed)``, saved with the ``module.`` prefix."""
    import torch

    from geocon_core.flow.raft import RaftSmall

    rng = np.random.default_rng(seed)
    state = {}
    for key, value in sorted(RaftSmall().state_dict().items()):
        shape = tuple(value.shape)
        fan_in = int(np.prod(shape[1:])) if len(shape) > 1 else int(shape[0])
        weights = (rng.uniform(-1.0, 1.0, size=shape) / np.sqrt(fan_in)).astype(np.float32)
        state["module." + key] = torch.from_numpy(weights)
    torch.save(state, path)
    return path


def bench_raft(res: Results, grays: list[np.ndarray], device: str, batches: Sequence[int], repeats: int) -> None:
    from geocon_core.flow import RaftFlow

    pairs = list(zip(grays[:-1], grays[1:], strict=True))
    h, w = grays[0].shape
    with tempfile.TemporaryDirectory() as tmp:
        backend = RaftFlow(checkpoint=raft_checkpoint(Path(tmp) / "raft-small.pth"), device=device)
    note = f"{w}x{h}, {len(pairs)} pairs, fwd+bwd flow and fb check"

    def alone() -> None:
        for g0, g1 in pairs:
            backend.compute_both(g0, g1)

    _reset_peak(device)
    seconds = timed(alone, device, repeats)
    res.add("raft", "compute_both, one pair per call", 1000 * seconds / len(pairs), "ms/pair", note)
    res.add("raft", "  peak GPU memory, one pair", _peak_gib(device), "GiB")
    for b in batches:
        try:
            _reset_peak(device)
            seconds = timed(partial(backend.compute_both_many, pairs, batch=b), device, repeats)
            peak = _peak_gib(device)
            res.add("raft", f"compute_both_many, batch {b}", 1000 * seconds / len(pairs), "ms/pair", note)
            n, seconds = _raft_network(backend.model, pairs[:b], device, repeats)
            res.add("raft", f"  network only, {2 * n} images/call", 1000 * seconds / n, "ms/pair")
            res.add("raft", f"  peak GPU memory, batch {b}", peak, "GiB")
        except Exception as exc:  # e.g. out of memory at the largest batch
            res.errors.append(f"raft batch {b}: {type(exc).__name__}: {exc}")
            print(f"raft batch {b}: failed ({type(exc).__name__}: {str(exc)[:200]})", flush=True)
        finally:
            _release(device)


def _raft_network(
    model: Any, pairs: list[tuple[np.ndarray, np.ndarray]], device: str, repeats: int
) -> tuple[int, float]:
    """(pairs, median s) of one network call on ``pairs`` as :class:`RaftFlow` batches them
    (each pair's forward and backward flow), the images already on the device."""
    import torch

    from geocon_core.flow.raft import MIN_SIDE

    h, w = pairs[0][0].shape
    x = torch.from_numpy(np.repeat(np.stack([g for pair in pairs for g in pair])[:, None], 3, axis=1))
    ph, pw = max(MIN_SIDE, -(-h // 8) * 8) - h, max(MIN_SIDE, -(-w // 8) * 8) - w  # as RaftFlow pads
    x = torch.nn.functional.pad(x.float().to(device), (0, pw, 0, ph), mode="replicate")
    y = x.view(len(pairs), 2, *x.shape[1:]).flip(1).reshape(x.shape)  # (a, b) -> (b, a) per pair

    def network() -> None:
        with torch.no_grad():
            model(x, y)

    return len(pairs), timed(network, device, repeats)


def bench_dis(res: Results, grays: list[np.ndarray], repeats: int) -> None:
    from geocon_core.flow import DisFlow

    pairs = list(zip(grays[:-1], grays[1:], strict=True))
    h, w = grays[0].shape
    backend = DisFlow(preset="medium")
    default = cv2.getNumThreads()

    def run() -> None:
        for g0, g1 in pairs:
            backend.compute_both(g0, g1)

    try:
        for threads in (1, default):
            cv2.setNumThreads(threads)
            seconds = timed(run, "cpu", repeats)
            note = f"{w}x{h}, medium preset, fwd+bwd flow and fb check, CPU"
            res.add("dis", f"compute_both, {threads} OpenCV thread(s)", 1000 * seconds / len(pairs), "ms/pair", note)
    finally:
        cv2.setNumThreads(default)


# -- SAM-2 -----------------------------------------------------------------------------------------


def sam2_missing() -> str | None:
    """Why SAM-2 cannot run here (a missing or broken package), or None."""
    missing = [m for m in ("torch", "sam2", "hydra", "iopath") if importlib.util.find_spec(m) is None]
    if missing:
        return f"not installed ({', '.join(missing)} missing)"
    try:
        import sam2.build_sam  # noqa: F401
    except Exception as exc:  # any import failure means: skip
        return f"does not import ({type(exc).__name__}: {exc})"
    return None


def sam2_checkpoint(path: Path, model: str, seed: int = 0) -> Path:
    """A random SAM-2 checkpoint as ``tests/test_sam2.py`` builds it: the model from SAM-2's
    builder after ``torch.manual_seed(seed)``, saved as ``{"model": state_dict}``."""
    import torch
    from sam2.build_sam import build_sam2_video_predictor

    from geocon_core.masks.sam2 import resolve_sam2_config

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = build_sam2_video_predictor(resolve_sam2_config(model), None, device="cpu")
        torch.save({"model": net.state_dict()}, path)
    return path


def bench_sam2(
    res: Results, frames: list[np.ndarray], boxes: list[tuple], device: str, model: str, size: int, repeats: int
) -> None:
    why = sam2_missing()
    if why is not None:
        print(f"SAM-2: {why}, skipped", flush=True)
        res.add("sam2", "skipped", None, "", f"SAM-2 {why}")
        return
    from geocon_core.config import Sam2Config
    from geocon_core.masks.sam2 import load_sam2

    config = Sam2Config(model=model, image_size=size)
    with tempfile.TemporaryDirectory() as tmp:
        video = load_sam2(sam2_checkpoint(Path(tmp) / "sam2.pt", model), config, device=device)
    h, w = frames[0].shape[:2]
    interp = cv2.INTER_AREA if size < min(w, h) else cv2.INTER_LINEAR  # as Sam2Masks
    images = [cv2.resize(f, (size, size), interpolation=interp) for f in frames]
    x0, y0, x1, y1 = boxes[0]
    box = (x0 / w, y0 / h, x1 / w, y1 / h)  # normalised, as Sam2Masks prompts
    n = len(images)

    def clip(count: int) -> tuple[float, float]:
        """(s of frame 0 tracked and prompted, s of frames 1..count-1 tracked)."""
        session = video.session(count)
        t0 = time.perf_counter()
        session.track(0, images[0])
        session.prompt(0, images[0], 1, box)
        _sync(device)
        t1 = time.perf_counter()
        for t in range(1, count):
            session.track(t, images[t])
        _sync(device)
        return t1 - t0, time.perf_counter() - t1

    clip(min(n, 3))  # warm-up
    _reset_peak(device)
    runs = [clip(n) for _ in range(repeats)]
    prompt_s = statistics.median(r[0] for r in runs)
    track_s = statistics.median(r[1] for r in runs)
    note = f"{model} at {size}x{size}, random weights, {n} frames, float32"
    res.add("sam2", "tracking (frames 1..n-1)", (n - 1) / track_s if n > 1 else None, "frames/s", note)
    res.add("sam2", "  tracking, per frame", 1000 * track_s / max(1, n - 1), "ms/frame")
    res.add("sam2", "  frame 0, track and box prompt", 1000 * prompt_s, "ms")
    res.add("sam2", "  peak GPU memory", _peak_gib(device), "GiB")


# -- DUSt3R ----------------------------------------------------------------------------------------


def dust3r_checkpoint(path: Path, model_string: str, seed: int = 0) -> Path:
    """A random DUSt3R checkpoint in the released format, as ``tests/test_dust3r.py`` builds it:
    ``torch.manual_seed(seed)``, the model of ``model_string``, the confidence channel's bias of
    a linear head raised by 3 (the random network is then confident about most pixels), saved as
    ``{"args": Namespace(model=...), "model": state_dict}``."""
    import torch

    from geocon_core.pose.dust3r import import_model_class, parse_model_string

    cls, _ = import_model_class()
    spec = parse_model_string(model_string)
    torch.manual_seed(seed)
    net = cls(**spec.kwargs)
    with torch.no_grad():
        for head in (net.downstream_head1, net.downstream_head2):
            if hasattr(head, "proj"):
                head.proj.bias[3 * spec.patch_size**2 :] += 3.0
    torch.save({"args": argparse.Namespace(model=model_string), "model": net.state_dict()}, path)
    return path


def dust3r_missing() -> str | None:
    """Why DUSt3R cannot run here, or None."""
    try:
        from geocon_core.pose.dust3r import import_model_class

        import_model_class()
    except Exception as exc:  # ValueError naming what is missing, or any import failure
        return str(exc)
    return None


def bench_dust3r(res: Results, frames: list[np.ndarray], device: str, models: Sequence[str], repeats: int) -> None:
    why = dust3r_missing()
    if why is not None:
        print(f"DUSt3R: not installed, skipped ({why})", flush=True)
        res.add("dust3r", "skipped", None, "", why)
        return
    for name in models:
        try:
            _dust3r_model(res, frames, device, name, repeats)
        except Exception as exc:  # e.g. out of memory with the large model
            traceback.print_exc()
            res.errors.append(f"dust3r {name}: {type(exc).__name__}: {exc}")
            print(f"dust3r {name}: failed ({type(exc).__name__}: {str(exc)[:200]})", flush=True)
        finally:
            _release(device)


def _dust3r_model(res: Results, frames: list[np.ndarray], device: str, name: str, repeats: int) -> None:
    """The rows of one DUSt3R model (``tiny`` or ``vitl512``) on the first and last frame."""
    from geocon_core.pose import default_intrinsics
    from geocon_core.pose.dust3r import Dust3rPose, network_input

    h, w = frames[0].shape[:2]
    box = (0, 0, w, h)
    K = default_intrinsics(box, 60.0)
    string = {"tiny": DUST3R_TINY, "vitl512": DUST3R_LARGE}[name]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        backend = Dust3rPose(checkpoint=dust3r_checkpoint(Path(tmp) / f"{name}.pth", string), device=device)
    build = time.perf_counter() - t0
    size, patch = backend.spec.img_size, backend.spec.patch_size
    img0, _ = network_input(frames[0], box, size, patch)
    img1, _ = network_input(frames[-1], box, size, patch)
    params = sum(p.numel() for p in backend.model.parameters()) / 1e6
    note = f"{img0.shape[1]}x{img0.shape[0]} input, {params:.1f} M parameters, float32"
    _reset_peak(device)
    seconds = timed(lambda: backend._infer(img0, img1), device, repeats)  # the forward pass alone
    res.add("dust3r", f"{name}: forward, both orders", 1000 * seconds, "ms/pair", note)
    seconds = timed(lambda: backend.estimate_frames(frames[0], frames[-1], box, K, (0, 1)), device, repeats)
    res.add("dust3r", f"  {name}: estimate_frames", 1000 * seconds, "ms/pair", "resize, forward, alignment")
    res.add("dust3r", f"  {name}: peak GPU memory", _peak_gib(device), "GiB")
    res.add("dust3r", f"  {name}: random checkpoint, write and load", build, "s")


# -- the run ---------------------------------------------------------------------------------------


def _meta(args: argparse.Namespace, device: str) -> dict[str, Any]:
    meta: dict[str, Any] = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "device": device,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "cpu": f"{platform.machine()}, {cv2.getNumberOfCPUs()} cores",
    }
    try:
        import torch

        meta["torch"] = torch.__version__
        meta["torch threads"] = torch.get_num_threads()
        if device.startswith("cuda"):
            meta["gpu"] = torch.cuda.get_device_name(device)
            meta["cuda"] = torch.version.cuda
    except Exception as exc:  # the DIS section still runs without torch
        meta["torch"] = f"unavailable ({type(exc).__name__}: {exc})"
    try:
        if device.startswith("cuda"):
            tf32 = torch.backends.cudnn.allow_tf32
            meta["tf32"] = f"cudnn convolutions {tf32}, matmul precision {torch.get_float32_matmul_precision()}"
    except Exception as exc:  # a torch without these settings
        meta["tf32"] = f"unknown ({type(exc).__name__})"
    meta["args"] = {k: v for k, v in vars(args).items() if k != "out"}
    return meta


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for bench_gpu.json")
    ap.add_argument("--device", default=None, help="torch device (default: cuda when torch sees one, else cpu)")
    ap.add_argument("--size", default=None, help="frame size WxH (default 1024x720; --quick 256x180)")
    ap.add_argument("--frames", type=int, default=None, help="frames of the clip (default 32; --quick 4)")
    ap.add_argument("--batches", default=None, help="RAFT pairs per call, comma-separated (default 1,4,8,16)")
    ap.add_argument("--repeats", type=int, default=None, help="timed runs per measurement (default 3; --quick 1)")
    ap.add_argument("--sam2-model", default=None, help="SAM-2 model configuration (default: Sam2Config's)")
    ap.add_argument("--sam2-size", type=int, default=None, help="SAM-2 image side (default: Sam2Config's; --quick 256)")
    ap.add_argument("--only", default=",".join(SECTIONS), help=f"sections to run ({', '.join(SECTIONS)})")
    ap.add_argument(
        "--torch-threads",
        type=int,
        default=None,
        help="torch's CPU threads (default: torch's choice; --quick 1, which a busy small machine runs fastest)",
    )
    ap.add_argument("--quick", action="store_true", help="tiny sizes for a CPU check (256x180, 4 frames, batches 1,2)")
    args = ap.parse_args(argv)
    quick = args.quick
    args.size = args.size or ("256x180" if quick else "1024x720")
    args.frames = args.frames or (4 if quick else 32)
    args.batches = args.batches or ("1,2" if quick else "1,4,8,16")
    args.repeats = args.repeats or (1 if quick else 3)
    args.torch_threads = args.torch_threads or (1 if quick else None)
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = sorted(set(only) - set(SECTIONS))
    if unknown:
        ap.error(f"unknown section(s) {', '.join(unknown)}; valid: {', '.join(SECTIONS)}")
    args.only = only
    if args.frames < 2 or args.repeats < 1:
        ap.error("--frames must be at least 2 and --repeats at least 1")
    return args


def _set_threads(threads: int | None) -> None:
    """Give torch ``threads`` CPU threads (None: leave torch's choice)."""
    if threads is None:
        return
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:  # no torch: only DIS runs
        pass


def _default_device() -> str:
    try:
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"
    except Exception:  # no torch: only DIS runs
        return "cpu"


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    device = args.device or _default_device()
    w, h = (int(v) for v in args.size.lower().split("x"))
    batches = [int(b) for b in args.batches.split(",")]
    _set_threads(args.torch_threads)
    res = Results(args.out, _meta(args, device))
    print("\n".join(f"{k}: {v}" for k, v in res.meta.items() if k != "args"), flush=True)
    t0 = time.perf_counter()
    frames, boxes = render_clip((w, h), args.frames)
    grays = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    print(f"clip: {args.frames} frames of {w}x{h} rendered in {time.perf_counter() - t0:.1f} s", flush=True)

    if "raft" in args.only:
        with res.section("raft"):
            bench_raft(res, grays, device, batches, args.repeats)
    if "dis" in args.only:
        with res.section("dis"):
            bench_dis(res, grays, args.repeats)
    if "sam2" in args.only:
        with res.section("sam2"):
            from geocon_core.config import Sam2Config

            default = Sam2Config()
            size = args.sam2_size or (256 if args.quick else default.image_size)
            bench_sam2(res, frames, boxes, device, args.sam2_model or default.model, size, args.repeats)
    if "dust3r" in args.only:
        with res.section("dust3r"):
            models = ["tiny"] if args.quick else ["tiny", "vitl512"]
            bench_dust3r(res, frames, device, models, args.repeats)

    res.meta["total seconds"] = round(time.perf_counter() - t0, 1)
    res.write()
    print("\n" + res.table())
    print(f"\nwritten: {args.out / 'bench_gpu.json'}")
    return 1 if res.errors else 0


if __name__ == "__main__":
    sys.exit(main())
