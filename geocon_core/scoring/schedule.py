"""The streaming schedule of one clip's work: which stage runs on which frames, when, and what
is kept in memory meanwhile.

:class:`StreamSchedule` reads frames once, in order, and drives a :class:`Stages` object (the
scorer's stages, or fakes in tests). For each frame ``t`` it

1. gives the frame to the mask stage (:meth:`Stages.push`) as soon as it is decoded;
2. once the mask stage has seen ``lookahead`` frames past ``t`` (or the clip ended), asks for the
   final labels of ``t`` (:meth:`Stages.labels`; None without masks), and once they are there and
   the next frame's are asked for, in this order:

   - waits while more than ``workers`` feature extractions are in flight, or ``2 * workers``
     pair fits (bounded read-ahead: memory stays flat however fast frames decode);
   - submits the features of ``t`` (:meth:`Stages.extract`);
   - for each gap ``g``, the pair ``(t - g, t)``: :meth:`Stages.score_pair` on the worker pool, or
     :meth:`Stages.skip_pair` at once when ``skip_reason(t - g, t)`` names a reason (cut,
     duplicate);
   - with labels, the objects of ``t - g`` on the pair ``(t - g, t)``, ``g`` the object gap, given
     the frames ``t - g .. t`` and their labels (:meth:`Stages.score_objects`);
   - for each pose window ``(s, t)`` ending at ``t``, its pose (:meth:`Stages.pose`), and at the
     last frame the first-last pose, which also receives frame 0;
   - evicts what no later work needs, tells the mask stage it may drop ``t - 1``
     (:meth:`Stages.release`), and reports ``progress(t + 1, n)``.

The mask stage is sequential (each frame's segmentation continues the last one's tracks), so it
runs on a thread of its own, the *mask lane*, in submission order: push, labels, release and
finish never overlap one another, and the lane segments frame ``t + 1`` while the calling thread
decodes and submits the work of frame ``t`` (the newest labels asked for stay in flight). An error
of the lane is raised on the calling thread at the next frame.

Pair fits and poses need the features of two frames; they are handed to the pool only once both
are extracted, so a worker never sits blocked on another task while work is waiting.

Guarantees: ``on_frame(frame, labels, flows)`` is called exactly once per frame, in frame order,
on the calling thread, with the object flows of the pair ``(t, t + g)`` (empty when there are
none); the features of frame ``k`` are kept while a pair may still need them
(``k >= t - max(gaps)``), while a pose window starting at ``k`` has not ended, and for frame 0
until the first-last pose; decoded frames and labels are kept for ``g + 1`` frames (and frame 0
until the first-last pose). Results are
returned in submission order (pairs by frame then gap, skipped pairs separately); every random
choice belongs to the stages, which seed it from the pair's identity, so the outcome does not
depend on thread timing.
"""

from __future__ import annotations

import threading
from collections import deque
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Protocol, Sequence

import numpy as np

from ..media import Frame

__all__ = ["Stages", "StreamSchedule", "ScheduleResult", "gate_windows"]


def gate_windows(n: int, window: int, stride: int) -> list[tuple[int, int]]:
    """The gate timeline's windows ``(start, end)`` over ``n`` frames: every ``stride`` frames a
    window of ``window`` frames, or the whole clip when it is not longer than one window."""
    if n - 1 <= window:
        return [(0, n - 1)]
    return [(s, s + window) for s in range(0, n - 1 - window + 1, stride)]


class Stages(Protocol):
    """The work the schedule drives. ``push``, ``labels``, ``release`` and ``finish`` run one at a
    time, in order, on the mask lane (a thread of their own); the others run on the worker pool and
    receive the features of a frame as the :class:`~concurrent.futures.Future` returned by its
    ``extract``, which the schedule submits in frame order."""

    lookahead: int
    """How many frames past ``t`` the mask stage must have seen before ``labels(t)`` is final."""

    def push(self, frame: Frame) -> None: ...

    def finish(self) -> None: ...

    def labels(self, t: int) -> np.ndarray | None: ...

    def release(self, t: int) -> None: ...

    def observe(self, frame: Frame, labels: np.ndarray | None) -> None:
        """Frame ``t`` with its final labels, on the calling thread, once per frame in frame order
        (before its features are submitted)."""

    def extract(self, frame: Frame, labels: np.ndarray | None) -> Any: ...

    def score_pair(self, a: Future, b: Future, t0: int, t1: int, gap: int) -> list[Any]: ...

    def skip_pair(self, t0: int, t1: int, gap: int, reason: str) -> list[Any]: ...

    def score_objects(
        self, frames: Sequence[Frame], labels: Sequence[np.ndarray], skip: str | None
    ) -> tuple[list[Any], Sequence[Any]]: ...

    def pose(self, a: Future, b: Future, t0: int, t1: int, first: Frame | None) -> Any: ...


@dataclass
class ScheduleResult:
    """What a run produced, as the stages returned it: ``pairs`` (scored, then skipped),
    ``windows`` ``[((start, end), pose)]`` in window order, ``first_last`` the first-last pose and
    ``objects`` every object pair score."""

    pairs: list[Any]
    windows: list[tuple[tuple[int, int], Any]]
    first_last: Any
    objects: list[Any]


@dataclass
class _Pending:
    """A frame waiting for its object flows before it is emitted."""

    frame: Frame
    labels: np.ndarray | None
    objects: Future | None = None
    ready: bool = False


@dataclass
class StreamSchedule:
    """Runs the :class:`Stages` over a clip of ``num_frames`` frames (see the module docstring).
    ``windows`` are the pose windows to estimate besides the first-last pose; ``skip_reason(t0,
    t1)`` says why a pair must not be scored (None to score it); ``object_gap`` is the gap of the
    object pairs."""

    stages: Stages
    pool: Executor
    num_frames: int
    gaps: Sequence[int]
    windows: Sequence[tuple[int, int]]
    skip_reason: Callable[[int, int], str | None]
    workers: int
    on_frame: Callable[[Frame, np.ndarray | None, tuple], None] | None = None
    progress: Callable[[int, int], None] | None = None
    object_gap: int = 1
    features: dict[int, Future] = field(default_factory=dict)
    """Features of the frames still needed (frame index -> future), for inspection."""

    def __post_init__(self) -> None:
        self._inflight: deque[Future] = deque()
        self._pairs: list[Future] = []
        self._skipped: list[Any] = []
        self._objects: list[Future] = []
        self._windows: list[tuple[tuple[int, int], Future]] = []
        self._first_last: Future | None = None
        self._frames: dict[int, Frame] = {}
        self._labels: dict[int, np.ndarray] = {}
        self._pending: deque[_Pending] = deque()
        self._ends: dict[int, list[tuple[int, int]]] = {}
        for w in self.windows:
            self._ends.setdefault(w[1], []).append(w)
        self._max_gap = max(self.gaps)
        self._lane_jobs: deque[Future] = deque()

    def run(self, frames: Iterable[Frame]) -> ScheduleResult:
        """Consume ``frames`` (in order) and return every stage's results once all have finished."""
        stages, n = self.stages, self.num_frames
        asked = stepped = 0  # frames whose labels are asked of the mask lane; frames stepped
        labels: deque[Future] = deque()  # labels(t) of the frames not yet stepped, in order
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="geocon-masks") as lane:
            self._lane = lane
            for frame in frames:
                self._frames[frame.index] = frame
                self._lane_jobs.append(lane.submit(stages.push, frame))
                while asked <= frame.index - stages.lookahead:
                    labels.append(lane.submit(stages.labels, asked))
                    asked += 1
                # the newest labels stay in flight: the lane segments the next frame while this
                # thread decodes and submits
                while len(labels) > 1:
                    self._step(stepped, labels.popleft())
                    stepped += 1
            self._lane_jobs.append(lane.submit(stages.finish))
            labels.extend(lane.submit(stages.labels, t) for t in range(asked, n))
            while labels:
                self._step(stepped, labels.popleft())
                stepped += 1
        self._check_lane(wait=True)
        self._emit(final=True)
        assert self._first_last is not None, "the clip had no frame"
        return ScheduleResult(
            pairs=[r for f in self._pairs for r in f.result()] + self._skipped,
            windows=[(w, f.result()) for w, f in self._windows],
            first_last=self._first_last.result(),
            objects=[r for f in self._objects for r in f.result()[0]],
        )

    def _after(self, deps: Sequence[Future], fn: Callable[..., Any], *args: Any) -> Future:
        """A future of ``fn(*args)``, submitted to the pool once every future of ``deps`` is done:
        a task that waited for its features on a worker would hold the worker idle."""
        if not deps:
            return self.pool.submit(fn, *args)
        out: Future = Future()
        remaining = [len(deps)]
        lock = threading.Lock()
        # the task's inputs include the futures whose callback this closure becomes, a reference
        # cycle that only the cyclic collector would free, holding each frame's features long
        # after use; the closure lets go of them once it has submitted the task
        job: list[Any] = [fn, args]

        def relay(inner: Future) -> None:
            error = inner.exception()
            if error is None:
                out.set_result(inner.result())
            else:
                out.set_exception(error)

        def start(_: Future) -> None:
            with lock:
                remaining[0] -= 1
                if remaining[0]:
                    return
                task, task_args = job
                job.clear()
            try:
                self.pool.submit(task, *task_args).add_done_callback(relay)
            except RuntimeError as error:  # the pool shut down after an error elsewhere
                out.set_exception(error)

        for dep in deps:
            dep.add_done_callback(start)
        return out

    def _check_lane(self, wait: bool = False) -> None:
        """Raise the first error of the mask lane's pushes and releases (those done, or all)."""
        jobs = self._lane_jobs
        while jobs and (wait or jobs[0].done()):
            jobs.popleft().result()

    # --- one frame ---------------------------------------------------------------------------
    def _step(self, t: int, asked: Future) -> None:
        """Everything that needs frame t and its labels (``asked``: the lane's labels(t))."""
        frame, stages = self._frames[t], self.stages
        self._check_lane()
        labels = asked.result()
        if labels is not None:
            self._labels[t] = labels
        stages.observe(frame, labels)
        self._wait_for_room()
        self.features[t] = self.pool.submit(stages.extract, frame, labels)
        self._inflight.append(self.features[t])
        self._submit_pairs(t)
        g = self.object_gap
        if self.on_frame is not None:
            self._pending.append(_Pending(frame, labels))
        if labels is not None and t >= g and all(k in self._labels for k in range(t - g, t + 1)):
            span = range(t - g, t + 1)
            skip = self.skip_reason(t - g, t)
            self._objects.append(
                self.pool.submit(
                    stages.score_objects, [self._frames[k] for k in span], [self._labels[k] for k in span], skip
                )
            )
            for p in self._pending:
                if p.frame.index == t - g:
                    p.objects = self._objects[-1]  # frame t-g is complete once its flows are
        if self.on_frame is not None:
            for p in self._pending:
                p.ready = p.ready or p.frame.index <= t - g
            self._emit(final=False)
        for w in self._ends.get(t, []):
            a, b = self.features[w[0]], self.features[t]
            self._windows.append((w, self._after((a, b), stages.pose, a, b, *w, None)))
        if t == self.num_frames - 1:
            a, b = self.features[0], self.features[t]
            self._first_last = self._after((a, b), stages.pose, a, b, 0, t, self._frames[0])
        self._evict(t)
        self._lane_jobs.append(self._lane.submit(stages.release, t - 1))
        if self.progress is not None:
            self.progress(t + 1, self.num_frames)

    def _wait_for_room(self) -> None:
        """Bounded read-ahead: a few frames wait for features, a few pairs for fitting."""
        while len(self._inflight) > self.workers:
            self._inflight.popleft().result()
        while sum(not f.done() for f in self._pairs[-4 * self.workers :]) >= 2 * self.workers:
            next(f for f in self._pairs if not f.done()).result()

    def _submit_pairs(self, t: int) -> None:
        for gap in self.gaps:
            t0 = t - gap
            if t0 < 0:
                continue
            reason = self.skip_reason(t0, t)
            if reason is not None:
                self._skipped.extend(self.stages.skip_pair(t0, t, gap, reason))
            else:
                a, b = self.features[t0], self.features[t]
                self._pairs.append(self._after((a, b), self.stages.score_pair, a, b, t0, t, gap))

    def _needed(self, k: int, t: int) -> bool:
        """Whether the features of frame k are still needed after step t."""
        return k == 0 or k >= t - self._max_gap or any(s == k and e > t for s, e in self.windows)

    def _evict(self, t: int) -> None:
        for k in [k for k in self.features if not self._needed(k, t)]:
            del self.features[k]
        keep = t - self.object_gap
        for k in [k for k in self._frames if k < keep and k != 0]:  # frame 0 serves the first-last pose
            del self._frames[k]
        for k in [k for k in self._labels if k < keep]:
            del self._labels[k]

    def _emit(self, final: bool) -> None:
        """Hand finished frames to ``on_frame`` in order. Before the end, a frame waits for its
        object flows unless more than ``2 * workers + g + 1`` frames are waiting."""
        if self.on_frame is None:
            return
        pending = self._pending
        while pending and (final or pending[0].ready):
            head = pending[0]
            fut = head.objects
            room = 2 * self.workers + self.object_gap + 1
            if not final and fut is not None and not fut.done() and len(pending) <= room:
                break
            pending.popleft()
            flows = () if fut is None else tuple(fut.result()[1])
            self.on_frame(head.frame, head.labels, flows)
