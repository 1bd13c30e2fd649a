"""Fuzzed inputs: bytes of a small valid MP4, GIF, PNG frame, masks ``.npz`` and pose log are
flipped, truncated, inserted, deleted and overwritten, and each mutant goes through the cheapest
entry point that still parses it. Every mutant must give a valid result or a clear error (a
``ValueError`` whose message names the file), never another exception, a ``ValueError`` from
inside numpy or OpenCV without the file's name, or a hang.

The examples are derandomized (the same mutants on every run). Each test runs all its examples,
collects the distinct failures (by exception type and message, numbers masked) with the first
mutation that gave each, and fails once with the whole list, so one run shows every kind of
failure rather than the first. 860 mutants in all (the counts passed to each test below); raise
them for a longer hunt."""

from __future__ import annotations

import io
import json
import re
import shutil
import threading
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from geocon_core.masks import ExternalMasks
from geocon_core.media import iter_frames, probe_clip
from geocon_core.pose import load_pose_log

from .bad_inputs import POSITIONS, mutate, pan_frames, write_gif, write_palette_png, write_pngs, write_video
from .conftest import clip_info

TIME_LIMIT_S = 30.0
"""A mutant still being parsed after this long hangs. Not a speed limit: OpenCV's PNG decoder
spends 3-4 s refusing some damaged 8 kB PNGs on this machine (more when the machine is busy)."""
DECODED_FRAMES = 3
"""Frames decoded after a successful probe (the probe itself decodes them all)."""

BINARY_PAYLOADS = (
    b"\x00\x00\x00\x00",
    b"\xff\xff\xff\xff",
    b"\x7f\xff\xff\xff",
    b"\x80\x00\x00\x00",
    b"\x00\x00\x00\x01",
    b"moov",
    b"mdat",
    b"IHDR",
    b"IEND",
    b"PK\x03\x04",
)
"""Payloads that break binary parsers more often than random bytes: sizes (zero, huge, negative
as int32, one) and the names of MP4 boxes, PNG chunks and ZIP records."""
TEXT_PAYLOADS = (
    "1e308",
    "-1e308",
    "1e-320",
    "NaN",
    "Infinity",
    "-0",
    "99999999999999999999",
    "[[[[[[[[[[",
    "{}",
    "null",
    "true",
    '"',
    "\\u0000",
    "'<f8'",
    "'|O'",
    "(999999999, 999999999, 3)",
    "'fortran_order': True",
)
"""Text that breaks JSON and .npy headers: huge, tiny and non-finite numbers, nesting, a lone
quote, escapes, dtypes (an object dtype needs pickle), a huge shape."""


def mutations(payload: st.SearchStrategy[bytes]) -> st.SearchStrategy[list]:
    """1-4 mutations for :func:`~tests.bad_inputs.mutate`, positions spread over the file."""
    op = st.tuples(
        st.sampled_from(("flip", "truncate", "insert", "overwrite", "delete", "zero", "repeat")),
        st.integers(0, POSITIONS),
        st.integers(0, 1 << 16),
        payload,
    )
    return st.lists(op, min_size=1, max_size=4)


BINARY = mutations(st.one_of(st.sampled_from(BINARY_PAYLOADS), st.binary(min_size=1, max_size=32)))
TEXT = mutations(
    st.one_of(
        st.sampled_from(TEXT_PAYLOADS),
        st.text(alphabet="0123456789.-+eE[]{},:\" ntrufalsNI\\'()", min_size=1, max_size=12),
    ).map(lambda t: t.encode("utf-8"))
    | st.binary(min_size=1, max_size=8)
)


def fuzz_settings(max_examples: int) -> settings:
    return settings(
        max_examples=max_examples,
        derandomize=True,
        database=None,
        deadline=None,
        phases=(Phase.explicit, Phase.generate),
        suppress_health_check=list(HealthCheck),
    )


def within_time(fn: Callable[[], object]) -> tuple[str, BaseException | None]:
    """Run ``fn`` in a thread for at most :data:`TIME_LIMIT_S`: ``("ok" | "raised" | "hang", exc)``."""
    caught: list[BaseException] = []

    def target() -> None:
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - every exception is judged by the caller
            caught.append(exc)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(TIME_LIMIT_S)
    if thread.is_alive():
        return "hang", None
    return ("raised", caught[0]) if caught else ("ok", None)


def judge(fn: Callable[[], object], names: tuple[str, ...]) -> str | None:
    """None when ``fn`` returned or raised a clear error naming one of ``names``; else the problem."""
    status, exc = within_time(fn)
    if status == "hang":
        return f"hang: still running after {TIME_LIMIT_S:g} s"
    if exc is None:
        return None
    message = str(exc)
    if isinstance(exc, ValueError) and any(name in message for name in names):
        return None
    why = "ValueError without the file's name" if isinstance(exc, ValueError) else "not a ValueError"
    return f"{why}: {type(exc).__name__}: {message[:300]} (raised at {_origin(exc)})"


def _origin(exc: BaseException) -> str:
    """``module.py:line`` of the innermost frame of ``exc``'s traceback."""
    tb = exc.__traceback__
    if tb is None:
        return "?"
    while tb.tb_next is not None:
        tb = tb.tb_next
    return f"{Path(tb.tb_frame.f_code.co_filename).name}:{tb.tb_lineno}"


class Fuzzer:
    """Runs mutants through one entry point and collects the distinct failures."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.count = 0
        self.failures: dict[str, str] = {}

    def record(self, problem: str | None, ops: list) -> None:
        self.count += 1
        if problem is None:
            return
        key = re.sub(r"\d+", "#", re.sub(r"/\S+", "<path>", problem))[:160]
        self.failures.setdefault(key, f"{problem}\n      mutations: {ops!r}")

    def check(self, what: str, max_examples: int) -> None:
        assert self.count >= max_examples * 0.9, f"{what}: only {self.count} mutants ran"
        assert not self.failures, (
            f"{what}: {len(self.failures)} kinds of failure in {self.count} mutants:\n"
            + "\n".join(f"  - {text}" for text in self.failures.values())
        )


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The valid inputs that are mutated (clips: 64x48, 6 frames; masks: 32x24, 4 frames)."""
    root = tmp_path_factory.mktemp("fuzz-seeds")
    frames = pan_frames(64, 48, 6, seed=7)
    found = {
        "mp4": write_video(root / "seed.mp4", frames),
        "faststart": write_video(root / "faststart.mp4", frames, faststart=True),
        "gif": write_gif(root / "seed.gif", frames),
        "png": write_pngs(root / "frames", frames[:3]),
    }
    labels = np.zeros((4, 24, 32), np.uint8)
    labels[:, 4:12, 4:14] = 1
    labels[:, 14:22, 18:30] = 2
    np.savez(root / "seed.npz", labels=labels)
    found["npz"] = root / "seed.npz"
    (root / "davis").mkdir()
    for t, lab in enumerate(labels):
        write_palette_png(root / "davis" / f"{t:05d}.png", lab * 3)
    found["davis"] = root / "davis"
    c, s = np.cos(0.1), np.sin(0.1)
    pose = {
        "format": "geocon-pose/1",
        "T_cam0_camT": [[c, 0, s, 0.06], [0, 1, 0, 0], [-s, 0, c, 0.01], [0, 0, 0, 1]],
        "scale": "metric",
        "mean_scene_distance": 3.7,
        "pose_present": True,
        "source": "dust3r ViTLarge_512",
    }
    (root / "seed.json").write_text(json.dumps(pose))
    found["json"] = root / "seed.json"
    return found


MASKS_INFO = clip_info(source_size=(32, 24), working_size=(32, 24), content_box=(0, 0, 32, 24), num_frames=4)


def read_clip(path: Path) -> None:
    """Probe a clip and decode its first frames (the reader's two passes)."""
    info = probe_clip(path)
    frames = iter_frames(info)
    try:
        for _, frame in zip(range(DECODED_FRAMES), frames, strict=False):
            assert frame.rgb.shape[:2] == info.working_size[::-1]
    finally:
        frames.close()


def read_masks(path: Path) -> None:
    masks = ExternalMasks(path, MASKS_INFO)
    masks.labels(0)
    masks.labels(MASKS_INFO.num_frames - 1)


def test_the_seeds_are_valid(seeds):
    read_clip(seeds["mp4"])
    read_clip(seeds["faststart"])
    read_clip(seeds["gif"])
    read_clip(seeds["png"])
    read_masks(seeds["npz"])
    read_masks(seeds["davis"])
    assert load_pose_log(seeds["json"]).pose_present


def fuzz_file(
    data: bytes,
    suffix: str,
    entry: Callable[[Path], object],
    folder: Path,
    max_examples: int,
    ops_strategy: st.SearchStrategy[list] = BINARY,
    pack: Callable[[bytes], bytes] = lambda b: b,
) -> None:
    """Mutate ``data`` ``max_examples`` times; each mutant, ``pack``-ed, is written to
    ``mutantNNNN<suffix>`` and goes through ``entry``."""
    fuzzer = Fuzzer(folder)

    @fuzz_settings(max_examples)
    @given(ops=ops_strategy)
    def run(ops: list) -> None:
        path = folder / f"mutant{fuzzer.count:04d}{suffix}"
        path.write_bytes(pack(mutate(data, ops)))
        fuzzer.record(judge(lambda: entry(path), (str(path), path.name)), ops)
        path.unlink(missing_ok=True)

    run()
    fuzzer.check(f"{suffix} mutants", max_examples)


def test_mutated_mp4(seeds, tmp_path):
    """An MP4 with its index (``moov``) at the end: most truncations lose it."""
    fuzz_file(seeds["mp4"].read_bytes(), ".mp4", read_clip, tmp_path, 100)


def test_mutated_faststart_mp4(seeds, tmp_path):
    """An MP4 with its index first: truncations and damage reach the decoder."""
    fuzz_file(seeds["faststart"].read_bytes(), ".mp4", read_clip, tmp_path, 100)


def test_mutated_gif(seeds, tmp_path):
    fuzz_file(seeds["gif"].read_bytes(), ".gif", read_clip, tmp_path, 100)


def test_mutated_masks_npz(seeds, tmp_path):
    """The .npz file's bytes (ZIP records, CRCs, the stored array)."""
    fuzz_file(seeds["npz"].read_bytes(), ".npz", read_masks, tmp_path, 80)


def _zip_npy(npy: bytes) -> bytes:
    """An .npz (a valid ZIP) holding ``npy`` as ``labels.npy``."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        z.writestr("labels.npy", npy)
    return buf.getvalue()


def test_mutated_npy_inside_masks_npz(seeds, tmp_path):
    """The array ``labels.npy`` mutated (header: magic, dtype, shape, order; then the data) and
    stored in a valid ZIP, so the mutants reach numpy's .npy parser."""
    with zipfile.ZipFile(seeds["npz"]) as z:
        npy = z.read("labels.npy")
    fuzz_file(npy[:160], ".npz", read_masks, tmp_path, 120, TEXT, pack=lambda head: _zip_npy(head + npy[160:]))


def test_mutated_pose_log(seeds, tmp_path):
    fuzz_file(seeds["json"].read_bytes(), ".json", load_pose_log, tmp_path, 200, TEXT)


def fuzz_folder_frame(
    folder: Path, name: str, reader: Callable[[Path], object], tmp_path: Path, n: int, what: str
) -> None:
    """``n`` copies of ``folder`` whose file ``name`` is mutated, each read by ``reader``; the
    error may name the folder or the file."""
    fuzzer = Fuzzer(tmp_path)
    data = (folder / name).read_bytes()

    @fuzz_settings(n)
    @given(ops=BINARY)
    def run(ops: list) -> None:
        copy = tmp_path / f"{folder.name}{fuzzer.count:04d}"
        shutil.copytree(folder, copy)
        (copy / name).write_bytes(mutate(data, ops))
        fuzzer.record(judge(lambda: reader(copy), (str(copy), copy.name)), ops)
        shutil.rmtree(copy, ignore_errors=True)

    run()
    fuzzer.check(what, n)


def test_mutated_png_frame(seeds, tmp_path):
    """Frame 1 of a 3-frame PNG folder mutated."""
    fuzz_folder_frame(seeds["png"], "00001.png", read_clip, tmp_path, 80, "PNG frame mutants")


def test_mutated_palette_mask_png(seeds, tmp_path):
    """Frame 0 of a DAVIS-layout masks folder (indexed PNGs, read through PyAV) mutated."""
    fuzz_folder_frame(seeds["davis"], "00000.png", read_masks, tmp_path, 80, "palette mask PNG mutants")


# --- file names and container flags ---------------------------------------------------------------

NAME_BYTES = st.binary(min_size=1, max_size=250).map(lambda b: bytes(c for c in b if c not in (0, 47)) or b"x")
"""Any byte but NUL and '/', 1 to 250 bytes: every name a Linux file system holds (255-byte limit
with the suffix), including names that are not UTF-8, start with '-' or '.', or hold newlines."""


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=NAME_BYTES, suffix=st.sampled_from([".mp4", ".gif", ".MP4", ""]))
def test_any_file_name_is_read_or_refused_in_one_sentence(seeds, tmp_path, raw, suffix):
    """Every legal file name reaches the decoders safely: the clip reads the same as under a plain
    name (a name with no suffix too), its fingerprint is found again, and an image written under a
    name of the same bytes reads back."""
    import os

    from geocon_core.media import clip_fingerprint, imread_any, imwrite_any, locate_clip

    name = os.fsdecode(raw[: 250 - len(suffix)]) + suffix
    if name in (".", ".."):
        return
    src = seeds["mp4"] if suffix.lower() != ".gif" else seeds["gif"]
    folder = tmp_path / "names"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    clip = folder / name
    shutil.copyfile(src, clip)
    info = probe_clip(clip)
    plain = probe_clip(src)
    assert (info.num_frames, info.source_size, info.cuts) == (plain.num_frames, plain.source_size, plain.cuts)
    frames = [f.rgb for f in iter_frames(info)]
    assert all(np.array_equal(a.rgb, b) for a, b in zip(iter_frames(plain), frames, strict=True))
    assert info.fingerprint == clip_fingerprint(src) and locate_clip(info, tmp_path / "rec").path == str(clip)
    png = folder / (name[:200] + ".png")
    assert imwrite_any(png, frames[0][..., ::-1]) and np.array_equal(imread_any(png)[..., ::-1], frames[0])


@settings(max_examples=12, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    container=st.sampled_from(["mp4", "mov", "matroska", "avi"]),
    faststart=st.booleans(),
    intra=st.booleans(),
    fps=st.sampled_from([1, 8, 24, 60, 240]),
)
def test_container_flags_read_the_same_frames(tmp_path, container, faststart, intra, fps):
    """One clip written with each container, ``movflags``, key-frame layout and frame rate decodes
    to the same number of frames and size, with the frame rate the container states."""
    suffix = {"matroska": ".mkv"}.get(container, f".{container}")
    path = write_video(tmp_path / f"c{suffix}", pan_frames(96, 64, 6, seed=4), container=container,
                       faststart=faststart and container in ("mp4", "mov"), intra=intra, fps=fps)  # fmt: skip
    info = probe_clip(path)
    assert (info.num_frames, info.source_size) == (6, (96, 64))
    assert abs(info.fps - fps) < 0.01 * fps
