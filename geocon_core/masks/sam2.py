"""SAM-2 masks (``sam2``): the built-in motion segmentation finds the movers, SAM-2's video
predictor segments and tracks them.

The motion segmentation (:class:`~geocon_core.masks.motion.MotionSegmenter`) runs as usual.
When a motion id appears for the first time in a frame, the box of its motion mask (grown by
``box_margin``) prompts SAM-2 on that frame, under the same id; from there on SAM-2's memory
tracks the object frame by frame, whatever the motion segmentation sees later. A new motion id
whose mask already lies inside objects SAM-2 tracks (``prompt_cover``) is a mover the motion
segmentation re-detected and adds no prompt. A hard cut starts a new SAM-2 session (ids of
objects that reappear after it are prompted again). Settings: :class:`~geocon_core.config.stages.Sam2Config`.

Labels are final once the motion labels of the frame are (the motion segmentation's
``lookahead``), so the source streams with the same lookahead: each frame is tracked as soon as
its prompts are known. SAM-2 sees the content box resized to a square of ``image_size`` px;
its mask logits (a quarter of that size) are resized bilinearly to the content box, and each
pixel takes the object with the highest logit above ``mask_threshold``. Memory: the images of
the frames not yet tracked, and SAM-2's memory of the last frames its attention can reach
(older outputs are dropped), so it does not grow with the clip.

The model is built from a configuration shipped in the ``sam2`` package (``sam2.1_hiera_t``, ...)
by SAM-2's own builder, with the user's checkpoint read by ``torch.load(..., weights_only=True)``
(:func:`load_sam2`); nothing is downloaded. A GPU is used when torch sees one.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from ..config import Sam2Config
from ..media import ClipInfo, Frame
from .base import Coverage
from .motion import MotionSegmenter

__all__ = [
    "SAM2_INSTALL",
    "Sam2Masks",
    "Sam2Video",
    "Sam2Tracker",
    "Prompt",
    "load_sam2",
    "sam2_config_names",
    "resolve_sam2_config",
    "prompt_box",
]

SAM2_INSTALL = (
    "pip install 'geocon[neural]' && SAM2_BUILD_CUDA=0 pip install --no-build-isolation --no-deps sam2==1.1.0"
)
"""How to install SAM-2 without pulling a CUDA build of torch (``scripts/bootstrap.sh neural`` does it)."""

_POSTPROCESSING = (
    # SAM-2's own video settings: fall back to multimask output when one mask is unstable, and
    # feed binarised masks of prompted frames to the memory. Its hole filling needs a compiled
    # CUDA extension and is left out, so masks do not depend on the build.
    "++model.sam_mask_decoder_extra_args.dynamic_multimask_via_stability=true",
    "++model.sam_mask_decoder_extra_args.dynamic_multimask_stability_delta=0.05",
    "++model.sam_mask_decoder_extra_args.dynamic_multimask_stability_thresh=0.98",
    "++model.binarize_mask_from_pts_for_mem_enc=true",
)


class Prompt:
    """A box prompt: object ``obj_id`` on frame ``t``, box ``(x0, y0, x1, y1)`` in working px."""

    __slots__ = ("t", "obj_id", "box")

    def __init__(self, t: int, obj_id: int, box: tuple[float, float, float, float]) -> None:
        self.t, self.obj_id, self.box = t, obj_id, box

    def __repr__(self) -> str:
        return f"Prompt(t={self.t}, obj_id={self.obj_id}, box={tuple(round(v, 1) for v in self.box)})"


class Sam2Tracker(Protocol):
    """One SAM-2 video session (frames ``0 .. num_frames - 1`` of a shot), frame by frame.
    Images are (S, S, 3) uint8 RGB; boxes are normalised to [0, 1]; logits are (h, w) float32
    at the model's mask resolution."""

    def track(self, t: int, image: np.ndarray) -> dict[int, np.ndarray]:
        """Mask logits of every object prompted so far, on frame t (frames in increasing order)."""
        ...

    def prompt(self, t: int, image: np.ndarray, obj_id: int, box: tuple[float, float, float, float]) -> np.ndarray:
        """Start tracking object ``obj_id`` from frame t (after ``track(t)``); its logits there."""
        ...


class Sam2Video:
    """A SAM-2 video predictor (:func:`load_sam2`) on a stream: :meth:`session` starts a shot."""

    def __init__(self, predictor: Any, config: Sam2Config) -> None:
        self.predictor = predictor
        self.config = config

    @property
    def device(self) -> str:
        return str(self.predictor.device)

    @property
    def image_size(self) -> int:
        """Side (px) of the square image the model sees."""
        return int(self.predictor.image_size)

    def session(self, num_frames: int) -> "_Session":
        return _Session(self.predictor, num_frames)


class _Images:
    """The inference state's frames: normalised on demand from uint8 images, dropped once tracked."""

    def __init__(self, num_frames: int, device: Any) -> None:
        import torch

        self.n = num_frames
        self.device = device
        self.frames: dict[int, Any] = {}
        self.mean = torch.tensor([0.485, 0.456, 0.406]).view(3, 1, 1)
        self.std = torch.tensor([0.229, 0.224, 0.225]).view(3, 1, 1)

    def put(self, t: int, image: np.ndarray) -> None:
        import torch

        if t not in self.frames:
            x = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float() / 255.0
            self.frames[t] = (x - self.mean) / self.std
        for k in [k for k in self.frames if k < t - 1]:  # the previous frame may still be encoded
            del self.frames[k]

    def __getitem__(self, t: int) -> Any:
        return self.frames[t]

    def __len__(self) -> int:
        return self.n


class _Session:
    """The inference state of SAM-2's video predictor, built from frames as they arrive (the
    predictor's own ``init_state`` reads a whole video from disk)."""

    def __init__(self, predictor: Any, num_frames: int) -> None:
        from collections import OrderedDict

        self.p = predictor
        size = predictor.image_size // 4  # masks stay at the decoder's resolution
        device = predictor.device
        self.images = _Images(num_frames, device)
        self.state: dict[str, Any] = {
            "images": self.images,
            "num_frames": num_frames,
            "offload_video_to_cpu": False,
            "offload_state_to_cpu": False,
            "video_height": size,
            "video_width": size,
            "device": device,
            "storage_device": device,
            "point_inputs_per_obj": {},
            "mask_inputs_per_obj": {},
            "cached_features": {},
            "constants": {},
            "obj_id_to_idx": OrderedDict(),
            "obj_idx_to_id": OrderedDict(),
            "obj_ids": [],
            "output_dict_per_obj": {},
            "temp_output_dict_per_obj": {},
            "frames_tracked_per_obj": {},
        }
        # outputs older than this are beyond the reach of the memory attention and object pointers
        self.keep = max(
            predictor.num_maskmem * predictor.memory_temporal_stride_for_eval, predictor.max_obj_ptrs_in_encoder
        )

    def track(self, t: int, image: np.ndarray) -> dict[int, np.ndarray]:
        import torch

        self.images.put(t, image)
        st = self.state
        if not st["obj_ids"]:
            return {}
        out: dict[int, np.ndarray] = {}
        with torch.inference_mode():
            self.p.propagate_in_video_preflight(st)  # memory of the frames prompted last
            for idx, obj_id in st["obj_idx_to_id"].items():
                outputs = st["output_dict_per_obj"][idx]
                if t in outputs["cond_frame_outputs"]:
                    masks = outputs["cond_frame_outputs"][t]["pred_masks"]
                else:
                    current, masks = self.p._run_single_frame_inference(
                        inference_state=st,
                        output_dict=outputs,
                        frame_idx=t,
                        batch_size=1,
                        is_init_cond_frame=False,
                        point_inputs=None,
                        mask_inputs=None,
                        reverse=False,
                        run_mem_encoder=True,
                    )
                    outputs["non_cond_frame_outputs"][t] = current
                st["frames_tracked_per_obj"][idx][t] = {"reverse": False}
                out[int(obj_id)] = masks[0, 0].float().cpu().numpy()
                old = [k for k in outputs["non_cond_frame_outputs"] if k < t - self.keep]
                for k in old:
                    del outputs["non_cond_frame_outputs"][k]
        return out

    def prompt(self, t: int, image: np.ndarray, obj_id: int, box: tuple[float, float, float, float]) -> np.ndarray:
        import torch

        self.images.put(t, image)
        with torch.inference_mode():
            _, ids, masks = self.p.add_new_points_or_box(
                self.state,
                frame_idx=t,
                obj_id=obj_id,
                box=torch.tensor(box, dtype=torch.float32),
                normalize_coords=False,
            )
        return masks[list(ids).index(obj_id), 0].float().cpu().numpy()


def _sam2_root() -> Path | None:
    spec = importlib.util.find_spec("sam2")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def sam2_config_names() -> dict[str, str]:
    """The model configurations shipped in the installed ``sam2`` package: short name
    (``sam2.1_hiera_t``) -> the name SAM-2's builder takes (``configs/sam2.1/sam2.1_hiera_t.yaml``);
    training configurations are left out. Empty without the package."""
    root = _sam2_root()
    if root is None or not (root / "configs").is_dir():
        return {}
    found = sorted((root / "configs").glob("*/*.yaml"))
    return {p.stem: p.relative_to(root).as_posix() for p in found if "training" not in p.parent.name}


def resolve_sam2_config(name: str) -> str:
    """The builder's name of the model configuration ``name`` (``sam2.1_hiera_t``, with or without
    ``.yaml`` or a ``configs/<family>/`` prefix); ValueError listing the valid names otherwise."""
    names = sam2_config_names()
    stem = Path(str(name).strip()).name.removesuffix(".yaml")
    if stem not in names:
        raise ValueError(f"unknown SAM-2 model configuration {name!r}; valid: {', '.join(names) or 'none installed'}")
    return names[stem]


def _check_installed() -> None:
    missing = [m for m in ("torch", "sam2", "hydra", "iopath") if importlib.util.find_spec(m) is None]
    if missing:
        raise ValueError(f"SAM-2 masks need {', '.join(missing)}: {SAM2_INSTALL}")


def load_sam2(checkpoint: str | Path | None, config: Sam2Config | None = None, device: str | None = None) -> Sam2Video:
    """SAM-2's video predictor for the model configuration ``config.model`` at ``config.image_size``,
    with the weights of ``checkpoint`` (a released ``sam2*.pt``, ``{"model": state_dict}``, or a
    bare state dict) read with ``torch.load(..., weights_only=True)``, in eval mode on ``device``
    (default: CUDA when torch sees one). A missing package, a missing or unreadable checkpoint,
    an unknown configuration or a checkpoint of another model raise ``ValueError`` with one
    sentence."""
    cfg = config or Sam2Config()
    if checkpoint is None:
        raise ValueError("SAM-2 masks need a checkpoint: pass --sam2-checkpoint PATH (e.g. sam2.1_hiera_tiny.pt)")
    _check_installed()
    path = Path(checkpoint)
    if not path.is_file():
        raise ValueError(f"SAM-2 checkpoint {path} does not exist (pass --sam2-checkpoint with a SAM-2 .pt file)")
    from ..files import read_checkpoint_file

    config_name = resolve_sam2_config(cfg.model)
    try:
        import torch
        from sam2.build_sam import build_sam2_video_predictor
    except ImportError as exc:
        raise ValueError(f"SAM-2 does not import ({exc}): {SAM2_INSTALL}") from None
    loaded = read_checkpoint_file(path, "SAM-2 checkpoint", "pass --sam2-checkpoint with a SAM-2 .pt file")
    state = loaded.get("model", loaded) if isinstance(loaded, dict) else None
    if not isinstance(state, dict) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"SAM-2 checkpoint {path} holds no state dict of tensors (expected {{'model': state_dict}})")
    overrides = [f"++model.image_size={cfg.image_size}", *_POSTPROCESSING]
    with torch.random.fork_rng(devices=[]):  # the random initialisation is overwritten; leave the global RNG
        model = build_sam2_video_predictor(
            config_name, None, device="cpu", hydra_overrides_extra=overrides, apply_postprocessing=False
        )
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    wrong = [k for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k].shape)]
    if missing or extra or wrong:
        what = f"missing {missing[:2]}" if missing else f"unexpected {extra[:2]}" if extra else f"shape of {wrong[0]}"
        raise ValueError(
            f"SAM-2 checkpoint {path} does not fit the model {cfg.model} ({what}); "
            "pass the --sam2-config it was made for"
        )
    model.load_state_dict(state)
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    return Sam2Video(model.eval().to(device), cfg)


def prompt_box(mask: np.ndarray, margin: float) -> tuple[float, float, float, float]:
    """The box ``(x0, y0, x1, y1)`` (end-exclusive, px) of the pixels of ``mask`` ((H, W) bool,
    not empty) grown by ``margin`` times its width and height on each side, clipped to the image."""
    ys, xs = np.nonzero(mask)
    x0, y0, x1, y1 = float(xs.min()), float(ys.min()), float(xs.max()) + 1.0, float(ys.max()) + 1.0
    gx, gy = margin * (x1 - x0), margin * (y1 - y0)
    h, w = mask.shape
    return max(0.0, x0 - gx), max(0.0, y0 - gy), min(float(w), x1 + gx), min(float(h), y1 + gy)


class Sam2Masks(Coverage):
    """SAM-2 masks prompted by the motion segmentation (``name = "sam2"``; see the module
    docstring). ``model``: :func:`load_sam2`'s result, or any object whose ``session(num_frames)``
    gives a :class:`Sam2Tracker`; ``motion``: the segmentation whose movers prompt it (its
    lookahead is this source's). ``prompts`` lists every prompt given, in order."""

    name = "sam2"

    def __init__(self, info: ClipInfo, model: Any, motion: MotionSegmenter, config: Sam2Config | None = None) -> None:
        super().__init__(info)
        self.config = config or Sam2Config()
        self.model = model
        self.motion = motion
        self.lookahead = motion.lookahead
        self.prompts: list[Prompt] = []
        self._size = int(getattr(model, "image_size", self.config.image_size))
        x0, y0, x1, y1 = info.content_box
        self._cw, self._ch = x1 - x0, y1 - y0
        n = info.num_frames
        starts = sorted({0, *(c for c in info.cuts if 0 < c < n)})
        self._shots = list(zip(starts, [*starts[1:], n], strict=True))  # [start, end) of each shot
        self._session: Sam2Tracker | None = None
        self._shot_start = self._shot_end = 0
        self._prompted: set[int] = set()  # motion ids of this shot that were prompted or absorbed
        self._images: dict[int, np.ndarray] = {}
        self._labels: dict[int, np.ndarray] = {}
        self._pushed = 0
        self._done = 0  # frames tracked
        self._finished = False
        self._released = 0

    # -- streaming ------------------------------------------------------------------------------

    def push(self, frame: Frame) -> None:
        if self._finished:
            raise ValueError("push() after finish()")
        self.motion.push(frame)
        x0, y0, x1, y1 = self.info.content_box
        crop = frame.rgb[y0:y1, x0:x1]
        interp = cv2.INTER_AREA if self._size < min(self._cw, self._ch) else cv2.INTER_LINEAR
        self._images[frame.index] = cv2.resize(crop, (self._size, self._size), interpolation=interp)
        self._pushed = frame.index + 1
        while self._done <= frame.index - self.lookahead:
            self._step(self._done)

    def finish(self) -> None:
        if self._finished:
            return
        self.motion.finish()
        while self._done < self._pushed:
            self._step(self._done)
        self._finished = True

    def labels(self, t: int) -> np.ndarray:
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} is outside 0..{self.info.num_frames - 1}")
        if t < self._released:
            raise ValueError(f"labels of frame {t} were released")
        if t not in self._labels:
            raise ValueError(
                f"labels of frame {t} are not final before frame {t + self.lookahead} is pushed or finish() is called"
            )
        return self._labels[t]

    def release(self, t: int) -> None:
        for k in [k for k in self._labels if k < t]:
            del self._labels[k]
        self._released = max(self._released, t)

    # -- one frame ------------------------------------------------------------------------------

    def _step(self, t: int) -> None:
        """Track frame t, prompt its new movers and store its labels."""
        if self._session is None or t >= self._shot_end:
            start, end = next((s, e) for s, e in self._shots if s <= t < e)
            self._session = self.model.session(end - start)
            self._shot_start, self._shot_end = start, end
            self._prompted = set()
        image = self._images.pop(t)
        local = t - self._shot_start
        logits = self._session.track(local, image)
        motion = self.motion.labels(t)
        self.motion.release(t + 1)
        x0, y0, x1, y1 = self.info.content_box
        moving = motion[y0:y1, x0:x1]
        tracked = self._content_labels(logits)
        for k in (int(k) for k in np.unique(moving) if k and int(k) not in self._prompted):
            self._prompted.add(k)
            mask = moving == k
            if np.count_nonzero(mask & (tracked > 0)) >= self.config.prompt_cover * np.count_nonzero(mask):
                continue  # a mover SAM-2 already tracks, re-detected by the motion segmentation
            bx0, by0, bx1, by1 = prompt_box(mask, self.config.box_margin)
            self.prompts.append(Prompt(t, k, (bx0 + x0, by0 + y0, bx1 + x0, by1 + y0)))
            box = (bx0 / self._cw, by0 / self._ch, bx1 / self._cw, by1 / self._ch)
            logits[k] = self._session.prompt(local, image, k, box)
        out = np.zeros(self.info.working_size[::-1], np.uint8)
        out[y0:y1, x0:x1] = self._content_labels(logits)
        out.flags.writeable = False
        self._labels[t] = out
        self._record(t, out)
        self._done = t + 1

    def _content_labels(self, logits: dict[int, np.ndarray]) -> np.ndarray:
        """(ch, cw) uint8 labels of the content box: per pixel the object with the highest logit
        above ``mask_threshold`` (logits resized bilinearly to the content box), else 0."""
        out = np.zeros((self._ch, self._cw), np.uint8)
        if not logits:
            return out
        ids = sorted(logits)
        size = (self._cw, self._ch)
        stack = np.stack([cv2.resize(logits[k].astype(np.float32), size, interpolation=cv2.INTER_LINEAR) for k in ids])
        best = np.argmax(stack, axis=0)
        lut = np.asarray(ids, np.uint8)
        keep = np.take_along_axis(stack, best[None], axis=0)[0] > self.config.mask_threshold
        out[keep] = lut[best[keep]]
        return out
