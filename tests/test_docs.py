"""The documentation site builds in strict mode, and a broken link or a missing API reference
fails the build (shown on a planted two-page site with the same configuration)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict",
                           "-f", str(config), "-d", str(site)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def test_site_builds_strict_with_the_api_reference(tmp_path):
    out = _build(ROOT / "mkdocs.yml", tmp_path / "site")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "WARNING" not in out.stderr, out.stderr
    # pages from the nav, the generated architecture picture, docstrings in the API pages
    assert (tmp_path / "site/guides/foxglove/index.html").is_file()
    arch = (tmp_path / "site/architecture/index.html").read_text()
    assert 'class="mermaid"' in arch
    api = (tmp_path / "site/api/controllers/index.html").read_text()
    assert "controllers.fpid.IT2FPID" in api and "Karnik" in api
    assert "estimators.mckf.MCKF" in (tmp_path / "site/api/estimators/index.html").read_text()


def test_every_docs_page_is_in_the_nav():
    nav = (ROOT / "mkdocs.yml").read_text().split("\nnav:", 1)[1]
    listed = set(re.findall(r":\s*([\w./-]+\.md)\s*$", nav, flags=re.M))
    pages = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")}
    assert pages == listed


def _planted(tmp_path: Path, page: str) -> Path:
    """A two-page site with the real configuration (theme, plugins, strictness)."""
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# Home\n\nSee [the other page](other.md).\n")
    (docs / "other.md").write_text(page)
    head = (ROOT / "mkdocs.yml").read_text().split("\nnav:", 1)[0]
    head = head.replace("docs_dir: docs", f"docs_dir: {docs}")
    head = head.replace("paths: [.]", f"paths: [{ROOT}]")
    cfg = tmp_path / "mkdocs.yml"
    cfg.write_text(head + "\nnav:\n  - index.md\n  - other.md\n")
    return cfg


def test_planted_site_builds(tmp_path):
    cfg = _planted(tmp_path, "# Other\n\n::: estimators.kf.KF\n\n[home](index.md)\n")
    out = _build(cfg, tmp_path / "site")
    assert out.returncode == 0, out.stdout + out.stderr


def test_a_broken_link_fails_the_build(tmp_path):
    cfg = _planted(tmp_path, "# Other\n\nSee [the guide](guides/nowhere.md).\n")
    out = _build(cfg, tmp_path / "site")
    assert out.returncode != 0
    assert "guides/nowhere.md" in out.stderr


def test_a_missing_anchor_fails_the_build(tmp_path):
    cfg = _planted(tmp_path, "# Other\n\nSee [home](index.md#no-such-section).\n")
    out = _build(cfg, tmp_path / "site")
    assert out.returncode != 0
    assert "no-such-section" in out.stderr


def test_a_missing_api_reference_fails_the_build(tmp_path):
    cfg = _planted(tmp_path, "# Other\n\n::: estimators.kf.NoSuchFilter\n")
    out = _build(cfg, tmp_path / "site")
    assert out.returncode != 0
    assert "NoSuchFilter" in out.stderr


README_MAX_LINES = 170
HEADLINE_MAX_WORDS = 30


def test_the_readme_answers_in_a_line():
    """The README stays short, and each headline answer is a line: the conditions and the history
    of a figure live on the page it links to (docs/results.md gives them all)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES
    table = text.split("## Headline results", 1)[1].split("\n## ", 1)[0]
    rows = [r for r in table.splitlines() if r.startswith("| ") and not r.startswith("| question")]
    assert len(rows) >= 10
    long = [(r.split(" | ")[0], len(r.split(" | ")[1].split())) for r in rows
            if len(r.split(" | ")[1].split()) > HEADLINE_MAX_WORDS]
    assert not long, long
    results = (ROOT / "docs/results.md").read_text(encoding="utf-8")
    missing = [r.split(" | ")[0][2:] for r in rows if r.split(" | ")[0][2:] not in results]
    assert not missing, f"questions without their full answer in docs/results.md: {missing}"
