"""The README, the changelog and the pages under docs/: every relative link resolves, every page is
reachable from docs/index.md, the pages read as a guide, not a lab notebook (no issue numbers, no dated
measurements, no "second pass" or "not adopted"), and every ``docs/...md`` page and ``tests/...`` file that
the docs, the code, the tests, the benchmarks, the scripts and CI name exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from helpers import TESTS

ROOT = TESTS.parent
DOCS = ROOT / "docs"
PAGES = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *DOCS.rglob("*.md")])

#: where code names doc pages: the product, the tests, benchmarks, scripts, examples, CI, the build
CODE = [
    "src",
    "firmware_model",
    "vcan_sim",
    "tests",
    "bench",
    "scripts",
    "examples",
    ".ci",
    "dbc",
    "pyproject.toml",
]
#: a doc page as code names it: a path from the repository root
DOC_PATH = re.compile(r"\bdocs/[\w./-]*\w\.md\b")
#: a test file as docs and code name it: a path from the repository root
TEST_PATH = re.compile(r"(?<![\w/.-])tests/[\w/.-]*\w\.(?:py|sh|c|mjs|json|toml|md)\b")
TEXT_SUFFIXES = {".py", ".sh", ".toml", ".md", ".txt", ".cfg", ".json", ".mjs", ".c", ""}

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


def _code_files() -> list[Path]:
    out = []
    for name in CODE:
        top = ROOT / name
        files = [top] if top.is_file() else top.rglob("*")
        out += [
            f
            for f in files
            if f.is_file()
            and f.suffix in TEXT_SUFFIXES
            and "node_modules" not in f.parts
            and "__pycache__" not in f.parts
        ]
    return out


def _named_doc_pages(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return []
    return [(n, m.group(0)) for n, line in enumerate(text.splitlines(), 1) for m in DOC_PATH.finditer(line)]


def test_every_doc_page_named_in_the_code_exists() -> None:
    missing = [
        f"{f.relative_to(ROOT)}:{n}: {page}"
        for f in _code_files()
        for n, page in _named_doc_pages(f)
        if not (ROOT / page).is_file()
    ]
    assert not missing, "names a doc page that does not exist:\n" + "\n".join(missing)


def test_the_doc_page_check_sees_a_missing_page(tmp_path: Path) -> None:
    gone = "docs/" + "estimator.md"  # a page that went (spelt apart, so that this file does not name it)
    f = tmp_path / "mod.py"
    f.write_text(f'"""See docs/design/filters.md and {gone}, "Twist bound"."""\n')
    assert _named_doc_pages(f) == [(1, "docs/design/filters.md"), (1, gone)]
    assert not (ROOT / gone).exists() and (ROOT / "docs/design/filters.md").is_file()


def test_every_test_file_named_in_the_docs_and_the_code_exists() -> None:
    missing = [
        f"{f.relative_to(ROOT)}:{n}: {m.group(0)}"
        for f in [*_code_files(), *PAGES]
        for n, line in enumerate(f.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
        for m in TEST_PATH.finditer(line)
        if not (ROOT / m.group(0)).is_file()
    ]
    assert not missing, "names a test file that does not exist:\n" + "\n".join(missing)
