"""The clip-model catalogue: the clip model as versioned data. A record made with another clip
model (an earlier release's, a model fitted anew) is scored again when ``geocon bench`` resumes
(and the run says which clips and why), opens in ``geocon view`` and the audit app with the verdict
it was made with and a note naming the model's digest; a clip model file that cannot be used
(missing, not JSON, a field of the wrong type or out of range, another digest than the presets
pin) is one sentence naming the file and the field in ``score``, ``view``, ``serve``, ``bench`` and
``validate``, before any work; ``geocon doctor`` checks it.

The cases use the framework of :mod:`tests.test_bad_input`. No case touches the package's own
``clip_model.json``: the fixture :func:`mctx` copies it into the case's folder (``pkg/``) and
points the package's model folder there, and a case damages the copy."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import geocon_core.signals.model as model_module
from geocon_core.config import ScoreConfig, config_hash
from geocon_core.config.stages import SHIPPED_MODEL_DIGEST

from .test_bad_input import FAST, Case, Ctx, Outcome, assets, build_all, ctx, run_case  # noqa: F401

OTHER = "0123456789ab"
"""The digest of a clip model this GeoCon does not have (an earlier release's, say)."""
AUDIT = ("--preset", "audit")
SHIPPED = Path(model_module.__file__).resolve().parent / "clip_model.json"
"""The package's own clip model (read, never written)."""


@pytest.fixture()
def mctx(ctx: Ctx, monkeypatch: pytest.MonkeyPatch) -> Ctx:  # noqa: F811
    """A case folder whose ``pkg/clip_model.json`` (a copy of the shipped one) is the package's
    clip model for the case."""
    pkg = ctx.tmp / "pkg"
    pkg.mkdir()
    shutil.copyfile(SHIPPED, pkg / "clip_model.json")
    monkeypatch.setattr(model_module, "MODEL_DIR", pkg, raising=False)
    monkeypatch.setattr(model_module, "__file__", str(pkg / "model.py"))  # where earlier code looked
    return ctx


# --- builders -------------------------------------------------------------------------------------


def audit_record(c: Ctx) -> None:
    """``rec``: the C4 clip (``c4.mp4``) scored with the audit preset (the clip model decides it)."""
    c.c4()
    res = c.invoke(["score", "c4.mp4", *AUDIT, "--out", "rec"])
    assert res.code == 0, res.describe()
    assert json.loads((c.tmp / "rec" / "record.json").read_text())["readings"] is not None


def edit_json(path: str, change: Callable[[dict[str, Any]], None]) -> Callable[[Ctx], None]:
    def build(c: Ctx) -> None:
        file = c.tmp / path
        doc = json.loads(file.read_text())
        change(doc)
        file.write_text(json.dumps(doc, indent=1))

    return build


def pin(digest: str) -> Callable[[dict[str, Any]], None]:
    """A record's (or a ``bench.json``'s) configuration pinned to the clip model ``digest``, its
    hash made anew as the GeoCon that wrote it would have."""

    def change(doc: dict[str, Any]) -> None:
        doc["config"]["signals"]["model_sha256"] = digest
        doc["config_hash"] = config_hash(ScoreConfig.from_dict(doc["config"]))

    return change


def pinned_record(digest: str) -> Callable[[Ctx], None]:
    return build_all(audit_record, edit_json("rec/record.json", pin(digest)))


def model_edit(change: Callable[[dict[str, Any]], None]) -> Callable[[Ctx], None]:
    """The case's clip model file edited by ``change`` (its parsed JSON)."""
    return edit_json("pkg/clip_model.json", change)


def model_bytes(data: bytes | None) -> Callable[[Ctx], None]:
    """The case's clip model file replaced by ``data`` (removed when None)."""

    def build(c: Ctx) -> None:
        if data is None:
            (c.tmp / "pkg" / "clip_model.json").unlink()
        else:
            (c.tmp / "pkg" / "clip_model.json").write_bytes(data)

    return build


def term(i: int, **fields: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["terms"][i].update(fields)


def weight_as_string(d: dict[str, Any]) -> None:
    d["terms"][1]["weight"] = str(d["terms"][1]["weight"])[:6]


def benched(c: Ctx) -> None:
    """``ds/a.mp4`` (the C4 clip) and ``ds/b.mp4`` (a pan) scored by ``geocon bench`` with the audit
    preset into ``out``."""
    c.c4()
    c.copy(c.tmp / "c4.mp4", "ds/a.mp4")
    c.pan("ds/b.mp4")
    res = c.invoke(["bench", "ds", "--out", "out", *AUDIT, "--no-rrd"])
    assert res.code == 0, res.describe()


def bench_pinned(*clips: str, manifest: bool = False) -> Callable[[Ctx], None]:
    """``benched``, then the records of ``clips`` (and ``bench.json`` with ``manifest``) pinned to
    :data:`OTHER`: results of an earlier release, or records copied in from one."""
    steps: list[Callable[[Ctx], object]] = [benched]
    steps += [edit_json(f"out/clips/{clip}/record.json", pin(OTHER)) for clip in clips]
    if manifest:
        steps.append(edit_json("out/bench.json", pin(OTHER)))
    return build_all(*steps)


# --- checks ---------------------------------------------------------------------------------------


def said(*words: str, stream: str = "stderr") -> Callable[[Ctx, Outcome], None]:
    def check(_c: Ctx, res: Outcome) -> None:
        text = " ".join(getattr(res, stream).split())
        missing = [w for w in words if w not in text]
        assert not missing, f"{stream} does not say {missing}: {text[-600:]!r}"

    return check


def not_said(*words: str) -> Callable[[Ctx, Outcome], None]:
    def check(_c: Ctx, res: Outcome) -> None:
        text = " ".join((res.stdout + res.stderr).split())
        assert not [w for w in words if w in text], text[-600:]

    return check


def all_of(*checks: Callable[[Ctx, Outcome], None]) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, res: Outcome) -> None:
        for one in checks:
            one(c, res)

    return check


def rescored(*clips: str) -> Callable[[Ctx, Outcome], None]:
    """The records of ``clips`` are made with the shipped model now, and so is ``bench.json``."""

    def check(c: Ctx, _res: Outcome) -> None:
        for clip in clips:
            doc = json.loads((c.tmp / "out" / "clips" / clip / "record.json").read_text())
            assert doc["config"]["signals"]["model_sha256"] == SHIPPED_MODEL_DIGEST, clip
        bench = json.loads((c.tmp / "out" / "bench.json").read_text())
        assert bench["config"]["signals"]["model_sha256"] == SHIPPED_MODEL_DIGEST
        assert (c.tmp / "out" / "tables" / "clips.parquet").is_file()

    return check


def made_with_shipped(folder: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        doc = json.loads((c.tmp / folder / "record.json").read_text())
        assert doc["config"]["signals"]["model_sha256"] == SHIPPED_MODEL_DIGEST, "not made with the shipped model"

    return check


def saved(name: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        assert (c.tmp / name).stat().st_size > 0, f"{name} was not written"

    return check


def view(target: str = "rec") -> tuple[str, ...]:
    return ("view", target, "--headless", "--save", "x.rrd")


def score(preset: tuple[str, ...] = AUDIT) -> tuple[str, ...]:
    return ("score", "c4.mp4", *preset, "--out", "out")


def c4(c: Ctx) -> None:
    c.c4()


WEIGHT_WORDS = ("clip_model.json", "terms[1] ('unkept') weight", "not a number")

# --- the catalogue --------------------------------------------------------------------------------

RECORDS = [
    Case("bench-resume-of-a-record-of-another-model", bench_pinned("ds-a"),
         ("bench", "ds", "--out", "out", *AUDIT, "--no-rrd"), 0,
         check=all_of(said("1 finished clip(s) were made with the clip model 0123456789ab", "scored again: ds-a"),
                      rescored("ds-a"))),
    Case("bench-resume-of-the-results-of-an-earlier-release", bench_pinned("ds-a", "ds-b", manifest=True),
         ("bench", "ds", "--out", "out", *AUDIT, "--no-rrd"), 0,
         check=all_of(said("out was scored with the clip model 0123456789ab", "2 finished clip(s)", "ds-a, ds-b"),
                      rescored("ds-a", "ds-b"))),
    Case("bench-resume-of-another-model-and-another-setting",
         build_all(bench_pinned("ds-a", "ds-b", manifest=True),
                   edit_json("out/bench.json", lambda d: d["config"]["signals"].update(decisive_shortfall=7.0))),
         ("bench", "ds", "--out", "out", *AUDIT, "--no-rrd"), 2, ("out", "another configuration")),
    Case("view-of-a-record-of-another-model", pinned_record(OTHER), view(), 0,
         check=all_of(said("made with the clip model 0123456789ab", f"not this GeoCon's {SHIPPED_MODEL_DIGEST}"),
                      saved("x.rrd")),
         needs=("rerun",)),
    Case("view-of-a-record-of-another-model-with-a-damaged-verdict",
         build_all(pinned_record(OTHER), edit_json("rec/record.json", lambda d: d["summary"]["verdict"].update(
             verdict="maybe"))),
         view(), 2, ("rec/record.json", "0123456789ab", "score the clip again"), needs=("rerun",)),
    Case("view-of-a-record-pinned-to-any-model", pinned_record(""), view(), 0,
         check=all_of(not_said("made with the clip model"), saved("x.rrd")), needs=("rerun",)),
    Case("view-of-a-fast-record-pinned-to-another-model",
         build_all(lambda c: c.record("rec"), edit_json("rec/record.json", pin(OTHER))), view(), 0,
         check=all_of(not_said("made with the clip model"), saved("x.rrd")), needs=("rerun",)),
    Case("view-of-an-audit-record-when-the-model-file-was-edited",
         build_all(audit_record, model_edit(term(1, weight=1.5))), view(), 0,
         check=all_of(said(f"made with the clip model {SHIPPED_MODEL_DIGEST}"), saved("x.rrd")), needs=("rerun",)),
    Case("score-into-the-record-of-another-model", build_all(pinned_record(OTHER), lambda c: (c.tmp / "rec").rename(
         c.tmp / "out")), score(), 0, check=all_of(not_said("made with the clip model"), made_with_shipped("out"))),
]  # fmt: skip

MODEL_FILES = [
    Case("score-with-a-weight-written-as-a-string", build_all(c4, model_edit(weight_as_string)), score(), 2,
         WEIGHT_WORDS),
    Case("view-with-a-weight-written-as-a-string", build_all(audit_record, model_edit(weight_as_string)), view(), 2,
         WEIGHT_WORDS, needs=("rerun",)),
    Case("serve-with-a-weight-written-as-a-string", build_all(benched, model_edit(weight_as_string)),
         ("serve", "out", "--port", "0"), 2, WEIGHT_WORDS, needs=("viser",)),
    Case("bench-with-a-weight-written-as-a-string",
         build_all(c4, lambda c: c.copy(c.tmp / "c4.mp4", "ds/a.mp4"), model_edit(weight_as_string)),
         ("bench", "ds", "--out", "out", *AUDIT, "--no-rrd"), 2, WEIGHT_WORDS),
    Case("validate-with-a-weight-written-as-a-string", model_edit(weight_as_string),
         ("validate", "--quick", "--no-real", "--no-peer", "--families", "C1", "--failures", "none", "--out", "v"), 2,
         WEIGHT_WORDS),
    Case("score-fast-with-a-damaged-model-file", build_all(c4, model_edit(weight_as_string)), score(FAST), 0),
    Case("score-with-the-model-file-missing", build_all(c4, model_bytes(None)), score(), 2,
         ("pkg/clip_model.json", "does not exist", "reinstall GeoCon")),
    Case("score-with-a-model-file-cut-short",
         build_all(c4, lambda c: model_bytes(SHIPPED.read_bytes()[:300])(c)), score(), 2,
         ("pkg/clip_model.json", "is not JSON")),
    Case("score-with-a-model-file-in-utf16",
         build_all(c4, model_bytes(SHIPPED.read_text().encode("utf-16"))), score(), 2,
         ("pkg/clip_model.json", "is not JSON")),
    Case("score-with-a-model-file-that-is-an-array", build_all(c4, model_bytes(b"[1, 2]")), score(), 2,
         ("pkg/clip_model.json", "JSON array", "not a clip model")),
    Case("score-with-a-nan-weight", build_all(c4, model_bytes(
        SHIPPED.read_text().replace('"weight": 0.0', '"weight": NaN', 1).encode())), score(), 2,
         ("weight is nan", "not a finite number")),
    Case("score-with-a-negative-weight", build_all(c4, model_edit(term(0, weight=-0.5))), score(), 2,
         ("terms[0] ('shortfall') weight is -0.5", "at least 0")),
    Case("score-with-a-boolean-weight", build_all(c4, model_edit(term(0, weight=True))), score(), 2,
         ("weight is true (a JSON boolean)", "not a number")),
    Case("score-with-a-scale-of-zero", build_all(c4, model_edit(term(2, scale=0))), score(), 2,
         ("terms[2] ('flow_failure') scale is 0", "above 0")),
    Case("score-with-a-center-written-as-text", build_all(c4, model_edit(term(0, center="middle"))), score(), 2,
         ("center is \"middle\" (a JSON string)",)),
    Case("score-with-a-threshold-of-1.5", build_all(c4, model_edit(lambda d: d.update(threshold=1.5))), score(), 2,
         ("threshold is 1.5", "outside (0, 1)")),
    Case("score-with-a-threshold-written-as-text",
         build_all(c4, model_edit(lambda d: d.update(threshold="0.5"))), score(), 2,
         ("threshold is \"0.5\" (a JSON string)", "not a number")),
    Case("score-with-a-null-intercept", build_all(c4, model_edit(lambda d: d.update(intercept=None))), score(), 2,
         ("intercept is null",)),
    Case("score-with-a-version-that-is-a-number", build_all(c4, model_edit(lambda d: d.update(version=2026))),
         score(), 2, ("version is 2026", "not a string")),
    Case("score-with-fitted-that-is-a-list", build_all(c4, model_edit(lambda d: d.update(fitted=[1]))), score(), 2,
         ("fitted is [1]", "not a JSON object")),
    Case("score-with-no-terms", build_all(c4, model_edit(lambda d: d.update(terms=[]))), score(), 2,
         ("terms is an empty array",)),
    Case("score-with-terms-that-are-an-object", build_all(c4, model_edit(lambda d: d.update(terms={"a": 1}))),
         score(), 2, ("terms is {\"a\": 1}",)),
    Case("score-with-a-term-without-its-weight", build_all(c4, model_edit(lambda d: d["terms"][3].pop("weight"))),
         score(), 2, ("terms[3] has no field 'weight'",)),
    Case("score-with-a-term-of-an-unknown-field", build_all(c4, model_edit(term(0, bias=1.0))), score(), 2,
         ("terms[0] has the unknown field 'bias'",)),
    Case("score-with-a-term-of-an-unknown-reading", build_all(c4, model_edit(term(0, name="sparkle"))), score(), 2,
         ("terms[0].name is \"sparkle\"", "not a reading GeoCon makes")),
    Case("score-with-a-reading-weighed-twice", build_all(c4, model_edit(term(1, name="shortfall"))), score(), 2,
         ("terms[1] ('shortfall') weighs the reading 'shortfall' a second time",)),
    Case("score-with-a-model-of-a-newer-format",
         build_all(c4, model_edit(lambda d: d.update(format="geocon-clip-model/2"))), score(), 2,
         ("model format geocon-clip-model/2", "reads geocon-clip-model/1")),
    Case("score-with-a-model-file-edited-to-another-digest", build_all(c4, model_edit(term(1, weight=1.5))),
         score(), 2, ("pkg/clip_model.json has digest", f"pins {SHIPPED_MODEL_DIGEST}", "reinstall GeoCon"),
         forbids=("set signals.model_sha256",)),
    Case("doctor-with-the-model-file-missing", model_bytes(None), ("doctor",), 2,
         ("clip model", "pkg/clip_model.json does not exist", "reinstall geocon")),
    Case("doctor-with-a-weight-written-as-a-string", model_edit(weight_as_string), ("doctor",), 2,
         ("clip model", "terms[1] ('unkept') weight")),
    Case("doctor-with-a-model-of-another-digest", model_edit(term(1, weight=1.5)), ("doctor",), 2,
         ("clip model", "has digest", f"the presets pin {SHIPPED_MODEL_DIGEST}")),
    Case("doctor-with-the-shipped-model", lambda c: None, ("doctor",), 0,
         check=said("clip model", SHIPPED_MODEL_DIGEST, stream="stdout")),
]  # fmt: skip

CASES = RECORDS + MODEL_FILES


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"
    assert len(CASES) >= 35


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_model(case: Case, mctx: Ctx):
    run_case(case, mctx)


# --- the rules' one home --------------------------------------------------------------------------


def _shipped() -> dict[str, Any]:
    return json.loads(SHIPPED.read_text())


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda d: d["terms"][1].update(weight="1.2"), "terms[1] ('unkept') weight is \"1.2\" (a JSON string)"),
        (lambda d: d["terms"][0].update(scale=-1), "terms[0] ('shortfall') scale is -1, and it must be above 0"),
        (lambda d: d["terms"][0].update(center=float("inf")), "center is inf, not a finite number"),
        (lambda d: d.update(threshold=0), "threshold is 0, outside (0, 1)"),
        (lambda d: d["terms"][0].update(label=3), "label is 3 (a JSON number), not a string"),
        (lambda d: d["terms"].append("x"), 'terms[8] is "x" (a JSON string), not a JSON object'),
        (lambda d: d.pop("version"), "has no field 'version'"),
    ],
)
def test_every_field_of_a_model_file_is_checked_and_named(change, words):
    from geocon_core.signals import ClipModel, ClipModelError

    d = _shipped()
    change(d)
    with pytest.raises(ClipModelError) as caught:
        ClipModel.from_dict(d, "m.json")
    assert str(caught.value).startswith("m.json: ") and words in str(caught.value), str(caught.value)


def test_the_checks_keep_the_shipped_models_digest():
    from geocon_core.signals import ClipModel

    assert ClipModel.from_dict(_shipped()).digest() == SHIPPED_MODEL_DIGEST


def test_a_stored_finding_is_read_only_when_it_could_be_one():
    from geocon_core.record import stored_finding

    good = {"verdict": {"verdict": "inconsistent", "reason": "r"}, "clip_score": 0.7, "why": {"unkept": 0.5}}
    found = stored_finding(good)
    assert found is not None and found.verdict == "inconsistent" and found.parts == (("unkept", 0.5),)
    assert stored_finding({**good, "clip_score": 1.5}) is None
    assert stored_finding({**good, "clip_score": True}) is None
    assert stored_finding({**good, "why": {"unkept": "x"}}) is None
    assert stored_finding({**good, "verdict": {"verdict": "fine", "reason": "r"}}) is None
    assert stored_finding({**good, "clip_score": None}) is not None  # cannot judge: no score
    assert stored_finding(None) is None


@pytest.mark.full
def test_the_audit_app_card_says_a_record_was_made_with_another_model(mctx: Ctx):
    """``geocon serve``: the card of a clip whose record was made with another clip model shows the
    verdict it was made with and names the model."""
    from geocon_core.record import read_record
    from geocon_core.results import ResultsIndex
    from geocon_viewer.audit.views import ClipView, clip_card

    bench_pinned("ds-a")(mctx)
    folder = mctx.tmp / "out" / "clips" / "ds-a"
    made_with = json.loads((folder / "record.json").read_text())["summary"]["verdict"]
    index = ResultsIndex.open(mctx.tmp / "out")
    record = read_record(folder)
    verdict = index.verdict("ds-a", index.recorded)
    assert verdict is not None
    card = clip_card(ClipView("ds-a", folder, record, None, 1.0), verdict, index.by_id["ds-a"], index.recorded,
                     index.recorded)  # fmt: skip
    assert f"made with the clip model {OTHER}" in card and made_with["reason"] in card, card


@pytest.mark.full
def test_the_rerun_card_of_a_record_of_another_model_shows_its_own_verdict(mctx: Ctx):
    from geocon_core.record import read_record
    from geocon_viewer.rerun.card import audit_card

    pinned_record(OTHER)(mctx)
    doc = json.loads((mctx.tmp / "rec" / "record.json").read_text())
    record = read_record(mctx.tmp / "rec")
    card = audit_card(record)
    assert f"made with the clip model {OTHER}" in card
    assert doc["summary"]["verdict"]["reason"] in card
    assert record.finding().clip_score == pytest.approx(doc["summary"]["clip_score"])
    assert dict(record.finding().parts) == pytest.approx(doc["summary"]["why"])
