"""The documentation: the MkDocs site over docs/ builds with --strict (no broken link or anchor,
no page left out of the nav), and the README stays a first-visit page whose commands and links
are real."""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import markdown  # installed with mkdocs
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
README_MAX_LINES = 200

# [text](target) and ![alt](target); the target ends at the first space or ')'.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """One strict build of the site (about 3 s), shared by the tests below."""
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")  # Material's end-of-life banner, not a build warning
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=240,
    )
    return proc, out


def test_mkdocs_strict_build_passes(site):
    proc, out = site
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{log}"
    assert "WARNING" not in log, log
    assert (out / "index.html").is_file()
    # Files that are not pages are published as they are, so pages can link to them.
    for f in ("maps/ros2-robot.yaml", "maps/skid-steer-rover.json", "foxglove/soilocp-layout.json",
              "dashboard.png"):
        assert (out / f).read_bytes() == (ROOT / "docs" / f).read_bytes(), f


def test_pages_render_their_markdown(site):
    """Python-Markdown, unlike GitHub, wants 4-space indents inside list items and a blank line
    before a list: otherwise a list or a bold run shows up as raw '- ' / '**' text on the site."""
    proc, out = site
    assert proc.returncode == 0, proc.stdout + proc.stderr
    raw = re.compile(r"^\s*- |\*\*|\]\(", re.M)
    for page in sorted(out.rglob("index.html")):
        html_text = page.read_text()
        article = html_text[html_text.find("<article"):html_text.find("</article>")]
        article = re.sub(r"<pre.*?</pre>|<code>.*?</code>", "", article, flags=re.S)
        text = html.unescape(re.sub(r"<[^>]+>", "", article))
        leftovers = [text[max(0, m.start() - 60):m.end() + 30] for m in raw.finditer(text)]
        assert not leftovers, f"{page.relative_to(out)}: Markdown left unrendered: {leftovers[:3]}"


def test_every_docs_page_is_in_the_nav():
    """mkdocs builds pages that are not in the nav without a word; the site's reader would never find them."""
    nav = (ROOT / "mkdocs.yml").read_text()
    listed = set(re.findall(r":\s*([\w./-]+\.md)\s*$", nav, flags=re.M))
    pages = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")}
    assert pages == listed, f"not in the nav: {sorted(pages - listed)}; in the nav but missing: {sorted(listed - pages)}"


def test_readme_is_short():
    n = len(README.read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines; measurements and notes belong in docs/"


def _section(text: str, title: str) -> str:
    assert f"\n## {title}\n" in text, f"README.md has no '## {title}' section"
    return text.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def _make_targets() -> set[str]:
    return set(re.findall(r"^([A-Za-z0-9_.-]+)\s*:(?!=)", (ROOT / "Makefile").read_text(), flags=re.M))


def test_quick_start_is_the_two_make_targets():
    quick = _section(README.read_text(), "Quick start")
    blocks = re.findall(r"```[^\n]*\n(.*?)```", quick, flags=re.S)
    commands = [line.split("#", 1)[0].strip() for block in blocks for line in block.splitlines()]
    commands = [c for c in commands if c]
    assert commands == ["make demo", "make test"]
    assert {"demo", "test"} <= _make_targets()


def _heading_ids(page: Path) -> set[str]:
    """The ids MkDocs gives the page's headings: the same Markdown toc extension renders them."""
    html = markdown.Markdown(extensions=["toc", "tables", "fenced_code"]).convert(page.read_text())
    return set(re.findall(r'\bid="([^"]+)"', html))


def test_readme_links_resolve():
    """Every relative link of the README names a file that exists, and a link to a docs/ page's
    heading names a heading it has (the strict build checks only links inside docs/)."""
    links = [t for t in LINK.findall(README.read_text()) if not re.match(r"[a-z]+:", t)]
    assert any(t.startswith("docs/") for t in links)
    for target in links:
        path, _, anchor = target.partition("#")
        assert path, f"README.md: in-page link {target!r}: link a docs/ page instead"
        assert (ROOT / path).exists(), f"README.md links to {target!r}, which does not exist"
        if anchor:
            assert path.startswith("docs/") and path.endswith(".md"), target
            assert anchor in _heading_ids(ROOT / path), f"README.md: {target!r}: the page has no such heading"
