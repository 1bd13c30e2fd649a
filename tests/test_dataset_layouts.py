"""Datasets as they come: a plain folder of clips (one sub-folder per platform) and a CSV or JSONL
manifest are read with stated defaults, `geocon dataset --write` spells them out as sidecars, and
`geocon bench` gives the same tables on every layout as on hand-written sidecars."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.bench import (
    DatasetError,
    clip_ids,
    prompt_from_name,
    sanitise_clip_id,
    scan_dataset,
    scene_ids,
)
from geocon_viewer.cli import app

from .bad_inputs import pan_frames, write_gif, write_pngs, write_video
from .conftest import read_video


def _run(*args: str):
    """``geocon ARGS`` in this process: its exit code, stdout and stderr."""
    return CliRunner().invoke(app, list(args))


def _clip(path: Path, seed: int = 0) -> Path:
    """A tiny readable clip (64x48, 4 frames of a pan) at ``path`` (mp4, or gif by suffix)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = pan_frames(64, 48, 4, seed)
    return write_gif(path, frames) if path.suffix == ".gif" else write_video(path, frames)


# ---- the naming rules --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("stem", "prompt", "index"),
    [
        ("a-cat-playing-piano-0", "a cat playing piano", 0),  # words joined by '-', the trailing index stripped
        ("A cat playing piano-4", "A cat playing piano", 4),  # VBench: the prompt as written, then -<i>
        ("a_dog_running_on_grass_12", "a dog running on grass", 12),
        ("A close-up of a dog's nose, at dawn-1", "A close-up of a dog's nose, at dawn", 1),
        ("two dogs and 3 cats-2", "two dogs and 3 cats", 2),  # a number among the words
        ("sunset over the sea", "sunset over the sea", None),  # no index
        ("clip_0007", None, 7),  # one word: a counter, not a prompt
        ("00012", None, None),
        ("sample_video_0001", None, 1),  # two words
        ("animatediff_realestatelora_emptyroom_0f47577ab3441480", None, None),  # a hash is no word
        ("motionlora_m01_01_zoomin", None, None),
        ("c1_static-s0", None, None),
    ],
)
def test_prompt_from_file_name(stem, prompt, index):
    assert prompt_from_name(stem) == (prompt, index)


def test_clip_ids_are_valid_and_collisions_numbered_in_order():
    ids = clip_ids(["m-a b", "m-a-b", "M-A-B", "m-\u00e9t\u00e9", "m-taken", "--", "x" * 300], taken=["m-taken"])
    assert ids == ["m-a-b", "m-a-b_2", "M-A-B_3", "m-t", "m-taken_2", "clip", "x" * 190]
    assert sanitise_clip_id("sora/A cat, at night [v2]-0") == "sora-A-cat-at-night-v2-0"


def test_a_scene_is_shared_only_by_platforms_with_the_same_prompt_and_index():
    clips = [
        ("a-cat-0", "a", "cat", 0),
        ("b-cat-0", "b", "cat", 0),  # the same prompt and index on another platform: one scene
        ("b-cat-1", "b", "cat", 1),  # another index, no other platform has it
        ("a-dog-0", "a", "dog", 0),
        ("a-dog-0_2", "a", "dog", 0),  # the same platform twice is not a cross-platform scene
        ("a-x", "a", None, None),
        ("b-x", "b", None, None),  # no prompt: a scene of its own, even with the same file name
    ]
    assert scene_ids(clips) == ["cat #0", "cat #0", "b-cat-1", "a-dog-0", "a-dog-0_2", "a-x", "b-x"]


# ---- plain folders ------------------------------------------------------------------------------


def test_plain_folder_fills_every_field_with_a_stated_source(tmp_path):
    root = tmp_path / "videos"
    _clip(root / "sora" / "a cat playing piano-0.mp4")
    _clip(root / "kling" / "a cat playing piano-0.gif")
    _clip(root / "kling" / "clip_0007.mp4")
    _clip(root / "loose.mp4")
    (root / "kling" / "notes.txt").write_text("not a clip")
    ds = scan_dataset(root)
    assert ds.layout == "folder"
    by_id = {e.clip_id: e for e in ds.entries}
    assert sorted(by_id) == [
        "kling-a-cat-playing-piano-0",
        "kling-clip_0007",
        "sora-a-cat-playing-piano-0",
        "videos-loose",
    ]
    sora, kling = by_id["sora-a-cat-playing-piano-0"], by_id["kling-a-cat-playing-piano-0"]
    assert sora.meta["prompt"] == kling.meta["prompt"] == "a cat playing piano"
    assert sora.scene_id == kling.scene_id == "a cat playing piano #0"  # two platforms, one scene
    assert sora.category is None and sora.meta["category"] is None  # never guessed
    assert (
        sora.meta["resolution"] == [64, 48] and sora.meta["fps"] == 24.0 and sora.meta["duration"] == round(4 / 24, 3)
    )
    assert sora.sources == {
        "clip_id": "file name",
        "prompt": "file name",
        "model": "folder",
        "model_version": "default",
        "seed": "default",
        "resolution": "clip file",
        "fps": "clip file",
        "duration": "clip file",
        "masks_path": "default",
        "category": "default",
        "scene_id": "default",
        "video": "folder",
    }
    counter = by_id["kling-clip_0007"]
    assert counter.meta["prompt"] is None and counter.sources["prompt"] == "default"
    assert counter.scene_id == "kling-clip_0007"
    loose = by_id["videos-loose"]
    assert loose.model == "videos" and loose.sources["model"] == "default"
    notes = " | ".join(ds.notes)
    assert "platform 'videos' (its name)" in notes
    assert "4 of 4 clip(s) have no category" in notes and "1 scene(s) shared" in notes


def test_plain_folder_numbers_colliding_ids_and_says_so(tmp_path):
    root = tmp_path / "d"
    _clip(root / "m" / "a b.mp4")
    _clip(root / "m" / "a-b.mp4")
    _clip(root / "m" / "a-b.gif")
    ds = scan_dataset(root)
    assert {e.video.name: e.clip_id for e in ds.entries} == {
        "a b.mp4": "m-a-b",
        "a-b.gif": "m-a-b_2",
        "a-b.mp4": "m-a-b_3",
    }
    assert any(n.startswith("m/a-b.gif: clip id m-a-b_2 (numbered") for n in ds.notes), ds.notes
    assert any(n.startswith("m/a-b.mp4: clip id m-a-b_3 (numbered") for n in ds.notes), ds.notes
    sidecars = {e.video.name: e.sidecar.name for e in ds.entries}
    assert len(set(sidecars.values())) == 3  # a-b.gif and a-b.mp4 cannot share a-b.meta.json


def test_plain_folder_leaves_out_results_and_hidden_folders_and_reports_unreadable_clips(tmp_path):
    root = tmp_path / "d"
    _clip(root / "m" / "x.mp4")
    _clip(root / "results" / "clips" / "m-x" / "overlay.mp4")
    (root / "results" / "bench.json").write_text("{}")
    _clip(root / ".cache" / "y.mp4")
    ds = scan_dataset(root)
    assert [e.clip_id for e in ds.entries] == ["m-x"]
    assert any("left out 1 results folder(s)" in n for n in ds.notes)
    (root / "m" / "bad.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 not really a video")
    (root / "m" / "short.gif").write_bytes(b"GIF89a")
    with pytest.raises(DatasetError) as exc:
        scan_dataset(root)
    assert [p.split(":")[0] for p in exc.value.problems] == ["m/bad.mp4", "m/short.gif"]
    assert all("unreadable clip" in p for p in exc.value.problems)


def test_empty_folder_names_every_layout_it_looked_for(tmp_path):
    (tmp_path / "readme.txt").write_text("no clips")
    with pytest.raises(DatasetError, match=r"no clips found: no clip metadata \(\*\.meta\.json\), no manifest.csv"):
        scan_dataset(tmp_path)


# ---- manifests ---------------------------------------------------------------------------------


def test_manifest_problems_are_listed_at_once_with_their_lines(tmp_path):
    for name in ("a", "b", "c", "d"):
        _clip(tmp_path / "clips" / f"{name}.mp4")
    (tmp_path / "manifest.csv").write_text(
        "path,model,category,clip_id,seed\n"
        "clips/a.mp4,m,C9,,1\n"
        "clips/missing.mp4,m,C1,,\n"
        "clips/b.mp4,m,C1,dup,\n"
        "clips/c.mp4,m,,dup,\n"
        "clips/d.mp4,m,C3,bad id!,[3]\n"
        ",m,C1,,\n"
    )
    with pytest.raises(DatasetError) as exc:
        scan_dataset(tmp_path)
    problems = exc.value.problems
    assert problems == [  # in line order
        "manifest.csv line 2: unknown category 'C9' (expected one of C1, C2, C3, C4, C5, C6, or empty for the "
        "scorer's)",
        "manifest.csv line 3: clip file clips/missing.mp4 does not exist",
        "manifest.csv line 5: clip_id 'dup' is also used by manifest.csv line 4",
        "manifest.csv line 6: clip_id 'bad id!' must start with a letter or a digit and hold only letters, digits "
        "and . _ + = - (at most 200 characters; it names the result folder), or be empty for one made from the file "
        "name",
        "manifest.csv line 7: no path (the clip file, relative to the manifest)",
    ]
    assert "5 problems in the dataset" in str(exc.value)


def test_manifest_without_a_path_column_and_broken_jsonl_lines(tmp_path):
    bad = tmp_path / "list.csv"
    bad.write_text("file,prompt\nx.mp4,a cat\n")
    with pytest.raises(DatasetError, match=r"list.csv: no 'path' column naming the clip files \(or 'video'\); its "):
        scan_dataset(bad)
    _clip(tmp_path / "x.mp4")
    jsonl = tmp_path / "clips.jsonl"
    jsonl.write_text(
        '{"path": "x.mp4", "category": "C2"}\n\n'
        "{not json\n"
        '["x.mp4"]\n'
        '{"path": "x.mp4", "video": "y.mp4"}\n'
        '{"path": "x.mp4", "category": "C2", "category": "C3"}\n'
    )
    with pytest.raises(DatasetError) as exc:
        scan_dataset(jsonl)
    assert [p.split(":")[0] for p in exc.value.problems] == [
        "clips.jsonl line 3",  # not JSON
        "clips.jsonl line 4",  # not an object
        "clips.jsonl line 5",  # path and video
        "clips.jsonl line 5",  # ... and the video it names is missing
        "clips.jsonl line 6",  # a key twice
    ]
    assert exc.value.problems[2] == "clips.jsonl line 5: gives both path and video"


def test_manifest_in_the_folder_or_given_by_path_reads_the_same(tmp_path):
    _clip(tmp_path / "sora" / "a cat playing piano-0.mp4")
    _clip(tmp_path / "kling" / "a cat playing piano-0.mp4")
    masks = tmp_path / "masks" / "k0"
    masks.mkdir(parents=True)
    cv2.imwrite(str(masks / "00000.png"), np.zeros((96, 128), np.uint8))  # masks are checked to be masks
    (tmp_path / "manifest.jsonl").write_text(
        '{"path": "sora/a cat playing piano-0.mp4", "category": "C3", "seed": 7, "reviewer": "ann"}\n'
        '{"video": "kling/a cat playing piano-0.mp4", "platform": "kling-2", "prompt": "a cat at a piano", '
        '"masks_path": "masks/k0", "scene_id": "piano"}\n'
    )
    ds = scan_dataset(tmp_path)
    assert ds.layout == "manifest" and ds.root == tmp_path / "manifest.jsonl"
    assert [(e.clip_id, e.meta) for e in ds.entries] == [
        (e.clip_id, e.meta) for e in scan_dataset(tmp_path / "manifest.jsonl").entries
    ]
    kling, sora = ds.entries
    assert (kling.clip_id, kling.model, kling.scene_id, kling.meta["prompt"]) == (
        "kling-2-a-cat-playing-piano-0",
        "kling-2",
        "piano",
        "a cat at a piano",
    )
    assert kling.masks == masks.resolve() and kling.meta["masks_path"] == "../masks/k0"
    assert kling.sources["model"] == kling.sources["prompt"] == kling.sources["masks_path"] == "manifest"
    assert (sora.model, sora.sources["model"], sora.category, sora.meta["seed"]) == ("sora", "folder", "C3", 7)
    assert sora.meta["reviewer"] == "ann"  # extra columns are kept
    assert sora.scene_id == sora.clip_id  # its prompt (from the file name) is on no other platform


def test_sidecars_win_over_a_manifest_beside_them(tmp_path):
    _clip(tmp_path / "m" / "x.mp4")
    (tmp_path / "manifest.csv").write_text("path,category\nm/x.mp4,C1\n")
    first = scan_dataset(tmp_path)
    assert first.layout == "manifest" and first.entries[0].category == "C1"
    (tmp_path / "m" / "x.meta.json").write_text(json.dumps({**first.entries[0].meta, "category": "C4"}))
    again = scan_dataset(tmp_path)
    assert again.layout == "sidecars" and again.entries[0].category == "C4"
    assert again.notes[0].startswith("manifest.csv is ignored: the sidecars")


# ---- geocon dataset -----------------------------------------------------------------------------


def test_geocon_dataset_lists_and_writes_sidecars_that_read_back_the_same(tmp_path):
    root = tmp_path / "videos"
    _clip(root / "sora" / "a cat playing piano-0.mp4")
    _clip(root / "kling" / "a cat playing piano-0.mp4", seed=1)
    _clip(root / "kling" / "a cat playing piano-0.gif", seed=2)
    _clip(root / "kling" / "00012.mp4", seed=3)
    before = scan_dataset(root)
    listed = _run("dataset", str(root))
    assert listed.exit_code == 0, listed.stderr
    assert "a plain folder of clips, 4 clip(s) on 2 platform(s) (kling, sora)" in listed.stdout
    assert "from scorer" in listed.stdout and "kling-00012" in listed.stdout
    assert "note: 4 of 4 clip(s) have no category" in listed.stderr
    assert not list(root.rglob("*.meta.json"))  # listing writes nothing

    written = _run("dataset", str(root), "--write")
    assert written.exit_code == 0, written.stderr
    assert "wrote 4 sidecar(s)" in written.stdout
    sidecars = sorted(p.relative_to(root).as_posix() for p in root.rglob("*.meta.json"))
    assert sidecars == [
        "kling/00012.meta.json",
        "kling/a cat playing piano-0.meta.json",  # the gif, first in path order
        "kling/a cat playing piano-0.mp4.meta.json",  # the mp4 beside it: a sidecar of its own
        "sora/a cat playing piano-0.meta.json",
    ]
    after = scan_dataset(root)
    assert after.layout == "sidecars"
    assert [(e.clip_id, e.video, e.masks, e.meta) for e in after.entries] == [
        (e.clip_id, e.video, e.masks, e.meta) for e in before.entries
    ]
    assert all(set(e.sources.values()) == {"sidecar"} for e in after.entries)

    edited = root / "kling" / "00012.meta.json"
    edited.write_text(json.dumps({**json.loads(edited.read_text()), "category": "C2"}))
    kept = _run("dataset", str(root), "--write")
    assert kept.exit_code == 0 and "kept 4 existing sidecar(s)" in kept.stdout
    assert json.loads(edited.read_text())["category"] == "C2"  # never overwritten without --force
    assert _run("dataset", str(root), "--force").exit_code == 2


def test_geocon_dataset_refuses_a_bad_dataset_in_one_sentence(tmp_path):
    proc = _run("dataset", str(tmp_path / "nowhere"))
    assert proc.exit_code == 2
    assert proc.stderr.strip().startswith("error: the dataset cannot be benchmarked:") and "not a folder" in proc.stderr
    assert "Traceback" not in proc.stderr


# ---- the expected-gate statistics count only given categories -----------------------------------


def test_anomaly_rates_and_consensus_leave_out_clips_without_a_given_category():
    pd = pytest.importorskip("pandas")
    from geocon_core.report import stats

    clips = pd.DataFrame(
        # a clip without a given category carries the scorer's category and no expected model
        [
            ("p", "C1", "H", "s1", "H", "H", True),
            ("p", "C1", "H", "s2", "F", "F", True),  # an anomaly
            ("p", "C1", None, "s3", "H", "H", True),  # not given: the scorer's C1
            ("q", "C3", None, "s3", "F", "F", True),  # the same scene, judged F: the scorer's C3
        ],
        columns=["model", "category", "expected_model", "scene_id", "gate_label", "gate_model", "pose_present"],
    )
    clips["status"] = "ok"
    rates = stats.gate_rates(clips).set_index(["model", "category"])
    p = rates.loc[("p", "C1")]
    assert (p.n_clips, p.n_expected) == (3, 2)
    assert p.anomaly_rate_present == 0.5 and p.anomaly_rate_fail_f == 0.5  # 1 of the 2 given, not 2 of 3
    assert p.f_rate_fail_f == pytest.approx(1 / 3)  # F-rates count every clip
    q = rates.loc[("q", "C3")]
    assert q.n_expected == 0 and q.anomaly_rate_fail_f != q.anomaly_rate_fail_f  # NaN: nothing to judge
    cons = stats.consensus(clips).set_index("scene_id")
    assert cons.loc["s3"].platforms == 2 and cons.loc["s3"].unanimous == False  # noqa: E712  one scene, not split


# ---- the acceptance: the same tables from every layout -------------------------------------------

PROMPTS = {"C1": "a quiet room seen by a still camera", "C3": "a camera gliding sideways past crates"}


@pytest.fixture(scope="module")
def layouts(tmp_path_factory) -> dict[str, Path]:
    """One tiny benchmark (3 platforms x 2 families, the ``elastic`` platform as GIF) in three
    layouts: a plain folder, the same files with hand-written sidecars, and a CSV manifest."""
    from geocon_core.synth import plan_benchmark, write_benchmark

    base = tmp_path_factory.mktemp("layouts")
    render = base / "render"
    write_benchmark(render, plan_benchmark(families=("C1", "C3"), scenes=1), width=128, height=96, num_frames=6)
    plain = base / "plain"
    rows = []
    for sidecar in sorted(render.rglob("*.meta.json")):
        meta = json.loads(sidecar.read_text())
        src = sidecar.parent / meta["video"]
        platform, family = meta["model"], meta["category"]
        name = f"{PROMPTS[family].replace(' ', '-')}-0"
        dst = plain / platform / f"{name}{'.gif' if platform == 'elastic' else '.mp4'}"
        dst.parent.mkdir(parents=True, exist_ok=True)
        if platform == "elastic":
            write_gif(dst, read_video(src))
        else:
            shutil.copy(src, dst)
        rows.append((platform, dst, family))
    sidecars = base / "sidecars"
    shutil.copytree(plain, sidecars)
    manifest = base / "manifest"
    shutil.copytree(plain, manifest)
    lines = ["path,category"]
    for platform, dst, family in rows:
        rel = dst.relative_to(plain)
        (sidecars / rel.parent / f"{dst.stem}.meta.json").write_text(
            json.dumps(
                {
                    "clip_id": f"{platform}-{dst.stem}",
                    "prompt": PROMPTS[family],
                    "model": platform,
                    "model_version": None,
                    "seed": None,
                    "resolution": [128, 96],
                    "fps": 24,
                    "duration": 0.25,
                    "masks_path": None,
                    "category": family,
                    "scene_id": f"{PROMPTS[family]} #0",
                }
            )
        )
        lines.append(f"{rel.as_posix()},{family}")
    (manifest / "clips.csv").write_text("\n".join(lines) + "\n")
    return {"plain": plain, "sidecars": sidecars, "manifest": manifest / "clips.csv"}


@pytest.fixture(scope="module")
def tables(layouts, tmp_path_factory) -> dict[str, dict]:
    pytest.importorskip("pyarrow")
    from geocon_core.bench import read_tables, run_bench
    from geocon_core.config import preset

    out = tmp_path_factory.mktemp("layout-results")
    got = {}
    for name, dataset in layouts.items():
        notes: list[str] = []
        summary = run_bench(dataset, out / name, preset("fast"), workers=1, on_note=notes.append)
        assert (summary.total, summary.failed) == (6, 0), name
        got[name] = {"tables": read_tables(out / name), "notes": notes, "results": out / name}
    return got


def test_manifest_and_plain_folder_give_the_tables_of_hand_written_sidecars(tables):
    pd = pytest.importorskip("pandas")
    hand = tables["sidecars"]["tables"]
    clips = hand["clips"]
    assert sorted(clips["model"].unique()) == ["breathing", "clean", "elastic"]
    assert set(clips["scene_id"]) == {f"{p} #0" for p in PROMPTS.values()}  # one scene per prompt, 3 platforms
    assert (clips["expected_model"] == clips["category"].map({"C1": "H", "C3": "F"})).all()
    for name in hand:  # the manifest states the categories: every table is the same
        pd.testing.assert_frame_equal(tables["manifest"]["tables"][name], hand[name], check_exact=True)
    # the plain folder gives no category: the scorer's stands in, and no clip has an expected gate
    scored = dict(zip(clips["clip_id"], clips["observed_category"], strict=True))
    plain = tables["plain"]["tables"]
    for name in hand:
        want = hand[name].copy()
        want["category"] = want["clip_id"].map(scored).astype(plain[name]["category"].dtype)
        if name == "clips":
            want["expected_model"] = None
        pd.testing.assert_frame_equal(plain[name], want, check_exact=True)
    assert plain["clips"]["category"].notna().all()
    assert any("6 of 6 clip(s) have no category" in n for n in tables["plain"]["notes"])
    assert not any("category" in n for n in tables["manifest"]["notes"])


def test_the_audit_app_lists_the_scorers_category_where_none_was_given(tables):
    """The audit app's clip list (read from the tables, or from each record when they are stale)
    shows a clip without a given category under the scorer's, with no expected gate."""
    from geocon_core.bench import read_tables
    from geocon_core.results import clip_from_record_json, read_bench_clips

    results = tables["plain"]["results"]
    scored = read_tables(results)["clips"].set_index("clip_id")["observed_category"].to_dict()
    clips = read_bench_clips(results)
    assert len(clips) == 6 and all(c.category == scored[c.clip_id] and c.expected_model is None for c in clips)
    for c in clips:  # the same from the record itself
        assert c.folder is not None
        status = json.loads((c.folder / "status.json").read_text())
        assert clip_from_record_json(c.clip_id, status, c.folder).category == scored[c.clip_id]


def test_categories_set_in_written_sidecars_reach_the_tables_without_scoring_again(layouts, tables):
    """The workflow of a plain folder: bench it, spell it out as sidecars, set the categories, bench
    again into the same results: nothing is scored twice and the tables are the manifest's."""
    pd = pytest.importorskip("pandas")
    from geocon_core.bench import read_tables, run_bench, write_sidecars
    from geocon_core.config import preset

    manifest_clips = tables["manifest"]["tables"]["clips"]
    given = dict(zip(manifest_clips["clip_id"], manifest_clips["category"], strict=True))
    written = write_sidecars(scan_dataset(layouts["plain"]))
    for sidecar in written.written:
        meta = json.loads(sidecar.read_text())
        sidecar.write_text(json.dumps({**meta, "category": given[meta["clip_id"]]}))
    notes: list[str] = []
    results = tables["plain"]["results"]
    summary = run_bench(layouts["plain"], results, preset("fast"), workers=1, on_note=notes.append)
    assert (summary.scored, summary.skipped) == (0, 6)
    assert "6 finished clip(s) took the dataset's new metadata (their scores are unchanged)" in notes
    again = read_tables(results)
    for name, want in tables["manifest"]["tables"].items():
        pd.testing.assert_frame_equal(again[name], want, check_exact=True)


@pytest.mark.full
def test_plain_folder_reads_folders_of_frames_as_clips(tmp_path):
    """A sub-folder of PNG/JPEG frames is one clip: its platform the folder above, its id and prompt
    from the folder's whole name, its rate the default; a folder with videos beside images stays a
    platform folder; `geocon bench` scores both kinds."""
    root = tmp_path / "videos"
    frames = pan_frames(64, 48, 4, 1)
    shot = write_pngs(root / "sora" / "a dolly shot past stalls-2", frames)
    _clip(root / "sora" / "a dolly shot past stalls-3.mp4")
    _clip(root / "kling" / "a dolly shot past stalls-2.mp4")  # the same scene as the frames of sora
    still = root / "kling" / "take.v2"  # a dot in a folder name is no suffix
    still.mkdir(parents=True)
    for i, f in enumerate(frames[:2]):
        assert cv2.imwrite(str(still / f"{i}.jpg"), f[:, :, ::-1])
    ds = scan_dataset(root)
    by_id = {e.clip_id: e for e in ds.entries}
    assert sorted(by_id) == [
        "kling-a-dolly-shot-past-stalls-2",
        "kling-take.v2",
        "sora-a-dolly-shot-past-stalls-2",
        "sora-a-dolly-shot-past-stalls-3",
    ]
    folder = by_id["sora-a-dolly-shot-past-stalls-2"]
    assert folder.video == shot and folder.model == "sora"
    assert folder.meta["prompt"] == "a dolly shot past stalls"
    assert folder.scene_id == by_id["kling-a-dolly-shot-past-stalls-2"].scene_id == "a dolly shot past stalls #2"
    assert folder.meta["fps"] == 24.0 and folder.sources["fps"] == "default"
    assert folder.meta["resolution"] == [64, 48] and folder.meta["duration"] == round(4 / 24, 3)
    assert any("2 folder(s) of PNG/JPEG frames read as one clip each" in n for n in ds.notes), ds.notes

    out = tmp_path / "results"
    res = _run("bench", str(root), "--out", str(out), "--preset", "fast", "--workers", "1")
    assert res.exit_code == 0, res.output
    status = {p.parent.name: json.loads(p.read_text())["status"] for p in (out / "clips").glob("*/status.json")}
    assert status == dict.fromkeys(by_id, "ok"), status


def test_sidecars_note_loose_clips_but_not_masks_folders(tmp_path):
    from geocon_core.bench import write_sidecars

    root = tmp_path / "d"
    _clip(root / "m" / "a cat playing piano-0.mp4")
    write_sidecars(scan_dataset(root))
    sidecar = next((root / "m").glob("*.meta.json"))
    write_pngs(root / "m" / "masks-of-a", [np.zeros((48, 64), np.uint8)] * 4)  # PNG labels, not frames
    meta = json.loads(sidecar.read_text())
    sidecar.write_text(json.dumps({**meta, "masks_path": "masks-of-a"}))
    write_pngs(root / "m" / "extra shot", pan_frames(64, 48, 3, 2))  # frames nobody described
    ds = scan_dataset(root, check_clips=False)
    assert ds.layout == "sidecars" and [e.masks.name for e in ds.entries] == ["masks-of-a"]
    loose = [n for n in ds.notes if "have no sidecar" in n]
    assert len(loose) == 1 and loose[0].startswith("1 clip(s) below") and "m/extra shot" in loose[0], ds.notes
