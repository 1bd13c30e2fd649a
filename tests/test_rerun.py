"""Rerun recordings read back with Rerun's own reader: the content matches the record."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from geocon_core.config import preset  # noqa: E402
from geocon_core.reconstruction import DenseCloud, DenseCloudConfig, WindowCloud  # noqa: E402
from geocon_core.record import OverlayWriter, read_overlays, read_record, record_id, write_record  # noqa: E402
from geocon_core.scoring import score_clip  # noqa: E402
from geocon_viewer.rerun.dense import WINDOW_POINTS, WORLD_POINTS  # noqa: E402
from geocon_viewer.rerun.layers import RecordLayers  # noqa: E402
from geocon_viewer.rerun.log import RrdSink, audit_card, residual_map, write_rrd  # noqa: E402


def _rows(rrd: Path) -> dict[str, list[dict]]:
    """Every logged row of the recording (not the blueprint), per entity path, as
    {column: value} dicts with the ``frame`` time (None for static rows)."""
    reader = RrdReader(rrd)
    (store,) = reader.recordings()
    out: dict[str, list[dict]] = defaultdict(list)
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        keep = [n for n in rb.schema.names if n not in ("log_time", "video_time", "rerun.controls.RowId")]
        batch = rb.select(keep).to_pydict()
        for i in range(chunk.num_rows):
            out[chunk.entity_path].append({k: v[i] for k, v in batch.items()})
    for rows in out.values():
        rows.sort(key=lambda r: -1 if r.get("frame") is None else r["frame"])
    return out


def _score(clip: Path, folder: Path, cfg, masks=None, dense=None):
    sink = RrdSink(folder / "live.rrd")
    overlays = OverlayWriter(folder / "record")

    def on_frame(fd):
        overlays(fd)
        sink(fd)

    record = score_clip(clip, cfg, masks=masks, on_frame=on_frame, dense=dense)
    overlays.close(record_id(record))
    write_record(record, folder / "record")
    sink.finish(record)
    return record


@pytest.fixture(scope="module")
def objects_run(synth_dir: Path, tmp_path_factory) -> tuple:
    """The static-camera clip with two moving objects, its shipped masks, recorded live."""
    folder = tmp_path_factory.mktemp("rrd_c4")
    record = _score(synth_dir / "c4_objects.mp4", folder, preset("paper"), masks=synth_dir / "c4_objects.masks")
    return record, folder, _rows(folder / "live.rrd")


@pytest.fixture(scope="module")
def parallax_run(synth_dir: Path, tmp_path_factory) -> tuple:
    """The translating camera (strong parallax): the dense point clouds and both cameras."""
    folder = tmp_path_factory.mktemp("rrd_c3")
    cfg = preset("paper").with_(masks="none")
    record = _score(synth_dir / "c3_translation.mp4", folder, cfg, dense=DenseCloudConfig())
    return record, folder, _rows(folder / "live.rrd")


@pytest.fixture(scope="module")
def audit_run(synth_dir: Path, tmp_path_factory) -> tuple:
    """The clip with two moving objects scored with the default preset (readings and their maps)."""
    folder = tmp_path_factory.mktemp("rrd_audit")
    record = _score(synth_dir / "c4_objects.mp4", folder, preset("audit"))
    return record, folder, _rows(folder / "live.rrd")


@pytest.mark.full
def test_the_reading_maps_are_the_records_and_the_card_says_where_to_look(audit_run):
    import cv2

    from geocon_core.signals import MAP_NAMES, MAP_VIEWS, heat_rgba, map_on_frame
    from geocon_viewer.rerun.card import reading_tab

    record, _, rows = audit_run
    a = record.readings.appearance
    assert a is not None and a.maps is not None
    w, h = record.video.working_size
    for name in MAP_NAMES:
        (row,) = rows[f"/frame/readings/{name}"]
        assert row.get("frame") is None  # static: the map sums the whole clip
        blob = next(v for k, v in row.items() if k.endswith("blob") and v is not None)
        data = np.asarray(blob[0] if isinstance(blob[0], list) else blob, np.uint8)
        shown = cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
        want = heat_rgba(map_on_frame(a.maps, name, record.video.content_box, (w, h)), MAP_VIEWS[name].vmax)
        np.testing.assert_array_equal(shown, want)
    # the objects move against the still background: the movers picture is not empty
    assert rows["/frame/readings/movers"] and a.maps.movers.max() > 128
    card = audit_card(record)
    assert "where to look" in card
    weighed = [name for name, _ in record.finding().parts]
    assert "unexplained_appearance" in weighed and f"tab *{reading_tab('unexplained')}*" in card


def test_entity_paths_present(objects_run):
    record, _, rows = objects_run
    ids = [o.object_id for o in record.objects]
    assert ids, "the C4 clip has objects"
    expected = (
        [
            "/frame/image",
            "/frame/content",
            "/frame/objects",
            "/frame/flow",
            "/frame/matches/inliers",
            "/frame/matches/outliers",
            "/frame/matches/lines",
            "/frame/residual_map",
            "/series/background/ir/gap1/scale1",
            "/series/background/ge/gap1/scale1",
            "/series/background/ir/gate",
            "/series/background/ge/gate",
            "/series/gate/t_inf",
            "/series/gate/low",
            "/series/gate/high",
            "/world/cam_first",
            "/audit",
        ]
        + [f"/frame/cells/{i}/observed" for i in ids]
        + [f"/frame/cells/{i}/predicted" for i in ids]
        + [f"/series/objects/{i}" for i in ids]
    )
    missing = [p for p in expected if p not in rows]
    assert not missing, missing


def test_frames_on_timeline_equal_clip(objects_run):
    record, _, rows = objects_run
    n = record.video.num_frames
    refs = [r for r in rows["/frame/image"] if r.get("frame") is not None]
    assert sorted(r["frame"] for r in refs) == list(range(n))
    # one static video asset holding exactly n frames; each reference points at a distinct frame
    assets = [r for r in rows["/frame/image"] if r.get("frame") is None and r.get("AssetVideo:blob") is not None]
    assert len(assets) == 1
    stamps = [int(r["VideoFrameReference:timestamp"][0]) for r in refs]
    assert len(set(stamps)) == n
    asset = rr.AssetVideo(contents=bytes(assets[0]["AssetVideo:blob"][0]), media_type="video/mp4")
    assert sorted(stamps) == sorted(int(v) for v in asset.read_frame_timestamps_nanos())
    # segmentation per frame while objects are visible, and the labels the scorer used
    seg_frames = {r["frame"] for r in rows["/frame/objects"] if r.get("frame") is not None}
    assert seg_frames == set(range(n))


def test_inlier_counts_equal_record(objects_run):
    record, _, rows = objects_run
    fam = record.background.model
    pairs = [p for p in record.pairs if p.gap == 1 and p.scale == 1.0 and p.skip is None]
    by_frame = {r["frame"]: r for r in rows["/frame/matches/inliers"] if r.get("frame") is not None}
    out_by_frame = {r["frame"]: r for r in rows["/frame/matches/outliers"] if r.get("frame") is not None}
    for p in (pairs[0], pairs[len(pairs) // 2], pairs[-1]):
        fit = p.fit(fam)
        assert len(by_frame[p.t0]["Points2D:positions"]) == fit.n_inliers
        assert len(by_frame[p.t0]["Points2D:positions"]) + len(out_by_frame[p.t0]["Points2D:positions"]) == p.n_matches
        # positions are the stored x_t (+0.5: Rerun's pixel centres)
        arr = record.matches.pair(p.index)
        inl = arr["h_inl"] if fam == "H" else arr["f_inl"]
        logged = np.array(by_frame[p.t0]["Points2D:positions"], dtype=np.float32)
        assert np.allclose(logged, arr["x1"][inl] + 0.5, atol=1e-3)
        assert f"{fit.tau:g}" in by_frame[p.t0]["Points2D:labels"][0]


def test_ir_series_equals_record(objects_run):
    record, _, rows = objects_run
    fam = record.background.model
    for s in record.config.scales:
        expect = {
            p.t0: p.fit(fam).ir
            for p in record.pairs
            if p.gap == 1 and p.scale == s and p.skip is None and p.fit(fam).valid
        }
        logged = {
            r["frame"]: r["Scalars:scalars"][0]
            for r in rows[f"/series/background/ir/gap1/scale{s:g}"]
            if r.get("frame") is not None
        }
        assert logged == pytest.approx(expect, abs=0), s
    # AdaDFRC per object equals the record's D_t
    for o in record.objects:
        expect = {
            e.t0: e.d_t for e in record.object_entries if e.object_id == o.object_id and e.scale == 1.0 and e.valid
        }
        logged = {
            r["frame"]: r["Scalars:scalars"][0]
            for r in rows[f"/series/objects/{o.object_id}"]
            if r.get("frame") is not None
        }
        assert logged == pytest.approx(expect)


def test_cells_are_the_records_vectors(objects_run):
    record, _, rows = objects_run
    e = next(e for e in record.object_entries if e.valid and e.scale == 1.0)
    cells = record.cells.entry(e.index)
    row = next(r for r in rows[f"/frame/cells/{e.object_id}/observed"] if r.get("frame") == e.t0)
    vectors = np.array(row["Arrows2D:vectors"], dtype=np.float32)
    from geocon_viewer.rerun.log import ARROW_GAIN

    assert np.allclose(vectors, ARROW_GAIN * cells["observed"], atol=1e-4)


def test_sparse_cloud_when_the_record_has_no_dense_one(parallax_run, tmp_path):
    record, _, _ = parallax_run
    assert record.cloud is not None and len(record.cloud.xyz) > 100
    rec = rr.RecordingStream("geocon-test")
    rec.save(tmp_path / "world.rrd")
    RecordLayers(rec, 30.0, None)._log_world(replace(record, dense=()))
    rec.disconnect()  # writes the file's footer
    rows = _rows(tmp_path / "world.rrd")
    pts = next(r for r in rows["/world/points"])["Points3D:positions"]
    # outlier removal keeps most of a clean synthetic cloud, never adds points
    assert 0.8 * len(record.cloud.xyz) <= len(pts) <= len(record.cloud.xyz)
    assert "/world/dense" not in rows and "/window/dense" not in rows


def test_a_pair_without_parallax_says_so_in_the_3d_views(parallax_run, tmp_path):
    record, _, _ = parallax_run
    n = record.video.num_frames
    empty = DenseCloud(
        np.zeros((0, 3), np.float32),
        np.zeros((0, 3), np.uint8),
        np.zeros((0, 2), np.float32),
        np.zeros(0, np.float32),
        np.zeros(0, np.uint8),
        "rotation only: the camera did not move, so there is no parallax and no depth",
    )
    rec = rr.RecordingStream("geocon-test")
    rec.save(tmp_path / "world.rrd")
    layers = RecordLayers(rec, 30.0, None)
    layers._log_world(replace(record, dense=(WindowCloud(0, n - 1, empty), WindowCloud(0, 8, empty))))
    rec.disconnect()
    rows = _rows(tmp_path / "world.rrd")
    assert "/world/dense" not in rows
    (note,) = rows["/world/dense_note"]
    assert "no parallax" in note["Points3D:labels"][0] and note["Points3D:show_labels"][0]
    (window,) = [r for r in rows["/window/note"] if r.get("Points3D:labels") is not None]
    assert window["frame"] == 0 and window["Points3D:labels"][0].startswith("frames 0-8: rotation only")


def test_dense_clouds_first_last_in_world_and_each_window_on_the_timeline(parallax_run):
    record, _, rows = parallax_run
    first, windows = record.dense[0], record.dense[1:]
    assert len(first.cloud) > 20_000 and len(windows) >= 1 and "/world/points" not in rows
    (row,) = rows["/world/dense"]
    pts, colors = np.asarray(row["Points3D:positions"]), np.asarray(row["Points3D:colors"])
    # open3d thins the cloud to the recording's budget and drops strays, never adds points
    assert 0.5 * WORLD_POINTS <= len(pts) <= WORLD_POINTS and len(colors) == len(pts)
    assert np.median(pts[:, 2]) == pytest.approx(np.median(first.cloud.xyz[:, 2]), rel=0.05)
    logged = [r for r in rows["/window/dense"] if r.get("Points3D:positions") is not None]
    assert [r["frame"] for r in logged] == [w.start for w in windows if len(w.cloud)]
    for r, w in zip(logged, [w for w in windows if len(w.cloud)], strict=True):
        assert 0 < len(r["Points3D:positions"]) <= min(WINDOW_POINTS, len(w.cloud))
    ends = [r for r in rows["/window/cam_end"] if r.get("Transform3D:translation") is not None]
    for r, w in zip(ends, [w for w in windows if w.T_cam0_camT is not None], strict=True):
        tr = r["Transform3D:translation"]
        assert np.allclose(tr[0] if np.ndim(tr[0]) else tr, np.asarray(w.T_cam0_camT)[:3, 3], atol=1e-5)
    for cam in ("/world/cam_first", "/world/cam_last"):
        row = next(r for r in rows[cam] if r.get("Pinhole:image_from_camera") is not None)
        K = np.array(row["Pinhole:image_from_camera"][0]).reshape(3, 3).T  # stored column-major
        assert np.allclose(K[:2, 2], np.asarray(record.intrinsics)[:2, 2])
    T = np.asarray(record.gate.pose.T_cam0_camT)
    tr = next(r for r in rows["/world/cam_last"] if r.get("Transform3D:translation") is not None)[
        "Transform3D:translation"
    ]
    assert np.allclose(tr[0] if np.ndim(tr[0]) else tr, T[:3, 3], atol=1e-5)


def test_blueprint_stored(objects_run):
    _, folder, _ = objects_run
    reader = RrdReader(folder / "live.rrd")
    (bp,) = reader.blueprints()
    paths = {c.entity_path for c in reader.stream(store=bp)}
    assert any("view" in p.lower() or "container" in p.lower() for p in paths), paths


def test_view_rerenders_from_saved_record(objects_run, tmp_path):
    """`write_rrd` rebuilds the same diagnostics from the record folder, without scoring."""
    record, folder, live = objects_run
    again = _rows(write_rrd(folder / "record", tmp_path / "again.rrd"))
    for path in ("/frame/matches/inliers", "/series/background/ir/gap1/scale1", "/frame/objects"):
        a = [
            (
                r["frame"],
                len(next(v for k, v in r.items() if k.endswith(("positions", "scalars", "buffer")) and v is not None)),
            )
            for r in live[path]
            if r.get("frame") is not None
        ]
        b = [
            (
                r["frame"],
                len(next(v for k, v in r.items() if k.endswith(("positions", "scalars", "buffer")) and v is not None)),
            )
            for r in again[path]
            if r.get("frame") is not None
        ]
        assert a == b, path
    assert read_overlays(folder / "record").labels(0) is not None


def test_audit_card_names_versions_and_thresholds(objects_run):
    record, _, rows = objects_run
    card = audit_card(record)
    assert rr.__version__ in card and record.config_hash in card
    assert "0.97" in card and "3.5" in card and record.gate.label in card
    finding = record.finding()
    assert f"**Finding: {finding.verdict}**" in card and finding.reason in card
    logged = next(r for r in rows["/audit"])["TextDocument:text"]
    assert logged[0] == card if isinstance(logged, list) else logged == card


def test_residual_map_tracks_residuals():
    """Where residuals are high the map is bright, where there are no matches it is clear."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [400, 200], (2000, 2))
    res = np.where(xy[:, 0] < 200, 0.2, 3.8)
    rgba = residual_map(xy, res, (800, 200), vmax=4.0)
    assert rgba.shape == (25, 100, 4)
    assert rgba[12, 5:20, 3].min() > 150 and rgba[12, 70:, 3].max() == 0  # evidence only where matches are
    assert rgba[12, 35:45, :3].mean() > 2 * rgba[12, 5:15, :3].mean()  # inferno: high residual is brighter


@pytest.mark.slow
def test_cli_score_rrd_and_view(synth_dir, tmp_path):
    """`geocon score --rrd` writes a recording; `geocon view --headless` re-renders it."""
    geocon = Path(sys.executable).parent / "geocon"
    clip = synth_dir / "c1_static.mp4"
    res = subprocess.run(
        [
            str(geocon),
            "score",
            str(clip),
            "--no-masks",
            "--out",
            str(tmp_path / "rec"),
            "--rrd",
            str(tmp_path / "a.rrd"),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    record = read_record(tmp_path / "rec")
    assert json.loads(res.stdout)["config_hash"] == record.config_hash
    assert (tmp_path / "a.rrd").stat().st_size > 10_000
    # a recording comes with the dense clouds; a still camera's are empty, and the 3D view says why
    assert record.dense and all(len(w.cloud) == 0 for w in record.dense)
    (note,) = _rows(tmp_path / "a.rrd")["/world/dense_note"]
    assert "no parallax" in note["Points3D:labels"][0] and note["Points3D:show_labels"] is not None
    res = subprocess.run(
        [str(geocon), "view", str(tmp_path / "rec"), "--headless", "--save", str(tmp_path / "b.rrd")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    assert "/frame/matches/inliers" in _rows(tmp_path / "b.rrd")
    res = subprocess.run(
        [str(geocon), "view", str(tmp_path / "nothing-here"), "--headless"], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 2 and "does not exist" in res.stderr


def test_video_encoder_leaves_no_realtime_threads(objects_run) -> None:
    """SVT-AV1 run as root makes its threads and the caller SCHED_FIFO 99; after recording, every
    thread of this process is back under the normal policy (or the test runs unprivileged and the
    encoder never changed them)."""
    import os

    policies = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            policies[int(tid)] = os.sched_getscheduler(int(tid))
        except OSError:
            continue  # the thread ended meanwhile
    realtime = {tid: p for tid, p in policies.items() if p in (os.SCHED_FIFO, os.SCHED_RR)}
    assert not realtime, f"threads left under a real-time policy: {realtime}"


def test_flow_hue_is_one_frame_sized_layer_inside_the_masks(objects_run):
    """The hue slices keep the frame's size on every frame (a changing size breaks the viewer) and are
    drawn only where an object was masked on that frame."""
    import cv2

    record, folder, rows = objects_run
    overlays = read_overlays(folder / "record")
    flows = [r for r in rows["/frame/flow"] if r.get("frame") is not None and r.get("EncodedImage:blob") is not None]
    assert len(flows) >= 10
    shapes = set()
    for r in flows:
        blob = np.asarray(r["EncodedImage:blob"][0], dtype=np.uint8)
        img = cv2.imdecode(blob, cv2.IMREAD_UNCHANGED)
        shapes.add(img.shape)
        drawn = img[..., 3] > 0
        labels = overlays.labels(r["frame"])
        assert drawn.any()
        assert np.all(labels[drawn] > 0), f"hue drawn outside the object masks on frame {r['frame']}"
    assert len(shapes) == 1
    (shape,) = shapes
    assert shape[:2] == tuple(record.video.working_size[::-1])


@pytest.mark.full
def test_a_flagged_clip_opens_on_its_evidence(synth_dir, tmp_path):
    """`geocon view` of a clip the model flags on a pictured reading: the recording's layout opens
    that map's tab, and the start frame is where the reading is strongest."""
    import rerun.blueprint as rrb

    from geocon_viewer.rerun.card import evidence, reading_tab
    from geocon_viewer.rerun.log import blueprint

    from .flagged import STRONGEST_FRAME, flagged_on_appearance

    source = tmp_path / "scored"
    write_record(score_clip(synth_dir / "c1_static.mp4", preset("audit")), source)
    rec, _ = flagged_on_appearance(source, tmp_path / "flagged")
    assert evidence(rec) == ("unexplained", STRONGEST_FRAME)
    tabs = [c for c in blueprint("unexplained").root_container.contents[0].contents if isinstance(c, rrb.Tabs)]
    (reading_tabs,) = tabs
    assert reading_tabs.contents[reading_tabs.active_tab].name == reading_tab("unexplained")
    assert write_rrd(tmp_path / "flagged", tmp_path / "f.rrd").stat().st_size > 0
