"""The README and the documentation pages: their runnable code blocks run, their relative links resolve.

A fenced block is runnable when the line right before its opening fence is ``<!-- runnable -->``
(an HTML comment: GitHub and MkDocs show nothing). Bash blocks run under ``bash -euo pipefail``
and Python blocks under this interpreter, each in an empty temporary folder with this
environment's ``geocon`` first on PATH and the checkout on PYTHONPATH. Only cheap,
self-contained blocks are marked (a few seconds each). The site itself is built by
``scripts/docs.sh`` (``mkdocs build --strict``), not here.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = "<!-- runnable -->"
TIMEOUT_S = 120
"""Per block; the blocks marked runnable take a few seconds each on two cores."""

_FENCE = re.compile(r"^(`{3,}|~{3,})\s*([\w+-]*)")
_INLINE_CODE = re.compile(r"(`+).*?\1")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REF_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$")
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def markdown_files() -> list[Path]:
    """README.md and every page under docs/."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


@dataclass(frozen=True)
class Block:
    """One fenced code block: where it opens (1-based line), its language and body."""

    path: Path
    line: int
    lang: str
    body: str
    runnable: bool

    @property
    def name(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def parse(path: Path) -> tuple[list[Block], list[tuple[int, str]]]:
    """The fenced blocks of a Markdown file, and its prose lines (1-based number, text) outside them."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    prose: list[tuple[int, str]] = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i].lstrip())
        if not m:
            prose.append((i + 1, lines[i]))
            i += 1
            continue
        fence, lang, start = m.group(1), m.group(2).lower(), i
        indent = len(lines[i]) - len(lines[i].lstrip())
        body: list[str] = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i][indent:] if lines[i][:indent].isspace() else lines[i])
            i += 1
        runnable = start > 0 and lines[start - 1].strip() == MARKER
        blocks.append(Block(path, start + 1, lang, "\n".join(body) + "\n", runnable))
        i += 1  # the closing fence
    return blocks, prose


def runnable_blocks() -> list[Block]:
    return [b for p in markdown_files() for b in parse(p)[0] if b.runnable]


def test_every_marker_sits_on_a_block_this_test_can_run():
    """A marker that is not right above a bash or python fence would be silently ignored."""
    problems = []
    for path in markdown_files():
        blocks, prose = parse(path)
        starts = {b.line for b in blocks if b.runnable}
        for number, text in prose:
            if text.strip() == MARKER and number + 1 not in starts:
                problems.append(f"{path.relative_to(ROOT)}:{number}: {MARKER} is not right above a code fence")
        for b in blocks:
            if b.runnable and b.lang not in ("bash", "sh", "python"):
                problems.append(f"{b.name}: a runnable block must be bash or python, not {b.lang or 'unlabelled'}")
    assert not problems, "\n".join(problems)
    assert runnable_blocks(), "no code block is marked runnable"


@pytest.mark.full
@pytest.mark.parametrize("block", runnable_blocks(), ids=lambda b: b.name)
def test_runnable_block(block: Block, tmp_path: Path):
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "geocon").exists(), f"no geocon command beside {sys.executable}: install the package first"
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(bin_dir), env.get("PATH", "")])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    env["NO_COLOR"] = "1"
    if block.lang == "python":
        script = tmp_path / "block.py"
        cmd = [sys.executable, str(script)]
    else:
        script = tmp_path / "block.sh"
        cmd = ["bash", "-euo", "pipefail", str(script)]
    script.write_text(block.body, encoding="utf-8")
    work = tmp_path / "work"
    work.mkdir()
    try:
        done = subprocess.run(
            cmd, cwd=work, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=TIMEOUT_S
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{block.name}: still running after {TIMEOUT_S} s:\n{block.body}")
    assert done.returncode == 0, (
        f"{block.name} exited with {done.returncode}:\n{block.body}\n"
        f"--- stdout (end)\n{done.stdout[-3000:]}\n--- stderr (end)\n{done.stderr[-3000:]}"
    )


def relative_links(path: Path) -> list[tuple[int, str]]:
    """(line, target) of every link and image outside code whose target is a relative path."""
    found = []
    for number, text in parse(path)[1]:
        text = _INLINE_CODE.sub("", text)
        targets = [m.group(1) for m in _LINK.finditer(text)]
        ref = _REF_DEF.match(text)
        if ref:
            targets.append(ref.group(1))
        for target in targets:
            if _SCHEME.match(target) or target.startswith(("#", "/")):
                continue
            found.append((number, target))
    return found


def test_relative_links_point_at_files_that_exist():
    broken = []
    for path in markdown_files():
        for number, target in relative_links(path):
            file_part = target.split("#", 1)[0].split("?", 1)[0]
            if file_part and not (path.parent / file_part).exists():
                broken.append(f"{path.relative_to(ROOT)}:{number}: {target}")
    assert not broken, "links to missing files:\n" + "\n".join(broken)


def test_the_link_checker_sees_links():
    """The checker is not vacuous: it finds the README's links into docs/ and the pages' images."""
    readme = {t for _, t in relative_links(ROOT / "README.md")}
    assert "docs/scoring.md" in readme and "docs/images/dog-audit.jpg" in readme
    index = {t for _, t in relative_links(ROOT / "docs" / "index.md")}
    assert "images/dog-audit.jpg" in index
