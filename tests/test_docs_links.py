"""The README and the pages under docs/: every relative link resolves, every page is reachable from
docs/index.md, and the pages read as a guide, not a lab notebook (no issue numbers, no dated
measurements, no "second pass" or "not adopted")."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted([ROOT / "README.md", *DOCS.rglob("*.md")])

#: [text](target) and ![alt](target); the target ends at the first space or closing parenthesis
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
#: fenced code blocks: their brackets and parentheses are code, not links
FENCE = re.compile(r"^```.*?^```", re.M | re.S)
#: what a diary says and a guide does not
DIARY = re.compile(
    r"\bissues? \d+|\b(?:second|third|fourth|fifth|sixth) (?:pass|session)\b|\bnot adopted\b|"
    r"\breverted\b|\b20\d\d-\d\d-\d\d\b",
    re.I,
)


def _links(page: Path) -> list[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return [m.group(1) for m in LINK.finditer(text)]


def _relative(target: str) -> bool:
    return not re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) and not target.startswith("#")


def _resolve(page: Path, target: str) -> Path:
    return (page.parent / target.split("#", 1)[0]).resolve()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    broken = [t for t in _links(page) if _relative(t) and not _resolve(page, t).exists()]
    assert not broken, f"{page.relative_to(ROOT)}: links to nothing: {', '.join(broken)}"


def test_every_page_under_docs_is_reachable_from_the_index() -> None:
    seen: set[Path] = set()
    todo = [DOCS / "index.md"]
    while todo:
        page = todo.pop()
        if page in seen or page.suffix != ".md" or not page.is_file():
            continue
        seen.add(page)
        todo += [_resolve(page, t) for t in _links(page) if _relative(t)]
    orphans = [str(p.relative_to(ROOT)) for p in DOCS.rglob("*.md") if p.resolve() not in seen]
    assert not orphans, f"not linked from docs/index.md (directly or through a linked page): {orphans}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_read_as_a_guide_not_a_diary(page: Path) -> None:
    hits = [
        f"line {n}: {m.group(0)!r}"
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
        for m in DIARY.finditer(line)
    ]
    assert not hits, f"{page.relative_to(ROOT)}: development history belongs in git: {'; '.join(hits)}"


def test_the_link_check_sees_a_broken_link(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("[ok](page.md) [gone](missing.md#x) [web](https://example.org) [anchor](#top)\n")
    assert [t for t in _links(page) if _relative(t) and not _resolve(page, t).exists()] == ["missing.md#x"]
