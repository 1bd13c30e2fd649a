"""RAFT-small optical flow (Teed and Deng, ECCV 2020), GeoCon's own torch module.

Built from the paper's description of its small model: feature and context encoders of
bottleneck residual blocks at 1/8 resolution (instance-normalised features, un-normalised
context), an all-pairs correlation volume dotted over 128 feature channels and scaled by
``1/sqrt(128)``, pooled into 4 levels and read in a 7x7 window (radius 3) around the current
estimate, a motion encoder, a convolutional GRU with 96 hidden channels updated 12 times by
default, and the low-resolution flow upsampled 8x bilinearly. Parameter names follow the
authors' released checkpoints (``raft-small.pth``), with or without the ``module.`` prefix that
``DataParallel`` adds, so :func:`load_raft_small` takes such a file as it is. Nothing is
downloaded: the checkpoint is the user's.

Equivalence with the authors' implementation is a test (``tests/test_raft.py``): with a seeded
random state dict in the released key layout, this module reproduces the reference flow of two
128x160 frames to 1e-4 px.

Only :mod:`geocon_core.flow` imports this module, when the ``raft`` backend is chosen; torch is
the ``neural`` extra (``pip install 'geocon[neural]'``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["RaftSmall", "load_raft_small", "CORR_LEVELS", "CORR_RADIUS", "HIDDEN", "CONTEXT"]

CORR_LEVELS = 4
"""Levels of the correlation pyramid (each halves the second frame's feature grid)."""
CORR_RADIUS = 3
"""Half-width of the correlation window read at each level (a 7x7 window)."""
HIDDEN = 96
"""Channels of the GRU's hidden state."""
CONTEXT = 64
"""Channels of the context features fed to every update."""
FEATURES = 128
"""Channels of the matching features."""


class _Bottleneck(nn.Module):
    """1x1 -> 3x3 (stride) -> 1x1 convolutions at a quarter of ``planes`` channels, with a
    residual connection (a strided 1x1 convolution when the resolution changes)."""

    def __init__(self, inputs: int, planes: int, stride: int, instance_norm: bool) -> None:
        super().__init__()
        mid = planes // 4
        self.conv1 = nn.Conv2d(inputs, mid, 1)
        self.conv2 = nn.Conv2d(mid, mid, 3, stride=stride, padding=1)
        self.conv3 = nn.Conv2d(mid, planes, 1)

        def norm(c: int) -> nn.Module:
            return nn.InstanceNorm2d(c) if instance_norm else nn.Identity()

        self.norm1, self.norm2, self.norm3 = norm(mid), norm(mid), norm(planes)
        self.downsample = (
            None if stride == 1 else nn.Sequential(nn.Conv2d(inputs, planes, 1, stride=stride), norm(planes))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = F.relu(self.norm2(self.conv2(y)))
        y = F.relu(self.norm3(self.conv3(y)))
        if self.downsample is not None:
            x = self.downsample(x)
        return F.relu(x + y)


class _Encoder(nn.Module):
    """An image (N, 3, H, W) in [-1, 1] -> features (N, out, H/8, W/8)."""

    def __init__(self, out: int, instance_norm: bool) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, 32, 7, stride=2, padding=3)
        self.norm1 = nn.InstanceNorm2d(32) if instance_norm else nn.Identity()
        self.layer1 = self._stage(32, 32, 1, instance_norm)
        self.layer2 = self._stage(32, 64, 2, instance_norm)
        self.layer3 = self._stage(64, 96, 2, instance_norm)
        self.conv2 = nn.Conv2d(96, out, 1)

    @staticmethod
    def _stage(cin: int, cout: int, stride: int, instance_norm: bool) -> nn.Sequential:
        return nn.Sequential(_Bottleneck(cin, cout, stride, instance_norm), _Bottleneck(cout, cout, 1, instance_norm))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu(self.norm1(self.conv1(x)))
        x = self.layer3(self.layer2(self.layer1(x)))
        return self.conv2(x)


class _MotionEncoder(nn.Module):
    """Correlation features and the current flow -> motion features (80 channels plus the flow)."""

    def __init__(self) -> None:
        super().__init__()
        window = CORR_LEVELS * (2 * CORR_RADIUS + 1) ** 2
        self.convc1 = nn.Conv2d(window, 96, 1)
        self.convf1 = nn.Conv2d(2, 64, 7, padding=3)
        self.convf2 = nn.Conv2d(64, 32, 3, padding=1)
        self.conv = nn.Conv2d(96 + 32, 80, 3, padding=1)

    def forward(self, flow: torch.Tensor, corr: torch.Tensor) -> torch.Tensor:
        c = F.relu(self.convc1(corr))
        f = F.relu(self.convf2(F.relu(self.convf1(flow))))
        return torch.cat([F.relu(self.conv(torch.cat([c, f], dim=1))), flow], dim=1)


class _ConvGru(nn.Module):
    """A GRU whose gates are 3x3 convolutions over the hidden state and the input."""

    def __init__(self, hidden: int, inputs: int) -> None:
        super().__init__()
        self.convz = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)
        self.convr = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)
        self.convq = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        hx = torch.cat([h, x], dim=1)
        z = torch.sigmoid(self.convz(hx))
        r = torch.sigmoid(self.convr(hx))
        q = torch.tanh(self.convq(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q


class _FlowHead(nn.Module):
    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(hidden, 128, 3, padding=1)
        self.conv2 = nn.Conv2d(128, 2, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv2(F.relu(self.conv1(x)))


class _UpdateBlock(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.encoder = _MotionEncoder()
        self.gru = _ConvGru(HIDDEN, CONTEXT + 80 + 2)
        self.flow_head = _FlowHead(HIDDEN)

    def forward(
        self, hidden: torch.Tensor, context: torch.Tensor, corr: torch.Tensor, flow: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        motion = self.encoder(flow, corr)
        hidden = self.gru(hidden, torch.cat([context, motion], dim=1))
        return hidden, self.flow_head(hidden)


def _sample(volume: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``volume`` (M, 1, h, w) at pixel coordinates ``xy`` (M, a, b, 2) as
    (x, y) with pixel centres at integers; zero outside."""
    h, w = volume.shape[-2:]
    gx = 2 * xy[..., :1] / (w - 1) - 1
    gy = 2 * xy[..., 1:] / (h - 1) - 1
    return F.grid_sample(volume, torch.cat([gx, gy], dim=-1), align_corners=True)


class _Correlation:
    """The all-pairs correlation of two feature maps (N, C, h, w), as a pyramid over the second
    frame's grid; :meth:`lookup` reads the window around each first-frame pixel's estimate."""

    def __init__(self, f1: torch.Tensor, f2: torch.Tensor) -> None:
        n, c, h, w = f1.shape
        corr = torch.matmul(f1.view(n, c, h * w).transpose(1, 2), f2.view(n, c, h * w)) / c**0.5
        level = corr.reshape(n * h * w, 1, h, w)
        self.pyramid = [level]
        for _ in range(CORR_LEVELS - 1):
            level = F.avg_pool2d(level, 2, stride=2)
            self.pyramid.append(level)
        r = CORR_RADIUS
        d = torch.linspace(-r, r, 2 * r + 1, device=f1.device, dtype=f1.dtype)
        # window offsets (2r+1, 2r+1, 2): the x offset runs along the first axis, the y offset along
        # the second, so channel i * (2r+1) + j reads (x + d_i, y + d_j), the released models' order
        self.window = torch.stack(torch.meshgrid(d, d, indexing="ij"), dim=-1)

    def lookup(self, xy: torch.Tensor) -> torch.Tensor:
        """Correlation windows (N, levels * (2r+1)^2, h, w) around ``xy`` (N, 2, h, w)."""
        n, _, h, w = xy.shape
        centre = xy.permute(0, 2, 3, 1).reshape(n * h * w, 1, 1, 2)
        side = 2 * CORR_RADIUS + 1
        out = []
        for k, level in enumerate(self.pyramid):
            sampled = _sample(level, centre / 2**k + self.window.view(1, side, side, 2))
            out.append(sampled.view(n, h, w, -1))
        return torch.cat(out, dim=-1).permute(0, 3, 1, 2).contiguous()


class RaftSmall(nn.Module):
    """RAFT-small: two images (N, 3, H, W), RGB values 0..255, H and W multiples of 8 and at
    least 128 -> flow from the first to the second (N, 2, H, W) in pixels, (dx, dy)."""

    def __init__(self) -> None:
        super().__init__()
        self.fnet = _Encoder(FEATURES, instance_norm=True)
        self.cnet = _Encoder(HIDDEN + CONTEXT, instance_norm=False)
        self.update_block = _UpdateBlock()

    def forward(self, image1: torch.Tensor, image2: torch.Tensor, iters: int = 12) -> torch.Tensor:
        _check_size(image1.shape[-2:])
        x1 = 2 * (image1 / 255.0) - 1
        x2 = 2 * (image2 / 255.0) - 1
        f1, f2 = self.fnet(torch.cat([x1, x2], dim=0)).split(x1.shape[0], dim=0)
        corr = _Correlation(f1.float(), f2.float())
        hidden, context = self.cnet(x1).split([HIDDEN, CONTEXT], dim=1)
        hidden, context = torch.tanh(hidden), F.relu(context)
        n, _, h, w = f1.shape
        ys, xs = torch.meshgrid(
            torch.arange(h, device=f1.device, dtype=f1.dtype),
            torch.arange(w, device=f1.device, dtype=f1.dtype),
            indexing="ij",
        )
        grid = torch.stack([xs, ys], dim=0)[None].expand(n, -1, -1, -1)
        xy = grid.clone()
        for _ in range(iters):
            hidden, delta = self.update_block(hidden, context, corr.lookup(xy), xy - grid)
            xy = xy + delta
        low = xy - grid
        return 8 * F.interpolate(low, size=(8 * h, 8 * w), mode="bilinear", align_corners=True)


MIN_SIDE = 128
"""Shortest image side RAFT-small accepts: the coarsest correlation level must keep 2 pixels."""


def _check_size(hw: Any) -> None:
    h, w = int(hw[0]), int(hw[1])
    if h % 8 or w % 8 or min(h, w) < MIN_SIDE:
        raise ValueError(
            f"RAFT-small needs image sides that are multiples of 8 and at least {MIN_SIDE} px, got {w}x{h}"
        )


def load_raft_small(checkpoint: str | Path, device: str | torch.device = "cpu") -> RaftSmall:
    """A :class:`RaftSmall` with the weights of ``checkpoint`` (a released ``raft-small.pth`` or a
    state dict in its layout; the ``module.`` prefix is optional), read with
    ``torch.load(..., weights_only=True)``, in eval mode on ``device``. A missing file, a file
    that is not a state dict, or one with other parameter names raises ``ValueError`` naming it."""
    from ..files import read_checkpoint_file

    path = Path(checkpoint)
    state = read_checkpoint_file(path, "RAFT checkpoint", "pass --raft-checkpoint with raft-small.pth")
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"RAFT checkpoint {path} is not a state dict of tensors")
    state = {k.removeprefix("module."): v for k, v in state.items()}
    model = RaftSmall()
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    if missing or extra:
        what = f"missing {missing[:3]}" if missing else f"unexpected {extra[:3]}"
        raise ValueError(
            f"RAFT checkpoint {path} is not a RAFT-small checkpoint ({what}; the full RAFT model is not supported)"
        )
    wrong = [k for k, v in state.items() if tuple(v.shape) != tuple(expected[k].shape)]
    if wrong:
        raise ValueError(f"RAFT checkpoint {path} has parameters of other shapes ({wrong[0]})")
    model.load_state_dict(state)
    return model.eval().to(device)
