"""Dense optical flow behind one small interface (:class:`FlowBackend`).

>>> backend = make_flow_backend("dis")                     # doctest: +SKIP
>>> field = backend.compute(gray0, gray1, box=(x0, y0, x1, y1))  # doctest: +SKIP
>>> field.flow, field.reliable, field.fb_error             # doctest: +SKIP

A backend turns two grey frames ``I_t``, ``I_{t+1}`` ((h, w) uint8, same size) into a
:class:`FlowField`: the forward flow ``F`` (``I_t(x) ~ I_{t+1}(x + F(x))``, pixels, pixel
centres at integer coordinates), the forward-backward error and a reliability mask.

Reliability (every backend): with ``B`` the backward flow ``I_{t+1} -> I_t``, sampled
bilinearly at ``x + F(x)``, ``fb_error(x) = |F(x) + B(x + F(x))|`` and ``x`` is reliable iff

* ``x + F(x)`` lies inside the computed region (``0 <= x' <= w - 1``, ``0 <= y' <= h - 1``):
  a pixel that leaves the view has no partner; its ``fb_error`` is ``inf``;
* ``fb_error(x) <= fb_abs + fb_rel * |F(x)|``: occluded pixels (whose partner is another
  surface, which flows back elsewhere) and mismatches fail it.

With a ``box`` only the box grown by ``margin`` pixels (clipped to the frame) is computed and
the field is cropped back to the box, so small objects are cheap; the margin gives the
coarse-to-fine search context and room for pixels that move out of the box. ``box=None`` is
the whole frame.

:func:`chained_flow` composes the flows of consecutive frames into the flow over several frames
(object rigidity on frames ``object_gap`` apart).

A backend may also offer ``compute_both(gray0, gray1, box)``, the forward field and the
backward field (``gray1 -> gray0``, on ``gray1``'s pixels) from the same two flow runs;
:class:`DisFlow` does, and the motion segmentation uses it when present (else it calls
``compute`` twice).

Backends
--------
``dis`` (:class:`DisFlow`, default, no weights)
    OpenCV's Dense Inverse Search (Kroeger et al. 2016) with the ``MEDIUM`` preset (8 px
    patches every 3 px down to 1/2 resolution, 25 gradient-descent iterations, variational
    refinement; ``FAST`` stops at 1/4 resolution with patches every 4 px): on translated or
    affinely warped textures the median error is 0.02-0.08 px (tests: < 0.1 px); about 6 ms
    per direction at 512x288 and 23 ms at 1024x576 on an idle 2-core machine (``FAST``: 1.4 /
    5 ms, similar error on strong texture, worse on weak). Forward-backward threshold
    ``fb_abs`` px plus ``fb_rel`` of the flow length (flow errors grow with the displacement;
    settings in :class:`~geocon_core.config.stages.FlowConfig`). DIS is deterministic across
    thread counts, but an OpenCV DIS object keeps state from its previous call, so every call
    uses a fresh one: the flow of two images does not depend on what was computed before, and
    :meth:`DisFlow.compute` is thread-safe.
``raft`` (:class:`RaftFlow`, the ``neural`` extra and a checkpoint the user gives)
    RAFT-small (Teed and Deng 2020; :mod:`geocon_core.flow.raft`, this project's own torch module in
    the released checkpoints' layout) with 12 iterations, on the grey image repeated in three
    channels; the computed region is padded (edge pixels repeated) to sides that are multiples
    of 8 and at least 128 px. Forward and backward flow run as one batch of two, and the same
    forward-backward rule as DIS decides reliability (the ``fb_abs``, ``fb_rel`` and ``margin``
    of :class:`~geocon_core.config.stages.FlowConfig`; its DIS preset does not apply). A GPU is
    used when torch sees one. :meth:`RaftFlow.compute_both_many` gives the fields of many frame
    pairs with several pairs per network call (a GPU's throughput; ``benchmarks/bench_gpu.py``).
    ``make_flow_backend("raft", checkpoint=PATH)``.
"""

from __future__ import annotations

import importlib.util
import math
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, Sequence

import cv2
import numpy as np

from ..config import FlowConfig

__all__ = [
    "FlowField",
    "FlowBackend",
    "DisFlow",
    "FLOW_BACKENDS",
    "RaftFlow",
    "DIS_PRESETS",
    "make_flow_backend",
    "forward_backward",
    "chained_flow",
    "FlowChain",
]

Box = tuple[int, int, int, int]

DIS_PRESETS: dict[str, int] = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
"""OpenCV DIS presets by name."""


@dataclass(frozen=True, eq=False)
class FlowField:
    """Forward flow over a region of a frame.

    box: (x0, y0, x1, y1), end-exclusive, frame pixels: the region the arrays cover.
    flow: (y1 - y0, x1 - x0, 2) float32 forward flow ``I_t -> I_{t+1}`` in pixels, (dx, dy);
        the pixel at array index (i, j) is frame pixel (x0 + j, y0 + i) and moves to
        (x0 + j + dx, y0 + i + dy).
    reliable: (h, w) bool: forward-backward consistent and not leaving the computed region.
    fb_error: (h, w) float32 ``|F(x) + B(x + F(x))|`` in pixels; ``inf`` where ``x + F(x)``
        leaves the computed region.
    """

    box: Box
    flow: np.ndarray
    reliable: np.ndarray
    fb_error: np.ndarray

    def __post_init__(self) -> None:
        x0, y0, x1, y1 = self.box
        shape = (y1 - y0, x1 - x0)
        if self.flow.shape != (*shape, 2) or self.reliable.shape != shape or self.fb_error.shape != shape:
            raise ValueError(
                f"FlowField arrays {self.flow.shape}, {self.reliable.shape}, {self.fb_error.shape} "
                f"do not match box {self.box}"
            )


class FlowBackend(Protocol):
    """Dense optical flow between two grey frames."""

    name: str

    def compute(self, gray0: np.ndarray, gray1: np.ndarray, box: Box | None = None) -> FlowField:
        """Forward flow ``gray0 -> gray1`` ((h, w) uint8 each) over ``box`` (whole frame if
        None), with its forward-backward reliability."""
        ...


def forward_backward(fwd: np.ndarray, bwd: np.ndarray, fb_abs: float, fb_rel: float) -> tuple[np.ndarray, np.ndarray]:
    """``(fb_error, reliable)`` of the forward flow ``fwd`` (h, w, 2) given the backward flow
    ``bwd`` (h, w, 2) of the same region (the rule in the module docstring)."""
    h, w = fwd.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx, my = gx + fwd[..., 0], gy + fwd[..., 1]
    back = cv2.remap(bwd, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    s = fwd + back
    err = cv2.magnitude(s[..., 0], s[..., 1])
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    err[~inside] = np.inf
    mag = cv2.magnitude(np.ascontiguousarray(fwd[..., 0]), np.ascontiguousarray(fwd[..., 1]))
    reliable = inside & (err <= np.float32(fb_abs) + np.float32(fb_rel) * mag)
    return err, reliable


def _check_images(gray0: np.ndarray, gray1: np.ndarray) -> None:
    for name, g in (("gray0", gray0), ("gray1", gray1)):
        if not isinstance(g, np.ndarray) or g.ndim != 2 or g.dtype != np.uint8:
            raise ValueError(
                f"{name} must be an (h, w) uint8 grey image, "
                f"got {getattr(g, 'shape', None)} {getattr(g, 'dtype', type(g))}"
            )
    if gray0.shape != gray1.shape:
        raise ValueError(f"gray0 and gray1 differ in size: {gray0.shape} vs {gray1.shape}")
    if min(gray0.shape) < 2:
        raise ValueError(f"images of {gray0.shape} are too small for optical flow")


def _check_box(box: Box | None, shape: tuple[int, int]) -> Box:
    h, w = shape
    if box is None:
        return (0, 0, w, h)
    if len(box) != 4:
        raise ValueError(f"box must be (x0, y0, x1, y1), got {box!r}")
    x0, y0, x1, y1 = (int(v) for v in box)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise ValueError(f"box {tuple(box)} is empty or outside the {w}x{h} frame")
    return (x0, y0, x1, y1)


class _RegionFlow:
    """What every backend does around its flow: the box grown by the margin, forward and
    backward flow of that region (:meth:`_both`, the backend's own), the forward-backward check
    of each, and the fields cropped back to the box."""

    config: FlowConfig

    def _both(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - overridden
        raise NotImplementedError

    def compute(self, gray0: np.ndarray, gray1: np.ndarray, box: Box | None = None) -> FlowField:
        """Forward flow ``gray0 -> gray1`` over ``box`` (the whole frame if None): the forward
        field of :meth:`compute_both`, without checking the backward one."""
        box, region, a, b = self._region(gray0, gray1, box)
        fwd, bwd = self._both(a, b)
        return self._field(box, region, fwd, bwd)

    def compute_both(self, gray0: np.ndarray, gray1: np.ndarray, box: Box | None = None) -> tuple[FlowField, FlowField]:
        """The forward field ``gray0 -> gray1`` (on ``gray0``'s pixels) and the backward field
        ``gray1 -> gray0`` (on ``gray1``'s pixels) over the same ``box``, each with its own
        forward-backward check; one pair of flow runs serves both."""
        box, region, a, b = self._region(gray0, gray1, box)
        return self._fields(box, region, *self._both(a, b))

    def _region(self, gray0: np.ndarray, gray1: np.ndarray, box: Box | None) -> tuple[Box, Box, np.ndarray, np.ndarray]:
        """The checked ``box``, the computed region (the box grown by the margin, clipped to the
        frame) and the two images cut to that region."""
        _check_images(gray0, gray1)
        h, w = gray0.shape
        x0, y0, x1, y1 = _check_box(box, (h, w))
        m = self.config.margin
        region = (max(0, x0 - m), max(0, y0 - m), min(w, x1 + m), min(h, y1 + m))
        rx0, ry0, rx1, ry1 = region
        a = np.ascontiguousarray(gray0[ry0:ry1, rx0:rx1])
        b = np.ascontiguousarray(gray1[ry0:ry1, rx0:rx1])
        return (x0, y0, x1, y1), region, a, b

    def _field(self, box: Box, region: Box, flow: np.ndarray, other: np.ndarray) -> FlowField:
        """The field over ``box`` of the flow ``flow`` of ``region``, checked against ``other``,
        the flow of the same region the other way."""
        x0, y0, x1, y1 = box
        rx0, ry0 = region[:2]
        err, rel = forward_backward(flow, other, self.config.fb_abs, self.config.fb_rel)
        sl = (slice(y0 - ry0, y1 - ry0), slice(x0 - rx0, x1 - rx0))
        return FlowField(
            box=box,
            flow=np.ascontiguousarray(flow[sl], dtype=np.float32),
            reliable=np.ascontiguousarray(rel[sl]),
            fb_error=np.ascontiguousarray(err[sl], dtype=np.float32),
        )

    def _fields(self, box: Box, region: Box, fwd: np.ndarray, bwd: np.ndarray) -> tuple[FlowField, FlowField]:
        """The forward and backward fields over ``box`` of the flows ``fwd`` and ``bwd`` of
        ``region``, each with its forward-backward check."""
        return self._field(box, region, fwd, bwd), self._field(box, region, bwd, fwd)


def _dis_safe_padding(h: int, w: int, patch: int, finest: int, ph: int, pw: int) -> tuple[int, int]:
    """The padding (rows, columns) that lets OpenCV's DIS compute an (h, w) region (already padded
    by ``ph``, ``pw``) without reading outside its pyramid: ``ph``, ``pw`` themselves, unless the
    region is so thin that DIS crashes the process (a segmentation fault, or an assertion in
    ``resize``). DIS builds its pyramid from the longer side down to the level where the shorter
    one still holds a patch; when that level is finer than the preset's finest scale, it picks
    the levels from the width alone, and a strip (16x256 px: a 2048x16 clip at working
    resolution) then has levels less than a patch high. Such a region is padded so that the
    shorter side holds a patch at the finest scale and the longer one spans the preset's usual
    pyramid (2048x16 becomes 2048x32 with the ``fast`` preset); regions DIS reads as they are
    (every clip's frames and objects of ordinary shape) keep their flow unchanged."""
    longer, shorter = max(h, w), min(h, w)
    usual = min(int(math.log2(longer / (4.0 * patch)) + 0.5), int(math.log2(shorter / patch)))
    if usual >= finest:
        return ph, pw
    by_width = max(0, math.floor(math.log2(2.0 * w / (5.0 * patch))))  # OpenCV's choice from the width
    if (h >> by_width) >= patch and (w >> by_width) >= patch:
        return ph, pw
    need_short = patch << finest
    need_long = math.ceil(4.0 * patch * 2.0 ** (finest + 0.5))
    grow_h = max(need_short, need_long if h >= w else 0) - h
    grow_w = max(need_short, need_long if w > h else 0) - w
    return ph + max(0, grow_h), pw + max(0, grow_w)


class DisFlow(_RegionFlow):
    """OpenCV DIS optical flow (``name = "dis"``); see the module docstring for the preset and
    the reliability rule.

    config: the settings (:class:`~geocon_core.config.stages.FlowConfig`): DIS preset, the
        forward-backward threshold ``fb_abs + fb_rel * |F|`` (px), the context ``margin`` (px)
        computed around a ``box`` on every side, and ``min_side`` (px): smaller regions are padded
        (edge pixels repeated) because DIS needs at least one patch (12 px with the medium preset).
        Keyword arguments override single fields (``DisFlow(preset="fast")``).
    """

    name = "dis"

    def __init__(self, config: FlowConfig | None = None, **overrides: Any) -> None:
        if "preset" in overrides:
            overrides["preset"] = str(overrides["preset"]).strip().lower()
        self.config = replace(config or FlowConfig(), **overrides)

    def __repr__(self) -> str:
        c = self.config
        return f"DisFlow(preset={c.preset!r}, fb_abs={c.fb_abs}, fb_rel={c.fb_rel}, margin={c.margin})"

    def _calc(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        h, w = a.shape
        side = self.config.min_side
        ph, pw = max(0, side - h), max(0, side - w)
        # A fresh OpenCV instance per call: a DIS object keeps state from its previous call (a reused
        # one gives different flow for the same images depending on what it computed before), so
        # reusing one per thread made results depend on thread scheduling.
        dis = cv2.DISOpticalFlow_create(DIS_PRESETS[self.config.preset])  # type: ignore[attr-defined]  # missing from the cv2 stubs
        ph, pw = _dis_safe_padding(max(h, side), max(w, side), dis.getPatchSize(), dis.getFinestScale(), ph, pw)
        if ph or pw:  # DIS needs a side of at least one patch: pad tiny or thin regions, crop back
            a = cv2.copyMakeBorder(a, 0, ph, 0, pw, cv2.BORDER_REPLICATE)
            b = cv2.copyMakeBorder(b, 0, ph, 0, pw, cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(dis.calc(a, b, None)[:h, :w])

    def _both(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._calc(a, b), self._calc(b, a)


class RaftFlow(_RegionFlow):
    """RAFT-small optical flow (``name = "raft"``; see the module docstring). ``checkpoint``:
    the user's ``raft-small.pth``; ``device``: a torch device (default: CUDA when torch sees
    one, else the CPU). Calls are serialised (one network, torch spreads each call over the
    cores itself)."""

    name = "raft"

    def __init__(
        self, config: FlowConfig | None = None, *, checkpoint: str | Path | None = None, device: str | None = None
    ) -> None:
        if checkpoint is None:
            raise ValueError("the raft flow backend needs a checkpoint: pass --raft-checkpoint PATH (raft-small.pth)")
        if importlib.util.find_spec("torch") is None:
            raise ValueError("the raft flow backend needs torch: pip install 'geocon[neural]'")
        import torch

        from .raft import load_raft_small

        self.config = config or FlowConfig()
        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        self.model = load_raft_small(checkpoint, self.device)
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"RaftFlow(device={self.device!r}, fb_abs={self.config.fb_abs}, fb_rel={self.config.fb_rel})"

    def _both(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._run([(a, b)])[0]

    def _run(self, regions: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Forward and backward flow of every pair of same-size regions, all in one network call
        (a batch of ``2 * len(regions)``: each pair's forward, then its backward)."""
        import torch

        from .raft import MIN_SIDE

        h, w = regions[0][0].shape
        ph = max(MIN_SIDE, -(-h // 8) * 8) - h
        pw = max(MIN_SIDE, -(-w // 8) * 8) - w
        first, second = [], []
        for a, b in regions:
            pads = [cv2.copyMakeBorder(g, 0, ph, 0, pw, cv2.BORDER_REPLICATE) for g in (a, b)]
            rgb = [torch.from_numpy(np.repeat(g[None], 3, axis=0)).float() for g in pads]
            first += [rgb[0], rgb[1]]
            second += [rgb[1], rgb[0]]
        with self._lock, torch.no_grad():
            flow = self.model(torch.stack(first).to(self.device), torch.stack(second).to(self.device))
        out = flow.permute(0, 2, 3, 1).cpu().numpy()[:, :h, :w]
        return [(np.ascontiguousarray(out[2 * i]), np.ascontiguousarray(out[2 * i + 1])) for i in range(len(regions))]

    def compute_both_many(
        self, pairs: Sequence[tuple[np.ndarray, np.ndarray]], box: Box | None = None, *, batch: int = 8
    ) -> list[tuple[FlowField, FlowField]]:
        """:meth:`compute_both` of every ``(gray0, gray1)`` in ``pairs`` (frames of one size, the
        same ``box``), ``batch`` pairs per network call (``2 * batch`` images on the device, each
        pair's correlation volume among them); the same fields as one call per pair, up to the
        float rounding of batched convolutions."""
        if batch < 1:
            raise ValueError(f"batch must be at least 1, got {batch}")
        cut = [self._region(g0, g1, box) for g0, g1 in pairs]
        if len({c[1] for c in cut}) > 1:
            raise ValueError("compute_both_many needs frames of one size")
        out: list[tuple[FlowField, FlowField]] = []
        for start in range(0, len(cut), batch):
            chunk = cut[start : start + batch]
            flows = self._run([(a, b) for _, _, a, b in chunk])
            out += [self._fields(c[0], c[1], fwd, bwd) for c, (fwd, bwd) in zip(chunk, flows, strict=True)]
        return out


class FlowChain:
    """A forward flow composed hop by hop: started with the flow of frames (0, 1), :meth:`extend`
    adds the flow of the next consecutive pair, each computed over the first hop's box. A pixel
    follows each hop's flow from where the previous hops took it (bilinear sampling); it is
    reliable while every hop is reliable where it passes and it stays inside the box, and its
    ``fb_error`` is the sum of the hops' errors along the path."""

    def __init__(self, first: FlowField) -> None:
        self.box = first.box
        self.flow, self.reliable, self.err = first.flow.copy(), first.reliable.copy(), first.fb_error.copy()
        h, w = self.reliable.shape
        self._gx, self._gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))

    def extend(self, hop: FlowField) -> None:
        """Compose the flow of the next pair (over the same box)."""
        h, w = self.reliable.shape
        mx, my = self._gx + self.flow[..., 0], self._gy + self.flow[..., 1]
        inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
        self.flow += cv2.remap(hop.flow, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        hop_ok = cv2.remap(hop.reliable.astype(np.uint8), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
        hop_err = cv2.remap(hop.fb_error, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
        self.reliable &= inside & (hop_ok > 0)
        self.err = np.where(inside, self.err + hop_err, np.float32(np.inf)).astype(np.float32)

    def field(self) -> FlowField:
        """The composed flow so far."""
        return FlowField(self.box, self.flow, self.reliable, self.err)


def chained_flow(backend: FlowBackend, grays: Sequence[np.ndarray], box: Box | None = None) -> FlowField:
    """Forward flow ``grays[0] -> grays[-1]`` over ``box``, composed from the flows of the
    consecutive frames (:class:`FlowChain`), so a displacement of many pixels over several frames
    is tracked in steps the flow's search range covers. Two frames give ``backend.compute``
    itself."""
    if len(grays) < 2:
        raise ValueError(f"chained_flow needs at least two frames, got {len(grays)}")
    first = backend.compute(grays[0], grays[1], box)
    if len(grays) == 2:
        return first
    chain = FlowChain(first)
    for g0, g1 in zip(grays[1:-1], grays[2:], strict=True):
        chain.extend(backend.compute(g0, g1, first.box))
    return chain.field()


FLOW_BACKENDS: dict[str, type] = {"dis": DisFlow, "raft": RaftFlow}
"""Available flow backends by name."""


def make_flow_backend(name: str, config: FlowConfig | None = None, **kwargs: Any) -> FlowBackend:
    """The flow backend called ``name`` (case-insensitive), built with its settings ``config``
    (defaults when None) and its keyword arguments ``kwargs`` (``DisFlow``: single-field
    overrides; ``RaftFlow``: ``checkpoint``, ``device``). Raises ValueError for unknown names
    (listing the valid ones) and, for ``raft``, when torch or the checkpoint is missing."""
    key = str(name).strip().lower()
    if key not in FLOW_BACKENDS:
        raise ValueError(f"unknown flow backend {name!r}; valid: {', '.join(FLOW_BACKENDS)}")
    return FLOW_BACKENDS[key](config, **kwargs)
