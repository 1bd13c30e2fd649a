"""The Ray executor of ``geocon bench``: every clip is one Ray task, on one machine or a cluster.

A task scores its clip into a temporary folder on the node that runs it and returns the folder's
files; the driver (the ``geocon bench`` process) writes them into ``RESULTS/clips/<clip_id>/`` and
writes ``status.json`` last, exactly as the process-pool executor leaves a clip. So the results folder
lives on the driver's disk alone, a run can be resumed with either executor, and the tables are the
same. Only the clips (and external mask folders) must be readable by the workers, at the path the
dataset gives: on a cluster, a filesystem every node mounts at the same place.

Failures are those of the process pool: a clip that fails in scoring is recorded with its reason; a
clip whose worker process or node dies is scored again, and recorded as failed once that happened
:data:`~geocon_core.bench.MAX_CRASHES` times. Tasks are never retried by Ray itself, so no clip is
counted twice. Ray is imported only here, and only when this executor is chosen.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import tempfile
from collections.abc import Callable
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import ScoreConfig
from ..files import start_reaper
from .clip import MAX_CRASHES, BenchError, crashed_status, failed_status, install_clip, score_one
from .dataset import ClipEntry
from .layout import STATUS_NAME, clip_dir

__all__ = ["DISTRIBUTED_EXTRA", "RayOptions", "neural_backends", "preflight", "score_all_ray"]

DISTRIBUTED_EXTRA = "pip install 'geocon[distributed]'"
"""What installs Ray (``bash scripts/bootstrap.sh distributed`` in a checkout)."""

Finished = Callable[[dict[str, Any]], None]
Note = Callable[[str], None]


@dataclass(frozen=True)
class RayOptions:
    """Where and how clips run on Ray.

    ``address``: a running cluster (``ray start --head`` prints it, e.g. ``10.0.0.5:6379``); ``None``
    starts a private Ray instance on this machine, bound to 127.0.0.1, with ``local_cpus`` CPUs
    (``geocon bench --workers``). ``cpus_per_clip``: CPUs a clip's task asks for (and the threads
    OpenCV uses in it). ``gpus_per_clip``: GPUs a clip's task asks for; ``None`` asks for one when
    the configuration selects a neural backend and the cluster has a GPU, else none."""

    address: str | None = None
    local_cpus: int = 1
    cpus_per_clip: float = 1.0
    gpus_per_clip: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cpus_per_clip) and self.cpus_per_clip > 0):
            raise ValueError(f"--ray-cpus-per-clip must be a positive number of CPUs, got {self.cpus_per_clip:g}")
        gpus = self.gpus_per_clip
        if gpus is not None and not (math.isfinite(gpus) and gpus >= 0):
            raise ValueError(f"--ray-gpus-per-clip must be a number of GPUs (0 or more), got {gpus:g}")
        if self.local_cpus < 1:
            raise ValueError(f"--workers must be at least 1, got {self.local_cpus}")


def neural_backends(cfg: ScoreConfig) -> list[str]:
    """The neural backends ``cfg`` selects (the ones that run faster on a GPU)."""
    chosen = {"RAFT flow": cfg.flow == "raft", "SAM-2 masks": cfg.masks == "sam2"}
    chosen["DUSt3R pose"] = cfg.pose_backend == "dust3r"
    return [name for name, on in chosen.items() if on]


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ImportError(f"--executor ray needs Ray: {DISTRIBUTED_EXTRA}") from None
    return ray


def _unreadable(path: Path | None) -> str | None:
    """Why this process cannot read ``path`` (a video file or a folder of frames), or None."""
    if path is None:
        return None
    if not path.exists():
        return "it does not exist there"
    if not os.access(path, os.R_OK | (os.X_OK if path.is_dir() else 0)):
        return "it is not readable there"
    return None


def score_packed(
    entry: ClipEntry, cfg_dict: dict[str, Any], renderer: Any, threads: int
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """Task body: score one clip into a temporary folder and return its status and its files
    (relative path -> bytes, ``status.json`` left out; the driver writes that last). A clip this
    node cannot see is a failed clip whose reason names the node and the path."""
    for what, path in (("clip", entry.video), ("mask folder", entry.masks)):
        why = _unreadable(path)
        if why is not None:
            error = (
                f"ClipNotVisible: the Ray worker on {socket.gethostname()} cannot read the {what} {path} ({why}); "
                "clips must be on a filesystem every node of the cluster sees at the same path"
            )
            return failed_status(entry, ScoreConfig.from_dict(cfg_dict), error), {}
    with tempfile.TemporaryDirectory(prefix="geocon-ray-") as tmp:
        folder = Path(tmp) / "clip"
        status = score_one(entry, cfg_dict, str(folder), renderer, threads)
        files = {
            p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != STATUS_NAME
        }
    return status, files


LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""Ray's switch for a single-machine instance: set to 0, the node's address is 127.0.0.1 and every
Ray service listens there alone (by default Ray advertises the machine's address and listens on
every interface)."""


@contextmanager
def _loopback(ray):
    """Start-up of a private local instance bound to 127.0.0.1 (:data:`LOOPBACK_ENV`): the switch
    for the processes Ray starts, and Ray's reading of it in this one, for the call's duration."""
    from ray._private import ray_constants

    old_env, old_flag = os.environ.get(LOOPBACK_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[LOOPBACK_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = old_flag
        if old_env is None:
            os.environ.pop(LOOPBACK_ENV, None)
        else:
            os.environ[LOOPBACK_ENV] = old_env


def _is_loopback(address: str) -> bool:
    """Whether a cluster address names this machine's loopback (a head started with
    ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, as the README shows): the driver must then join it
    as a loopback node too, or Ray swaps 127.0.0.1 for the machine's address."""
    host = address.rpartition(":")[0].strip("[]") if "://" not in address else ""
    return host in ("localhost", "::1") or host.startswith("127.")


CONNECT_TRIES = 3
"""Attempts Ray makes to reach a cluster's GCS before giving up (Ray's own default is 20, some
12 minutes when the address answers but is not a Ray head)."""


@contextmanager
def _few_retries(ray):
    from ray._private import ray_constants

    old = ray_constants.NUM_REDIS_GET_RETRIES
    if "RAY_NUM_REDIS_GET_RETRIES" not in os.environ:
        ray_constants.NUM_REDIS_GET_RETRIES = min(old, CONNECT_TRIES)
    try:
        yield
    finally:
        ray_constants.NUM_REDIS_GET_RETRIES = old


def _start_local(ray, cpus: int) -> subprocess.Popen | None:
    """Start a private Ray instance on 127.0.0.1 with ``cpus`` CPUs, and a watchdog
    (:func:`geocon_core.files.procs.start_reaper`) that stops what it started should this process be
    killed (Ray's node processes die with their driver, the agents they start do not)."""
    try:
        import psutil
    except ImportError:
        psutil = None
    me = psutil.Process() if psutil is not None else None
    before = {c.pid for c in me.children()} if me is not None else set()
    with _loopback(ray):
        ray.init(
            address="local",
            num_cpus=cpus,
            include_dashboard=False,
            log_to_driver=False,
            logging_level="ERROR",  # nothing of a private instance's start-up concerns the user
        )
    if me is None:
        return None
    return start_reaper([c.pid for c in me.children() if c.pid not in before])


def _connect(ray, options: RayOptions) -> tuple[bool, subprocess.Popen | None]:
    """Join the cluster, or start a private local instance: (whether this call started Ray, the
    local instance's watchdog)."""
    if ray.is_initialized():
        return False, None
    if options.address is None:
        return True, _start_local(ray, options.local_cpus)
    local = _is_loopback(options.address)
    try:
        with _loopback(ray) if local else nullcontext(), _few_retries(ray):
            ray.init(address=options.address, log_to_driver=False, logging_level="WARNING")
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        hint = "start one with `ray start --head` and pass the address it prints"
        if "RAY_AUTH_MODE" not in os.environ:  # Ray sends its token to a named address only when told to
            hint = (
                "a head started by Ray 2.60 asks for its token: run with RAY_AUTH_MODE=token and the head's "
                "~/.ray/auth_token here (or RAY_AUTH_TOKEN); else " + hint
            )
        raise BenchError(
            f"--ray-address {options.address}: no Ray cluster could be joined there ({first}); {hint}"
        ) from None
    return True, None


PROBE_S = 5.0
"""Seconds :func:`_probe` waits for a cluster's head to accept a connection and answer as the
gRPC (HTTP/2) server it is (Ray itself retries for minutes, also on a port that accepts and never
answers)."""


def _answer(host: str, port: int) -> str | None:
    """None when the head at ``host``:``port`` answers as a gRPC server within :data:`PROBE_S`
    (on any of the host's addresses), else why not in words."""
    from ..files import http2_answer, resolve

    found = resolve(host, port, PROBE_S)
    if isinstance(found, str):
        return found
    why = "no address"
    for family, sockaddr in found:
        why = http2_answer(family, sockaddr, PROBE_S) or ""
        if not why:
            return None
    return why


def _probe(address: str) -> None:
    """Refuse at once an address ``HOST:PORT`` where nothing answers as a Ray head does, within
    :data:`PROBE_S` (:func:`geocon_core.files.answers.http2_answer`): a head's GCS ``HOST:PORT`` and
    a Ray client's ``ray://HOST:PORT`` both speak gRPC; ``auto`` is left to Ray."""
    target = address.removeprefix("ray://")
    if address == "auto" or "://" in target:
        return
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise BenchError(f"--ray-address {address}: expected HOST:PORT, as `ray start --head` prints it")
    why = _answer(host.strip("[]"), int(port))
    if why is not None:
        raise BenchError(
            f"--ray-address {address}: no Ray cluster answers there ({why}); start one with `ray start --head` "
            "and pass the address it prints"
        ) from None


def preflight(options: RayOptions) -> None:
    """What can be refused before a run touches its results folder: Ray missing, a cluster address
    where nothing answers."""
    _import_ray()
    if options.address is not None:
        _probe(options.address)


def _gpus(ray, options: RayOptions, cfg: ScoreConfig, note: Note) -> float:
    if options.gpus_per_clip is not None:
        return options.gpus_per_clip
    neural = neural_backends(cfg)
    if not neural:
        return 0.0
    if ray.cluster_resources().get("GPU", 0) >= 1:
        return 1.0
    note(f"the cluster has no GPU; {', '.join(neural)} run on CPUs (slow)")
    return 0.0


def score_all_ray(
    todo: list[ClipEntry],
    out: Path,
    cfg: ScoreConfig,
    renderer: Any,
    finished: Finished,
    options: RayOptions,
    note: Note = lambda _msg: None,
) -> None:
    """Score ``todo`` as Ray tasks, installing each finished clip into ``out`` and calling
    ``finished(status)``. Ctrl-C cancels the tasks in flight (their clips are scored again on
    resume) and stops a local instance this call started."""
    ray = _import_ray()
    started, reaper = _connect(ray, options)
    try:
        gpus = _gpus(ray, options, cfg, note)
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < options.cpus_per_clip:
            raise BenchError(
                f"the Ray cluster has {cpus:g} CPUs, fewer than --ray-cpus-per-clip {options.cpus_per_clip:g}"
            )
        where = "a local Ray instance (127.0.0.1)" if options.address is None else f"the cluster at {options.address}"
        note(f"scoring on {where}: {cpus:g} CPUs, {options.cpus_per_clip:g} per clip")
        task = ray.remote(score_packed).options(
            num_cpus=options.cpus_per_clip, num_gpus=gpus, max_retries=0, retry_exceptions=False
        )
        args = (ray.put(cfg.to_dict()), renderer, max(1, int(options.cpus_per_clip)))
        slots = max(1, int(2 * cpus // options.cpus_per_clip))  # enough queued to keep every CPU busy
        queue = list(todo)
        inflight: dict[Any, ClipEntry] = {}
        crashes: dict[str, int] = {}
        try:
            while queue or inflight:
                while queue and len(inflight) < slots:
                    entry = queue.pop(0)
                    inflight[task.remote(entry, *args)] = entry
                ready, _ = ray.wait(list(inflight), num_returns=1)
                entry = inflight.pop(ready[0])
                result = _result(ray, ready[0], entry, cfg, crashes, note)
                if result is None:
                    queue.insert(0, entry)
                    continue
                install_clip(clip_dir(out, entry.clip_id), *result)
                finished(result[0])
        except BaseException:  # Ctrl-C: finished clips are kept, clips in flight are scored again on resume
            for ref in inflight:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started:
            ray.shutdown()
        if reaper is not None:  # it stops what ray.shutdown() left, then exits
            try:
                reaper.wait(timeout=10)
            except subprocess.TimeoutExpired:
                reaper.kill()


def _result(
    ray, ref, entry: ClipEntry, cfg: ScoreConfig, crashes: dict[str, int], note: Note
) -> tuple[dict[str, Any], dict[str, bytes]] | None:
    """A finished task's (status, files), or None when its worker died and the clip is to be scored
    again (counted in ``crashes``; failed once that happened :data:`MAX_CRASHES` times)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:  # raised outside scoring's own error handling
        return failed_status(entry, cfg, _task_error(exc)), {}
    except ray.exceptions.RayError as exc:  # the worker process or its node died
        crashes[entry.clip_id] = crashes.get(entry.clip_id, 0) + 1
        if crashes[entry.clip_id] >= MAX_CRASHES:
            return crashed_status(entry, cfg), {}
        note(f"{entry.clip_id}: the Ray worker scoring it died ({type(exc).__name__}); scoring it again")
        return None


def _task_error(exc: BaseException) -> str:
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        return f"{type(cause).__name__}: {cause}"
    return str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
