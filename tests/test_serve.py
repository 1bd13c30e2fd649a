"""`geocon serve`, the Viser audit app, driven from Python against a real (synthetic) benchmark:
live re-gating reproduces the stored sensitivity scan exactly, the triage list is ordered and
filtered by verdict, a selected clip shows its own point cloud and inliers, the server binds to
127.0.0.1 only and frees its port, and headless Chromium renders the page."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")

from geocon_core.bench import read_tables, run_bench  # noqa: E402
from geocon_core.config import ScoreConfig  # noqa: E402
from geocon_core.record import read_record  # noqa: E402
from geocon_core.results import VERDICTS, ResultsError, ResultsIndex  # noqa: E402
from geocon_core.scoring import pair_inliers, regate_family  # noqa: E402
from geocon_core.synth import plan_benchmark, write_benchmark  # noqa: E402
from geocon_viewer.audit.app import LIST_ROWS, AuditApp  # noqa: E402

from .bad_inputs import broken_bench_clip  # noqa: E402

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """Six synthetic clips (C1 and C3: clean, breathing, elastic) and one that fails to score."""
    data = tmp_path_factory.mktemp("serve-data")
    write_benchmark(data, plan_benchmark(families=("C1", "C3"), scenes=1), width=320, height=180, num_frames=16)
    broken_bench_clip(data)
    out = tmp_path_factory.mktemp("serve-results") / "r"
    summary = run_bench(data, out, ScoreConfig(working_size=(320, 180)), workers=2)
    assert (summary.total, summary.failed) == (7, 1)
    return out


@pytest.fixture()
def app(results):
    audit = AuditApp(results, port=0, preload=False)
    yield audit
    audit.stop()


def _local_listeners(port: int) -> list[str]:
    """Local addresses (hex, as /proc/net/tcp{,6} write them) of sockets listening on ``port``."""
    found = []
    for name in ("tcp", "tcp6"):
        path = Path("/proc/net") / name
        if not path.is_file():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            addr, port_hex = fields[1].rsplit(":", 1)
            if int(port_hex, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                found.append(addr)
    return found


# --- live re-gating ------------------------------------------------------------------------------


@pytest.mark.full
def test_tau_h_from_the_scan_gives_exactly_the_scans_ir(app, results):
    sens = read_tables(results)["sensitivity"]
    h = sens[(sens["family"] == "H") & ~sens["is_default"]]
    tau = 3.0
    assert tau in set(h["tau"]) and tau != app.index.recorded.tau_h
    app.clip.value = "breathing-c3_translation-s0"
    app.number["tau_h"].value = tau  # as if typed into the panel: the callback re-gates
    assert app.thresholds.tau_h == tau
    scan = h[h["tau"] == tau].set_index("clip_id")
    ok = [r for r in app.rows if r.verdict is not None]
    assert len(ok) == 6
    for row in ok:
        assert row.verdict.ir_h == scan.loc[row.clip_id, "ir"]  # exactly, not approximately
        assert row.verdict.ge_h == scan.loc[row.clip_id, "ge"]
    # the selected clip's verdict, card and thresholds note follow
    v = app.verdict
    assert v is not None and v.ir_h == scan.loc[app.view.clip_id, "ir"]
    assert "tau_H (px) 3 (recorded" in app.thresholds_md.content


@pytest.mark.full
def test_tau_f_from_the_scan_gives_exactly_the_scans_ir_and_reset_restores_the_record(app, results):
    sens = read_tables(results)["sensitivity"]
    tau = 0.2
    scan = sens[(sens["family"] == "F") & (sens["tau"] == tau)].set_index("clip_id")
    assert len(scan) == 6
    app.number["tau_f"].value = tau
    for row in (r for r in app.rows if r.verdict is not None):
        assert row.verdict.ir_f == scan.loc[row.clip_id, "ir"]
        if row.verdict.model == "F":
            assert row.verdict.ir == scan.loc[row.clip_id, "ir"]
    app.reset.value = True  # a button press
    app._reset_thresholds()
    assert app.thresholds == app.index.recorded
    assert app.thresholds_md.content.startswith("All thresholds as recorded")
    clips = read_tables(results)["clips"].set_index("clip_id")
    for row in (r for r in app.rows if r.verdict is not None):
        assert row.verdict.ir == clips.loc[row.clip_id, "ir"] and row.verdict.ge == clips.loc[row.clip_id, "ge"]
        assert row.verdict.consistent == bool(clips.loc[row.clip_id, "consistent"])


@pytest.mark.full
def test_report_gate_reorders_the_list_by_verdict(app):
    # At the recorded gates every synthetic clip passes and the unscorable one comes first;
    # a GE gate below every clip's GE fails them all, deepest failure (largest GE) first.
    assert [r.state for r in app.rows] == ["error"] + ["passes"] * 6
    ge_gate = 0.5 * min(r.verdict.ge for r in app.rows if r.verdict is not None)
    app.number["ge_gate"].value = ge_gate
    states = [r.state for r in app.rows]
    assert states == ["fails"] * 6 + ["error"]
    ges = [r.verdict.ge for r in app.rows if r.state == "fails"]
    assert ges == sorted(ges, reverse=True), "deepest beyond the GE gate first"
    assert f"GE gate (px) {ge_gate:g} (recorded" in app.thresholds_md.content
    app.state.value = "passes"
    assert app.rows == [] and "no clip matches" in app.table_md.content
    # an impossible gate (low above high) is refused with a note, not applied
    app.number["tau_t_low"].value = app.thresholds.tau_t_high + 1.0
    assert app.thresholds.tau_t_low == app.index.recorded.tau_t_low
    assert app.thresholds_md.content.startswith("⚠")


@pytest.mark.full
def test_triage_filters_and_severity_order(app, results):
    index = app.index
    rows = index.triage()
    assert [VERDICTS.index(r.state) for r in rows] == sorted(VERDICTS.index(r.state) for r in rows)
    assert {r.clip.category for r in rows} == {"C1", "C3"}
    # the elastic clips break the background: they are the most severe passing/failing clips
    app.category.value = "C3"
    assert app.rows and all(r.clip.category == "C3" for r in app.rows)
    assert app.clip.options == tuple(r.clip_id for r in app.rows) or list(app.clip.options) == [
        r.clip_id for r in app.rows
    ]
    assert app.view is not None and app.view.clip_id == app.rows[0].clip_id
    app.category.value = "any"
    app.state.value = "error"
    assert [r.clip_id for r in app.rows] == ["broken-c1"]
    assert "could not be scored" in app.card_md.content and app.cloud_handle is None
    app.state.value = "any"
    app.gate_label.value = "H"
    assert app.rows and all(r.verdict.label == "H" for r in app.rows)
    assert {r.clip.category for r in app.rows} == {"C1"}  # static-camera scenes gate to H
    assert len(app.table_md.content.splitlines()) <= LIST_ROWS + 4


# --- the selected clip ------------------------------------------------------------------------------


@pytest.mark.full
def test_selecting_a_clip_loads_its_point_cloud_and_frames(app, results):
    for clip_id in ("clean-c3_translation-s0", "elastic-c3_translation-s0"):
        app.clip.value = clip_id
        record = read_record(results / "clips" / clip_id)
        assert app.view.clip_id == clip_id
        assert record.cloud is not None and len(record.cloud.xyz) > 50
        assert app.cloud_handle is not None
        assert app.cloud_handle.points.shape == record.cloud.xyz.shape
        np.testing.assert_allclose(app.cloud_handle.points, record.cloud.xyz.astype(np.float32))
        assert clip_id in app.card_md.content
        finding = record.finding()  # the recorded thresholds: the card reads as the record's summary
        assert f"**{finding.verdict}** (clip score" in app.card_md.content and finding.reason in app.card_md.content
    assert app.view.frames_ready.wait(60) and app.view.frames_error is None
    assert len(app.view.frames) == app.view.num_frames == 16
    # both cameras show their frame once it is decoded: first and last, at thumbnail width
    assert sorted(app.view.frustums) == [0, 15]
    for t, handle in app.view.frustums.items():
        frame = app.view.frames[t]
        assert handle.image is not None and handle.image.shape == (round(256 * frame.shape[0] / frame.shape[1]), 256, 3)
        assert abs(float(handle.image.mean()) - float(frame.mean())) < 2.0, "the camera shows its own frame"


@pytest.mark.full
def test_switching_clips_while_frames_decode_raises_in_no_thread(app, monkeypatch):
    """Clips switched again and again while their frames decode: the decoder of a clip that is no
    longer selected stops and never writes into the scene the switch rebuilt; the last clip is
    shown whole."""
    import threading
    import time

    raised: list[str] = []
    monkeypatch.setattr(threading, "excepthook", lambda a: raised.append(f"{a.thread.name}: {a.exc_value!r}"))
    clips = ["clean-c3_translation-s0", "elastic-c3_translation-s0", "breathing-c1_static-s0"]
    decoders: list[threading.Thread] = []
    for i in range(24):
        app.clip.value = clips[i % len(clips)]
        decoders.append(app._decoder)
        time.sleep(0.002 * (i % 4))  # switch before, during and after the first frames are written
    for thread in decoders:
        thread.join(timeout=60)
        assert not thread.is_alive()
    assert raised == []
    view = app.view
    assert view.clip_id == clips[23 % len(clips)] and view.frames_ready.is_set() and view.frames_error is None
    assert len(view.frames) == view.num_frames
    assert all(handle.image is not None for handle in view.frustums.values()), "the shown cameras got their frames"


@pytest.mark.full
def test_frame_slider_shows_the_pairs_inliers_under_the_thresholds(app, results):
    app.clip.value = "clean-c3_translation-s0"
    record = app.view.record
    model = app.verdict.model
    top, gap = max(record.config.scales), min(record.config.gaps)
    for t in (0, 7):
        app.slider.value = t
        assert app.frame == t
        xy, inliers = app.frame_matches(t)
        pair = next(p for p in record.pairs if p.t0 == t and p.gap == gap and p.scale == top)
        assert inliers.sum() == pair.fit(model).n_inliers
        assert len(xy) == len(inliers) == pair.n_matches
        assert f"{int(inliers.sum())} of {len(inliers)} matches inliers" in app.frame_md.content
    # a tighter threshold marks fewer inliers, with the same count the re-gate uses
    key = "tau_h" if model == "H" else "tau_f"
    for tau in (0.5, 0.25, 0.1) if model == "H" else (0.025, 0.01, 0.005):
        app.number[key].value = tau
        _, tight = app.frame_matches(7)
        if tight.sum() < inliers.sum():
            break
    assert tight.sum() < inliers.sum(), "no tighter threshold marked fewer inliers"
    assert tight.sum() == pair_inliers(record, pair.index, model, tau).sum()
    assert app.view.frames_ready.wait(60)
    img = app.frame_image(7)
    assert img.shape[:2] == app.view.frames[7].shape[:2]
    assert not np.array_equal(img, app.view.frames[7])  # the overlay is drawn


@pytest.mark.full
def test_plots_follow_the_regated_pairs(app):
    app.clip.value = "elastic-c1_static-s0"
    x, ir, gate = app.ir_plot.data
    assert len(x) == app.view.num_frames
    rec = app.view.record
    top, gap = max(rec.config.scales), min(rec.config.gaps)
    for p in rec.pairs:
        if p.gap == gap and p.scale == top and p.skip is None:
            assert ir[p.t0] == pytest.approx(p.fit(app.verdict.model).ir)
    assert np.all(gate == app.thresholds.ir_gate)
    assert len(app.obj_plot.data) >= 2 and len(app.gate_plot.data) == 5


@pytest.mark.full
def test_rrd_button_writes_the_recording(app, results):
    pytest.importorskip("rerun")
    app.clip.value = "elastic-c3_translation-s0"
    rrd = results / "clips" / "elastic-c3_translation-s0" / "audit.rrd"
    rrd.unlink(missing_ok=True)
    path = app.write_rrd()
    assert path == rrd and rrd.is_file() and rrd.stat().st_size > 10_000
    assert "audit.rrd" in app.rrd_md.content


# --- the server ---------------------------------------------------------------------------------


@pytest.mark.full
def test_binds_to_localhost_only_and_frees_its_port(results):
    audit = AuditApp(results, port=0, preload=True)
    port = audit.port
    try:
        assert audit.host == "127.0.0.1" and audit.url == f"http://127.0.0.1:{port}"
        listeners = _local_listeners(port)
        assert listeners, "nothing listens on the port"
        assert all(a in ("0100007F", "00000000000000000000000001000000") for a in listeners), listeners
        with urllib.request.urlopen(audit.url, timeout=10) as resp:
            assert resp.status == 200 and b"<html" in resp.read(2000).lower()
        # not reachable on another address of this machine
        with socket.socket() as s:
            s.settimeout(2)
            assert s.connect_ex(("127.0.0.2", port)) != 0 or not listeners
    finally:
        audit.stop()
    assert not _local_listeners(port)
    with socket.socket() as s:  # the port is free again
        s.bind(("127.0.0.1", port))


def _ignore_sigint() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.full
@pytest.mark.parametrize("sig, inherited_ignore", [("SIGINT", False), ("SIGINT", True), ("SIGTERM", False)])
def test_cli_serves_until_ctrl_c_then_frees_its_port(results, sig, inherited_ignore):
    """``inherited_ignore``: started as a background job of a non-interactive shell is, with
    SIGINT ignored; Ctrl-C must still stop it."""
    import signal

    proc = subprocess.Popen(
        [*GEOCON, "serve", str(results), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_ignore_sigint if inherited_ignore else None,
    )
    try:
        line = ""
        while "GeoCon audit app:" not in line:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read()
        assert "this machine only" in line and "7 clips" in line
        url = line.split("GeoCon audit app:", 1)[1].split()[0]
        port = int(url.rsplit(":", 1)[1])
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200
        proc.send_signal(getattr(signal, sig))
        _, stderr = proc.communicate(timeout=60)  # drains both pipes: a full pipe must not block the stop
        assert proc.returncode == 0, stderr
        assert "stopping" in stderr
    finally:
        proc.kill()
        proc.wait()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))


@pytest.mark.full
def test_preload_reads_every_residual(results):
    index = ResultsIndex.open(results)
    seen = []
    index.preload(progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (6, 6) and index.loaded() == 6
    th = index.recorded.__class__(**{**index.recorded.__dict__, "tau_h": 1.0})
    for c in index.clips:
        if c.status == "ok":
            assert index.verdict(c.clip_id, th).ir_h == regate_family(read_record(c.folder), "H", 1.0).ir


@pytest.mark.full
def test_a_single_record_folder_opens(results, tmp_path):
    folder = tmp_path / "one"
    shutil.copytree(results / "clips" / "clean-c1_static-s0", folder)
    audit = AuditApp(folder, port=0)
    try:
        assert audit.index.kind == "record" and [r.clip_id for r in audit.rows] == ["one"]
        assert audit.view is not None and audit.verdict.model == "H"
    finally:
        audit.stop()


def test_bad_results_folders_are_refused(tmp_path):
    with pytest.raises(ResultsError, match="does not exist"):
        ResultsIndex.open(tmp_path / "nowhere")
    with pytest.raises(ResultsError, match="neither bench.json"):
        ResultsIndex.open(tmp_path)
    (tmp_path / "bench.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(ResultsError, match="not a GeoCon benchmark manifest"):
        ResultsIndex.open(tmp_path)
    record = tmp_path / "record"
    record.mkdir()
    (record / "record.json").write_text("{not json")
    with pytest.raises(ResultsError, match="not a readable GeoCon record"):
        ResultsIndex.open(record)
    proc = subprocess.run(
        [*GEOCON, "serve", str(tmp_path / "nowhere"), "--port", "0"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode != 0 and "does not exist" in proc.stderr


# --- in a browser ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_headless_chromium_shows_the_list_scene_and_plots(results, tmp_path):
    from geocon_viewer.capture.screenshot import find_chromium

    if find_chromium() is None:
        pytest.skip("no Chromium on this machine (bash scripts/bootstrap.sh test installs it)")
    import cv2

    png = tmp_path / "serve.png"
    proc = subprocess.run(
        [
            *GEOCON,
            "serve",
            str(results),
            "--port",
            "0",
            "--clip",
            "elastic-c3_translation-s0",
            "--screenshot",
            str(png),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "GeoCon audit app: http://127.0.0.1:" in proc.stdout
    img = cv2.imread(str(png))
    assert img is not None and img.shape[:2] == (1000, 1600)

    def busy(region: np.ndarray) -> float:
        """Share of pixels that differ from the region's most common colour (0: blank)."""
        flat = region.reshape(-1, 3)
        values, counts = np.unique(flat, axis=0, return_counts=True)
        return 1.0 - counts.max() / len(flat)

    left, centre, right = img[:, :470], img[150:850, 520:1150], img[:, 1180:]
    assert busy(left[60:400]) > 0.2, "the frame panel shows a frame"
    assert busy(centre) > 0.05, "the 3D scene shows a point cloud and frustums"
    assert busy(right) > 0.05, "the triage list is drawn"


# --- dense point clouds -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dense_record(tmp_path_factory) -> Path:
    """A translating clip scored into a record with dense clouds (first/last and one gate window)."""
    from geocon_core.bench import score_to_folder
    from geocon_core.reconstruction import DenseCloudConfig
    from geocon_core.synth import ClipPlan, write_clip

    data = tmp_path_factory.mktemp("dense-clip")
    gt = write_clip(ClipPlan("C3"), data, width=320, height=180, num_frames=20)
    folder = data / "record"
    score_to_folder(data / f"{gt.clip_id}.mp4", ScoreConfig(), folder, dense=DenseCloudConfig())
    return folder


def test_switching_pairs_while_frames_decode_raises_in_no_thread(dense_record, monkeypatch):
    """The clip selected again and again, and its pairs switched (each switch rebuilds the
    cameras) while its frames decode: no thread writes into a camera a switch removed, and the
    cameras shown at the end carry their frames."""
    import threading

    raised: list[str] = []
    monkeypatch.setattr(threading, "excepthook", lambda a: raised.append(f"{a.thread.name}: {a.exc_value!r}"))
    audit = AuditApp(dense_record, port=0, preload=False)
    try:
        clip_id = audit.view.clip_id
        options = list(audit.pair.options)
        decoders = []
        for _ in range(20):
            audit._on_clip(clip_id)  # what selecting it in the list does: a new view, a new decoder
            decoders.append(audit._decoder)
            for value in options[1:] + options[:1]:
                audit.pair.value = value
        for thread in decoders:
            thread.join(timeout=60)
            assert not thread.is_alive()
        assert raised == []
        assert audit.view.frames_ready.is_set() and len(audit.view.frames) == audit.view.num_frames
        assert all(handle.image is not None for handle in audit.view.frustums.values())
    finally:
        audit.stop()


def test_the_scene_shows_the_dense_cloud_of_the_pair_picked_with_its_legend(dense_record):
    from geocon_viewer.audit.views import DENSE_POINTS
    from geocon_viewer.shared.clouds import dense_points

    record = read_record(dense_record)
    assert [(w.start, w.end) for w in record.dense] == [(0, 19), (0, 16)]
    audit = AuditApp(dense_record, port=0, preload=False)
    try:
        assert list(audit.pair.options) == ["first/last", "window 0-16"]
        assert "outlier" in audit.legend_html.content and "moving object" in audit.legend_html.content
        for value, w in zip(audit.pair.options, record.dense, strict=True):
            audit.pair.value = value
            xyz, rgb = dense_points(w, DENSE_POINTS)
            assert audit.cloud_handle is not None and audit.cloud_handle.points.shape == xyz.shape
            np.testing.assert_allclose(audit.cloud_handle.points, xyz)
            np.testing.assert_array_equal(audit.cloud_handle.colors, rgb)
            assert sorted(audit.view.frustums) == [w.start, w.end]
            assert f"frames {w.start} -> {w.end}: {len(w.cloud)} points" in audit.pair_md.content
    finally:
        audit.stop()


@pytest.mark.full
def test_a_flagged_clip_opens_on_the_reading_its_score_leans_on(results, tmp_path):
    """The record's readings say the clip's appearance changes along the flow, strongest at a known
    frame and only inside a known patch: the app opens on that map and that frame, and paints the patch."""
    from geocon_core.signals import MAP_VIEWS
    from geocon_viewer.audit.views import MAP_MENU

    from .flagged import STRONGEST_FRAME, flagged_on_appearance

    rec, patch = flagged_on_appearance(results / "clips" / "clean-c1_static-s0", tmp_path / "flagged")
    assert rec.finding().verdict == "inconsistent" and rec.finding().parts[0][0] == "unexplained_appearance"
    audit = AuditApp(tmp_path / "flagged", port=0)
    try:
        assert audit.reading_map.value == MAP_VIEWS["unexplained"].title and audit.frame == STRONGEST_FRAME
        assert f"{MAP_MENU} *{MAP_VIEWS['unexplained'].title}*" in audit.card_md.content
        assert audit.view is not None and audit.view.frames_ready.wait(60)
        audit.show_matches.value = False
        t, k = STRONGEST_FRAME, audit.view.display_scale
        shown, plain = audit.frame_image(t).astype(np.int16), audit.view.frames[t].astype(np.int16)
        (ix, iy), (ox, oy) = ((round(x * k), round(y * k)) for x, y in (patch.centre, patch.far))
        assert np.abs(shown[iy, ix] - plain[iy, ix]).sum() > 60  # painted
        assert np.allclose(shown[oy, ox], plain[oy, ox] * 0.5, atol=2)  # only dimmed
        audit.reading_map.value = "none"
        np.testing.assert_array_equal(audit.frame_image(t), audit.view.frames[t])
    finally:
        audit.stop()
