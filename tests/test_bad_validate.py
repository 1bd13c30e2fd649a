"""The validate catalogue: what ``geocon validate`` finds but cannot take as it is. An annotated
clip missing from its folder, one whose bytes do not hash to its annotated SHA-256, a clip in the
cache replaced since it was made, a case whose saved record is damaged or another case's: each is
named in the run's summary (the terminal, ``validation.md`` and ``validation.json``: the count and
what to do), and a case that cannot stand is scored again (or, with ``--report-only``, left out),
never a traceback.

The cases use the framework of :mod:`tests.test_bad_input`: a tiny ``data/`` folder (the C4 clip
as ``a.mp4``, a pan as ``b.mp4``), a two-row annotation file ``ann.csv`` and the fast preset, so
each run takes a few seconds."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from .test_bad_input import Case, Ctx, Outcome, assets, build_all, ctx, run_case  # noqa: F401

HEADER = "clip,root,regime,gate,movers,static_camera,source,stable_scene,category,artifacts,note,sha256,exclude"
SMALL = ("--no-peer", "--max-frames", "8", "--preset", "fast", "--out", "out")
REAL = ("validate", "--no-synthetic", "--data", "data", "--annotations", "ann.csv", *SMALL)
CUT = ("validate", "--no-synthetic", "--data", "data", "--annotations", "ann.csv", "--no-peer", "--max-frames", "4",
       "--preset", "fast", "--out", "out")  # fmt: skip
"""The real clips cut to 4 frames (a folder of frames in the cache)."""
PLANTED = (*REAL, "--planted", "--plant-kinds", "slide", "--severity", "low", "--no-real")
SYNTH = ("validate", "--no-real", "--heights", "32", "--codecs", "crf28", "--families", "C1", "--failures", "none",
         "--frames", "8", *SMALL)  # fmt: skip
WRONG = "0" * 64


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def row(clip: str, root: str = "data", sha: str | None = None, exclude: str = "") -> Callable[[Ctx], None]:
    """A row of ``ann.csv`` for ``clip`` of ``root`` (a real-camera clip), hashing as the file in
    that root does (or as ``sha``)."""

    def build(c: Ctx) -> None:
        folder = {"data": "data", "real2": "real2", "footage": "foot"}[root]
        file = c.tmp / folder / clip
        digest = sha if sha is not None else (_sha(file) if file.is_file() else WRONG)
        with (c.tmp / "ann.csv").open("a", encoding="utf-8") as f:
            f.write(f"{clip},{root},static,H,0,yes,real,yes,C1,,a clip,{digest},{exclude}\n")

    return build


def tiny(c: Ctx) -> None:
    """``data/a.mp4`` (the C4 clip), ``data/b.mp4`` (a pan) and ``ann.csv`` annotating both."""
    c.c4()
    c.copy(c.tmp / "c4.mp4", "data/a.mp4")
    c.pan("data/b.mp4")
    c.write("ann.csv", HEADER + "\n")
    row("a.mp4")(c)
    row("b.mp4")(c)


def ran(*argv: str) -> Callable[[Ctx], None]:
    """``geocon ARGV`` run once (an earlier run that this case resumes)."""

    def build(c: Ctx) -> None:
        res = c.invoke(list(argv))
        assert res.code == 0, res.describe()

    return build


def validated(c: Ctx) -> None:
    tiny(c)
    ran(*REAL)(c)


def planted(c: Ctx) -> None:
    tiny(c)
    ran(*PLANTED)(c)


def synthetic(c: Ctx) -> None:
    ran(*SYNTH)(c)


def one(pattern: str) -> Callable[[Ctx], Path]:
    def find(c: Ctx) -> Path:
        found = sorted(c.tmp.glob(pattern))
        assert len(found) == 1, f"{pattern}: {found}"
        return found[0]

    return find


def put(target: str, source: str | bytes | None) -> Callable[[Ctx], None]:
    """``target`` (a glob matching one path) replaced by the file ``source`` (a glob), by bytes, or
    removed (None)."""

    def build(c: Ctx) -> None:
        path = one(target)(c)
        if source is None:
            path.unlink()
        elif isinstance(source, bytes):
            path.write_bytes(source)
        else:
            shutil.copyfile(one(source)(c), path)

    return build


def cut(target: str, keep: int) -> Callable[[Ctx], None]:
    def build(c: Ctx) -> None:
        path = one(target)(c)
        path.write_bytes(path.read_bytes()[:keep])

    return build


def swap_folder(c: Ctx) -> None:
    shutil.rmtree(c.tmp / "out/cases/real__a.mp4")
    shutil.copytree(c.tmp / "out/cases/real__b.mp4", c.tmp / "out/cases/real__a.mp4")


def extra_clip(c: Ctx) -> None:
    """``data/c.mp4``: a clip no annotation names (scored, unannotated)."""
    c.pan("data/c.mp4")


# --- checks ---------------------------------------------------------------------------------------


def notes(c: Ctx) -> list[str]:
    return json.loads((c.tmp / "out" / "validation.json").read_text())["notes"]


def noted(*words: str) -> Callable[[Ctx, Outcome], None]:
    """The run's summary names ``words`` in one note: on the terminal, in ``validation.json`` and
    in ``validation.md``."""

    def check(c: Ctx, res: Outcome) -> None:
        said = [n for n in notes(c) if all(w in n for w in words)]
        assert said, f"no note says {words}: {notes(c)}"
        terminal = " ".join(res.stdout.split())
        assert " ".join(said[0].split()) in terminal, f"the terminal does not show the note: {terminal[-800:]!r}"
        assert said[0] in (c.tmp / "out" / "validation.md").read_text(), "validation.md does not hold the note"

    return check


def no_notes(c: Ctx, res: Outcome) -> None:
    assert notes(c) == [] and "note:" not in res.stdout, notes(c)


def cases_are(*ids: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        got = sorted(r["case_id"] for r in json.loads((c.tmp / "out" / "validation.json").read_text())["cases"])
        assert got == sorted(ids), got

    return check


def all_of(*checks: Callable[[Ctx, Outcome], None]) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, res: Outcome) -> None:
        for one_check in checks:
            one_check(c, res)

    return check


def _dedupe(c: Ctx, clip: str) -> None:
    """Keep the last row of ``ann.csv`` for ``clip`` (a row written again with another hash)."""
    lines = (c.tmp / "ann.csv").read_text().splitlines()
    mine = [i for i, line in enumerate(lines) if line.startswith(f"{clip},")]
    kept = [line for i, line in enumerate(lines) if i not in mine[:-1]]
    (c.tmp / "ann.csv").write_text("\n".join(kept) + "\n")


def verdicts_differ(c: Ctx, _res: Outcome) -> None:
    """The two cases were scored from their own clips (a C4 scene and a pan read differently)."""
    rows = {r["case_id"]: r for r in json.loads((c.tmp / "out" / "validation.json").read_text())["cases"]}
    a, b = rows["real__a.mp4"], rows["real__b.mp4"]
    assert (a["ir"], a["ge"], a["objects"]) != (b["ir"], b["ge"], b["objects"]), "case a holds case b's record"


BOTH = ("real__a.mp4", "real__b.mp4")
PLANTS = ("planted__real__a.mp4__clean", "planted__real__a.mp4__slide-low-s0", "planted__real__b.mp4__clean",
          "planted__real__b.mp4__slide-low-s0")  # fmt: skip
AGAIN = "case(s) were scored again, as what was saved for them could not stand for them"
REMADE = "were not as they were made, and were made again"

# --- the catalogue --------------------------------------------------------------------------------

ANNOTATED = [
    Case("a-clean-run-names-nothing", tiny, REAL, 0, check=all_of(no_notes, cases_are(*BOTH))),
    Case("an-annotated-clip-missing-from-data", build_all(tiny, row("gone.mp4")), REAL, 0,
         check=all_of(noted("1 annotated clip(s) are not scored", "not found in --data data", "copy them into --data",
                            "gone.mp4"), cases_are(*BOTH))),
    Case("an-excluded-clip-missing-from-data-is-not-named", build_all(tiny, row("gone.mp4", exclude="blurred")),
         REAL, 0, check=no_notes),
    Case("a-data-clip-of-other-bytes-than-annotated", build_all(tiny, put("data/b.mp4", "data/a.mp4")), REAL, 0,
         check=all_of(noted("1 annotated clip(s) are not scored", "do not hash to the annotated SHA-256",
                            "data/b.mp4"), cases_are("real__a.mp4"))),
    Case("a-wrong-sha256-in-the-annotations", build_all(tiny, row("a.mp4", sha=WRONG),
                                                         lambda c: _dedupe(c, "a.mp4")), REAL, 0,
         check=all_of(noted("do not hash to the annotated SHA-256", "data/a.mp4"), cases_are("real__b.mp4"))),
    Case("a-real2-clip-of-other-bytes-than-annotated",
         build_all(tiny, lambda c: c.pan("real2/c.mp4"), row("c.mp4", "real2", sha=WRONG)),
         (*REAL, "--real2", "real2"), 0,
         check=all_of(noted("do not hash to the annotated SHA-256", "real2/c.mp4"), cases_are(*BOTH))),
    Case("an-annotated-clip-missing-from-real2", build_all(tiny, lambda c: (c.tmp / "real2").mkdir(),
                                                           row("gone.mp4", "real2")),
         (*REAL, "--real2", "real2"), 0,
         check=noted("1 annotated clip(s) are not scored", "not found in --real2 real2", "gone.mp4")),
    Case("a-footage-clip-of-other-bytes-than-annotated",
         build_all(tiny, lambda c: c.pan("foot/f.mp4"), row("f.mp4", "footage", sha=WRONG)),
         (*REAL, "--footage", "foot"), 0,
         check=all_of(noted("do not hash", "foot/f.mp4", "geocon footage status"), cases_are(*BOTH))),
    Case("an-annotated-clip-missing-from-the-footage-cache",
         build_all(tiny, lambda c: (c.tmp / "foot").mkdir(), row("gone.mp4", "footage")),
         (*REAL, "--footage", "foot"), 0,
         check=noted("not found in the footage cache foot", "geocon footage fill --from DIR", "gone.mp4")),
    Case("a-planted-source-of-other-bytes-than-annotated", build_all(tiny, put("data/b.mp4", "data/a.mp4")),
         PLANTED, 0, check=all_of(noted("do not hash", "data/b.mp4"), cases_are(*PLANTS[:2]))),
    Case("a-planted-source-missing", build_all(tiny, row("gone.mp4")), PLANTED, 0,
         check=all_of(noted("not found in --data data", "gone.mp4"), cases_are(*PLANTS))),
]  # fmt: skip

CACHE = [
    Case("a-planted-clip-replaced-in-the-cache",
         build_all(planted, put("out/cache/plant-a-slide-*/a.slide-low-s0.mp4",
                                "out/cache/plant-b-slide-*/b.slide-low-s0.mp4")), PLANTED, 0,
         check=all_of(noted("1 clip(s) in the cache", REMADE, "a.slide-low-s0.mp4 was replaced since it was made"),
                      cases_are(*PLANTS))),
    Case("a-clean-reencode-replaced-in-the-cache",
         build_all(planted, put("out/cache/plant-a-clean-*/a.clean.mp4", "out/cache/plant-b-clean-*/b.clean.mp4")),
         PLANTED, 0, check=all_of(noted(REMADE, "a.clean.mp4 was replaced"), cases_are(*PLANTS))),
    Case("a-planted-ground-truth-removed-from-the-cache",
         build_all(planted, put("out/cache/plant-a-slide-*/a.slide-low-s0.gt.json", None)), PLANTED, 0,
         check=all_of(noted(REMADE, "a.slide-low-s0.gt.json is gone"), cases_are(*PLANTS))),
    Case("a-damaged-done-json-in-the-cache", build_all(validated, put("out/cache/real-a-*/done.json", b"{")), REAL,
         0, check=all_of(noted(REMADE, "done.json cannot be read"), cases_are(*BOTH))),
    Case("a-done-json-without-its-clip", build_all(validated, put("out/cache/real-a-*/done.json", b"{}")), REAL, 0,
         check=all_of(noted(REMADE, "done.json is not the record of a finished cache entry"), cases_are(*BOTH))),
    Case("a-planted-done-json-that-is-an-array",
         build_all(planted, put("out/cache/plant-a-slide-*/done.json", b"[]")), PLANTED, 0,
         check=all_of(noted(REMADE, "not a JSON object"), cases_are(*PLANTS))),
    Case("a-frame-of-a-cut-clip-replaced-in-the-cache",
         build_all(tiny, ran(*CUT), put("out/cache/real-a-*/frames/00000.png", "out/cache/real-a-*/frames/00003.png")),
         CUT, 0,
         check=all_of(noted(REMADE, "frames was replaced"), cases_are(*BOTH))),
    Case("a-synthetic-encoding-replaced-in-the-cache",
         build_all(tiny, synthetic, put("out/cache/synth-*/*.crf28.mp4", "data/b.mp4")), SYNTH, 0,
         check=all_of(noted(REMADE, ".crf28.mp4 was replaced"), cases_are("C1__clean__h32__crf28"))),
    Case("a-synthetic-frame-replaced-in-the-cache",
         build_all(synthetic, put("out/cache/synth-*/*.frames/00000.png", b"\x89PNG not a frame")), SYNTH, 0,
         check=all_of(noted(REMADE, "was replaced since it was made"), cases_are("C1__clean__h32__crf28"))),
]  # fmt: skip

RECORDS = [
    Case("a-record-json-of-another-case",
         build_all(validated, put("out/cases/real__a.mp4/record.json", "out/cases/real__b.mp4/record.json")), REAL,
         0, check=all_of(noted("1 " + AGAIN, "real__a.mp4", "belongs to another record"), cases_are(*BOTH))),
    Case("a-whole-record-of-another-case",
         build_all(validated, put("out/cases/real__a.mp4/record.json", "out/cases/real__b.mp4/record.json"),
                   put("out/cases/real__a.mp4/matches.npz", "out/cases/real__b.mp4/matches.npz")), REAL, 0,
         check=all_of(noted(AGAIN, "scored from other bytes than data/a.mp4 holds now"), cases_are(*BOTH),
                      verdicts_differ)),
    Case("a-case-folder-of-another-case", build_all(validated, swap_folder), REAL, 0,
         check=all_of(noted(AGAIN, "is that of the case 'real__b.mp4', not of real__a.mp4"), cases_are(*BOTH),
                      verdicts_differ)),
    Case("a-truncated-record-json", build_all(validated, cut("out/cases/real__a.mp4/record.json", 500)), REAL, 0,
         check=all_of(noted(AGAIN, "record.json is not a readable GeoCon record"), cases_are(*BOTH))),
    Case("a-truncated-matches-npz", build_all(validated, cut("out/cases/real__a.mp4/matches.npz", 500)), REAL, 0,
         check=all_of(noted(AGAIN, "matches.npz is missing or not a whole .npz archive"), cases_are(*BOTH))),
    Case("a-damaged-case-json", build_all(validated, put("out/cases/real__a.mp4/case.json", b"{")), REAL, 0,
         check=all_of(noted(AGAIN, "case.json is damaged"), cases_are(*BOTH))),
    Case("a-case-json-that-is-an-array", build_all(validated, put("out/cases/real__a.mp4/case.json", b"[]")), REAL,
         0, check=all_of(noted(AGAIN, "case.json is damaged (not a JSON object)"), cases_are(*BOTH))),
    Case("a-record-json-removed-from-a-case", build_all(validated, put("out/cases/real__a.mp4/record.json", None)),
         REAL, 0, check=all_of(noted(AGAIN, "record.json does not exist"), cases_are(*BOTH))),
    Case("an-unannotated-clip-replaced-in-data",
         build_all(tiny, extra_clip, ran(*REAL), put("data/c.mp4", "data/a.mp4")), REAL, 0,
         check=all_of(noted(AGAIN, "real__c.mp4", "its clip data/c.mp4 changed since it was scored"),
                      cases_are(*BOTH, "real__c.mp4"))),
    Case("report-only-with-a-truncated-record-json",
         build_all(validated, cut("out/cases/real__a.mp4/record.json", 500)), (*REAL, "--report-only"), 0,
         check=all_of(noted("left out of this report", "run without --report-only", "real__a.mp4"),
                      cases_are("real__b.mp4"))),
    Case("report-only-with-a-record-of-another-case",
         build_all(validated, put("out/cases/real__a.mp4/record.json", "out/cases/real__b.mp4/record.json")),
         (*REAL, "--report-only"), 0,
         check=all_of(noted("left out of this report", "belongs to another record"), cases_are("real__b.mp4"))),
    Case("report-only-of-a-whole-run-names-nothing", validated, (*REAL, "--report-only"), 0,
         check=all_of(no_notes, cases_are(*BOTH))),
]  # fmt: skip


CASES = ANNOTATED + CACHE + RECORDS


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_validate(case: Case, ctx: Ctx):  # noqa: F811
    run_case(case, ctx)


# --- the rules' one home --------------------------------------------------------------------------


@pytest.mark.full
def test_the_fit_names_a_damaged_case_and_a_case_of_another(ctx: Ctx):  # noqa: F811
    """``geocon validate --fit`` reads the cases of ``--out``: a ``case.json`` that cannot be read,
    or that is another case's, is a line of what was left out, never skipped without a word."""
    from geocon_core.config import preset
    from geocon_core.validation import fit_cases, read_annotations

    validated(ctx)
    ctx.pan("data/c.mp4")
    ran(*REAL)(ctx)
    (ctx.tmp / "out/cases/real__a.mp4/case.json").write_bytes(b"{")
    shutil.rmtree(ctx.tmp / "out/cases/real__c.mp4")
    shutil.copytree(ctx.tmp / "out/cases/real__b.mp4", ctx.tmp / "out/cases/real__c.mp4")
    rows, problems = fit_cases(ctx.tmp / "out/cases", read_annotations(ctx.tmp / "ann.csv"), preset("audit"))
    assert [r.case_id for r in rows] == ["real__b.mp4"]
    assert problems == [
        "real__a.mp4: its case.json cannot be read (JSONDecodeError)",
        "real__c.mp4: its case.json is not this case's (it names 'real__b.mp4')",
    ]


def test_an_annotated_clip_of_other_bytes_is_left_out_of_the_plan(tmp_path: Path):
    from geocon_core.validation import Annotation, ValidationPlan, plan_cases, wrong_clips

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "a.mp4").write_bytes(b"a")
    (tmp_path / "data" / "b.mp4").write_bytes(b"b")

    def note(clip: str, sha: str) -> Annotation:
        return Annotation(clip, "static", "H", 0, True, "real", True, "C1", "", "", sha256=sha)

    notes = {"data:a.mp4": note("a.mp4", hashlib.sha256(b"a").hexdigest()), "data:b.mp4": note("b.mp4", WRONG)}
    plan = ValidationPlan(data=tmp_path / "data", synthetic=False)
    assert [a.key for a in wrong_clips(plan, notes)] == ["data:b.mp4"]
    assert [c.case_id for c in plan_cases(plan, notes)] == ["real__a.mp4"]  # not scored as unannotated either


def test_a_cache_entry_names_what_is_wrong_with_it(tmp_path: Path):
    from geocon_core.validation import CaseSpec
    from geocon_core.validation.prepare import entry_problem

    case = CaseSpec("planted__x__clean", "planted", source="x.mp4")
    entry = tmp_path / "entry"
    entry.mkdir()
    assert entry_problem(case, entry) is None  # not finished: nothing to say
    (entry / "c.mp4").write_bytes(b"clip")
    from geocon_core.media import clip_fingerprint

    done = {"clip": "c.mp4", "truth": None, "source": "x.mp4", "made": {"c.mp4": clip_fingerprint(entry / "c.mp4")}}
    (entry / "done.json").write_text(json.dumps(done))
    assert entry_problem(case, entry) is None
    (entry / "c.mp4").write_bytes(b"another clip")
    assert entry_problem(case, entry) == f"{entry / 'c.mp4'} was replaced since it was made"
    (entry / "done.json").write_text(json.dumps({k: v for k, v in done.items() if k != "made"}))
    assert entry_problem(case, entry) is None  # an entry made before fingerprints were kept is taken as it is
    (entry / "done.json").write_text("[")
    assert "cannot be read" in str(entry_problem(case, entry))
