"""Dataset validation: every problem reported at once, with file names."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from geocon_core.bench import REQUIRED_FIELDS, DatasetError, load_dataset
from geocon_core.synth import plan_benchmark, write_benchmark


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("dataset")
    write_benchmark(
        root, plan_benchmark(families=("C1", "C4"), scenes=1, platforms=("clean",)), width=96, height=64, num_frames=4
    )
    return root


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _sidecar(root: Path, clip_id: str) -> Path:
    for path in root.rglob("*.meta.json"):
        if json.loads(path.read_text())["clip_id"] == clip_id:
            return path
    raise AssertionError(clip_id)


def test_valid_dataset_loads_sorted_with_resolved_paths(tiny_dataset):
    entries = load_dataset(tiny_dataset)
    assert [e.clip_id for e in entries] == ["clean-c1_static-s0", "clean-c4_objects-s0"]
    for e in entries:
        assert e.video.is_file() and e.video.suffix == ".mp4"
        assert e.masks is not None and e.masks.is_dir()
        assert e.model == "clean" and e.category in ("C1", "C4") and e.scene_id.endswith("seed0")


def test_every_problem_is_reported_at_once_with_file_names(tiny_dataset, tmp_path):
    root = _copy(tiny_dataset, tmp_path / "d")
    c1, c4 = _sidecar(root, "clean-c1_static-s0"), _sidecar(root, "clean-c4_objects-s0")
    meta1 = json.loads(c1.read_text())
    del meta1["scene_id"], meta1["fps"]
    meta1["category"] = "C9"
    c1.write_text(json.dumps(meta1))
    meta4 = json.loads(c4.read_text())
    meta4["masks_path"] = "nowhere.masks"
    c4.write_text(json.dumps(meta4))
    (root / "clean" / c4.parent.name / meta4["video"]).write_bytes(b"\x00\x00\x00\x18ftypmp42 not really a video")
    (root / "broken.meta.json").write_text("{not json")
    dup = root / "dup"
    dup.mkdir()
    shutil.copy(c4, dup / "again.meta.json")
    with pytest.raises(DatasetError) as exc:
        load_dataset(root)
    problems = exc.value.problems
    text = str(exc.value)
    assert any("missing fields scene_id, fps" in p or "missing fields fps, scene_id" in p for p in problems), problems
    assert any("unknown category 'C9'" in p for p in problems)
    assert any("masks_path nowhere.masks does not exist" in p for p in problems)
    assert any("unreadable clip" in p for p in problems)
    assert any(p.startswith("broken.meta.json: not valid JSON") for p in problems)
    assert any(p.startswith("dup/again.meta.json: clip file") and "does not exist" in p for p in problems)
    assert len(problems) >= 6 and f"{len(problems)} problems" in text
    assert all(":" in p and ".meta.json" in p for p in problems)  # each names its file


def test_duplicate_clip_ids_are_reported(tiny_dataset, tmp_path):
    root = _copy(tiny_dataset, tmp_path / "d")
    c1 = _sidecar(root, "clean-c1_static-s0")
    other = c1.parent / "copy.meta.json"
    meta = json.loads(c1.read_text())
    other.write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="clip_id 'clean-c1_static-s0' is also used by"):
        load_dataset(root)


def test_empty_or_missing_dataset(tmp_path):
    with pytest.raises(DatasetError, match="no clip metadata"):
        load_dataset(tmp_path)
    with pytest.raises(DatasetError, match="not a folder"):
        load_dataset(tmp_path / "missing")


def test_required_fields_follow_the_spec():
    assert set(REQUIRED_FIELDS) == {
        "prompt",
        "model",
        "model_version",
        "seed",
        "resolution",
        "fps",
        "duration",
        "clip_id",
        "masks_path",
        "category",
        "scene_id",
    }


def test_two_sidecars_naming_one_clip_and_repeated_keys_are_refused(tiny_dataset, tmp_path):
    root = _copy(tiny_dataset, tmp_path / "d")
    c1 = _sidecar(root, "clean-c1_static-s0")
    meta = json.loads(c1.read_text())
    video = (c1.parent / meta["video"]).resolve()
    (c1.parent / "again.meta.json").write_text(json.dumps({**meta, "clip_id": "again", "video": meta["video"]}))
    link = c1.parent / "link.mp4"
    link.symlink_to(video)  # the same file under another name is the same clip
    (c1.parent / "linked.meta.json").write_text(json.dumps({**meta, "clip_id": "linked", "video": "link.mp4"}))
    c4 = _sidecar(root, "clean-c4_objects-s0")
    text = c4.read_text()
    c4.write_text(text.rstrip()[:-1] + ', "fps": 8}')  # fps given twice
    with pytest.raises(DatasetError) as exc:
        load_dataset(root)
    problems = exc.value.problems
    assert sum("names the same clip file as" in p for p in problems) == 2, problems
    assert any(p.endswith("key 'fps' is given twice (a JSON object names each key once)") for p in problems)
    huge = root / "huge.meta.json"
    huge.write_text('{"clip_id": "h", "fps": 1' + "0" * 5000 + "}")
    with pytest.raises(DatasetError, match=r"huge.meta.json: a number of 5001 characters"):
        load_dataset(root)
