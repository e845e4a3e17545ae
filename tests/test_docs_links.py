"""The repository speaks of itself only.

Every relative Markdown link of the README and ``docs/*.md`` resolves to a file of the
repository (and to a heading, when it names an anchor of a Markdown page); no text file cites a
document that is not in the repository (the output contract is ``docs/output-contract.md``) or
an absolute path of one machine.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from workspace import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# [text](target) and ![alt](target), with an optional "title"
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")
TEXT_SUFFIXES = {".md", ".py", ".smk", ".yaml", ".yml", ".rst", ".css", ".toml", ".txt", ".in"}
CHECKED = [ROOT / "README.md", ROOT / "Snakefile", ROOT / "Makefile", ROOT / "config.yaml",
           ROOT / "pyproject.toml", ROOT / "setup.py", ROOT / "MANIFEST.in",
           *(p for folder in ("docs", "workflow", "scripts", "tests", "data")
             for p in sorted((ROOT / folder).rglob("*"))
             if p.is_file() and p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts)]
# a design brief that is not part of the repository, and absolute paths of one machine
FOREIGN = re.compile(r"\bDESIGN\b|(?<![\w.~-])/(?:work|home|tmp)/")


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip()).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines():
        if match := re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line):
            slug = _slug(match[1])
            out.add(slug if slug not in seen else f"{slug}-{seen[slug]}")
            seen[slug] = seen.get(slug, 0) + 1
    return out


def _links(page: Path) -> list[str]:
    text = INLINE_CODE.sub("", FENCE.sub("", page.read_text(encoding="utf-8")))
    return LINK.findall(text)


def test_the_pages_are_found():
    assert ROOT / "docs" / "output-contract.md" in PAGES and len(PAGES) > 5


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve_inside_the_repository(page):
    broken = []
    for target in _links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.is_relative_to(ROOT) or not file.exists():
            broken.append(f"{target}: no such file in the repository")
        elif anchor and file.suffix == ".md" and anchor not in _anchors(file):
            broken.append(f"{target}: no heading with anchor #{anchor} in {file.name}")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


def test_slugs_follow_github():
    assert _slug("Rigs: several runs together") == "rigs-several-runs-together"
    assert _slug("`summary.json`") == "summaryjson"
    assert _slug("challenge_residuals_floor_summary") == "challenge_residuals_floor_summary"
    assert (_slug("Inside a PID loop: closed-loop benchmark")
            == "inside-a-pid-loop-closed-loop-benchmark")


# a section named in prose or a comment: README "Running on a cluster", docs/x.md "How it runs"
SECTION = re.compile(r'\b(README|docs/[\w.-]+\.md)(?:\.md)?,? "([^"]+)"')


def _headings(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {re.sub(r"[`*]", "", m[1]).strip()
            for m in re.finditer(r"^#{1,6}\s+(.*?)\s*#*\s*$", text, re.M)}


def test_sections_named_in_prose_and_comments_exist():
    missing = []
    for path in CHECKED:
        if path in GUARDS or not path.is_file():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for page, section in SECTION.findall(line):
                target = ROOT / ("README.md" if page == "README" else page)
                # a section is named by its heading or the heading's start ("Rigs" for
                # "Rigs: several runs together")
                if not target.is_file() or not any(h.startswith(section)
                                                   for h in _headings(target)):
                    missing.append(f"{path.relative_to(ROOT)}:{number}: {page} \"{section}\"")
    assert not missing, "\n".join(missing)


# Tests that guard against these strings name them.
GUARDS = {Path(__file__).resolve(), ROOT / "tests" / "test_benchmarks_package.py"}


def test_no_file_cites_a_document_outside_the_repository_or_an_absolute_path():
    found = []
    for path in CHECKED:
        if path in GUARDS or not path.is_file():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if FOREIGN.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not found, "\n".join(found)
