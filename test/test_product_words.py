# SPDX-License-Identifier: Apache-2.0
"""The product speaks of what the tool does, never of how it came to be.

README, the pages of ``docs/``, ``config/``, the package (code, comments, docstrings,
messages, the view's page) and the benchmarks' printed text say what a command does and
how far to trust it. Development-log words (a work item's number, a session, a commit
hash, a dated run log) belong to git's history, not to the product.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".json", ".js", ".html", ".css", ".txt"}

# each: (what it is, the pattern); case matters where a word has an ordinary use
HISTORY_WORDS = [
    ("a numbered stop", re.compile(r"(?<![-\w])[Ss]top \d+")),
    ("an issue number", re.compile(r"\b[Ii]ssues? #?\d+|\bissue's (day|case|targets?)\b")),
    ("a session", re.compile(r"(?<![\w])[Ss]essions?\b")),
    (
        "a commit",
        re.compile(
            r"\bcommit [0-9a-f]{7}|(?<![#\w])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}\b"
        ),
    ),
    ("a dated run", re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")),
    ("the code of a day", re.compile(r"\bthe code of\b")),
]


def product_files() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for folder in ("config", "mr_ident", "benchmarks"):
        files += sorted(
            p
            for p in (ROOT / folder).rglob("*")
            if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts
        )
    return files


def history_words(text: str) -> list[tuple[int, str, str]]:
    """``(line number, what, the words)`` of every development-log word in a text."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for what, pattern in HISTORY_WORDS:
            m = pattern.search(line)
            if m:
                found.append((number, what, m.group(0)))
    return found


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("as on stop 50's code", "a numbered stop"),
        ("Issue 41's case, small", "an issue number"),
        ("the figures of the issue's day", "an issue number"),
        ("re-run in this session", "a session"),
        ("since commit 399cb4e it is", "a commit"),
        ("the previous run (9e46559) gave", "a commit"),
        ("Run on 2026-11-23, 50 runs", "a dated run"),
        ("the code of the day before", "the code of a day"),
    ],
)
def test_the_check_finds_each_kind_of_history_word(text, what):
    assert [w for _, w, _ in history_words(text)] == [what]


@pytest.mark.parametrize(
    "text",
    [
        "mr-ident replay run1 --stop 144000 --out w.npz",
        'fillcolor: "#cf222e22"',
        "start_new_session=True",
        "the stop is requested; a signal stops 3 programs",
        "0x7fffffff and a window of 1000000 samples",
    ],
)
def test_the_check_lets_ordinary_words_pass(text):
    assert history_words(text) == []


def test_no_development_log_words_in_the_product():
    hits = []
    for path in product_files():
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        hits += [
            f"{path.relative_to(ROOT)}:{n}: {what}: {words!r}"
            for n, what, words in history_words(text)
        ]
    assert not hits, (
        "development-log words in the product (say what the tool does and how far to "
        "trust it; history lives in git):\n" + "\n".join(hits)
    )


#: A pointer to a section: ``README, "Bags"``, ``(README 'Monitoring')``,
#: ``docs/monitoring.md, 'Live view'``; or ``(README, Live view)`` without quotes.
SECTION_REF = re.compile(
    r"(README|docs/[\w-]+\.md)(?:\.md)?,?\s+(?:[\"'“]([^\"'”\n]+)[\"'”]|([A-Z][\w ]+)\))"
)


#: Docstrings in layers this check does not fix (live/, numerics/): their pointers go to
#: the pages in a change of those layers ("How stamps become samples" is docs/sources.md's
#: "Stamps to samples"; "The PFG from data" is docs/method.md's).
KNOWN_STALE = {
    "mr_ident/live/sampling.py": 'README, "How stamps become samples"',
    "mr_ident/numerics/lifted/alias_range.py": 'README, "The PFG from data"',
}


def _headings(page: Path) -> set[str]:
    return {
        line.lstrip("#").strip()
        for line in page.read_text().splitlines()
        if line.startswith("#") and not line.startswith("#!")
    }


def test_every_pointer_to_a_section_names_one_that_exists():
    """The hints of the programs, their help and the docs point at sections of the README
    or a docs page by name: each such section exists (make docs checks the links only)."""
    missing = []
    files = product_files() + [ROOT / "Makefile", *sorted((ROOT / "scripts").glob("*.py"))]
    for path in files:
        if not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for m in SECTION_REF.finditer(text):
            page = ROOT / ("README.md" if m.group(1) == "README" else m.group(1))
            name = (m.group(2) or m.group(3)).strip()
            rel = str(path.relative_to(ROOT))
            if KNOWN_STALE.get(rel) == m.group(0):
                continue
            if not page.is_file() or name not in _headings(page):
                missing.append(f"{path.relative_to(ROOT)}: {m.group(0)!r}")
    assert not missing, "pointers to sections that do not exist:\n" + "\n".join(missing)


def test_the_pointer_check_sees_each_form():
    text = "(README, Live view) README, \"Bags\" (README 'Monitoring') docs/node.md, 'Topics'"
    assert [m.group(2) or m.group(3) for m in SECTION_REF.finditer(text)] == [
        "Live view",
        "Bags",
        "Monitoring",
        "Topics",
    ]
