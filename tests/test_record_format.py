"""The record on disk: typed fields, an exact round trip, and a clear refusal of other formats."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from geocon_core.bench import score_to_folder
from geocon_core.config import ScoreConfig
from geocon_core.media import ClipInfo
from geocon_core.pose import PoseEstimate
from geocon_core.record import (
    RECORD_FORMAT,
    OverlayFlow,
    OverlayFrame,
    read_overlays,
    read_record,
    read_record_json,
    write_record,
)
from geocon_core.results import ResultsError, ResultsIndex
from geocon_core.synth import ClipPlan, write_clip

CFG = ScoreConfig(scales=(1.0,), gaps=(1,), working_size=(320, 180))


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("record")
    gt = write_clip(ClipPlan("C4"), out, seed=3, width=320, height=180, num_frames=6)
    score_to_folder(out / gt.video_path, CFG, out / "record", masks=out / gt.masks_path)
    return out / "record"


def test_video_and_pose_are_typed(folder):
    rec = read_record(folder)
    assert isinstance(rec.video, ClipInfo) and rec.video.num_frames == 6
    assert rec.video.working_size == (320, 180) and isinstance(rec.video.content_box, tuple)
    assert isinstance(rec.gate.pose, PoseEstimate)
    assert rec.gate.pose.pose_present == rec.gate.pose_present
    if rec.gate.pose.T_cam0_camT is not None:
        assert rec.gate.pose.T_cam0_camT.shape == (4, 4)


def test_write_read_write_is_byte_identical(folder, tmp_path):
    rec = read_record(folder)
    again = folder.parent / "again"  # beside it: the clip's path seen from the record is the same
    write_record(rec, again)
    for name in ("record.json", "matches.npz"):
        assert (folder / name).read_bytes() == (again / name).read_bytes(), name
    elsewhere = tmp_path / "deeper" / "again"
    write_record(rec, elsewhere)
    moved = read_record(elsewhere).video
    assert moved.from_record == os.path.relpath(str(rec.video.abs_path), str(elsewhere.parent))
    back = read_record(again)
    assert back.video == rec.video
    assert back.gate.pose.to_dict() == rec.gate.pose.to_dict()
    assert back.gate.timeline == rec.gate.timeline and back.pairs == rec.pairs
    assert back.summary() == rec.summary()


def test_json_layout_keeps_plain_dicts(folder):
    _, d = read_record_json(folder)
    assert d["format"] == RECORD_FORMAT
    assert set(d["video"]) >= {"num_frames", "fps", "working_size", "content_box", "duplicates", "cuts"}
    assert set(d["gate"]["pose"]) >= {"pose_present", "t_inf", "T_cam0_camT", "method", "focal_scale"}


def _other_format(folder: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "old"
    shutil.copytree(folder, copy)
    d = json.loads((copy / "record.json").read_text())
    d["format"] = "geocon-record/0"
    (copy / "record.json").write_text(json.dumps(d))
    return copy


def test_another_format_is_refused_in_one_sentence(folder, tmp_path):
    copy = _other_format(folder, tmp_path)
    with pytest.raises(ValueError, match="geocon-record/0") as info:
        read_record(copy)
    assert RECORD_FORMAT in str(info.value) and "\n" not in str(info.value)


def test_results_index_reads_through_the_same_format_check(folder, tmp_path):
    assert ResultsIndex.open(folder).clips[0].status == "ok"
    with pytest.raises(ResultsError, match="geocon-record/0"):
        ResultsIndex.open(_other_format(folder, tmp_path))


def test_overlay_index_entries_are_typed_and_round_trip(folder):
    overlays = read_overlays(folder)
    assert overlays is not None and overlays.frames == list(range(6))
    for t in overlays.frames:
        entry = overlays.entries[t]
        assert isinstance(entry, OverlayFrame)
        assert all(isinstance(f, OverlayFlow) and len(f.box) == 4 for f in entry.flows)
        assert OverlayFrame.from_json_dict(json.loads(json.dumps(entry.to_json_dict()))) == entry
    labelled = [t for t in overlays.frames if overlays.entries[t].labels is not None]
    assert labelled, "the clip has moving objects"
    labels = overlays.labels(labelled[0])
    assert labels is not None and labels.dtype == np.uint16 and labels.max() > 0
