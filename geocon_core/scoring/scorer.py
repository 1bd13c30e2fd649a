"""Scoring one clip: composes reading, matching, model fitting and gating into a record.

The scorer streams frames: features of a frame are extracted once per scale and kept only
while a pair, the first-last pose or a gate window still needs them, so memory does not grow
with clip length beyond the per-match arrays of the record itself. Work runs on a small thread
pool (OpenCV releases the GIL) beside the mask lane, and no worker waits for another task's
result: pair fits and poses are submitted once their features are ready. Every random choice is
seeded from the config seed and the pair's identity, so results do not depend on scheduling.

:func:`score_clip` composes the stages: the clip is probed, the stages of
:class:`~geocon_core.scoring.pipeline.Pipeline` (masks, features, pair fits, object rigidity,
poses) run under the streaming schedule of :mod:`geocon_core.scoring.schedule`, the multi-view
check reconstructs the clip, :mod:`geocon_core.scoring.judge` decides the background's verdict
once (through the rules of :mod:`geocon_core.scoring.verdict`), and
:mod:`geocon_core.scoring.assemble` builds the record last.
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ..config import ScoreConfig
from ..flow import FlowBackend, make_flow_backend
from ..geometry import (
    make_matcher,
)
from ..masks import check_masks_path, make_mask_source
from ..media import DEFAULT_FPS, ClipInfo, Frame, HeldFrames, as_bgr_frames, iter_frames, probe_clip, probe_frames
from ..pose import (
    PoseBackend,
    PoseEstimate,
    chain_hops,
    chain_lengths,
    compose_chain,
    default_intrinsics,
    load_pose_log,
    make_pose_backend,
    select_hops,
)
from ..pose import failure as pose_failure
from ..reconstruction import (
    DenseCloudBuilder,
    DenseCloudConfig,
    MultiViewResult,
    TrackObservations,
    WindowCloud,
    reconstruct,
)
from ..record import ClipRecord, FrameDiagnostics, MatchArrays, PairRecord
from ..regions import RegionsPart, RegionTracker, read_regions
from ..signals import ClipReadings, appearance_reading, configured_model, content_gray, plan_pairs, unkept_share
from .assemble import assemble_record, object_parts, pair_tables, software_versions
from .judge import judge_background, judge_drift
from .pipeline import DeferredPose, Pipeline, SharedMatches, Timer, keep_still, resolve_deferred
from .rigidity import quiet_pot_backends
from .schedule import StreamSchedule, gate_windows

__all__ = ["score_clip", "software_versions", "read_readings"]


def _chain_windows(span: tuple[int, int], cfg: ScoreConfig) -> list[tuple[int, int]]:
    """Every chain hop inside frames ``span`` (inclusive): hops of ``chain_hop`` frames and of
    the longer lengths up to ``chain_longest`` (none when chains are off or the span is one hop)."""
    start, end = span
    if cfg.chain_hop == 0 or end - start < 1:
        return []
    out: list[tuple[int, int]] = []
    for length in chain_lengths(cfg.chain_hop, cfg.chain_longest):
        out += [(start + a, start + b) for a, b in chain_hops(end - start + 1, length)]
    return list(dict.fromkeys(out))


def _chain_pose(
    span: tuple[int, int],
    by_window: dict[tuple[int, int], PoseEstimate],
    hops: list[tuple[int, int]],
    failed: PoseEstimate,
    cfg: ScoreConfig,
) -> PoseEstimate | None:
    """The pose over ``span`` composed from its hops (:func:`~geocon_core.pose.chain.select_hops`,
    :func:`~geocon_core.pose.chain.compose_chain`), or None when they span too little."""
    start, end = span
    local = {(a - start, b - start): by_window[(a, b)] for a, b in hops}
    chosen = select_hops(local, end - start + 1)
    return compose_chain(chosen, end - start + 1, failed, min_share=cfg.chain_min_share)


def _shot_pose(
    shot: tuple[int, int],
    by_window: dict[tuple[int, int], PoseEstimate],
    hops: list[tuple[int, int]],
    K: np.ndarray,
    cfg: ScoreConfig,
) -> PoseEstimate:
    """The pose of a shot's first and last frame, composed from its hops when that pair failed
    (as for a whole clip); a failure with reason ``single_frame`` for a shot of one frame."""
    start, end = shot
    if end == start:
        return pose_failure("single_frame", 0, float(np.sqrt(K[0, 0] * K[1, 1])))
    est: PoseEstimate = by_window[shot]
    if not est.pose_present and hops:
        est = _chain_pose(shot, by_window, hops, est, cfg) or est
    return est


def _mask_source(
    cfg: ScoreConfig, info: ClipInfo, masks: str | Path | None, flow: FlowBackend | None, sam2_model: Any = None
):
    if cfg.masks == "sam2":
        return make_mask_source("sam2", info, cfg.motion, model=sam2_model, sam2=cfg.sam2, flow=flow, seed=cfg.seed)
    if cfg.masks == "external":
        if masks is None:
            raise ValueError("config.masks is 'external' but no masks path was given")
        return make_mask_source("external", info, path=masks)
    if cfg.masks == "motion":
        return make_mask_source("motion", info, cfg.motion, flow=flow, seed=cfg.seed)
    return None


def _multiview(
    obs: TrackObservations, K: np.ndarray, cfg: ScoreConfig, info: ClipInfo, spans: list[tuple[int, int, str]]
) -> MultiViewResult:
    """The multi-view check (:mod:`geocon_core.reconstruction.multiview`): one reconstruction per
    span (each shot, or the whole clip; ``(start, end, model)``) under the model its gate chose.
    With cuts, the result kept is that of the first shot with a drifting layer, else of the
    longest shot."""
    results = []
    for start, end, model in spans:
        keep = [i for i, t in enumerate(obs.frames) if start <= t <= end]
        part = TrackObservations([obs.frames[i] for i in keep], [obs.ids[i] for i in keep], [obs.xy[i] for i in keep])
        results.append(
            (
                end - start,
                reconstruct(
                    part, K, info.working_size, "H" if model == "H" else "F", cfg.multiview, px_scale=info.scale
                ),
            )
        )
    flagged = [r for _, r in results if r.flagged]
    return flagged[0] if flagged else max(results, key=lambda lr: lr[0])[1]


def _import_aside(module: str) -> None:
    """Start importing ``module`` on a side thread. POT takes about a second to import (it loads
    much of SciPy); imported where first used, on a worker in the middle of the clip, it stalls
    the other threads, while during the probe pass, which decodes with the GIL released, one core
    is idle. A later ``import`` of the module simply waits for this one."""
    if module not in sys.modules:
        threading.Thread(target=_import_quietly, args=(module,), name=f"import-{module}", daemon=True).start()


def _import_quietly(module: str) -> None:
    """Import ``module``; a failure is left to the import where the module is used, which says why.
    Any failure is silent here: a short run may end while this side import is still going, and an
    import cut off by the interpreter's shutdown must not print a traceback after a finished run."""
    try:
        importlib.import_module(module)
    except Exception:  # noqa: BLE001  # re-raised by the real import, where it matters
        pass


def _timed(frames: Iterator[Frame], timer: Timer) -> Iterator[Frame]:
    """``frames``, with the time spent decoding each added to the timer."""
    while True:
        start = time.perf_counter()
        frame = next(frames, None)
        timer.add("decode", start)
        if frame is None:
            return
        yield frame


def _flow_backend(cfg: ScoreConfig, checkpoint: str | Path | None) -> FlowBackend | None:
    """The dense flow of the masks and objects (None without masks); a checkpoint only for a
    backend that loads one."""
    weighted = cfg.flow.strip().lower() == "raft"
    if checkpoint is not None and not weighted:
        raise ValueError(f"a flow checkpoint was given but the flow backend is {cfg.flow!r} (use --flow raft)")
    if cfg.masks == "none":
        return None
    return make_flow_backend(cfg.flow, cfg.flow_params, **({"checkpoint": checkpoint} if weighted else {}))


def _sam2_model(cfg: ScoreConfig, checkpoint: str | Path | None) -> Any:
    """SAM-2's model for ``masks = "sam2"`` (None otherwise), loaded before the clip is decoded."""
    if cfg.masks != "sam2":
        if checkpoint is not None:
            raise ValueError(f"a SAM-2 checkpoint was given but the masks are {cfg.masks!r} (use --masks sam2)")
        return None
    from ..masks import load_sam2

    return load_sam2(checkpoint, cfg.sam2)


def _pose_backend(cfg: ScoreConfig, checkpoint: str | Path | None, clone: str | Path | None) -> PoseBackend:
    """The pose backend ``cfg.pose_backend`` names, built (and its weights loaded) before decoding."""
    if cfg.pose_backend.strip().lower() == "dust3r":
        return make_pose_backend("dust3r", cfg.dust3r, checkpoint=checkpoint, clone=clone)
    if checkpoint is not None or clone is not None:
        raise ValueError(
            f"a DUSt3R checkpoint or path was given but the pose backend is {cfg.pose_backend!r} (use --pose dust3r)"
        )
    return make_pose_backend(cfg.pose_backend, cfg.pose)


def _probe(path: str | Path | HeldFrames, cfg: ScoreConfig) -> tuple[ClipInfo, np.ndarray | None]:
    """The clip's :class:`~geocon_core.media.ClipInfo`, and its frames when they are held in memory."""
    if isinstance(path, HeldFrames):
        return probe_frames(path.frames, path.name, cfg, fps=path.fps), path.frames
    return probe_clip(path, cfg), None


def score_clip(
    path: str | Path | HeldFrames,
    config: ScoreConfig | None = None,
    *,
    pose_log: str | Path | None = None,
    masks: str | Path | None = None,
    flow_checkpoint: str | Path | None = None,
    sam2_checkpoint: str | Path | None = None,
    dense: DenseCloudConfig | None = None,
    dust3r_checkpoint: str | Path | None = None,
    dust3r_path: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
    on_frame: Callable[[FrameDiagnostics], None] | None = None,
) -> ClipRecord:
    """Score one clip: ``path`` names a file or folder, or holds frames in memory
    (:class:`~geocon_core.media.HeldFrames`, as :func:`score_frames` makes). ``pose_log``
    replaces the pose backend by an external pose (JSON, see
    :mod:`geocon_core.pose`); ``masks`` is a path to external object masks (see
    :mod:`geocon_core.masks`), otherwise ``config.masks`` chooses the built-in segmentation or
    none; ``flow_checkpoint`` is the weights file of a neural flow backend (``config.flow ==
    "raft"``: a ``raft-small.pth``); ``sam2_checkpoint`` is SAM-2's weights file for ``config.masks
    == "sam2"`` (its model configuration is ``config.sam2.model``); ``dense``, if given, also
    makes the dense point clouds of the first/last pair and of every gate window
    (:mod:`geocon_core.reconstruction.dense`, no score changes);
    ``dust3r_checkpoint`` (and ``dust3r_path``, a DUSt3R checkout) serve ``config.pose_backend ==
    "dust3r"`` (:mod:`geocon_core.pose.dust3r`), which poses the first and last frame only;
    ``progress(done, total)`` is called as frames are processed; ``timings``, if given,
    receives seconds per stage (summed over worker threads); ``on_frame``, if given, receives a
    :class:`~geocon_core.record.overlays.FrameDiagnostics` per frame, in frame order, on the calling
    thread. Raises :class:`~geocon_core.media.reader.ClipError` for unusable input."""
    cfg = config or ScoreConfig()
    if masks is not None:
        cfg = cfg.with_(masks="external")
    timer = Timer(timings)
    configured_model(cfg.signals)  # the clip model that decides the verdict, before the clip is decoded
    if cfg.masks != "none":
        quiet_pot_backends()
        _import_aside("ot")  # AdaDFRC's transport solver
    # a pose log, external masks and flow weights are checked before the clip is decoded
    backend = load_pose_log(pose_log) if pose_log is not None else _pose_backend(cfg, dust3r_checkpoint, dust3r_path)
    if masks is not None:
        check_masks_path(masks)
    flow = _flow_backend(cfg, flow_checkpoint)  # shared: thread-safe per instance
    sam2_model = _sam2_model(cfg, sam2_checkpoint)
    start = time.perf_counter()
    info, held = _probe(path, cfg)
    timer.add("probe", start)
    n = info.num_frames
    matcher = make_matcher(cfg.matcher, max_features=cfg.max_features, ratio=cfg.ratio, anchors=(0, n - 1))
    mask_source = _mask_source(cfg, info, masks, flow, sam2_model)
    K = default_intrinsics(info.content_box, cfg.fov_x_deg)
    windows = gate_windows(n, cfg.gate_window, cfg.gate_stride)
    first_last_only = pose_log is not None or getattr(backend, "needs_frames", False)  # a log, DUSt3R
    hops = [] if first_last_only or cfg.chain_hop == 0 else _chain_windows((0, n - 1), cfg)
    pose_windows = [] if first_last_only else [w for w in windows if w != (0, n - 1)]
    builder = None
    if dense is not None and n >= 2:
        dense_flow = (
            flow
            if flow is not None and cfg.flow.strip().lower() != "dis"  # a neural flow serves the clouds too
            else make_flow_backend("dis", cfg.flow_params, preset=dense.dis_preset)
        )
        builder = DenseCloudBuilder(info.content_mask, [(0, n - 1), *pose_windows], dense_flow, dense)
    stages = Pipeline(
        info, cfg, matcher, flow, backend, K, mask_source, timer, keep_flows=on_frame is not None, dense=builder
    )
    if cfg.still_share > 0 and not first_last_only:
        stages.still_frames = frozenset(t for shot in info.shots for t in shot)
    shots = info.shots if cfg.judge_shots and len(info.shots) > 1 and not first_last_only else ()
    shot_hops = {shot: _chain_windows(shot, cfg) for shot in shots}
    for shot in shots:
        pose_windows += [w for w in (shot, *shot_hops[shot]) if w[1] > w[0] and w != (0, n - 1)]
    pose_windows += [h for h in hops if h not in pose_windows]
    pose_windows = list(dict.fromkeys(pose_windows))
    # a chain hop is estimated only if the first-last pose of its clip or shot fails
    stages.deferred = frozenset(set(hops).union(*shot_hops.values()) - {*windows, *shots, (0, n - 1)})
    stages.shared = SharedMatches(
        {
            (t0, t1, stages.s_max)
            for t0, t1 in [*pose_windows, (0, n - 1)]
            if t1 - t0 in cfg.gaps and info.pair_skip_reason(t0, t1) is None
        }
    )
    emit = None if on_frame is None else partial(stages.emit, on_frame)
    workers = workers or min(2, os.cpu_count() or 1)
    object_gap = min(cfg.object_gap, max(1, n - 1))  # a clip shorter than the gap: its first and last frame
    with ThreadPoolExecutor(max_workers=workers) as pool:
        schedule = StreamSchedule(
            stages, pool, n, cfg.gaps, pose_windows, info.pair_skip_reason, workers, emit, progress, object_gap
        )
        out = schedule.run(_timed(iter_frames(info, held), timer))
    pose, cloud = out.first_last
    by_window = dict(out.windows)
    if not pose.pose_present and hops:
        resolve_deferred(by_window, hops, workers, timer)
        pose = _chain_pose((0, n - 1), by_window, hops, pose, cfg) or pose
    if stages.still_frames and not shots:  # with cuts, each shot is tested on its own
        pose = stages.still_test((0, n - 1), pose, K)
    timeline = [(w, by_window[w]) for w in windows if w in by_window]
    for shot in shots:
        if shot[1] > shot[0] and not by_window[shot].pose_present:
            resolve_deferred(by_window, shot_hops[shot], workers, timer)
    shot_poses = [(shot, _shot_pose(shot, by_window, shot_hops[shot], K, cfg)) for shot in shots]
    if stages.still_frames:
        shot_poses = [(shot, stages.still_test(shot, est, K)) for shot, est in shot_poses]
    scored = keep_still(sorted(out.pairs, key=lambda r: (r.gap, r.t0, r.scale)), stages.still_maps, info, cfg)
    # the verdicts, read once from the finished stages; the record is assembled last
    judgement = judge_background(cfg, n, pose, timeline, scored, shot_poses)
    multiview = None
    if stages.tracks is not None:
        start = time.perf_counter()
        multiview = _multiview(stages.tracks.observations, K, cfg, info, judgement.spans(n))
        judgement = judge_drift(judgement, multiview)
        timer.add("multiview", start)
    tables = pair_tables(scored)
    readings = _readings(stages.reading_frames, tables, info, cfg, timer)
    regions = None if stages.regions is None else _regions(stages.regions, cfg, judgement.background.model, timer)
    objects = object_parts(
        cfg,
        sorted(out.objects, key=lambda r: r.key),
        scales=stages.object_scales,
        masked_share=stages.masked_share,
        object_share=stages.object_share,
        mask_source=mask_source,
        masks_path=masks,
    )
    notes = []
    if object_gap < cfg.object_gap and mask_source is not None:
        notes.append(f"objects scored on frames {object_gap} apart: the clip has {n} frames, fewer than object_gap + 1")
    clouds: tuple[WindowCloud, ...] = ()
    if builder is not None:
        start = time.perf_counter()
        resolved = {w: est for w, est in by_window.items() if not isinstance(est, DeferredPose)}
        clouds = builder.clouds(K, {**resolved, (0, n - 1): pose})
        timer.add("dense", start)
    return assemble_record(
        info.path,
        info,
        cfg,
        K,
        backend.name,
        judgement,
        timeline,
        windows,
        tables,
        objects,
        notes=notes,
        multiview=multiview,
        readings=readings,
        regions=regions,
        dense=clouds,
        cloud=cloud,
        pointmaps=stages.pointmaps,
    )


def score_frames(
    frames: Any,
    config: ScoreConfig | None = None,
    *,
    name: str = "frames",
    fps: float = DEFAULT_FPS,
    channel_order: str = "rgb",
    masks: str | Path | None = None,
    flow_checkpoint: str | Path | None = None,
    sam2_checkpoint: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
) -> ClipRecord:
    """Score one clip's decoded frames held in memory, as :func:`score_clip` scores a file:
    ``frames`` is a numpy array or a torch tensor (any device) of shape (T, H, W, 3),
    (T, 3, H, W) or (T, H, W), uint8 or floats in [0, 1] (:func:`~geocon_core.media.as_bgr_frames`);
    ``channel_order`` "rgb" or "bgr"; ``name`` stands in for the clip's path in the record and
    ``fps`` for its rate. Writes nothing. The same frames give the same record as ``geocon
    score`` on a folder of lossless PNG files of them, with the same configuration (the clip's
    path, fingerprint and timings aside). Raises :class:`~geocon_core.media.ClipError` for
    unusable frames."""
    held = HeldFrames(as_bgr_frames(frames, channel_order=channel_order, name=name), name, fps)
    return score_clip(
        held,
        config,
        masks=masks,
        flow_checkpoint=flow_checkpoint,
        sam2_checkpoint=sam2_checkpoint,
        workers=workers,
        progress=progress,
        timings=timings,
    )


def _regions(tracker: RegionTracker, cfg: ScoreConfig, camera: str, timer: Timer) -> RegionsPart:
    """The region readings (:mod:`geocon_core.regions`) of the tracks followed while the clip was
    read, each pair's camera of the family the gate chose."""
    start = time.perf_counter()
    tracks = tracker.result()
    family = camera if camera in ("H", "F") else None
    part = RegionsPart(read_regions(tracks, cfg.regions, cfg.seed, family), tracks, tracks.size, tracks.scale, family)
    timer.add("regions", start)
    return part


def read_readings(record: ClipRecord, record_dir: str | Path, config: ScoreConfig) -> ClipRecord:
    """``record`` with the readings ``config.signals`` makes (:mod:`geocon_core.signals`), read from its
    clip again (found as :func:`~geocon_core.media.locate_clip` finds it) and its stored matches:
    the numbers :func:`score_clip` would have recorded beside the same background fit. Raises
    :class:`~geocon_core.media.ClipError` when the clip is gone."""
    from ..media import locate_clip

    cfg = replace(record.config, signals=replace(config.signals, enabled=True))
    info = locate_clip(record.video, record_dir)
    far, near = plan_pairs(info.num_frames, cfg.signals)
    needed = {t for pair in (*far, *near) for t in pair}
    frames: dict[int, np.ndarray] = {}
    for frame in iter_frames(info):
        if frame.index in needed:
            frames[frame.index] = content_gray(frame.gray, info.content_box, cfg.signals)
        if len(frames) == len(needed):
            break
    return replace(record, readings=_readings(frames, (record.pairs, record.matches), record.video, cfg, Timer(None)))


def _readings(
    frames: dict[int, np.ndarray],
    tables: tuple[tuple[PairRecord, ...], MatchArrays],
    video: ClipInfo,
    cfg: ScoreConfig,
    timer: Timer,
) -> ClipReadings | None:
    """The readings beside the background fit (:mod:`geocon_core.signals`), when ``cfg.signals``
    is on: the appearance readings of the frames kept for them and the keep reading of the
    background matches (``tables``: the record's pairs and per-match arrays)."""
    if not cfg.signals.enabled:
        return None
    start = time.perf_counter()
    n = video.num_frames
    far, near = plan_pairs(n, cfg.signals)
    readable = all(t in frames for pair in (*far, *near) for t in pair) and bool(far or near)
    appearance = appearance_reading(frames, n, cfg.signals) if readable else None
    pairs, matches = tables
    offsets = matches.offsets
    rows = [(p.gap, p.scale, int(offsets[p.index]), int(offsets[p.index + 1])) for p in pairs if p.skip is None]
    unkept = unkept_share(rows, matches.f_res_px, video.working_size[0], cfg.signals)
    timer.add("signals", start)
    return ClipReadings(appearance, unkept)
