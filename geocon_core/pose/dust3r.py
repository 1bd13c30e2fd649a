"""DUSt3R pose backend: the first-last pose from DUSt3R's point maps of the two frames.

``dust3r`` (:class:`Dust3rPose`, ``geocon score --pose dust3r --dust3r-checkpoint PATH``)
    DUSt3R (Naver, CC BY-NC-SA 4.0: non-commercial use only) is not part of GeoCon and is never
    downloaded: the user installs it and gives a checkpoint. Two routes:

    - the ``mini_dust3r`` package (PyPI ``mini-dust3r``, an inference-only repackaging of
      DUSt3R under the same licence), used when no clone is given;
    - ``--dust3r-path CLONE``: a checkout of ``naver/dust3r`` with its ``croco`` submodule,
      whose ``dust3r`` package is imported from there.

    The checkpoint is DUSt3R's own format, ``{"args": Namespace(model="AsymmetricCroCo3DStereo(
    ...)"), "model": state_dict}``. DUSt3R's loader ``eval``\\ s that model string and unpickles
    the file; GeoCon does neither: the file is read with ``torch.load(..., weights_only=True)``
    allowing exactly one class besides tensors and containers (``argparse.Namespace``), and the
    model string is parsed (:func:`parse_model_string`): one call of an allow-listed class with
    allow-listed keyword arguments whose values are literals (numbers, strings, tuples, ``inf``).
    As in DUSt3R's loader, the patch embedding is the plain one and ``landscape_only`` is off
    (both frames have the same size).

Computation (:meth:`Dust3rPose.estimate_frames`): both frames are cut to the clip's content box
and resized as DUSt3R's own image loader does (:func:`network_input`: a 224 checkpoint sees the
centred square, resized to 224x224; a larger one the whole content with its long side at the
checkpoint's size, each side then cropped to a multiple of the patch size). One batched forward
runs both orders, (first, last) and (last, first). The first pass gives the first frame's points
in its own camera and the last frame's points in the first camera; the second pass the last
frame's points in its own camera. The pose ``T_cam0_camT`` is the weighted similarity alignment
of the last frame's own-camera points onto its first-camera points (:func:`similarity_align`,
weights the product of the log confidences of the two predictions, pixels below
``Dust3rConfig.min_conf`` in either left out); the similarity's scale absorbs the two passes'
unrelated scales. The translation is then divided by the mean distance of the first frame's
confident points from the first camera (the DUSt3R-scale convention of :mod:`geocon_core.pose`),
and the point maps, on that scale, go into the record (:class:`~geocon_core.record.PointMaps`).
For this backend ``n_matches`` counts the pixels of one point map and ``n_inliers`` the
confident pixels the alignment used.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import math
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..config import Dust3rConfig
from ..geometry import rotation_angle_deg
from .base import PoseEstimate, failure, focal_of

if TYPE_CHECKING:
    from .pointmaps import PointMaps

__all__ = [
    "DUST3R_INSTALL",
    "MODEL_CLASSES",
    "MODEL_KEYWORDS",
    "Dust3rPose",
    "ModelSpec",
    "PointMapFit",
    "parse_model_string",
    "read_checkpoint",
    "import_model_class",
    "network_input",
    "similarity_align",
    "pose_from_pointmaps",
]

DUST3R_INSTALL = (
    "pip install 'geocon[neural]' && pip install --no-deps mini-dust3r==0.1.2 "
    "(or pass --dust3r-path CLONE, a checkout of naver/dust3r with its croco submodule)"
)
"""How to get DUSt3R, named by every error about a missing package."""

MODEL_CLASSES = ("AsymmetricCroCo3DStereo",)
"""The model classes a checkpoint's model string may name."""

MODEL_KEYWORDS = frozenset(
    {
        "output_mode",
        "head_type",
        "depth_mode",
        "conf_mode",
        "freeze",
        "landscape_only",
        "patch_embed_cls",
        "img_size",
        "patch_size",
        "mask_ratio",
        "enc_embed_dim",
        "enc_depth",
        "enc_num_heads",
        "dec_embed_dim",
        "dec_depth",
        "dec_num_heads",
        "mlp_ratio",
        "norm_im2_in_dec",
        "pos_embed",
    }
)
"""The constructor arguments a checkpoint's model string may set."""

_MAX_MODEL_STRING = 4096
_PATCH_EMBEDS = ("PatchEmbedDust3R", "ManyAR_PatchEmbed")


@dataclass(frozen=True)
class ModelSpec:
    """A parsed model string: the class name and its keyword arguments (literal values)."""

    class_name: str
    kwargs: dict[str, Any]

    @property
    def img_size(self) -> int:
        """The checkpoint's training size (the longer side, px)."""
        size = self.kwargs.get("img_size", 224)
        return int(max(size) if isinstance(size, (tuple, list)) else size)

    @property
    def patch_size(self) -> int:
        return int(self.kwargs.get("patch_size", 16))


def _literal(node: ast.expr, where: str) -> Any:
    """The value of a literal node: a number, string, bool or None, ``inf`` or ``-inf``, or a
    tuple/list of those; anything else (a call, an attribute, a name) raises ``ValueError``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool, type(None))):
        return node.value
    if isinstance(node, ast.Name) and node.id == "inf":
        return math.inf
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _literal(node.operand, where)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, (ast.Tuple, ast.List)):
        return tuple(_literal(e, where) for e in node.elts)
    raise ValueError(
        f"{where}: the model string holds {ast.unparse(node)!r}, which is not a literal value "
        "(GeoCon builds DUSt3R from literal arguments only and never evaluates the string)"
    )


def parse_model_string(text: Any, where: str = "checkpoint") -> ModelSpec:
    """Parse DUSt3R's model string (``"AsymmetricCroCo3DStereo(img_size=(512, 512), ...)"``)
    without evaluating it: one call of a class in :data:`MODEL_CLASSES` with keyword arguments
    from :data:`MODEL_KEYWORDS` whose values are literals. Anything else raises ``ValueError``
    naming ``where``."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"{where}: args.model must be DUSt3R's model string, got {type(text).__name__}")
    if len(text) > _MAX_MODEL_STRING:
        raise ValueError(f"{where}: the model string is longer than {_MAX_MODEL_STRING} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        raise ValueError(f"{where}: the model string is not a constructor call ({text[:60]!r})") from None
    call = tree.body
    if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id in MODEL_CLASSES):
        head = ast.unparse(call.func) if isinstance(call, ast.Call) else ast.unparse(call)
        raise ValueError(
            f"{where}: the model string must call {', '.join(MODEL_CLASSES)}, not {head[:60]!r} "
            "(GeoCon never evaluates it)"
        )
    if call.args or any(k.arg is None for k in call.keywords):
        raise ValueError(f"{where}: the model string may only pass keyword arguments")
    kwargs: dict[str, Any] = {}
    for kw in call.keywords:
        assert kw.arg is not None
        if kw.arg not in MODEL_KEYWORDS:
            raise ValueError(f"{where}: the model string sets {kw.arg!r}, which is not a DUSt3R model setting")
        kwargs[kw.arg] = _literal(kw.value, where)
    embed = kwargs.get("patch_embed_cls", "PatchEmbedDust3R")
    if embed not in _PATCH_EMBEDS:
        raise ValueError(f"{where}: unknown patch embedding {embed!r}; valid: {', '.join(_PATCH_EMBEDS)}")
    # as DUSt3R's loader: the plain patch embedding, and no landscape transposition
    kwargs["patch_embed_cls"] = "PatchEmbedDust3R"
    kwargs["landscape_only"] = False
    return ModelSpec(call.func.id, kwargs)


def read_checkpoint(path: str | Path) -> tuple[ModelSpec, dict[str, Any]]:
    """The model spec and state dict of a DUSt3R checkpoint, read with ``torch.load(...,
    weights_only=True)`` that allows ``argparse.Namespace`` (DUSt3R's ``args``) and nothing else
    beyond tensors and containers. ``ValueError`` (one sentence naming the file) for a missing,
    unreadable or foreign file."""
    import torch

    from ..files import read_checkpoint_file

    where = f"DUSt3R checkpoint {Path(path)}"
    hint = "pass --dust3r-checkpoint with a DUSt3R .pth"
    ckpt = read_checkpoint_file(path, "DUSt3R checkpoint", hint, allow=[argparse.Namespace])
    args = ckpt.get("args") if isinstance(ckpt, dict) else None
    model_string = args.get("model") if isinstance(args, dict) else getattr(args, "model", None)
    state = ckpt.get("model") if isinstance(ckpt, dict) else None
    if model_string is None or not isinstance(state, dict):
        raise ValueError(f"{where} is not a DUSt3R checkpoint (it needs 'args' with a model string and 'model')")
    if not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
        raise ValueError(f"{where}: 'model' is not a state dict of tensors")
    return parse_model_string(model_string, where), state


@contextlib.contextmanager
def _quiet() -> Any:
    """DUSt3R prints a notice on import (no compiled RoPE kernel) and warns about its type hints
    and autocast calls; none of it may reach GeoCon's output (``--json`` prints on stdout)."""
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def import_model_class(clone: str | Path | None = None) -> tuple[type, str]:
    """DUSt3R's model class and where it came from: from the clone at ``clone`` (its ``dust3r``
    package, which imports its ``croco`` submodule), else from the installed ``mini_dust3r``.
    ``ValueError`` (one sentence naming what to install or pass) when it cannot be imported."""
    if clone is None:
        try:
            import torch  # noqa: F401
        except ImportError:
            raise ValueError("the dust3r pose backend needs torch: pip install 'geocon[neural]'") from None
        try:
            with _quiet():
                from mini_dust3r import model as module
        except ImportError as exc:
            raise ValueError(f"the dust3r pose backend needs DUSt3R (missing {exc.name}): {DUST3R_INSTALL}") from None
        except Exception as exc:  # e.g. its check of the huggingface_hub version
            raise ValueError(f"mini_dust3r does not import ({type(exc).__name__}: {exc}): {DUST3R_INSTALL}") from None
        from importlib.metadata import version

        return module.AsymmetricCroCo3DStereo, f"mini_dust3r {version('mini-dust3r')}"
    root = Path(clone).expanduser().resolve()
    if not (root / "dust3r" / "model.py").is_file():
        raise ValueError(f"--dust3r-path {clone} is not a DUSt3R checkout (no dust3r/model.py in it)")
    if not (root / "croco" / "models" / "croco.py").is_file():
        raise ValueError(
            f"--dust3r-path {clone} lacks its croco submodule (run `git submodule update --init` in the checkout)"
        )
    loaded = sys.modules.get("dust3r")
    if loaded is not None and not Path(getattr(loaded, "__file__", "") or "").resolve().is_relative_to(root):
        raise ValueError(
            f"another dust3r package is already imported ({loaded.__file__}); --dust3r-path {clone} is not"
        )
    sys.path.insert(0, str(root))
    try:
        import torch  # noqa: F401

        with _quiet():
            import dust3r.model as module
    except ImportError as exc:
        raise ValueError(
            f"DUSt3R at --dust3r-path {clone} does not import (missing {exc.name}): pip install 'geocon[neural]'"
        ) from None
    except Exception as exc:  # e.g. its check of the huggingface_hub version
        raise ValueError(f"DUSt3R at --dust3r-path {clone} does not import ({type(exc).__name__}: {exc})") from None
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(str(root))
    return module.AsymmetricCroCo3DStereo, f"dust3r at {root}"


def _build(cls: type, spec: ModelSpec, state: dict[str, Any], where: str) -> Any:
    """The model of ``spec`` with the weights of ``state``, in eval mode on the CPU."""
    try:
        with _quiet():
            net = cls(**spec.kwargs)
    except Exception as exc:  # DUSt3R checks its settings with asserts and exceptions of all kinds
        raise ValueError(f"{where}: DUSt3R cannot build the model it describes ({type(exc).__name__}: {exc})") from None
    try:
        result = net.load_state_dict(state, strict=False)
    except RuntimeError as exc:
        lines = str(exc).split("\n\t")
        first = lines[1].split(":")[0].strip() if len(lines) > 1 else type(exc).__name__
        raise ValueError(f"{where}: its weights do not fit the model it describes ({first})") from None
    if result.missing_keys:
        raise ValueError(
            f"{where}: its weights lack {len(result.missing_keys)} parameters of the model it describes "
            f"(first: {result.missing_keys[0]})"
        )
    return net.eval()


def network_input(
    rgb: np.ndarray, content_box: tuple[int, int, int, int], img_size: int, patch: int = 16
) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The network's input image of ``rgb`` ((H, W, 3) uint8) and the region of ``rgb`` it shows
    (x0, y0, x1, y1, px, end-exclusive), as DUSt3R's image loader makes it: for a 224 checkpoint
    the centred square of the content box resized to 224x224; otherwise the content box with its
    long side resized to ``img_size``, each side then cut (centred) to a multiple of ``patch``.
    Returns an (h, w, 3) uint8 image with h and w multiples of ``patch``."""
    x0, y0, x1, y1 = (int(v) for v in content_box)
    cw, ch = x1 - x0, y1 - y0
    if img_size == 224:
        side = min(cw, ch)
        bx, by = x0 + (cw - side) // 2, y0 + (ch - side) // 2
        box = (bx, by, bx + side, by + side)
        out_w = out_h = img_size
    else:
        s = img_size / max(cw, ch)
        out_w, out_h = patch * int(cw * s // patch), patch * int(ch * s // patch)
        if min(out_w, out_h) < patch:
            raise ValueError(f"the content box {cw}x{ch} px is too narrow for DUSt3R at {img_size} px")
        kw, kh = min(cw, round(out_w / s)), min(ch, round(out_h / s))
        bx, by = x0 + (cw - kw) // 2, y0 + (ch - kh) // 2
        box = (bx, by, bx + kw, by + kh)
    crop = rgb[box[1] : box[3], box[0] : box[2]]
    shrink = out_w < crop.shape[1]
    img = cv2.resize(crop, (out_w, out_h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC)
    return img, box


def similarity_align(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity ``dst ~ s R src + t`` minimising ``sum w |dst - s R src - t|^2`` (Umeyama's
    closed form): src, dst (N, 3), weights (N,) non-negative, not all zero. Returns the scale s,
    the rotation R (3, 3; det +1) and the translation t (3,)."""
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    a, b = src - mu_s, dst - mu_d
    cov = (b * w[:, None]).T @ a  # sum w (dst - mu_d)(src - mu_s)^T
    var_s = float(w @ np.einsum("ij,ij->i", a, a))
    U, S, Vt = np.linalg.svd(cov)
    D = np.diag([1.0, 1.0, 1.0 if np.linalg.det(U @ Vt) >= 0 else -1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / var_s)
    return s, R, mu_d - s * R @ mu_s


@dataclass(frozen=True, eq=False)
class PointMapFit:
    """The pose of two point maps (:func:`pose_from_pointmaps`), or why there is none.

    T_cam0_camT: (4, 4) last camera in first-camera coordinates, translation on the unit mean
    scene distance scale; mean_distance: mean distance of the first frame's confident points from
    the first camera (network units); scale: similarity scale between the two passes; rms: root
    mean square residual of the alignment (unit mean scene distance); n_points: pixels used;
    reason: ``"too_few_points"`` or ``"degenerate"`` when there is no pose (then the rest is None
    or 0). Falsy without a pose."""

    T_cam0_camT: np.ndarray | None
    mean_distance: float | None
    scale: float | None
    rms: float | None
    n_points: int
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.T_cam0_camT is not None


def _log_conf(conf: np.ndarray) -> np.ndarray:
    return np.log(np.maximum(np.asarray(conf, dtype=float), 1.0))


def pose_from_pointmaps(
    xyz0: np.ndarray,
    conf0: np.ndarray,
    xyz1_in0: np.ndarray,
    conf1_in0: np.ndarray,
    xyz1_own: np.ndarray,
    conf1_own: np.ndarray,
    *,
    min_conf: float,
    min_points: int,
) -> PointMapFit:
    """The relative pose of the last camera from DUSt3R's point maps (all (H, W, 3) points with
    (H, W) confidences): ``xyz0`` the first frame's points in the first camera, ``xyz1_in0`` the
    last frame's points in the first camera (same pass), ``xyz1_own`` the last frame's points in
    its own camera (the swapped pass, any scale). Pixels below ``min_conf`` are left out; the
    scene scale is the mean distance of the first frame's confident points from the first camera."""
    p0 = np.asarray(xyz0, dtype=float).reshape(-1, 3)
    c0 = np.asarray(conf0, dtype=float).reshape(-1)
    src = np.asarray(xyz1_own, dtype=float).reshape(-1, 3)
    dst = np.asarray(xyz1_in0, dtype=float).reshape(-1, 3)
    ca, cb = np.asarray(conf1_own, dtype=float).reshape(-1), np.asarray(conf1_in0, dtype=float).reshape(-1)
    seen0 = (c0 >= min_conf) & np.isfinite(p0).all(axis=1)
    use = (ca >= min_conf) & (cb >= min_conf) & np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    n = int(use.sum())
    if n < min_points or int(seen0.sum()) < min_points:
        return PointMapFit(None, None, None, None, n, "too_few_points")
    dist = float(np.linalg.norm(p0[seen0], axis=1).mean())
    w = _log_conf(ca[use]) * _log_conf(cb[use])
    a = src[use]
    spread = float(np.linalg.svd(a - a.mean(axis=0), compute_uv=False)[1]) if n >= 3 else 0.0
    if not (dist > 0 and w.sum() > 0 and spread > 1e-9 * max(1.0, float(np.abs(a).max()))):
        return PointMapFit(None, None, None, None, n, "degenerate")
    s, R, t = similarity_align(a, dst[use], w)
    if not (s > 0 and np.isfinite(t).all()):
        return PointMapFit(None, None, None, None, n, "degenerate")
    res = dst[use] - (s * a @ R.T + t)
    rms = float(np.sqrt((w * np.einsum("ij,ij->i", res, res)).sum() / w.sum())) / dist
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t / dist
    return PointMapFit(T, dist, s, rms, n)


def _grid(arr: np.ndarray, step: int) -> np.ndarray:
    return np.ascontiguousarray(arr[step // 2 :: step, step // 2 :: step])


class Dust3rPose:
    """The DUSt3R pose backend (module docstring): loads the model once from ``checkpoint`` (the
    user's DUSt3R ``.pth``) with the package of ``clone`` (a naver/dust3r checkout) or the
    installed ``mini_dust3r``; settings ``config``. ``ValueError`` (one sentence) when the package
    or the checkpoint is missing or unusable."""

    name = "dust3r"
    needs_frames = True
    """The scorer gives this backend the first and last frames (:meth:`estimate_frames`)."""

    def __init__(
        self,
        config: Dust3rConfig | None = None,
        *,
        checkpoint: str | Path | None = None,
        clone: str | Path | None = None,
        device: str | None = None,
    ) -> None:
        if checkpoint is None:
            raise ValueError(
                "the dust3r pose backend needs --dust3r-checkpoint PATH (a DUSt3R .pth; nothing is downloaded)"
            )
        self.config = config or Dust3rConfig()
        self.checkpoint = Path(checkpoint)
        if not self.checkpoint.is_file():  # before the slow import
            raise ValueError(f"DUSt3R checkpoint {checkpoint} does not exist or is not a file")
        cls, self.source = import_model_class(clone)
        self.spec, state = read_checkpoint(self.checkpoint)
        import torch

        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        self.model = _build(cls, self.spec, state, f"DUSt3R checkpoint {self.checkpoint}").to(self.device)

    def __repr__(self) -> str:
        return f"Dust3rPose({str(self.checkpoint)!r}, {self.source}, img_size={self.spec.img_size})"

    def estimate(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, *, seed: int = 0) -> PoseEstimate:
        """DUSt3R needs the frames, not matches: an explicit failure (``needs_frames``)."""
        return failure("needs_frames", len(np.asarray(x0).reshape(-1, 2)), focal_of(np.asarray(K, dtype=float)))

    def _infer(self, img0: np.ndarray, img1: np.ndarray) -> list[np.ndarray]:
        """Both orders in one batch: [first's points (own camera), first's confidence, last's
        points in the first camera, their confidence, last's points (own camera), their
        confidence], as float arrays."""
        import torch

        x = torch.from_numpy(np.stack([img0, img1]).astype(np.float32) / 127.5 - 1.0).permute(0, 3, 1, 2)
        x = x.to(self.device)
        shape = torch.tensor([list(img0.shape[:2])] * 2, device=self.device)
        view1 = {"img": x, "true_shape": shape, "instance": ["0", "1"], "idx": [0, 1]}
        view2 = {"img": x.flip(0), "true_shape": shape, "instance": ["1", "0"], "idx": [1, 0]}
        with torch.inference_mode(), warnings.catch_warnings():  # its autocast call is deprecated
            warnings.simplefilter("ignore", FutureWarning)
            r1, r2 = self.model(view1, view2)
        own, own_conf = r1["pts3d"].float().cpu().numpy(), r1["conf"].float().cpu().numpy()
        other, other_conf = r2["pts3d_in_other_view"].float().cpu().numpy(), r2["conf"].float().cpu().numpy()
        return [own[0], own_conf[0], other[0], other_conf[0], own[1], own_conf[1]]

    def estimate_frames(
        self,
        rgb0: np.ndarray,
        rgb1: np.ndarray,
        content_box: tuple[int, int, int, int],
        K: np.ndarray,
        frames: tuple[int, int],
    ) -> tuple[PoseEstimate, PointMaps | None]:
        """The first-last pose of the (H, W, 3) uint8 frames ``rgb0`` and ``rgb1`` (working
        resolution, content inside ``content_box``) and their point maps on the gate's scale
        (None when no scale could be found); ``K`` only names the focal length of the estimate."""
        from .pointmaps import PointMaps

        cfg = self.config
        img0, box = network_input(rgb0, content_box, self.spec.img_size, self.spec.patch_size)
        img1, _ = network_input(rgb1, content_box, self.spec.img_size, self.spec.patch_size)
        xyz0, c0, xyz1, c1, xyz1_own, c1_own = self._infer(img0, img1)
        fit = pose_from_pointmaps(
            xyz0, c0, xyz1, c1, xyz1_own, c1_own, min_conf=cfg.min_conf, min_points=cfg.min_points
        )
        f, n_px = focal_of(np.asarray(K, dtype=float)), int(c0.size)
        h, w = img0.shape[:2]
        maps = None
        if fit.mean_distance is not None:
            step = max(1, math.ceil(max(h, w) / cfg.record_side))
            note = (
                f"DUSt3R ({self.source}, checkpoint {self.checkpoint.name}) on {w}x{h} inputs, stored every {step} "
                f"px; alignment rms {fit.rms:.3g} mean scene distances over {fit.n_points} pixels"
            )
            maps = PointMaps(
                xyz0=_grid(xyz0, step) / fit.mean_distance,
                xyz1=_grid(xyz1, step) / fit.mean_distance,
                conf0=_grid(c0, step),
                conf1=_grid(c1, step),
                rgb0=_grid(img0, step),
                rgb1=_grid(img1, step),
                frames=frames,
                box=box,
                input_size=(w, h),
                step=step,
                note=note,
            )
        if not fit:
            return failure(fit.reason or "degenerate", n_px, f, n_inliers=fit.n_points, method="dust3r"), maps
        T = np.asarray(fit.T_cam0_camT)
        est = PoseEstimate(
            pose_present=True,
            t_inf=float(np.max(np.abs(T[:3, 3]))),
            T_cam0_camT=T,
            method="dust3r",
            reason=None,
            n_matches=n_px,
            n_inliers=fit.n_points,
            rotation_deg=rotation_angle_deg(T[:3, :3]),
            parallax_px=None,
            focal_px=f,
        )
        return est, maps
