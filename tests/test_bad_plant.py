"""The plant catalogue: sources a phone or a screen recorder writes, planted with ``geocon plant``.

A clip whose display matrix turns its stored frames (a phone held upright) is planted upright, as
``geocon score`` reads it (OpenCV turns its frames by the matrix): the planted and the clean clip
are written upright with no matrix, and the ground truth says the source was turned and by how
much; a matrix that mirrors the picture or turns it by another angle is refused in one sentence. A
clip of variable frame rate (or of a steady rate other than the one written) is re-timed to a
constant rate, which a warning and the ground truth's ``source.timing`` say.

The cases use the framework of :mod:`tests.test_bad_input` (a :class:`Case` per command line,
judged by :func:`judge`: a refusal is exit 2 with one ``error:`` line and nothing changed or left
behind; a valid run changes no input). The clips are encoded here with PyAV, single-threaded, the
display matrix written as the container's side data (``set_display_rotation``)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.media import display_turn, frame_timing, timing_note
from geocon_core.plant import probe_source
from geocon_core.plant.encode import decode_planes

from .bad_inputs import pan_frames
from .test_bad_input import Case, Ctx, Outcome, assets, ctx, record, run_case, score  # noqa: F401

W, H, N = 160, 96, 12
"""Size (stored, before any turn) and length of the clips planted here."""
VFR_MS = (0, 30, 50, 120, 130, 200, 260, 270, 300, 400, 410, 500)
"""Presentation times (ms) of a clip of variable frame rate: 10 to 100 ms apart."""
SLOWING_MS = (0, 33, 66, 100, 500, 533, 566, 600, 633, 1500, 1533, 1566)
"""A clip that pauses twice (a screen recorder writes a frame only when the picture changes)."""
UPRIGHT_MAD = 4.0
"""The clean clip's mean absolute difference (grey levels) from the source read upright stays
under this: the re-encode's loss (1.5-1.8 measured), far from a turned or mirrored picture."""


def write_turned(
    path: Path,
    frames: Sequence[np.ndarray],
    degrees: float | None = None,
    *,
    hflip: bool = False,
    container: str | None = None,
    pix_fmt: str = "yuv420p",
    pts_ms: Sequence[int] | None = None,
    tag: str | None = None,
    rate: Fraction = Fraction(24),
) -> Path:
    """Encode RGB ``frames`` with libx264 (single-threaded), with a display matrix turning them
    ``degrees`` counter-clockwise (and mirrored, ``hflip``) when given, each frame at ``pts_ms``
    when given, and a ``rotate`` metadata tag ``tag`` (no matrix) when given; the stream states ``rate``."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    with av.open(str(path), mode="w", format=container) as c:
        stream = c.add_stream("libx264", rate=rate, options={"preset": "ultrafast"})
        stream.width, stream.height, stream.pix_fmt = w, h, pix_fmt
        stream.thread_count = 1
        if degrees is not None:
            stream.set_display_rotation(degrees, hflip=hflip)
        if tag is not None:
            stream.metadata["rotate"] = tag
        if pts_ms is not None:
            stream.codec_context.time_base = Fraction(1, 1000)
            stream.time_base = Fraction(1, 1000)
        for t, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            if pts_ms is not None:
                frame.pts, frame.time_base = int(pts_ms[t]), Fraction(1, 1000)
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def frames() -> list[np.ndarray]:
    return pan_frames(W, H, N, seed=1)


def turned(name: str, degrees: float | None, **options) -> Callable[[Ctx], None]:
    return lambda c: write_turned(c.tmp / name, frames(), degrees, **options)


def plant(clip: str, *more: str, failure: str = "slide") -> tuple[str, ...]:
    """``plant CLIP --failure FAILURE --severity low --out out MORE``."""
    return ("plant", clip, "--failure", failure, "--severity", "low", "--out", "out", *more)


def read_bgr(path: Path) -> np.ndarray:
    """(T, h, w, 3) int16: every frame as OpenCV reads it, turned upright by its display matrix (the
    reader ``geocon score`` uses)."""
    cap = cv2.VideoCapture(str(path))
    out = []
    ok, frame = cap.read()
    while ok:
        out.append(frame.astype(np.int16))
        ok, frame = cap.read()
    cap.release()
    assert out, f"OpenCV decodes no frame of {path}"
    return np.stack(out)


def truth_of(c: Ctx, clip: str, failure: str = "slide") -> dict:
    (gt,) = (c.tmp / "out").glob(f"{Path(clip).stem}.{failure}-low-s0.gt.json")
    return json.loads(gt.read_text(encoding="utf-8"))


def warnings_of(res: Outcome) -> list[str]:
    return [line for line in res.stderr.splitlines() if line.startswith("warning: ")]


# --- checks ---------------------------------------------------------------------------------------


def upright(clip: str, degrees: int, frames_used: int = N, failure: str = "slide") -> Callable[[Ctx, Outcome], None]:
    """The planted and the clean clip hold the source's frames upright (as OpenCV reads the source)
    and carry no display matrix; the ground truth says the source was turned ``degrees``."""

    def check(c: Ctx, res: Outcome) -> None:
        import av

        stem = Path(clip).stem
        source = read_bgr(c.tmp / clip)[:frames_used]
        clean = read_bgr(c.tmp / "out" / f"{stem}.clean.mp4")
        planted = read_bgr(c.tmp / "out" / f"{stem}.{failure}-low-s0.mp4")
        assert clean.shape == source.shape == planted.shape, (clean.shape, source.shape)
        mad = float(np.abs(clean - source).mean())
        assert mad < UPRIGHT_MAD, f"the clean clip is not the source read upright (mean difference {mad:.1f})"
        assert np.abs(planted - clean).max() > 0, "nothing was planted"
        for name in (f"{stem}.clean.mp4", f"{stem}.{failure}-low-s0.mp4"):
            with av.open(str(c.tmp / "out" / name)) as written:
                assert display_turn(next(written.decode(video=0))) is None, f"{name} carries a display matrix"
        truth = truth_of(c, clip, failure)
        h, w = source.shape[1:3]
        stored = [w, h] if degrees % 180 == 0 else [h, w]
        assert truth["source"]["size"] == [w, h] and truth["size"] == [w, h], truth["source"]
        assert truth["source"]["display_rotation"]["degrees"] == degrees, truth["source"]
        assert truth["source"]["display_rotation"]["stored_size"] == stored, truth["source"]
        if degrees:
            assert f"turns its {stored[0]}x{stored[1]} frames {degrees} degrees" in res.stdout, res.stdout

    return check


def json_says(**expected: object) -> Callable[[Ctx, Outcome], None]:
    """``--json``'s stdout is one JSON object holding ``expected``."""

    def check(_c: Ctx, res: Outcome) -> None:
        summary = json.loads(res.stdout)
        for key, want in expected.items():
            assert summary[key] == want, f"{key} = {summary[key]!r}, expected {want!r}"

    return check


def retimed(clip: str, source: str, written: str, *words: str) -> Callable[[Ctx, Outcome], None]:
    """One warning on stderr that the clip is re-timed (naming it and ``words``), and the ground
    truth's ``source.timing``: the source's timing ``source``, the rate ``written``, re-timed."""

    def check(c: Ctx, res: Outcome) -> None:
        said = warnings_of(res)
        assert len(said) == 1, res.stderr
        for word in (clip, "re-timed to a constant", *words):
            assert word in said[0], said[0]
        timing = truth_of(c, clip)["source"]["timing"]
        assert timing["source"] == source and timing["retimed"] is True, timing
        assert timing["written"] == f"constant {written} frames/s", timing

    return check


def not_retimed(clip: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, res: Outcome) -> None:
        assert not warnings_of(res), res.stderr
        timing = truth_of(c, clip)["source"]["timing"]
        assert timing["source"] == "constant" and timing["retimed"] is False, timing

    return check


def all_of(*checks: Callable[[Ctx, Outcome], None]) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, res: Outcome) -> None:
        for one in checks:
            one(c, res)

    return check


def mkv_at(c: Ctx, name: str, step_ms: int) -> None:
    """A Matroska clip that states 24 frames/s but stamps its frames ``step_ms`` apart."""
    write_turned(c.tmp / name, frames(), container="matroska", pts_ms=[step_ms * t for t in range(N)])


def ntsc(rate: Fraction) -> Callable[[Ctx], None]:
    """A Matroska clip whose frames are 1001/30 ms apart in millisecond stamps, stating ``rate``."""
    stamps = [round(t * 1001 / 30) for t in range(N)]
    return lambda c: write_turned(c.tmp / "ntsc.mkv", frames(), container="matroska", pts_ms=stamps, rate=rate)


def later_variable(c: Ctx) -> None:
    """Steady for 6 frames (40 ms apart), then 1 s between frames."""
    write_turned(c.tmp / "late.mp4", frames(), pts_ms=[40 * t if t < 6 else 200 + 1000 * (t - 5) for t in range(N)])


# --- the catalogue --------------------------------------------------------------------------------

TURNS = [
    Case("plant-turned-90-is-planted-upright", turned("p90.mp4", 90), plant("p90.mp4"), 0,
         check=upright("p90.mp4", 90)),
    Case("plant-turned-270-is-planted-upright", turned("p270.mp4", -90), plant("p270.mp4"), 0,
         check=upright("p270.mp4", 270)),
    Case("plant-turned-180-is-planted-upright", turned("p180.mp4", 180), plant("p180.mp4"), 0,
         check=upright("p180.mp4", 180)),
    Case("plant-turned-90-in-matroska", turned("p90.mkv", 90, container="matroska"), plant("p90.mkv"), 0,
         check=upright("p90.mkv", 90)),
    Case("plant-turned-90-morph", turned("m90.mp4", 90), plant("m90.mp4", failure="morph"), 0,
         check=upright("m90.mp4", 90, failure="morph")),
    Case("plant-turned-90-first-frames", turned("f90.mp4", 90), plant("f90.mp4", "--frames", "5"), 0,
         check=upright("f90.mp4", 90, frames_used=5)),
    Case("plant-turned-90-4-2-2-is-written-in-4-4-4", turned("y422.mp4", 90, pix_fmt="yuv422p"), plant("y422.mp4"), 0,
         check=all_of(upright("y422.mp4", 90),
                      lambda c, _r: _assert_equal(truth_of(c, "y422.mp4")["encoding"]["pix_fmt"], "yuv444p"))),
    Case("plant-turned-90-json-names-the-turn", turned("j90.mp4", 90), plant("j90.mp4", "--json"), 0,
         check=json_says(display_rotation=90, warnings=[])),
    Case("plant-unturned-is-planted-as-stored", turned("flat.mp4", None), plant("flat.mp4"), 0,
         check=upright("flat.mp4", 0)),
    Case("plant-rotate-tag-without-a-matrix-as-score-reads-it", turned("tag.mkv", None, container="matroska", tag="90"),
         plant("tag.mkv"), 0, check=upright("tag.mkv", 0)),
    Case("plant-mirrored-matrix-is-refused", turned("mirror.mp4", 0, hflip=True), plant("mirror.mp4"), 2,
         ("mirror.mp4", "mirrors the picture", "re-encode it upright")),
    Case("plant-mirrored-and-turned-matrix-is-refused", turned("mt.mp4", 90, hflip=True), plant("mt.mp4"), 2,
         ("mt.mp4", "mirrors the picture", "90 degrees")),
    Case("plant-matrix-turned-45-degrees-is-refused", turned("r45.mp4", 45), plant("r45.mp4"), 2,
         ("r45.mp4", "45 degrees", "not a multiple of 90")),
    Case("plant-mirrored-refusal-names-no-output", turned("m.mp4", 180, hflip=True), plant("m.mp4", "--json"), 2,
         ("m.mp4", "mirrors"), forbids=("out/",)),
]  # fmt: skip

TIMING = [
    Case("plant-variable-rate-mp4-says-it-re-times", turned("vfr.mp4", None, pts_ms=VFR_MS), plant("vfr.mp4"), 0,
         check=retimed("vfr.mp4", "variable", "64000/2889", "variable frame rate", "10 to 100 ms apart")),
    Case("plant-slowing-matroska-says-it-re-times", turned("slow.mkv", None, container="matroska", pts_ms=SLOWING_MS),
         plant("slow.mkv"), 0, check=retimed("slow.mkv", "variable", "24", "33 to 867 ms apart", "24 frames/s")),
    Case("plant-steady-rate-other-than-stated-says-it-re-times", lambda c: mkv_at(c, "at25.mkv", 40),
         plant("at25.mkv"), 0, check=retimed("at25.mkv", "constant", "24", "its frames 40 ms apart", "25 frames/s")),
    Case("plant-steady-then-variable-first-frames-says-it-re-times", later_variable, plant("late.mp4", "--frames", "6"),
         0, check=retimed("late.mp4", "constant", "64000/33289", "its frames 40 ms apart", "1.923 frames/s")),
    Case("plant-constant-rate-says-nothing", turned("cfr.mp4", None), plant("cfr.mp4"), 0,
         check=not_retimed("cfr.mp4")),
    Case("plant-constant-rate-matroska-says-nothing", turned("at24.mkv", None, container="matroska"),
         plant("at24.mkv"), 0, check=not_retimed("at24.mkv")),
    Case("plant-29.97-in-millisecond-stamps-says-nothing", ntsc(Fraction(30000, 1001)), plant("ntsc.mkv"), 0,
         check=not_retimed("ntsc.mkv")),
    Case("plant-29.97-stamped-24-stated-says-it-re-times", ntsc(Fraction(24)), plant("ntsc.mkv"), 0,
         check=retimed("ntsc.mkv", "constant", "24", "33.4 ms apart", "29.97 frames/s")),
    Case("plant-variable-rate-json-keeps-stdout-json", turned("vj.mp4", None, pts_ms=VFR_MS), plant("vj.mp4", "--json"),
         0, check=lambda c, r: _json_retimed(r)),
    Case("plant-variable-rate-and-turned", turned("vt.mp4", 90, pts_ms=VFR_MS), plant("vt.mp4"), 0,
         check=all_of(upright("vt.mp4", 90), retimed("vt.mp4", "variable", "64000/2889", "10 to 100 ms apart"))),
]  # fmt: skip


def not_truncated(c: Ctx, _res: Outcome) -> None:
    """Every frame scored and no truncation said: the variable rate is named instead."""
    rec = record(c)
    assert rec["video"]["num_frames"] == N, rec["video"]
    assert not any("truncated" in w for w in rec["warnings"]), rec["warnings"]
    assert any(w.startswith("variable frame rate") for w in rec["warnings"]), rec["warnings"]


MEDIA = [
    Case("score-complete-pausing-matroska-is-not-truncated",
         turned("pause.mkv", None, container="matroska", pts_ms=SLOWING_MS), score("pause.mkv"), 0,
         check=not_truncated),
    Case("score-complete-pausing-turned-matroska-is-not-truncated",
         turned("pt.mkv", 90, container="matroska", pts_ms=SLOWING_MS), score("pt.mkv"), 0, check=not_truncated),
]  # fmt: skip


def _assert_equal(got: object, want: object) -> None:
    assert got == want, f"{got!r}, expected {want!r}"


def _json_retimed(res: Outcome) -> None:
    summary = json.loads(res.stdout)  # the warning went to stderr only
    assert summary["timing"]["source"] == "variable" and summary["timing"]["retimed"] is True, summary["timing"]
    assert len(summary["warnings"]) == 1 and "re-timed" in summary["warnings"][0], summary["warnings"]
    assert warnings_of(res) == [f"warning: {summary['warnings'][0]}"], res.stderr


CASES = TURNS + TIMING + MEDIA


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"
    assert len(CASES) >= 20


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_plant(case: Case, ctx: Ctx):  # noqa: F811
    run_case(case, ctx)


# --- the rules' homes -----------------------------------------------------------------------------


@pytest.mark.parametrize("degrees", [90, 180, -90])
def test_planes_are_decoded_upright_exactly(tmp_path: Path, degrees: int):
    """The planes of a turned clip are those of the same stream without a matrix, turned: the same
    frames encoded twice (single-threaded, so the streams are equal), once with a display matrix."""
    flat = write_turned(tmp_path / "flat.mp4", frames()[:4])
    turned_clip = write_turned(tmp_path / "turned.mp4", frames()[:4], degrees)
    turns = (degrees // 90) % 4
    pairs = zip(decode_planes(flat, "yuv420p"), decode_planes(turned_clip, "yuv420p"), strict=True)
    for t, (as_stored, up) in enumerate(pairs):
        for i, (a, b) in enumerate(zip(as_stored, up, strict=True)):
            assert np.array_equal(np.rot90(a, turns), b), f"frame {t} plane {i} is not the stored plane turned"
    source = probe_source(turned_clip)
    assert source.rotation == 90 * turns and source.stored_size == (W, H)
    assert (source.width, source.height) == ((H, W) if turns % 2 else (W, H))


@pytest.mark.parametrize(
    ("degrees", "hflip", "expected"),
    [(None, False, None), (90, False, (90.0, False)), (-90, False, (-90.0, False)), (180, False, (180.0, False)),
     (0, True, (180.0, True)), (30, False, (30.0, False))],
)  # fmt: skip
def test_display_turn_reads_the_matrix(tmp_path: Path, degrees, hflip, expected):
    import av

    clip = write_turned(tmp_path / "c.mp4", frames()[:2], degrees, hflip=hflip)
    with av.open(str(clip)) as container:
        turn = display_turn(next(container.decode(video=0)))
    assert (None if turn is None else (round(turn.degrees, 3), turn.mirrored)) == expected


def test_a_4_2_2_source_turned_a_quarter_is_handled_in_4_4_4(tmp_path: Path):
    source = probe_source(write_turned(tmp_path / "c.mp4", frames()[:3], 90, pix_fmt="yuv422p"))
    assert source.pix_fmt == "yuv422p" and source.work_format == "yuv444p" and source.rotation == 90
    assert probe_source(write_turned(tmp_path / "d.mp4", frames()[:3], 180, pix_fmt="yuv422p")).work_format == "yuv422p"


def test_frame_timing_tells_a_variable_rate_from_a_steady_one():
    steady = frame_timing([0, 40, 80, 120, 160], Fraction(1, 1000))
    assert steady is not None and not steady.variable and steady.keeps(25.0) and not steady.keeps(40.0)
    variable = frame_timing(list(VFR_MS), Fraction(1, 1000))
    assert variable is not None and variable.variable
    assert (variable.low, variable.median, variable.high) == pytest.approx((0.010, 0.030, 0.100))
    assert frame_timing([0, 40], Fraction(1, 1000)) is None and frame_timing([0, 40, 80], None) is None


def test_the_record_s_timing_sentence_is_unchanged(tmp_path: Path):
    clip = write_turned(tmp_path / "v.mp4", frames(), pts_ms=VFR_MS)
    assert timing_note(str(clip), 24.0) == (
        "variable frame rate: frames are 10 to 100 ms apart (the container states 24 frames/s); frame pairs are "
        "taken frame by frame, so a gap of g frames is not a fixed time"
    )


def test_the_source_says_how_it_is_re_timed(tmp_path: Path):
    steady = probe_source(write_turned(tmp_path / "a.mp4", frames()))
    assert steady.retiming is None and steady.timing_entry()["source"] == "constant"
    variable = probe_source(write_turned(tmp_path / "v.mp4", frames(), pts_ms=VFR_MS))
    assert variable.retimed and variable.retiming is not None and variable.retiming.startswith("v.mp4 has a variable")
    assert variable.timing_entry()["intervals_ms"] == {"min": 10.0, "median": 30.0, "mean": 45.455, "max": 100.0}


@pytest.mark.parametrize("degrees", [90, 180, -90])
def test_pyav_reads_a_turned_clip_upright_as_opencv_does(tmp_path: Path, degrees: int) -> None:
    """The decoder geocon score uses for AV1 and interlaced streams (PyAV) applies a display matrix
    as OpenCV's path does, so plant (which writes upright) and score see the same picture."""
    from geocon_core.media.decode import PyAVFrames

    clip = write_turned(tmp_path / "turned.mp4", frames()[:4], degrees)
    opencv = read_bgr(clip)
    pyav = np.stack([f.astype(np.int16) for f in PyAVFrames(str(clip))])
    assert pyav.shape == opencv.shape, (pyav.shape, opencv.shape)
    assert float(np.abs(pyav - opencv).mean()) < 1.0
