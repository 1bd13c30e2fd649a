"""Scoring decoded frames from a training script: one clip or a batch, in memory.

>>> from geocon_core.reward import RewardScorer                       # doctest: +SKIP
>>> scorer = RewardScorer()                                          # doctest: +SKIP
>>> results = scorer.score_batch([video_a, video_b])   # (T, H, W, 3) arrays or tensors  # doctest: +SKIP
>>> [r.score for r in results]                                      # doctest: +SKIP

Frames are sampled evenly (at most :attr:`~geocon_core.config.RewardConfig.max_frames`, first and
last kept), the guards read them (:mod:`.guards`), and a clip that passes is scored by
:func:`~geocon_core.scoring.score_frames` under the ``reward`` preset. Nothing is written. A
batch is scored by a pool of threads, one clip each (OpenCV releases the interpreter's lock), and
comes back in the order given; the same frames give the same numbers in any batch, on any
worker count.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import replace
from typing import Any

import numpy as np

from ..config import RewardConfig, ScoreConfig, preset
from ..media import ClipError, as_bgr_frames, probe_frames
from .guards import read_guards
from .result import RewardResult, reward_of_record

__all__ = ["REWARD_PRESET", "RewardScorer", "sample_evenly", "score_reward"]

REWARD_PRESET = "reward"
"""The preset a reward is scored with unless told otherwise."""


def sample_evenly(n: int, most: int) -> np.ndarray:
    """Indices of at most ``most`` frames of ``n``, evenly spaced, the first and the last kept."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.rint(np.linspace(0, n - 1, most)).astype(int))


def score_reward(
    frames: Any,
    *,
    name: str = "frames",
    config: ScoreConfig | None = None,
    reward: RewardConfig | None = None,
    channel_order: str = "rgb",
    fps: float = 24.0,
) -> RewardResult:
    """The reward of one clip's frames (numpy or torch; see
    :func:`~geocon_core.media.as_bgr_frames`); ``config`` defaults to the ``reward`` preset.
    Unusable frames (wrong shape, type or range) raise
    :class:`~geocon_core.media.ClipError`."""
    from ..scoring import score_frames

    start = time.perf_counter()
    cfg = config or preset(REWARD_PRESET)
    rcfg = reward or RewardConfig()
    bgr = as_bgr_frames(frames, channel_order=channel_order, name=name)
    whole = probe_frames(bgr, name, cfg, fps=fps)  # repeats and cuts are read on every frame, before sampling
    bgr = np.ascontiguousarray(bgr[sample_evenly(len(bgr), rcfg.max_frames)])
    guards = read_guards(bgr, whole, rcfg)
    if guards.tripped is not None:
        readings = {"guards": guards.to_dict()}
        return RewardResult(
            name, None, None, False, guards.reason, guards.tripped, readings, seconds=time.perf_counter() - start
        )
    record = score_frames(bgr, cfg, name=name, fps=fps, channel_order="bgr", workers=1)
    out = reward_of_record(record, rcfg, guards, name=name, frames=bgr)
    return replace(out, seconds=time.perf_counter() - start)


class RewardScorer:
    """Scores clips' frames in memory for a training loop, one at a time or in batches.

    ``preset_name`` (default ``reward``) or ``config`` chooses the scorer's settings, ``reward``
    the sampling, guards and interval; ``workers`` threads score a batch (default: the CPU count,
    at most 8)."""

    def __init__(
        self,
        preset_name: str = REWARD_PRESET,
        *,
        config: ScoreConfig | None = None,
        reward: RewardConfig | None = None,
        workers: int | None = None,
    ) -> None:
        self.config = config or preset(preset_name)
        self.reward = reward or RewardConfig()
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers or min(8, os.cpu_count() or 1)

    def score(self, frames: Any, *, name: str = "frames", channel_order: str = "rgb") -> RewardResult:
        """The reward of one clip (:func:`score_reward`)."""
        return score_reward(frames, name=name, config=self.config, reward=self.reward, channel_order=channel_order)

    def score_batch(
        self,
        clips: Sequence[Any],
        *,
        names: Sequence[str] | None = None,
        channel_order: str = "rgb",
        progress: Callable[[int, int], None] | None = None,
    ) -> list[RewardResult]:
        """The rewards of a batch, in its order: ``clips`` is a sequence of clips' frames, or one
        (B, T, ...) array or tensor. A clip whose frames are unusable comes back cannot judge with
        the one sentence that says why; the others are scored."""
        if hasattr(clips, "shape") and len(getattr(clips, "shape", ())) == 5:
            clips = [clips[i] for i in range(clips.shape[0])]
        labels = list(names) if names is not None else [f"clip {i}" for i in range(len(clips))]
        if len(labels) != len(clips):
            raise ValueError(f"{len(labels)} names for {len(clips)} clips")

        def one(i: int) -> RewardResult:
            try:
                return self.score(clips[i], name=labels[i], channel_order=channel_order)
            except ClipError as err:
                return RewardResult(labels[i], None, None, False, str(err), "frames")

        results: list[RewardResult | None] = [None] * len(clips)
        with ThreadPoolExecutor(max_workers=min(self.workers, max(1, len(clips)))) as pool:
            futures = {pool.submit(one, i): i for i in range(len(clips))}
            for done, future in enumerate(as_completed(futures), 1):
                results[futures[future]] = future.result()
                if progress is not None:
                    progress(done, len(clips))
        return [r for r in results if r is not None]
