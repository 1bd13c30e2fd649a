"""The bad-input catalogue: every unusable clip, masks file, pose log and option the issue
"Nothing lost, nothing hangs, every bad input gets one clear sentence" lists, built in a temporary
folder and run through the ``geocon`` command line.

Each :class:`Case` names its input (``build``), the command line, the exit code it must give
(2 with ``error: <one sentence>`` as the only line on stderr; 0 for a valid result), words the
sentence must hold (usually the file's name) and, where a valid result has a truth to check, a
``check``. Every case also asserts that nothing pre-existing changed: after a failure every file
that was in the working folder (an earlier record, the inputs) is byte-identical and no new file
was left behind; after a valid run the inputs are unchanged. All problems of a case are reported
together. Score and view run in-process (``CliRunner``, ``--preset fast``, the case's folder as
the current directory); ``serve`` and inputs that could block a reader (a FIFO) run as
subprocesses that are killed after :data:`SUBPROCESS_TIMEOUT_S`.

To add a case, append a ``Case`` to one of the tables (``CLIPS``, ``MASKS``, ``POSES``,
``OPTIONS``)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_viewer.cli import app

from .bad_inputs import (
    pan_frames,
    snapshot,
    write_animated,
    write_audio_only,
    write_gif,
    write_palette_png,
    write_pngs,
    write_video,
)

SUBPROCESS_TIMEOUT_S = 12.0
"""A subprocess case still running after this long hangs (it is killed and fails)."""
SERVE_LIMIT_S = 10.0
"""``geocon serve`` must refuse a bad address within this many seconds."""
FAST = ("--preset", "fast")
W, H, N = 160, 90, 12
"""Size and length of the clips rendered here (the C4 clip with masks is 128x96, 8 frames)."""


# --- session assets: rendered once, copied into each case's folder --------------------------------


class Assets:
    """Inputs shared by the cases, rendered on first use into a session folder."""

    def __init__(self, root: Path, synth_clips: Callable[..., Path]) -> None:
        self.root = root
        self._synth_clips = synth_clips
        self._made: dict[str, Path] = {}

    def _once(self, key: str, make: Callable[[Path], None]) -> Path:
        if key not in self._made:
            path = self.root / key
            make(path)
            self._made[key] = path
        return self._made[key]

    @property
    def pan(self) -> Path:
        """A consistent 160x90 H.264 clip of 12 frames."""
        return self._once("pan.mp4", lambda p: write_video(p, pan_frames(W, H, N, seed=1)))

    @property
    def c4(self) -> Path:
        """The folder of the synthetic C4 clip (two moving objects), 128x96, 8 frames:
        ``c4_objects.mp4``, its label masks ``c4_objects.masks/`` and ``c4_objects.gt.json``."""
        from geocon_core.synth import ClipPlan

        return self._synth_clips([ClipPlan("C4")], seed=1, width=128, height=96, num_frames=8)

    @property
    def record(self) -> Path:
        """The record folder of the C4 clip scored with its masks (``record.json``,
        ``matches.npz``, ``overlays/`` with label and flow PNGs)."""

        def make(p: Path) -> None:
            clip, masks = self.c4 / "c4_objects.mp4", self.c4 / "c4_objects.masks"
            res = CliRunner().invoke(app, ["score", str(clip), *FAST, "--masks", str(masks), "--out", str(p)])
            assert res.exit_code == 0, res.output
            assert (p / "overlays" / "index.json").is_file()

        return self._once("record", make)

    @property
    def big(self) -> Path:
        """A 3840x2160 H.264 clip of 3 frames."""
        return self._once("big.mp4", lambda p: write_video(p, pan_frames(3840, 2160, 3, seed=2, step=8)))


@pytest.fixture(scope="session")
def assets(tmp_path_factory: pytest.TempPathFactory, synth_clips) -> Assets:
    return Assets(tmp_path_factory.mktemp("bad-input-assets"), synth_clips)


@dataclass
class Outcome:
    """What one run gave: exit code, stdout, stderr, the uncaught exception (in-process runs)."""

    code: int
    stdout: str
    stderr: str
    exception: BaseException | None = None
    seconds: float = 0.0

    @property
    def first_line(self) -> str:
        lines = [line for line in self.stderr.splitlines() if line.strip()]
        return lines[0] if lines else ""

    def describe(self) -> str:
        exc = "none" if self.exception is None else f"{type(self.exception).__name__}: {self.exception}"
        return f"exit {self.code}; stderr first line {self.first_line!r}; exception {exc}"


class Ctx:
    """A case's working folder (the current directory while it runs) and helpers to fill it."""

    def __init__(self, tmp: Path, assets: Assets) -> None:
        self.tmp = tmp
        self.assets = assets
        self.frames_read = 0
        """Frames OpenCV decoded during the case's command (``cv2.VideoCapture.read`` calls)."""

    def copy(self, src: Path, name: str) -> Path:
        dst = self.tmp / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copyfile(src, dst)
        return dst

    def pan(self, name: str = "clip.mp4") -> Path:
        return self.copy(self.assets.pan, name)

    def c4(self) -> None:
        """``c4.mp4``, its masks ``c4.masks/`` and ground truth ``c4.gt.json``."""
        src = self.assets.c4
        self.copy(src / "c4_objects.mp4", "c4.mp4")
        self.copy(src / "c4_objects.masks", "c4.masks")
        self.copy(src / "c4_objects.gt.json", "c4.gt.json")

    def record(self, name: str = "rec") -> Path:
        return self.copy(self.assets.record, name)

    def write(self, name: str, data: bytes | str) -> Path:
        p = self.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, str):
            p.write_text(data, encoding="utf-8")
        else:
            p.write_bytes(data)
        return p

    def video(self, name: str, frames: list[np.ndarray], **options) -> Path:
        p = self.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return write_video(p, frames, **options)

    def npz(self, name: str, **arrays: np.ndarray) -> Path:
        p = self.tmp / name
        np.savez(p, **arrays)
        return p

    def masks(self) -> np.ndarray:
        """The C4 clip's label masks, (8, 96, 128) uint8."""
        folder = self.assets.c4 / "c4_objects.masks"
        return np.stack([cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in sorted(folder.glob("*.png"))])

    def invoke(self, argv: list[str]) -> Outcome:
        """``geocon ARGV`` in-process."""
        start = time.perf_counter()
        res = CliRunner().invoke(app, argv)
        exc = None if res.exception is None or isinstance(res.exception, SystemExit) else res.exception
        return Outcome(res.exit_code, res.stdout, res.stderr, exc, time.perf_counter() - start)

    def spawn(self, argv: list[str]) -> Outcome:
        """``geocon ARGV`` as a subprocess of its own (killed, with its group, after the time limit)."""
        start = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "geocon_viewer.cli", *argv],
            cwd=self.tmp,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
            encoding="utf-8",
            errors="replace",  # a file name that is not UTF-8 is printed as its bytes
            start_new_session=True,
        )
        try:
            stdout, stderr = proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            stdout, stderr = proc.communicate()
            stderr = f"<still running after {SUBPROCESS_TIMEOUT_S:g} s: killed> " + stderr
        return Outcome(proc.returncode, stdout, stderr, None, time.perf_counter() - start)


def record(ctx: Ctx, folder: str = "out") -> dict:
    return json.loads((ctx.tmp / folder / "record.json").read_text(encoding="utf-8"))


@dataclass(frozen=True)
class Case:
    """One bad (or tricky but valid) input: ``build`` fills the working folder, ``argv`` runs in
    it, ``code`` is the exit code it must give (a tuple: any of them), ``says`` are words the
    error sentence must hold, ``forbids`` words it must not, ``check`` a further check of a valid
    result (or of the failure)."""

    name: str
    build: Callable[[Ctx], object]
    argv: tuple[str, ...]
    code: int | tuple[int, ...] = 2
    says: tuple[str, ...] = ()
    forbids: tuple[str, ...] = ()
    check: Callable[[Ctx, Outcome], None] | None = None
    runner: Literal["cli", "subprocess"] = "cli"
    needs: tuple[str, ...] = ()
    """Modules the case needs (skipped without them)."""

    def codes(self) -> tuple[int, ...]:
        return self.code if isinstance(self.code, tuple) else (self.code,)


def nothing(_ctx: Ctx) -> None:
    """Build nothing."""


def score(clip: str, *more: str, out: str | None = "out") -> tuple[str, ...]:
    """``score CLIP --preset fast [--out OUT] MORE``."""
    return ("score", clip, *FAST, *(() if out is None else ("--out", out)), *more)


def build_all(*steps: Callable[[Ctx], object]) -> Callable[[Ctx], None]:
    def build(ctx: Ctx) -> None:
        for step in steps:
            step(ctx)

    return build


# --- clip builders --------------------------------------------------------------------------------


def frames_of(kind: str, width: int = W, height: int = H, n: int = N) -> list[np.ndarray]:
    if kind == "black":
        return [np.zeros((height, width, 3), np.uint8)] * n
    if kind == "gray":
        return [np.full((height, width, 3), 128, np.uint8)] * n
    if kind == "noise":
        rng = np.random.default_rng(5)
        return [rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(n)]
    return pan_frames(width, height, n, seed=3)


def truncated(name: str, fraction: float, *, faststart: bool) -> Callable[[Ctx], None]:
    """``full.mp4`` (every frame a key frame) and ``name``: its first ``fraction`` of bytes."""

    def build(ctx: Ctx) -> None:
        full = ctx.video("full.mp4", frames_of("pan"), faststart=faststart, intra=True)
        data = full.read_bytes()
        ctx.write(name, data[: int(len(data) * fraction)])

    return build


def truncation_is_warned(ctx: Ctx, _res: Outcome) -> None:
    """The truncated clip gives a result with fewer frames and a warning the full clip lacks."""
    full = ctx.invoke(list(score("full.mp4", out="full-out")))
    assert full.code == 0, full.describe()
    before = set(record(ctx, "full-out")["warnings"])
    rec = record(ctx)
    assert 2 <= rec["video"]["num_frames"] < N, rec["video"]
    assert rec["warnings"], "a truncated clip must say so in record.json warnings (it has none)"
    assert set(rec["warnings"]) - before, f"no warning about the truncation: {rec['warnings']}"


def video_is(**expected: object) -> Callable[[Ctx, Outcome], None]:
    """A check that ``record.json``'s ``video`` block holds ``expected``."""

    def check(ctx: Ctx, _res: Outcome) -> None:
        video = record(ctx)["video"]
        for key, want in expected.items():
            assert video[key] == want, f"video.{key} = {video[key]!r}, expected {want!r}"

    return check


def warned(words: str) -> Callable[[Ctx, Outcome], None]:
    """A check: the record warns with ``words``, and so does the terminal summary."""

    def check(ctx: Ctx, res: Outcome) -> None:
        assert any(words in w for w in record(ctx)["warnings"]), record(ctx)["warnings"]
        assert words.split()[0] in res.stdout, res.stdout

    return check


def build_all_checks(*checks: Callable[[Ctx, Outcome], None]) -> Callable[[Ctx, Outcome], None]:
    def check(ctx: Ctx, res: Outcome) -> None:
        for one in checks:
            one(ctx, res)

    return check


def big_is_downscaled(ctx: Ctx, _res: Outcome) -> None:
    video = record(ctx)["video"]
    assert video["source_size"] == [3840, 2160] and video["scale"] < 1 and video["num_frames"] == 3, video


def bars_found(ctx: Ctx, _res: Outcome) -> None:
    top, bottom, _left, _right = record(ctx)["video"]["bars"]
    assert top > 0 and bottom > 0, f"the letterbox bars were not found: {record(ctx)['video']['bars']}"


def gif_with_duplicates(ctx: Ctx) -> None:
    f = frames_of("pan")
    order = [0, 0, 1, 1, 2, 3, 3, 4, 5, 6]  # frames 1, 3 and 6 duplicate their predecessor
    write_gif(ctx.tmp / "dup.gif", [f[i] for i in order])


def hard_cut(ctx: Ctx) -> None:
    a = pan_frames(W, H, 6, seed=4, mean=70)
    b = pan_frames(W, H, 6, seed=9, mean=190)
    ctx.video("cut.mp4", a + b)


def letterbox(ctx: Ctx) -> None:
    frames = [f.copy() for f in frames_of("pan")]
    for f in frames:
        f[:6] = 0
        f[-6:] = 0
    ctx.video("letterbox.mp4", frames)


def vfr(ctx: Ctx) -> None:
    ctx.video("vfr.mp4", frames_of("pan"), pts_ms=[0, 30, 50, 120, 130, 200, 260, 270, 300, 400, 410, 500])


def png_folder(kind: str) -> Callable[[Ctx], None]:
    def build(ctx: Ctx) -> None:
        frames = frames_of("pan")
        folder = ctx.tmp / kind
        if kind == "png16":
            write_pngs(folder, [f.astype(np.uint16) * 257 for f in frames])
        elif kind == "gray":
            write_pngs(folder, [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames])
        elif kind == "mixed":
            write_pngs(folder, frames[:3] + [cv2.resize(frames[3], (W // 2, H // 2))] + frames[4:])
        elif kind == "corrupt":
            write_pngs(folder, frames)
            (folder / "00004.png").write_bytes(np.random.default_rng(0).bytes(2000))
        elif kind == "truncated":
            write_pngs(folder, frames)
            data = (folder / "00002.png").read_bytes()
            (folder / "00002.png").write_bytes(data[: len(data) // 2])
        elif kind == "jpeg":
            folder.mkdir()
            for t, f in enumerate(frames):
                cv2.imwrite(str(folder / f"frame_{t}.jpg"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        elif kind == "looplink":
            write_pngs(folder, frames)
            os.symlink("loop.png", folder / "loop.png")
        else:
            raise AssertionError(kind)

    return build


def notes_kept(ctx: Ctx, _res: Outcome) -> None:
    """A record written into a folder that holds other files leaves them alone."""
    assert (ctx.tmp / "mine" / "notes.txt").read_text() == "keep me\n"
    assert (ctx.tmp / "mine" / "record.json").is_file()


def odd_rgba_pngs(ctx: Ctx) -> None:
    """``odd/``: 161x91 RGBA frames (odd sizes cannot be H.264 4:2:0, but frames can be)."""
    frames = pan_frames(161, 91, 8)
    write_pngs(ctx.tmp / "odd", [np.dstack([f, np.full(f.shape[:2], 200, np.uint8)]) for f in frames])


def symlink_loop(ctx: Ctx) -> None:
    os.symlink("loop_b.mp4", ctx.tmp / "loop.mp4")
    os.symlink("loop.mp4", ctx.tmp / "loop_b.mp4")


def fifo(ctx: Ctx) -> None:
    os.mkfifo(ctx.tmp / "pipe.mp4")


def unicode_clip(ctx: Ctx) -> None:
    ctx.pan("vidéo 日本/clip ü.mp4")


def unicode_is_named(ctx: Ctx, _res: Outcome) -> None:
    assert record(ctx)["clip"].endswith("vidéo 日本/clip ü.mp4"), record(ctx)["clip"]


def audio_only(ctx: Ctx) -> None:
    """``audio.mp4``: one AAC stream, no video (skipped where PyAV cannot encode AAC)."""
    import av

    try:
        write_audio_only(ctx.tmp / "audio.mp4")
    except (av.FFmpegError, ValueError) as exc:
        pytest.skip(f"PyAV cannot write an audio-only MP4 here: {exc}")


def one_frame(ctx: Ctx) -> None:
    ctx.video("one.mp4", frames_of("pan")[:1])


def one_png(ctx: Ctx) -> None:
    cv2.imwrite(str(ctx.tmp / "frame.png"), frames_of("pan")[0])


# --- masks builders (the C4 clip, 128x96, 8 frames, objects 1 and 2) ------------------------------


def with_c4(make: Callable[[Ctx, np.ndarray], object] | None = None) -> Callable[[Ctx], None]:
    """The C4 clip (``c4.mp4``, ``c4.masks/``), then ``make(ctx, labels)`` with its labels."""

    def build(ctx: Ctx) -> None:
        ctx.c4()
        if make is not None:
            make(ctx, ctx.masks())

    return build


def object_npz(ctx: Ctx, _labels: np.ndarray) -> None:
    objects = np.empty(8, dtype=object)
    objects[:] = [{"id": k} for k in range(8)]
    ctx.npz("objects.npz", labels=objects)


def truncated_npz(ctx: Ctx, labels: np.ndarray) -> None:
    full = ctx.npz("full.npz", labels=labels)
    data = full.read_bytes()
    full.unlink()
    ctx.write("half.npz", data[: len(data) // 2])


def colour_pngs(ctx: Ctx, labels: np.ndarray) -> None:
    rgb = np.stack([labels * 100, labels * 40, 255 - labels * 90], axis=-1).astype(np.uint8)
    write_pngs(ctx.tmp / "colour.masks", list(rgb))


def davis_pngs(ctx: Ctx, labels: np.ndarray) -> None:
    """DAVIS layout: indexed PNGs ``davis/00000.png, ...``; objects 1 and 2 become ids 3 and 7."""
    remap = np.zeros(256, np.uint8)
    remap[1], remap[2] = 3, 7
    (ctx.tmp / "davis").mkdir()
    for t, lab in enumerate(labels):
        write_palette_png(ctx.tmp / "davis" / f"{t:05d}.png", remap[lab])


def short_folder(ctx: Ctx, _labels: np.ndarray) -> None:
    shutil.copytree(ctx.tmp / "c4.masks", ctx.tmp / "short.masks")
    (ctx.tmp / "short.masks" / "00007.png").unlink()


def resized_folder(ctx: Ctx, labels: np.ndarray) -> None:
    small = [cv2.resize(m, (64, 48), interpolation=cv2.INTER_NEAREST) for m in labels]
    write_pngs(ctx.tmp / "resized.masks", small)


def corrupt_png_folder(ctx: Ctx, _labels: np.ndarray) -> None:
    """``corrupt.masks``: the C4 masks with frame 5 a PNG signature and zeros (found mid-scoring)."""
    shutil.copytree(ctx.tmp / "c4.masks", ctx.tmp / "corrupt.masks")
    (ctx.tmp / "corrupt.masks" / "00005.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))


def object_folders(ctx: Ctx, labels: np.ndarray) -> None:
    for oid in (1, 2):
        write_pngs(ctx.tmp / "objects" / str(oid), [(lab == oid).astype(np.uint8) * 255 for lab in labels])


def zero_object_folder(ctx: Ctx, labels: np.ndarray) -> None:
    """Per-object folders ``zero/0/`` and ``zero/1/``: id 0 is the background, not an object."""
    for oid in (0, 1):
        write_pngs(ctx.tmp / "zero" / str(oid), [(lab == 1).astype(np.uint8) * 255 for lab in labels])


def late_numbered_folder(ctx: Ctx, labels: np.ndarray) -> None:
    """``late.masks/00005.png, ...``: frames must be numbered from 0 (or 1)."""
    (ctx.tmp / "late.masks").mkdir()
    for t, lab in enumerate(labels):
        cv2.imwrite(str(ctx.tmp / "late.masks" / f"{t + 5:05d}.png"), lab)


def wide_id_folder(ctx: Ctx, labels: np.ndarray) -> None:
    """``wide.masks``: 16-bit label PNGs with ids 1000 and 2000 (above 255)."""
    write_pngs(ctx.tmp / "wide.masks", [lab.astype(np.uint16) * 1000 for lab in labels])


def object_ids(*ids: int) -> Callable[[Ctx, Outcome], None]:
    def check(ctx: Ctx, _res: Outcome) -> None:
        rec = record(ctx)
        got = sorted(o["object_id"] for o in rec["objects"])
        assert got == sorted(ids), f"objects {got} in record.json, expected the mask ids {sorted(ids)}"

    return check


def masks_case(
    name: str,
    masks: str,
    make: Callable[[Ctx, np.ndarray], object] | None = None,
    code: int = 2,
    says: tuple[str, ...] = (),
    **more,
) -> Case:
    """``score c4.mp4 --masks MASKS`` after ``make`` wrote them; the sentence names ``masks``."""
    return Case(f"masks-{name}", with_c4(make), score("c4.mp4", "--masks", masks), code, says or (masks,), **more)


# --- pose-log builders ----------------------------------------------------------------------------

IDENTITY = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def pose(name: str, content: object | bytes) -> Callable[[Ctx], None]:
    """The pan clip as ``clip.mp4`` and a pose log ``name`` (a dict is written as JSON)."""

    def build(ctx: Ctx) -> None:
        ctx.pan()
        if isinstance(content, (bytes, str)):
            ctx.write(name, content)
        else:
            ctx.write(name, json.dumps(content))

    return build


def log(T: list[list[float]], **more: object) -> dict:
    return {"format": "geocon-pose/1", "T_cam0_camT": T, "scale": "unit_mean_distance", **more}


def pose_case(name: str, file: str, content: object, says: tuple[str, ...] = (), **more) -> Case:
    return Case(f"pose-{name}", pose(file, content), score("clip.mp4", "--pose-log", file), 2, (file, *says), **more)


def nothing_decoded(ctx: Ctx, _res: Outcome) -> None:
    assert ctx.frames_read == 0, f"{ctx.frames_read} frames were decoded before the pose log was refused"


def rec_untouched_marker(ctx: Ctx, _res: Outcome) -> None:
    """The pre-existing record really had overlays (so the byte-identity check meant something)."""
    assert (ctx.tmp / "rec" / "overlays" / "index.json").is_file()
    assert any((ctx.tmp / "rec" / "overlays").glob("*.png"))
    assert (ctx.tmp / "rec" / "record.json").is_file()


def gated_f_without_pose(ctx: Ctx, _res: Outcome) -> None:
    gate = record(ctx)["gate"]
    assert gate["label"] == "F" and gate["pose_present"] is False, gate


def pose_log_used(ctx: Ctx, _res: Outcome) -> None:
    assert record(ctx)["gate"]["backend"] == "log", record(ctx)["gate"]


# --- option / command builders --------------------------------------------------------------------


def dataset(ctx: Ctx) -> None:
    src = ctx.assets.c4
    (ctx.tmp / "ds").mkdir()
    for part in ("c4_objects.mp4", "c4_objects.meta.json", "c4_objects.gt.json", "c4_objects.masks"):
        ctx.copy(src / part, f"ds/{part}")
    ctx.write("results.txt", "not a folder\n")


def corrupt_record(content: str) -> Callable[[Ctx], None]:
    def build(ctx: Ctx) -> None:
        ctx.record()
        ctx.write("rec/record.json", content)

    return build


def huge_record_json(ctx: Ctx) -> None:
    """``rec/record.json`` replaced by a sparse file of 1 GiB (larger than any record)."""
    with open(ctx.tmp / "rec" / "record.json", "r+b") as f:
        f.truncate(1 << 30)


def fifo_record_json(ctx: Ctx) -> None:
    """``rec/record.json`` replaced by a FIFO that nobody writes (a reader must not wait on it)."""
    (ctx.tmp / "rec" / "record.json").unlink()
    os.mkfifo(ctx.tmp / "rec" / "record.json")


def scored_a(ctx: Ctx) -> None:
    """``a/clip.mp4`` (the C4 clip) scored into the default ``geocon-out/clip``, and
    ``b/clip.mp4``, another clip with the same file name."""
    ctx.copy(ctx.assets.c4 / "c4_objects.mp4", "a/clip.mp4")
    ctx.pan("b/clip.mp4")
    res = ctx.invoke(list(score("a/clip.mp4", out=None)))
    assert res.code == 0, res.describe()
    assert (ctx.tmp / "geocon-out" / "clip" / "record.json").is_file()


def default_out_written(ctx: Ctx, _res: Outcome) -> None:
    assert record(ctx, "geocon-out/clip")["clip"] == "a/clip.mp4"


CLIPS = [
    Case("missing-file", nothing, score("missing.mp4"), 2, ("missing.mp4", "no such file")),
    Case("empty-file", lambda c: c.write("empty.mp4", b""), score("empty.mp4"), 2, ("empty.mp4",)),
    Case(
        "random-bytes",
        lambda c: c.write("bytes.mp4", np.random.default_rng(3).bytes(5000)),
        score("bytes.mp4"),
        2,
        ("bytes.mp4",),
    ),
    Case(
        "text-named-mp4",
        lambda c: c.write("notes.mp4", "my holiday notes\n" * 20),
        score("notes.mp4"),
        2,
        ("notes.mp4",),
    ),
    Case("folder-named-mp4", lambda c: (c.tmp / "dir.mp4").mkdir(), score("dir.mp4"), 2, ("dir.mp4",)),
    Case("mp4-without-moov", truncated("cut.mp4", 0.6, faststart=False), score("cut.mp4"), 2, ("cut.mp4",)),
    Case(
        "mp4-truncated-half-faststart",
        truncated("half.mp4", 0.5, faststart=True),
        score("half.mp4"),
        0,
        check=truncation_is_warned,
    ),
    Case("one-frame-mp4", one_frame, score("one.mp4"), 2, ("one.mp4", "at least 2")),
    Case("one-png-file", one_png, score("frame.png"), 2, ("frame.png", "at least 2")),
    Case("audio-only", audio_only, score("audio.mp4"), 2, ("audio.mp4",)),
    Case("dev-null", nothing, score("/dev/null"), 2, ("/dev/null",)),
    Case("fifo", fifo, score("pipe.mp4"), 2, ("pipe.mp4",), runner="subprocess"),
    Case("symlink-loop", symlink_loop, score("loop.mp4"), 2, ("loop.mp4",)),
    Case("empty-folder", lambda c: (c.tmp / "empty").mkdir(), score("empty"), 2, ("empty",)),
    Case(
        "all-black",
        lambda c: c.video("black.mp4", frames_of("black")),
        score("black.mp4"),
        (0, 2),
        ("black.mp4",),
    ),
    Case("all-gray", lambda c: c.video("gray.mp4", frames_of("gray")), score("gray.mp4"), 0),
    Case("noise", lambda c: c.video("noise.mp4", frames_of("noise")), score("noise.mp4"), 0),
    Case(
        "tiny-16x16",
        lambda c: c.video("tiny.mp4", pan_frames(16, 16, 8)),
        score("tiny.mp4"),
        (0, 2),
        ("tiny.mp4",),
    ),
    Case(
        "thin-32x2000",
        lambda c: c.video("tall.mp4", pan_frames(32, 2000, 6)),
        score("tall.mp4"),
        (0, 2),
        ("tall.mp4",),
    ),
    Case("big-4k-3-frames", lambda c: c.copy(c.assets.big, "big.mp4"), score("big.mp4"), 0, check=big_is_downscaled),
    Case("gif-duplicated-frames", gif_with_duplicates, score("dup.gif"), 0, check=video_is(duplicates=[1, 3, 6])),
    Case("hard-cut", hard_cut, score("cut.mp4"), 0, check=video_is(cuts=[6])),
    Case("thin-letterbox", letterbox, score("letterbox.mp4"), 0, check=bars_found),
    Case(
        "vfr", vfr, score("vfr.mp4"), 0, check=build_all_checks(video_is(num_frames=N), warned("variable frame rate"))
    ),
    Case(
        "webm",
        lambda c: c.video("clip.webm", frames_of("pan"), codec="libvpx"),
        score("clip.webm"),
        0,
        check=video_is(num_frames=N),
    ),
    Case(
        "mov",
        lambda c: c.video("clip.mov", frames_of("pan"), container="mov"),
        score("clip.mov"),
        0,
        check=video_is(num_frames=N),
    ),
    Case(
        "avi-mjpeg",
        lambda c: c.video("clip.avi", frames_of("pan"), codec="mjpeg", pix_fmt="yuvj420p"),
        score("clip.avi"),
        0,
        check=video_is(num_frames=N),
    ),
    Case("mp4-named-gif", lambda c: c.pan("clip.gif"), score("clip.gif"), 0, check=video_is(num_frames=N)),
    Case("png-16-bit", png_folder("png16"), score("png16"), 0, check=video_is(num_frames=N, kind="images")),
    Case("png-gray", png_folder("gray"), score("gray"), 0, check=video_is(num_frames=N, kind="images")),
    Case("jpeg-folder", png_folder("jpeg"), score("jpeg"), 0, check=video_is(num_frames=N, kind="images")),
    Case("png-mixed-sizes", png_folder("mixed"), score("mixed"), 2, ("mixed", "00003.png")),
    Case("png-one-corrupt", png_folder("corrupt"), score("corrupt"), 2, ("00004.png",)),
    Case("png-one-truncated", png_folder("truncated"), score("truncated"), (0, 2), ("00002.png",)),
    Case("png-folder-with-symlink-loop", png_folder("looplink"), score("looplink"), (0, 2), ("loop.png",)),
    Case("unicode-path", unicode_clip, score("vidéo 日本/clip ü.mp4"), 0, check=unicode_is_named),
    Case(
        "two-frames",
        lambda c: c.video("two.mp4", frames_of("pan")[:2]),
        score("two.mp4"),
        0,
        check=video_is(num_frames=2),
    ),
    Case("png-odd-size-rgba", odd_rgba_pngs, score("odd"), 0, check=video_is(source_size=[161, 91])),
    Case("png-1x1", lambda c: write_pngs(c.tmp / "dot", pan_frames(1, 1, 4)), score("dot"), (0, 2), ("dot",)),
    Case("png-2x2", lambda c: write_pngs(c.tmp / "speck", pan_frames(2, 2, 4)), score("speck"), (0, 2), ("speck",)),
    Case(
        "out-folder-with-other-files",
        build_all(lambda c: c.pan(), lambda c: c.write("mine/notes.txt", "keep me\n")),
        score("clip.mp4", out="mine"),
        0,
        check=notes_kept,
    ),
]

MASKS = [
    masks_case("label-folder-ok", "c4.masks", None, 0, check=object_ids(1, 2)),
    masks_case("npz-ok", "ok.npz", lambda c, lab: c.npz("ok.npz", labels=lab), 0, check=object_ids(1, 2)),
    masks_case("object-folders-ok", "objects", object_folders, 0, check=object_ids(1, 2)),
    masks_case("palette-davis", "davis", davis_pngs, 0, check=object_ids(3, 7)),
    masks_case("missing", "nomasks"),
    masks_case(
        "random-bytes-npz",
        "junk.npz",
        lambda c, _: c.write("junk.npz", np.random.default_rng(1).bytes(4096)),
        forbids=("If you trust", "allow_pickle", "pickle"),
    ),
    masks_case("object-array-npz", "objects.npz", object_npz, forbids=("If you trust", "allow_pickle")),
    masks_case(
        "npz-without-labels",
        "nolabels.npz",
        lambda c, lab: c.npz("nolabels.npz", masks=lab),
        says=("nolabels.npz", "labels"),
    ),
    masks_case("npz-wrong-frame-count", "frames5.npz", lambda c, lab: c.npz("frames5.npz", labels=lab[:5])),
    masks_case("npz-wrong-size", "small.npz", lambda c, lab: c.npz("small.npz", labels=lab[:, ::2, ::2])),
    masks_case("npz-float", "float.npz", lambda c, lab: c.npz("float.npz", labels=lab.astype(np.float32))),
    masks_case("npz-2d", "flat.npz", lambda c, lab: c.npz("flat.npz", labels=lab[0])),
    masks_case("npz-truncated", "half.npz", truncated_npz),
    masks_case(
        "npz-id-above-255", "big_ids.npz", lambda c, lab: c.npz("big_ids.npz", labels=lab.astype(np.int32) * 300)
    ),
    masks_case("npz-negative-ids", "negative.npz", lambda c, lab: c.npz("negative.npz", labels=-lab.astype(np.int16))),
    masks_case("colour-png", "colour.masks", colour_pngs),
    masks_case("folder-wrong-count", "short.masks", short_folder),
    masks_case("folder-wrong-size", "resized.masks", resized_folder),
    masks_case("folder-corrupt-png", "corrupt.masks", corrupt_png_folder, says=("00005.png",)),
    masks_case("text-file", "masks.txt", lambda c, _: c.write("masks.txt", "1 2 3\n")),
    masks_case("dev-null", "/dev/null"),
    masks_case("empty-folder", "nothing.masks", lambda c, _: (c.tmp / "nothing.masks").mkdir()),
    masks_case("fifo", "pipe.npz", lambda c, _: os.mkfifo(c.tmp / "pipe.npz"), runner="subprocess"),
    masks_case("object-folder-0", "zero", zero_object_folder),
    masks_case("folder-numbered-from-5", "late.masks", late_numbered_folder),
    masks_case("png-16-bit-id-above-255", "wide.masks", wide_id_folder),
    Case(
        "masks-corrupt-png-into-existing-out",
        build_all(with_c4(corrupt_png_folder), lambda c: c.record()),
        ("score", "c4.mp4", *FAST, "--out", "rec", "--masks", "corrupt.masks"),
        2,
        ("00005.png",),
        check=rec_untouched_marker,
    ),
]

POSES = [
    Case(
        "pose-valid", pose("ok.json", log(IDENTITY)), score("clip.mp4", "--pose-log", "ok.json"), 0, check=pose_log_used
    ),
    Case("pose-missing", lambda c: c.pan(), score("clip.mp4", "--pose-log", "nopose.json"), 2, ("nopose.json",)),
    Case(
        "pose-directory",
        build_all(lambda c: c.pan(), lambda c: (c.tmp / "posedir").mkdir()),
        score("clip.mp4", "--pose-log", "posedir"),
        2,
        ("posedir",),
    ),
    pose_case(
        "binary-bytes",
        "pose.bin",
        b"\xff\xfe\x00\x81" + np.random.default_rng(2).bytes(300),
        forbids=("codec can't decode", "invalid start byte", "Traceback"),
    ),
    pose_case("empty", "empty.json", b""),
    pose_case(
        "repeated-key",
        "rep.json",
        '{"format": "geocon-pose/1", "pose_present": true, "pose_present": false, "T_cam0_camT": null}',
        ("pose_present", "twice"),
    ),
    pose_case(
        "5000-digit-number", "long.json", '{"format": "geocon-pose/1", "scale": 1' + "0" * 5000 + "}", ("number",)
    ),
    pose_case("invalid-json", "broken.json", '{"format": "geocon-pose/1", "T_cam0_camT": [[1, 0, 0'),
    pose_case("wrong-format", "wrong.json", {"format": "nope"}, says=("format",)),
    pose_case("json-array", "list.json", [1, 2, 3]),
    pose_case(
        "not-a-rotation", "skew.json", log([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), ("rotation",)
    ),
    pose_case(
        "nan",
        "nan.json",
        '{"format": "geocon-pose/1", "T_cam0_camT": [[1,0,0,NaN],[0,1,0,0],[0,0,1,0],[0,0,0,1]], '
        '"scale": "unit_mean_distance"}',
    ),
    pose_case("bad-last-row", "lastrow.json", log([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]])),
    pose_case("shape-3x4", "shape.json", log(IDENTITY[:3])),
    pose_case("no-scale", "noscale.json", {"format": "geocon-pose/1", "T_cam0_camT": IDENTITY}),
    pose_case("translation-1e308", "far.json", log([[1, 0, 0, 1e308], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
    pose_case(
        "metric-1e300-over-1e-300",
        "tiny.json",
        '{"format":"geocon-pose/1","T_cam0_camT":[[1,0,0,1e300],[0,1,0,0],[0,0,1,0.01],[0,0,0,1]],'
        '"scale":"metric","mean_scene_distance":1e-300}',
        check=nothing_decoded,
    ),
    pose_case("huge-file", "huge.json", '{"format": "geocon-pose/1", "pad": "' + "x" * (2 << 20) + '"}'),
    pose_case("present-not-bool", "yes.json", log(IDENTITY, pose_present="yes")),
    pose_case("negative-distance", "neg.json", log(IDENTITY, scale="metric", mean_scene_distance=-3.7)),
    pose_case("deep-nesting", "deep.json", "[" * 100_000 + "]" * 100_000),
    Case("pose-dev-null", lambda c: c.pan(), score("clip.mp4", "--pose-log", "/dev/null"), 2, ("/dev/null",)),
    Case(
        "pose-fifo",
        build_all(lambda c: c.pan(), lambda c: os.mkfifo(c.tmp / "pipe.json")),
        score("clip.mp4", "--pose-log", "pipe.json"),
        2,
        ("pipe.json",),
        runner="subprocess",
    ),
    Case(
        "pose-no-pose-is-valid",
        pose("failed.json", {"format": "geocon-pose/1", "pose_present": False}),
        score("clip.mp4", "--pose-log", "failed.json"),
        0,
        check=gated_f_without_pose,
    ),
    Case(
        "pose-synthetic-ground-truth",
        lambda c: c.c4(),
        score("c4.mp4", "--pose-log", "c4.gt.json"),
        0,
        check=pose_log_used,
    ),
    Case(
        "pose-failed-rescore-keeps-record",
        build_all(
            lambda c: c.c4(),
            lambda c: c.record(),
            lambda c: c.write(
                "far.json", json.dumps(log([[1, 0, 0, 1e308], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
            ),
        ),
        ("score", "c4.mp4", *FAST, "--masks", "c4.masks", "--out", "rec", "--pose-log", "far.json"),
        2,
        ("far.json",),
        check=rec_untouched_marker,
    ),
]

OPTIONS = [
    Case("fov-179.99", lambda c: c.pan(), score("clip.mp4", "--fov", "179.99"), 2, ("fov", "150")),
    Case("fov-0", lambda c: c.pan(), score("clip.mp4", "--fov", "0"), 2, ("fov", "150")),
    Case("fov-negative", lambda c: c.pan(), score("clip.mp4", "--fov", "-30"), 2, ("fov",)),
    Case("fov-nan", lambda c: c.pan(), score("clip.mp4", "--fov", "nan"), 2, ("fov",)),
    Case("fov-150-ok", lambda c: c.pan(), score("clip.mp4", "--fov", "150"), 0),
    Case("fov-inf", lambda c: c.pan(), score("clip.mp4", "--fov", "inf"), 2, ("fov",)),
    Case("preset-empty", lambda c: c.pan(), ("score", "clip.mp4", "--preset", ""), 2, ("valid:",)),
    Case(
        "out-is-a-file",
        build_all(lambda c: c.pan(), lambda c: c.write("taken.txt", "keep me\n")),
        score("clip.mp4", out="taken.txt"),
        2,
        ("taken.txt",),
    ),
    Case(
        "out-under-a-file",
        build_all(lambda c: c.pan(), lambda c: c.write("taken.txt", "keep me\n")),
        score("clip.mp4", out="taken.txt/sub"),
        2,
        ("taken.txt",),
    ),
    Case("out-in-proc", lambda c: c.pan(), score("clip.mp4", out="/proc/x"), 2, ("/proc/x",)),
    Case(
        "rrd-in-proc",
        lambda c: c.pan(),
        score("clip.mp4", "--rrd", "/proc/x.rrd"),
        2,
        ("/proc/x.rrd",),
        needs=("rerun",),
    ),
    Case("preset-nope", lambda c: c.pan(), ("score", "clip.mp4", "--preset", "nope"), 2, ("nope", "valid:")),
    Case("matcher-nope", lambda c: c.pan(), score("clip.mp4", "--matcher", "nope"), 2, ("nope", "valid:")),
    Case(
        "masks-with-no-masks",
        lambda c: c.c4(),
        score("c4.mp4", "--masks", "c4.masks", "--no-masks"),
        2,
        ("--masks", "--no-masks"),
    ),
    Case(
        "bench-out-is-a-file",
        dataset,
        ("bench", "ds", "--out", "results.txt", *FAST, "--no-rrd"),
        2,
        ("results.txt",),
    ),
    Case("bench-missing-dataset", nothing, ("bench", "nodata", "--out", "res", *FAST, "--no-rrd"), 2, ("nodata",)),
    Case(
        "view-at-negative",
        lambda c: c.record(),
        ("view", "rec", "--headless", "--at", "-5"),
        2,
        ("--at",),
        needs=("rerun",),
    ),
    Case(
        "view-at-100000",
        lambda c: c.record(),
        ("view", "rec", "--headless", "--at", "100000"),
        2,
        ("--at",),
        needs=("rerun",),
    ),
    Case(
        "view-corrupt-record",
        corrupt_record('{"format": "geocon-record/'),
        ("view", "rec", "--headless"),
        2,
        ("record.json",),
        needs=("rerun",),
    ),
    Case(
        "view-record-of-another-format",
        corrupt_record('{"format": "something-else/9"}'),
        ("view", "rec", "--headless"),
        2,
        ("record.json",),
        needs=("rerun",),
    ),
    Case("view-missing", nothing, ("view", "nothere", "--headless"), 2, ("nothere",), needs=("rerun",)),
    Case("view-at-last-frame", lambda c: c.record(), ("view", "rec", "--headless", "--at", "7"), 0, needs=("rerun",)),
    Case(
        "view-record-json-is-a-fifo",
        build_all(lambda c: c.record(), fifo_record_json),
        ("view", "rec", "--headless"),
        2,
        ("record.json",),
        runner="subprocess",
        needs=("rerun",),
    ),
    Case(
        "view-record-json-huge",
        build_all(lambda c: c.record(), huge_record_json),
        ("view", "rec", "--headless"),
        2,
        ("record.json",),
        needs=("rerun",),
    ),
    Case(
        "serve-port-70000",
        lambda c: c.record(),
        ("serve", "rec", "--port", "70000"),
        2,
        ("70000",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-port-minus-1",
        lambda c: c.record(),
        ("serve", "rec", "--port", "-1"),
        2,
        ("-1",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-host-999.1.1.1",
        lambda c: c.record(),
        ("serve", "rec", "--port", "0", "--host", "999.1.1.1"),
        2,
        ("999.1.1.1",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-host-localhostt",
        lambda c: c.record(),
        ("serve", "rec", "--port", "0", "--host", "localhostt"),
        2,
        ("localhostt",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-corrupt-record",
        corrupt_record('{"format": "geocon-record/'),
        ("serve", "rec", "--port", "0"),
        2,
        ("record.json",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-empty-folder",
        lambda c: (c.tmp / "empty").mkdir(),
        ("serve", "empty", "--port", "0"),
        2,
        ("empty",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case(
        "serve-missing",
        nothing,
        ("serve", "nothere", "--port", "0"),
        2,
        ("nothere",),
        runner="subprocess",
        needs=("viser",),
    ),
    Case("same-name-other-clip", scored_a, score("b/clip.mp4", out=None), 2, ("--out",)),
    Case("same-clip-again", scored_a, score("a/clip.mp4", out=None), 0, check=default_out_written),
]

# --- outputs never touch inputs -------------------------------------------------------------------


def clip_and_links(ctx: Ctx) -> None:
    """``clip.mp4``, a hard link ``hard.mp4`` and a symbolic link ``link.mp4`` to it."""
    clip = ctx.pan()
    os.link(clip, ctx.tmp / "hard.mp4")
    (ctx.tmp / "link.mp4").symlink_to("clip.mp4")


def clip_and_record(ctx: Ctx) -> None:
    """``clip.mp4`` and a record folder ``out`` (of another clip) it would be scored into."""
    ctx.pan()
    ctx.record("out")


def frame_folder(ctx: Ctx) -> None:
    write_pngs(ctx.tmp / "frames", frames_of("pan"))


def results_folder(ctx: Ctx) -> None:
    """A benchmark results folder ``res`` with its records and tables folders."""
    for part in ("clips", "tables"):
        (ctx.tmp / "res" / part).mkdir(parents=True)
    (ctx.tmp / "res" / "tables" / "clips.parquet").write_bytes(b"PAR1")


def clip_scored_to_rec(ctx: Ctx) -> None:
    """``clip.mp4`` and its record ``rec`` (scored here, so the record names this clip)."""
    ctx.pan()
    res = ctx.invoke(list(score("clip.mp4", out="rec")))
    assert res.code == 0, res.describe()


OUTPUTS = [
    Case("rrd-is-the-clip", lambda c: c.pan(), score("clip.mp4", "--rrd", "clip.mp4"), 2, ("--rrd", "clip")),
    Case("rrd-is-a-hard-link-of-the-clip", clip_and_links, score("clip.mp4", "--rrd", "hard.mp4"), 2, ("--rrd",)),
    Case("rrd-is-a-link-to-the-clip", clip_and_links, score("clip.mp4", "--rrd", "link.mp4"), 2, ("--rrd",)),
    Case("rrd-through-a-link-is-the-clip", clip_and_links, score("link.mp4", "--rrd", "clip.mp4"), 2, ("--rrd",)),
    Case(
        "rrd-is-the-records-json",
        clip_and_record,
        score("clip.mp4", "--rrd", "out/record.json"),
        2,
        ("--rrd", "record.json"),
    ),
    Case(
        "rrd-is-the-records-matches",
        clip_and_record,
        score("clip.mp4", "--rrd", "out/matches.npz"),
        2,
        ("--rrd", "matches.npz"),
    ),
    Case(
        "rrd-inside-the-records-overlays",
        clip_and_record,
        score("clip.mp4", "--rrd", "out/overlays/a.rrd"),
        2,
        ("--rrd", "overlays"),
    ),
    Case("out-is-the-frame-folder", frame_folder, score("frames", out="frames"), 2, ("--out", "frames")),
    Case("out-inside-the-frame-folder", frame_folder, score("frames", out="frames/rec"), 2, ("--out", "frames")),
    Case("rrd-inside-the-frame-folder", frame_folder, score("frames", "--rrd", "frames/a.rrd"), 2, ("--rrd",)),
    Case(
        "rrd-inside-the-masks",
        lambda c: c.c4(),
        score("c4.mp4", "--masks", "c4.masks", "--rrd", "c4.masks/a.rrd"),
        2,
        ("--rrd", "masks"),
    ),
    Case(
        "out-is-the-masks",
        lambda c: c.c4(),
        score("c4.mp4", "--masks", "c4.masks", out="c4.masks"),
        2,
        ("--out", "masks"),
    ),
    Case(
        "rrd-is-the-pose-log",
        pose("ok.json", log(IDENTITY)),
        score("clip.mp4", "--pose-log", "ok.json", "--rrd", "ok.json"),
        2,
        ("--rrd", "pose log"),
    ),
    Case(
        "view-save-is-the-records-json",
        clip_scored_to_rec,
        ("view", "rec", "--headless", "--save", "rec/record.json"),
        2,
        ("--save", "record.json"),
        needs=("rerun",),
    ),
    Case(
        "view-save-is-the-records-matches",
        clip_scored_to_rec,
        ("view", "rec", "--headless", "--save", "rec/matches.npz"),
        2,
        ("--save",),
        needs=("rerun",),
    ),
    Case(
        "view-save-is-the-clip",
        clip_scored_to_rec,
        ("view", "rec", "--headless", "--save", "clip.mp4"),
        2,
        ("--save", "clip"),
        needs=("rerun",),
    ),
    Case(
        "view-screenshot-is-the-records-json",
        clip_scored_to_rec,
        ("view", "rec", "--headless", "--screenshot", "rec/record.json"),
        2,
        ("--screenshot",),
        needs=("rerun",),
    ),
    Case("report-out-is-the-results", results_folder, ("report", "res", "--out", "res"), 2, ("--out", "res")),
    Case("report-out-holds-the-results", results_folder, ("report", "res", "--out", "."), 2, ("--out",)),
    Case("report-out-in-the-records", results_folder, ("report", "res", "--out", "res/clips"), 2, ("--out",)),
    Case("report-out-in-the-tables", results_folder, ("report", "res", "--out", "res/tables/r"), 2, ("--out",)),
    Case("synth-size-100000", nothing, ("synth", "C1", "--out", "s", "--size", "100000x100000"), 2, ("--size", "8192")),
    Case("bench-out-is-the-dataset", dataset, ("bench", "ds", "--out", "ds", *FAST, "--no-rrd"), 2, ("--out", "ds")),
]

# --- names that native libraries choke on ---------------------------------------------------------

LATIN1 = os.fsdecode(b"caf\xe9.mp4")
"""A file name that is not UTF-8 (a Latin-1 byte, as zip and old archives write them)."""
LONG = "l" * 247 + ".mp4"
"""A legal 251-byte file name."""


def named(name: str) -> Callable[[Ctx], None]:
    return lambda ctx: ctx.pan(name)


def scored_out(ctx: Ctx, _res: Outcome) -> None:
    assert record(ctx)["video"]["num_frames"] == N


NAMES = [
    Case("score-latin1-name", named(LATIN1), score(LATIN1), 0, check=scored_out, runner="subprocess"),
    Case("score-latin1-out", lambda c: c.pan(), score("clip.mp4", out=os.fsdecode(b"out/r\xe9s")), 0,
         runner="subprocess"),
    Case("score-latin1-rrd", lambda c: c.pan(), score("clip.mp4", "--rrd", os.fsdecode(b"out/\xe9.rrd")), 0,
         runner="subprocess", needs=("rerun",)),
    Case("synth-latin1-out", nothing, ("synth", "C1", "--out", os.fsdecode(b"out/s\xe9"), "--frames", "4",
         "--size", "64x48"), 0, runner="subprocess"),
    Case("score-251-byte-name", named(LONG), score(LONG), 0, check=scored_out),
    Case("score-251-byte-name-default-out", named(LONG), score(LONG, out=None), 0),
    Case("score-251-byte-rrd", lambda c: c.pan(), score("clip.mp4", "--rrd", "out/" + "r" * 247 + ".rrd"), 0,
         needs=("rerun",)),
    Case("score-latin1-missing", nothing, score(LATIN1), 2, ("caf",), runner="subprocess"),
]  # fmt: skip

# --- formats a phone or a generator writes --------------------------------------------------------


def encoded(name: str, codec: str, height: int = H, **options: object) -> Callable[[Ctx], None]:
    """``name``: the pan encoded with ``codec`` (interlaced coding needs a height divisible by 4)."""
    return lambda ctx: ctx.video(name, frames_of("pan", height=height), codec=codec, **options)  # type: ignore[arg-type]


def encoded_apart(name: str, codec: str, **options: object) -> Callable[[Ctx], None]:
    """``encoded``, in a process of its own: the SVT-AV1 encoder leaves state in the process that
    loads it (a later ``geocon bench`` started from that process spun in its workers' matrix
    products), so the test process never loads it."""

    def build(ctx: Ctx) -> None:
        frames = ctx.tmp / "frames.npy"
        np.save(frames, np.stack(frames_of("pan")))
        code = (
            "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from tests.bad_inputs import write_video; "
            f"write_video(sys.argv[2], list(np.load(sys.argv[3])), codec={codec!r}, **{options!r})"
        )
        root = str(Path(__file__).resolve().parents[1])
        subprocess.run([sys.executable, "-c", code, root, str(ctx.tmp / name), str(frames)], check=True,
                       capture_output=True, timeout=120)  # fmt: skip
        frames.unlink()

    return build


def animated(name: str) -> Callable[[Ctx], None]:
    return lambda ctx: write_animated(ctx.tmp / name, frames_of("pan"))


def decoded_by(note: str | None) -> Callable[[Ctx, Outcome], None]:
    """A check: every frame scored, the pan found consistent, the decoder named in the warnings."""

    def check(ctx: Ctx, _res: Outcome) -> None:
        rec = record(ctx)
        assert rec["video"]["num_frames"] == N, rec["video"]
        assert rec["summary"]["verdict"]["verdict"] == "consistent", rec["summary"]["verdict"]
        named = [w for w in rec["warnings"] if note is not None and note in w]
        assert bool(named) == (note is not None), rec["warnings"]

    return check


INTERLACED = {"x264-params": "interlaced=1"}
FORMATS = [
    Case("av1-mp4", encoded_apart("c.mp4", "libsvtav1"), score("c.mp4"), 0, check=decoded_by("PyAV")),
    Case("av1-webm", encoded_apart("c.webm", "libsvtav1", container="webm"), score("c.webm"), 0,
         check=decoded_by("PyAV")),
    Case("vp9-webm", encoded("c.webm", "libvpx-vp9", container="webm"), score("c.webm"), 0, check=decoded_by(None)),
    Case("h264-10bit", encoded("c.mp4", "libx264", pix_fmt="yuv420p10le"), score("c.mp4"), 0, check=decoded_by(None)),
    Case("h264-interlaced", encoded("c.mp4", "libx264", 96, extra=INTERLACED), score("c.mp4"), 0,
         check=decoded_by("interlaced")),
    Case("mpeg2-interlaced", encoded("c.mpg", "mpeg2video", 96, container="mpeg", extra={"flags": "+ilme+ildct"}),
         score("c.mpg"), 0, check=decoded_by("interlaced")),
    Case("apng", animated("c.png"), score("c.png"), 0, check=decoded_by("Pillow")),
    Case("apng-suffix", animated("c.apng"), score("c.apng"), 0, check=decoded_by("Pillow")),
    Case("animated-webp", animated("c.webp"), score("c.webp"), 0, check=decoded_by("Pillow")),
    Case("still-webp", lambda c: c.write("s.webp", b"RIFF\x00\x00\x00\x00WEBPVP8 "), score("s.webp"), 2, ("s.webp",)),
]  # fmt: skip

# --- records know their clip ----------------------------------------------------------------------


def project_moved(ctx: Ctx) -> None:
    """``p/videos/a.mp4`` scored into ``p/recs/a`` from inside ``p``, then ``p`` renamed ``q``."""
    ctx.pan("p/videos/a.mp4")
    os.chdir(ctx.tmp / "p")
    try:
        res = ctx.invoke(list(score("videos/a.mp4", out="recs/a")))
    finally:
        os.chdir(ctx.tmp)
    assert res.code == 0, res.describe()
    (ctx.tmp / "p").rename(ctx.tmp / "q")


def clip_replaced(ctx: Ctx) -> None:
    project_moved(ctx)
    ctx.video("q/videos/a.mp4", frames_of("noise"))


def clip_gone(ctx: Ctx) -> None:
    project_moved(ctx)
    (ctx.tmp / "q" / "videos" / "a.mp4").unlink()


def found_quietly(_ctx: Ctx, res: Outcome) -> None:
    assert "warning" not in res.stderr, res.stderr


def warned_gone(_ctx: Ctx, res: Outcome) -> None:
    assert "warning: the clip of this record is gone" in res.stderr, res.stderr


CLIP_IDENTITY = [
    Case("view-record-moved-with-its-clip", project_moved, ("view", "q/recs/a", "--headless"), 0, check=found_quietly,
         needs=("rerun",)),
    Case("view-clip-replaced-by-another", clip_replaced, ("view", "q/recs/a", "--headless"), 2, ("not the clip",),
         needs=("rerun",)),
    Case("view-clip-gone", clip_gone, ("view", "q/recs/a", "--headless"), 0, check=warned_gone, needs=("rerun",)),
]  # fmt: skip

CASES = CLIPS + MASKS + POSES + OPTIONS + OUTPUTS + NAMES + FORMATS + CLIP_IDENTITY


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"
    assert len(CASES) >= 60


@pytest.fixture()
def ctx(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, assets: Assets) -> Ctx:
    """The case's folder as the current directory, with OpenCV's frame reads counted."""
    monkeypatch.chdir(tmp_path)
    context = Ctx(tmp_path, assets)

    real = cv2.VideoCapture

    class CountingCapture:
        """An OpenCV capture that counts the frames read (a wrapper: OpenCV's classes do not
        subclass safely)."""

        def __init__(self, *args: object) -> None:
            self._cap = real(*args)

        def read(self, *args: object):
            context.frames_read += 1
            return self._cap.read(*args)

        def __getattr__(self, name: str):
            return getattr(self._cap, name)

    monkeypatch.setattr(cv2, "VideoCapture", CountingCapture)
    return context


def run_case(case: Case, ctx: Ctx, judged_by: Callable[..., list[str]] | None = None) -> Outcome:
    """Build ``case`` in its folder, run it and assert every requirement (:func:`judge`, or
    ``judged_by`` with the same arguments); the catalogue files of each area run their tables
    through this."""
    for module in case.needs:
        pytest.importorskip(module)
    case.build(ctx)
    ctx.frames_read = 0
    before = snapshot(ctx.tmp)
    res = ctx.invoke(list(case.argv)) if case.runner == "cli" else ctx.spawn(list(case.argv))
    problems = (judged_by or judge)(case, ctx, res, before)
    assert not problems, f"{case.name}: {res.describe()}\n  - " + "\n  - ".join(problems)
    return res


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input(case: Case, ctx: Ctx):
    run_case(case, ctx)


OUTPUT_FOLDERS = ("out/", "full-out/", "geocon-out/")
"""Where the cases' valid runs write (everything else in the working folder is input)."""


def judge(case: Case, ctx: Ctx, res: Outcome, before: dict[str, str]) -> list[str]:
    """Every way ``res`` departs from what ``case`` requires (empty when it is right)."""
    problems = []
    if res.exception is not None:
        problems.append(f"uncaught {type(res.exception).__name__}: {res.exception}")
    if "Traceback" in res.stderr or "Traceback" in res.stdout:
        tail = (res.stderr if "Traceback" in res.stderr else res.stdout).strip().splitlines()[-6:]
        problems.append("a traceback was printed, ending: " + " | ".join(tail))
    if res.code not in case.codes():
        problems.append(f"exit code {res.code}, expected {' or '.join(map(str, case.codes()))}")
    after = snapshot(ctx.tmp)
    changed = sorted(p for p in before if after.get(p) != before[p])
    if res.code == 2:
        lines = [line for line in res.stderr.splitlines() if line.strip()]
        if len(lines) != 1 or not lines[0].startswith("error: "):
            problems.append(f"stderr is not one line 'error: ...': {res.stderr!r}")
        sentence = next((line for line in lines if line.startswith("error: ")), "")
        problems += [f"the sentence should name {word!r}" for word in case.says if word not in sentence]
        problems += [f"the sentence should not say {word!r}" for word in case.forbids if word in sentence]
        if changed:
            problems.append(f"a failed run changed or removed {changed}")
        added = sorted(set(after) - set(before))
        if added:
            problems.append(f"a failed run left {added}")
    elif res.code == 0:
        if "error:" in res.stderr:
            problems.append(f"a valid run printed an error: {res.stderr!r}")
        inputs = [p for p in changed if not p.startswith(OUTPUT_FOLDERS)]
        if inputs:
            problems.append(f"a valid run changed or removed its inputs {inputs}")
    if case.runner == "subprocess" and case.argv[0] == "serve" and res.seconds >= SERVE_LIMIT_S:
        problems.append(f"took {res.seconds:.1f} s (at most {SERVE_LIMIT_S:g} s)")
    if case.check is not None and res.code in case.codes():
        try:
            case.check(ctx, res)
        except (AssertionError, OSError, ValueError, KeyError) as exc:
            problems.append(f"check {case.check.__name__}: {type(exc).__name__}: {exc}")
    return problems


def test_a_negative_report_seed_is_refused_before_any_work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    results_folder(Ctx(tmp_path, None))  # type: ignore[arg-type]
    before = snapshot(tmp_path)
    res = CliRunner().invoke(app, ["report", "res", "--seed", "-1"])
    assert res.exit_code == 2 and "--seed" in res.output
    assert snapshot(tmp_path) == before  # nothing read into a report, nothing written


@pytest.mark.parametrize("option", [("--fps", "1e308"), ("--fps", "nan"), ("--seed", "-1"), ("--frames", "1")])
def test_absurd_synth_options_are_refused_before_anything_is_written(tmp_path, monkeypatch, option):
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(app, ["synth", "C1", "--out", "s", *option])
    assert res.exit_code == 2 and option[0] in res.output and not (tmp_path / "s").exists()
