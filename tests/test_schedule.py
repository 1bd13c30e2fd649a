"""The streaming schedule on its own, with fake stages: every frame emitted once and in order with
its object flows, features kept exactly while a pair, a pose window or the first-last pose needs
them, skipped pairs never scored, labels taken only once final."""

from __future__ import annotations

import random
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np
import pytest

from geocon_core.scoring import StreamSchedule, gate_windows


class FakeStages:
    """Stages that return their inputs' identities (features of frame t are ``t``)."""

    def __init__(self, *, lookahead: int = 0, masks: bool = True, jitter: bool = True) -> None:
        self.lookahead, self.masks, self.jitter = lookahead, masks, jitter
        self.pushed: list[int] = []
        self.finished = False
        self.labelled: list[int] = []
        self.released: list[int] = []
        self.scored_pairs: list[tuple[int, int]] = []
        self.observed: list[tuple[int, bool]] = []
        self.lock = threading.Lock()
        self.rng = random.Random(0)

    def _sleep(self) -> None:
        if self.jitter:
            with self.lock:
                delay = self.rng.random() * 0.002
            time.sleep(delay)

    def push(self, frame) -> None:
        assert not self.finished
        self.pushed.append(frame.index)

    def finish(self) -> None:
        self.finished = True

    def labels(self, t: int):
        assert self.finished or max(self.pushed) >= t + self.lookahead, "labels taken before they are final"
        self.labelled.append(t)
        return np.full((2, 2), 1, np.int32) if self.masks else None

    def release(self, t: int) -> None:
        self.released.append(t)

    def observe(self, frame, labels) -> None:
        self.observed.append((frame.index, labels is not None))

    def extract(self, frame, labels):
        self._sleep()
        return frame.index

    def score_pair(self, a, b, t0, t1, gap):
        assert (a.result(), b.result()) == (t0, t1)
        self._sleep()
        with self.lock:
            self.scored_pairs.append((t0, t1))
        return [("pair", t0, t1, gap)]

    def skip_pair(self, t0, t1, gap, reason):
        return [("skip", t0, t1, gap, reason)]

    def score_objects(self, frames, labels, skip):
        self._sleep()
        idx = [f.index for f in frames]
        assert idx == list(range(idx[0], idx[-1] + 1)) and len(labels) == len(frames), "consecutive frames, labelled"
        return [("objects", idx[0], idx[-1], skip)], [f"flow {idx[0]}"]

    def pose(self, a, b, t0, t1, first):
        assert (a.result(), b.result()) == (t0, t1)
        return ("pose", t0, t1, None if first is None else first.index)


def _frames(n: int):
    return (SimpleNamespace(index=t) for t in range(n))


def _run(stages, n=20, gaps=(1, 2, 4), windows=((0, 8), (4, 12), (8, 16)), cut=None, workers=2, **kw):
    def skip(t0: int, t1: int):
        return "cut" if cut is not None and t0 < cut <= t1 else None

    with ThreadPoolExecutor(max_workers=workers) as pool:
        schedule = StreamSchedule(stages, pool, n, gaps, list(windows), skip, workers, **kw)
        return schedule, schedule.run(_frames(n))


@pytest.mark.parametrize("masks", [True, False])
@pytest.mark.parametrize("object_gap", [1, 4])
def test_every_frame_is_emitted_once_in_order_with_its_flows(masks, object_gap):
    emitted = []
    _, out = _run(
        FakeStages(masks=masks),
        on_frame=lambda f, labels, flows: emitted.append((f.index, flows)),
        object_gap=object_gap,
    )
    assert [t for t, _ in emitted] == list(range(20))
    if masks:
        last = 20 - object_gap
        assert [flows for _, flows in emitted] == [(f"flow {t}",) for t in range(last)] + [()] * object_gap
        assert [(o[1], o[2]) for o in out.objects] == [(t, t + object_gap) for t in range(last)]
    else:
        assert all(flows == () for _, flows in emitted)


def test_features_are_kept_exactly_while_needed():
    n, gaps, windows = 30, (1, 3), [(0, 10), (5, 15), (10, 20), (15, 25)]
    schedule = None
    kept: list[set[int]] = []

    def progress(done: int, total: int) -> None:
        assert total == n
        kept.append(set(schedule.features))

    stages = FakeStages()
    with ThreadPoolExecutor(max_workers=2) as pool:
        schedule = StreamSchedule(stages, pool, n, gaps, windows, lambda a, b: None, 2, progress=progress)
        out = schedule.run(_frames(n))
    assert len(kept) == n
    for t, live in enumerate(kept):
        expected = {
            k for k in range(t + 1) if k == 0 or k >= t - max(gaps) or any(s == k and e > t for s, e in windows)
        }
        assert live == expected, t
    # window anchors survived until their window's pose: every window and the first-last pose ran
    assert [w for w, _ in out.windows] == windows
    assert [p for _, p in out.windows] == [("pose", s, e, None) for s, e in windows]
    assert out.first_last == ("pose", 0, n - 1, 0)
    assert stages.released == list(range(-1, n - 1))


def test_skipped_pairs_are_never_scored_and_results_keep_submission_order():
    stages = FakeStages()
    _, out = _run(stages, cut=7)
    across = {(t0, t1) for t1 in range(20) for t0 in (t1 - 1, t1 - 2, t1 - 4) if 0 <= t0 < 7 <= t1}
    assert not across & set(stages.scored_pairs)
    skipped = [p for p in out.pairs if p[0] == "skip"]
    assert {(t0, t1) for _, t0, t1, _, _ in skipped} == across
    assert all(p[4] == "cut" for p in skipped)
    scored = [p for p in out.pairs if p[0] == "pair"]
    assert scored == sorted(scored, key=lambda p: (p[2], {1: 0, 2: 1, 4: 2}[p[3]]))  # by frame, then gap
    assert len(scored) + len(skipped) == sum(max(0, 20 - g) for g in (1, 2, 4))
    assert ("objects", 6, 7, "cut") in out.objects
    assert [o[1] for o in out.objects] == list(range(19))


@pytest.mark.parametrize("masks", [True, False])
def test_every_frame_is_observed_once_in_order_after_its_labels(masks):
    stages = FakeStages(lookahead=3, masks=masks)
    _run(stages)
    assert stages.observed == [(t, masks) for t in range(20)]


def test_labels_wait_for_the_mask_lookahead():
    stages = FakeStages(lookahead=3)
    emitted = []
    _run(stages, on_frame=lambda f, labels, flows: emitted.append(f.index))
    assert stages.labelled == list(range(20)) and emitted == list(range(20))


def test_gate_windows_cover_the_clip():
    assert gate_windows(10, 16, 8) == [(0, 9)]
    assert gate_windows(17, 16, 8) == [(0, 16)]
    assert gate_windows(40, 16, 8) == [(0, 16), (8, 24), (16, 32)]


def test_an_error_in_a_stage_reaches_the_caller_without_hanging():
    class Failing(FakeStages):
        def extract(self, frame, labels):
            if frame.index == 5:
                raise ValueError("frame 5 is unreadable")
            return super().extract(frame, labels)

    class FailingLane(FakeStages):
        def push(self, frame) -> None:
            if frame.index == 7:
                raise ValueError("segmentation failed at frame 7")
            super().push(frame)

    with pytest.raises(ValueError, match="frame 5 is unreadable"):
        _run(Failing())
    with pytest.raises(ValueError, match="segmentation failed at frame 7"):
        _run(FailingLane(lookahead=2))


def test_pair_fits_and_poses_start_only_once_their_features_exist():
    class Strict(FakeStages):
        def score_pair(self, a, b, t0, t1, gap):
            assert a.done() and b.done(), "a pair was handed to a worker before its features"
            return super().score_pair(a, b, t0, t1, gap)

        def pose(self, a, b, t0, t1, first):
            assert a.done() and b.done(), "a pose was handed to a worker before its features"
            return super().pose(a, b, t0, t1, first)

    stages = Strict()
    _, out = _run(stages, workers=3)
    assert len(stages.scored_pairs) == sum(20 - g for g in (1, 2, 4))
    assert out.first_last == ("pose", 0, 19, 0)
