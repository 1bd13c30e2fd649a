"""`geocon report` leads with pictures: one figure per question on the first screen, before any
table; sortable and filterable tables; a strip of thumbnails for every flagged clip; figures whose
tick labels never overlap."""

from __future__ import annotations

import base64
import re
import shutil
from html.parser import HTMLParser
from types import SimpleNamespace

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")
pytest.importorskip("matplotlib")

import cv2  # noqa: E402

from geocon_core.bench import read_tables, run_bench  # noqa: E402
from geocon_core.report import build_report  # noqa: E402
from geocon_core.report import figures as rf  # noqa: E402
from geocon_core.results import THUMB_WIDTH, clip_thumbs, thumbs_html  # noqa: E402
from geocon_core.synth import plan_benchmark, write_benchmark  # noqa: E402

QUESTIONS = ("summary_platforms", "summary_margins", "summary_failures")
LONG_NAMES = (
    "stable-video-diffusion-img2vid-xt",
    "runway-gen3-alpha-turbo-1080p",
    "kling-1.6-professional-mode",
    "sora-turbo-1080p-20s",
    "veo-2-preview-720p",
    "hunyuan-video-720p-fp8",
    "cogvideox-5b-i2v-v1.5",
    "ltx-video-0.9.1-distilled",
)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A report of 4 synthetic clips (clean and breathing, C1 and C3, 10 frames); the breathing
    clips (12 px) fail the report gate (C3 by far: IR about 0.75), so they are flagged. Every
    figure the report saves is checked for overlapping tick labels once it is saved."""
    root = tmp_path_factory.mktemp("pictures")
    plan = plan_benchmark(families=("C1", "C3"), scenes=1, platforms=("clean", "breathing"), breathing_px=12.0)
    write_benchmark(root / "data", plan, width=320, height=180, num_frames=10)
    run_bench(root / "data", root / "results", workers=2)
    checked: dict[str, list] = {}
    save = rf.FigureBuilder.save

    def checked_save(self, fig, name, *args, **kw):
        save(self, fig, name, *args, **kw)
        checked[name] = rf.tick_label_overlaps(fig)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(rf.FigureBuilder, "save", checked_save)
        res = build_report(root / "results", root / "report", bootstrap=200, formats=("png",))
    clips = read_tables(root / "results")["clips"]
    return SimpleNamespace(
        root=root, res=res, page=res.html.read_text(), overlaps=checked, clips=clips[clips["status"] == "ok"]
    )


class _Page(HTMLParser):
    """The elements of a report page in document order: (tag, attributes) of each start tag, with
    the rows of the flagged-clips table and the images inside each strip of thumbnails."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.flagged_rows = 0
        self.strips: list[list[str]] = []
        self._table: list[str] = []
        self._strip_depth = 0
        self._depth = 0

    def handle_starttag(self, tag, attrs):
        a = {k: v or "" for k, v in attrs}
        self.tags.append((tag, a))
        if tag == "table":
            self._table.append(a.get("class", ""))
        if tag == "tr" and self._table and "flagged" in self._table[-1].split():
            self.flagged_rows += 1
        if tag == "div":
            self._depth += 1
            if "thumbs" in a.get("class", "").split():
                self.strips.append([])
                self._strip_depth = self._depth
        if tag == "img" and self._strip_depth:
            self.strips[-1].append(a["src"])

    def handle_endtag(self, tag):
        if tag == "table" and self._table:
            self._table.pop()
        if tag == "div":
            if self._depth == self._strip_depth:
                self._strip_depth = 0
            self._depth -= 1


def _parse(page: str) -> _Page:
    p = _Page()
    p.feed(page)
    return p


def _crowded(b: rf.FigureBuilder):
    fig, ax = b.figure(size=(7, 3.6))
    pos = np.arange(1, len(LONG_NAMES) + 1)
    ax[0, 0].violinplot([np.random.default_rng(i).normal(size=30) for i in range(len(LONG_NAMES))], positions=pos)
    ax[0, 0].set_xticks(pos, LONG_NAMES)
    ax[0, 0].set_title("crowded")
    return fig, ax[0, 0]


def test_tick_label_check_finds_crowded_names_and_the_fix_removes_them(tmp_path):
    b = rf.FigureBuilder(tmp_path, "footer", ("png",), (0.03, 0.04, 0.05))
    fig, ax = _crowded(b)
    found = rf.tick_label_overlaps(fig)
    assert found and all(o.axes == "crowded" and o.axis == "x" for o in found)
    assert rf.Overlap("crowded", "x", LONG_NAMES[0], LONG_NAMES[1]) in found  # neighbours collide
    assert rf.fix_tick_labels(fig) == []
    assert rf.tick_label_overlaps(fig) == []
    labels = ax.get_xticklabels()
    assert [lab.get_text().replace("\n", " ").replace("- ", "-") for lab in labels] == list(LONG_NAMES)
    assert any(lab.get_rotation() for lab in labels) or any("\n" in lab.get_text() for lab in labels)
    # a rotated box is compared as drawn, not as its axis-aligned hull
    ax.set_xticks(ax.get_xticks(), ["x" * 20] * len(LONG_NAMES), rotation=45, ha="right", rotation_mode="anchor")
    fig.draw_without_rendering()
    hulls = [lab.get_window_extent() for lab in ax.get_xticklabels()]
    assert any(a.overlaps(b) for a, b in zip(hulls, hulls[1:], strict=False))
    assert rf.tick_label_overlaps(fig) == []
    # the builder fixes every figure it saves
    fig, _ = _crowded(b)
    b.save(fig, "crowded", "Crowded", "Long platform names.")
    assert b.figures[-1].overlaps == [] and (tmp_path / "figures" / "crowded.png").is_file()


@pytest.mark.full
def test_no_report_figure_has_overlapping_tick_labels(report):
    assert set(QUESTIONS) <= set(report.overlaps)
    assert {name: o for name, o in report.overlaps.items() if o} == {}
    assert not [w for w in report.res.warnings if "tick labels" in w]


@pytest.mark.full
def test_first_screen_is_one_figure_per_question_before_any_table(report):
    page = report.page
    assert page.index("<img") < page.index("<table")
    summary = page[page.index('<section class="summary">') : page.index("</section>")]
    assert page.index('<section class="summary">') < page.index("<table")
    for name, question in zip(
        QUESTIONS,
        ("Which platform is most consistent?", "Where is the gate thin?", "Which categories fail?"),
        strict=True,
    ):
        assert f'<figure id="{name}"><h3>{question}</h3><img' in summary
        assert (report.root / "report" / "figures" / f"{name}.png").is_file()
    assert summary.count('src="data:image/png;base64,') == 3
    # best first: the breathing clips fail the gate, so clean leads the platform figure's rows
    sb = pd.read_csv(report.root / "report" / "tables" / "scene_balanced.csv").query("metric == 'IR'")
    assert rf.platform_order(sb) == ["clean", "breathing"]


@pytest.mark.full
def test_tables_are_sortable_and_filterable_offline(report):
    page = report.page
    p = _parse(page)
    tables = [a for tag, a in p.tags if tag == "table"]
    boxes = {a["data-table"] for tag, a in p.tags if tag == "input" and a.get("class") == "filter"}
    assert len(tables) >= 6
    assert all("sortable" in t["class"].split() for t in tables)
    assert {t["id"] for t in tables} == boxes
    for t in tables:  # each box sits right above its table
        assert f'data-table="{t["id"]}"' in page[: page.index(f'<table id="{t["id"]}"')][-300:]
    script = re.findall(r"<script>(.*?)</script>", page, re.S)
    assert len(script) == 1 and "table.sortable" in script[0] and "input.filter" in script[0]
    assert "<script src" not in page and "<link" not in page
    refs = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert not [r for r in refs if r.startswith(("http:", "https:", "//"))]


@pytest.mark.full
def test_every_flagged_clip_has_a_strip_of_thumbnails(report):
    p = _parse(report.page)
    c3 = report.clips.set_index("clip_id").loc["breathing-c3_translation-s0"]
    assert c3["consistent"] == False  # noqa: E712  (so it is flagged)
    assert p.flagged_rows - 1 == len(p.strips) >= 1  # minus the header row
    assert "<td>breathing-c3_translation-s0</td>" in report.page
    for strip in p.strips:
        assert len(strip) == 3 and all(s.startswith("data:image/jpeg;base64,") for s in strip)
        first, worst, last = (
            cv2.imdecode(np.frombuffer(base64.b64decode(s.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR) for s in strip
        )
        assert first.shape == worst.shape == last.shape == (round(180 * THUMB_WIDTH / 320), THUMB_WIDTH, 3)
        b, g, r = (worst[..., i].astype(int) for i in range(3))
        assert ((g > 150) & (r < 110) & (b < 110)).sum() > 20  # inliers drawn green
        assert ((r > 170) & (g < 110) & (b < 110)).sum() > 5  # outliers drawn red
    assert "worst pair" in report.page and "IR" in report.page


@pytest.mark.full
def test_a_clip_flagged_on_a_reading_shows_where_it_fires(report, tmp_path):
    from geocon_core.signals import READING_LABELS

    from .flagged import flagged_on_appearance

    rec, patch = flagged_on_appearance(report.root / "results" / "clips" / "clean-c1_static-s0", tmp_path / "f")
    ct = clip_thumbs(tmp_path / "f")
    labels = [t.label for t in ct.thumbs]
    assert labels[1].startswith(READING_LABELS["unexplained_appearance"]) and len(labels) == 4, labels
    pic = cv2.cvtColor(cv2.imdecode(np.frombuffer(ct.thumbs[1].jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    first = cv2.cvtColor(cv2.imdecode(np.frombuffer(ct.thumbs[0].jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    k = THUMB_WIDTH / rec.video.working_size[0]
    (ix, iy), (ox, oy) = ((round(x * k), round(y * k)) for x, y in (patch.centre, patch.far))
    assert pic[iy, ix].astype(int).sum() > 500  # the patch at full colour (inferno's pale yellow)
    assert pic[oy, ox].astype(int).sum() < 0.7 * first[oy, ox].astype(int).sum() + 20  # elsewhere dimmed
    assert "the reading the clip score leans on most" in ct.thumbs[1].title


@pytest.mark.full
def test_a_clip_that_cannot_be_read_gets_a_note_instead(report, tmp_path):
    folder = report.root / "results" / "clips" / "breathing-c1_static-s0"
    video = next((report.root / "data" / "breathing").rglob("c1_static*.mp4"))
    moved = tmp_path / video.name
    shutil.move(video, moved)
    try:
        ct = clip_thumbs(folder)
    finally:
        shutil.move(moved, video)
    assert ct.thumbs == () and ct.note is not None
    assert ct.note.startswith("No thumbnails: the clip of this record is gone (looked at ") and str(video) in ct.note
    assert thumbs_html(ct) == f'<p class="nothumbs">{ct.note}</p>'
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "record.json").write_text("{not json")
    assert clip_thumbs(broken, "x").note.startswith("No thumbnails: the record cannot be read")


def _find(shot: np.ndarray, figure: np.ndarray) -> tuple[float, int, int]:
    """(score, y of the top, y of the bottom) of ``figure`` shown at any width from 40% to 100% of
    its own inside the screenshot ``shot``: normalised cross-correlation of blurred grey images
    (the browser resamples thin lines differently), coarse at half size, then fine around the best."""

    def grey(img: np.ndarray, scale: float, sigma: float) -> np.ndarray:
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if scale != 1.0:
            g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        return cv2.GaussianBlur(g, (0, 0), sigma)

    def best(area: np.ndarray, scales: np.ndarray, half: float, sigma: float) -> tuple[float, float, int, int]:
        top = (-1.0, 1.0, 0, 0)
        for s in scales:
            t = grey(figure, s * half, sigma)
            if t.shape[0] <= area.shape[0] and t.shape[1] <= area.shape[1]:
                _, score, _, (x, y) = cv2.minMaxLoc(cv2.matchTemplate(area, t, cv2.TM_CCOEFF_NORMED))
                if score > top[0]:
                    top = (float(score), float(s), x, y)
        return top

    _, s0, x0, y0 = best(grey(shot, 0.5, 1.5), np.arange(0.4, 1.0, 0.02), 0.5, 1.5)
    h, w = round(figure.shape[0] * (s0 + 0.03)), round(figure.shape[1] * (s0 + 0.03))
    ox, oy = max(0, 2 * x0 - 16), max(0, 2 * y0 - 16)
    area = grey(shot, 1.0, 3.0)[oy : oy + h + 32, ox : ox + w + 32]
    score, s, _, y = best(area, np.arange(s0 - 0.02, s0 + 0.021, 0.004), 1.0, 3.0)
    return score, oy + y, oy + y + round(figure.shape[0] * s)


@pytest.mark.full
def test_first_screen_in_chromium_shows_the_three_figures(report, tmp_path):
    from geocon_viewer.capture.chromium import find_chromium
    from geocon_viewer.capture.screenshot import screenshot_url

    if find_chromium() is None:
        pytest.skip("Chromium is not installed")
    png = screenshot_url(report.res.html.as_uri(), tmp_path / "first.png", width=1600, height=1000, settle_s=0.3)
    shot = cv2.imread(str(png))
    assert shot.shape == (1000, 1600, 3)
    for name in QUESTIONS:
        figure = cv2.imread(str(report.root / "report" / "figures" / f"{name}.png"))
        score, top, bottom = _find(shot, figure)
        assert score > 0.95, (name, score)
        assert 0 < top and bottom <= 1000, (name, top, bottom)  # wholly on the first screen
