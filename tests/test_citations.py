"""Every design citation in the repository points at a page and a numbered heading that exist.

Comments, docstrings and docs cite the design pages as ``docs/design/<page>.md §N.N`` (more
sections may follow: ``§5.2, §9.3``, ``§5.5/§6.1``, ``§6.4 and §9.1``, ``§9.2–9.4``, ``§7 #13``).
A section exists when the page has a markdown heading that starts with its number
(``## 6.2 TU1 and TU2`` or ``### 6.2``). Citations of the developers' private notes, which a clone
of the repository does not have, are refused outright.
"""

from __future__ import annotations

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design"
SKIP_DIRS = {".git", ".venv", "node_modules", "__pycache__", ".pytest_cache", ".hypothesis"}
SUFFIXES = {".py", ".md", ".yaml", ".yml"}

_SECTION = r"\d+(?:\.\d+)*[a-z]?"
#: ``docs/design/<page>.md`` then the first section (whitespace, even a line break, allowed).
CITATION = re.compile(r"docs/design/([A-Za-z0-9_\-]+)\.md\s*§\s*(" + _SECTION + ")")
#: Further sections chained right after a citation: ", §9.3", "/§6.1", " and §9.1", "–9.4".
CHAINED = re.compile(r"(?:\s*(?:,|/|\band\b)\s*§\s*|\s*[–-]\s*§?\s*)(" + _SECTION + ")")
HEADING = re.compile(r"^#{1,6}\s+(" + _SECTION + r")\.?(?:\s|$)")

# Built by concatenation so that this file does not match its own patterns.
FORBIDDEN = [
    re.compile(re.escape("../" + "shared")),
    re.compile("PAPER" + "_NOTES"),
    re.compile("MAVLINK" + "_NOTES"),
    re.compile("SITL" + "_NOTES"),
    re.compile("ARCHITECTURE" + r"(?:\.md)?\s*§"),
]


def repo_files(root: pathlib.Path = ROOT) -> list[pathlib.Path]:
    """Every .py / .md / .yaml file of the repository (not .git, not the virtualenv)."""
    out = []
    for path in root.rglob("*"):
        rel = path.relative_to(root)
        if any(part in SKIP_DIRS or part.endswith(".egg-info") for part in rel.parts[:-1]):
            continue
        if path.is_file() and path.suffix in SUFFIXES:
            out.append(path)
    return sorted(out)


def headings(page: pathlib.Path) -> set[str]:
    """Section numbers of a design page's markdown headings (outside code fences)."""
    numbers, fenced = set(), False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        m = None if fenced else HEADING.match(line)
        if m:
            numbers.add(m.group(1))
    return numbers


def citations(text: str) -> list[tuple[str, str, int]]:
    """(page, section, line) of every citation in ``text``, chained sections included."""
    found = []
    for m in CITATION.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        found.append((m.group(1), m.group(2), line))
        pos = m.end()
        while (c := CHAINED.match(text, pos)) is not None:
            found.append((m.group(1), c.group(1), line))
            pos = c.end()
    return found


def check_text(text: str, pages: dict[str, set[str]]) -> list[str]:
    """Problems in one file's text: unknown pages or sections, forbidden references."""
    problems = []
    for page, section, line in citations(text):
        if page not in pages:
            problems.append(f"line {line}: docs/design/{page}.md does not exist")
        elif section not in pages[page]:
            problems.append(f"line {line}: docs/design/{page}.md has no heading '{section}'")
    for pattern in FORBIDDEN:
        for m in pattern.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            problems.append(
                f"line {line}: reference to notes outside the repository: {m.group(0)!r}"
            )
    return problems


def design_pages() -> dict[str, set[str]]:
    return {p.stem: headings(p) for p in sorted(DESIGN.glob("*.md"))}


def test_design_pages_exist_and_are_numbered():
    pages = design_pages()
    assert {"model", "mavlink", "architecture"} <= set(pages), sorted(pages)
    for name, numbers in pages.items():
        assert numbers, f"docs/design/{name}.md has no numbered headings"


def test_every_citation_resolves():
    pages = design_pages()
    problems, n_citations = [], 0
    for path in repo_files():
        text = path.read_text(encoding="utf-8", errors="replace")
        n_citations += len(citations(text))
        problems += [f"{path.relative_to(ROOT)}: {p}" for p in check_text(text, pages)]
    assert not problems, "\n".join(problems)
    assert n_citations > 50, f"only {n_citations} design citations found: is the scanner broken?"


PAGES = {"model": {"6", "6.1", "6.2", "9.2", "9.4", "7"}, "mavlink": {"1.4", "5.1"}}


@pytest.mark.parametrize(
    "text, n_problems",
    [
        ("# see @/model.md §6.2", 0),
        ("(@/model.md §5.5/§6.1)", 1),  # 5.5 missing here
        ("@/model.md §9.2–9.4", 0),
        ("@/model.md §9.2–9.3", 1),
        ("@/model.md §6.4 and §9.1", 2),
        ("@/model.md §6.2 and 20 drones", 0),
        ("@/model.md §7 #13", 0),
        ("(@/model.md\n  §6.2)", 0),
        ("@/model.md §6.3", 1),  # no such heading
        ("@/nosuch.md §1.1", 1),  # no such page
        ("@/mavlink.md §1.4, @/model.md §6.2", 0),
        ("PAPER" + "_NOTES §6.2", 1),
        ("see ../" + "shared/docs/x.md", 1),
        ("MAVLINK" + "_NOTES §5", 1),
        ("ARCHITECTURE" + " §4.3", 1),
        ("SITL" + "_NOTES", 1),
    ],
)
def test_checker_catches_bad_citations(text, n_problems):
    # The cases write "@/" for the design folder so that this file's own scan stays clean.
    text = text.replace("@/", "docs/" + "design/")
    assert len(check_text(text, PAGES)) == n_problems, check_text(text, PAGES)


def test_headings_are_read_from_markdown(tmp_path):
    page = tmp_path / "p.md"
    page.write_text(
        "# Title\n## 1 Intro\n### 1.2. Sub\n```\n## 9 in a fence\n```\n#### 4.4b Extra\n"
        "text ## 7 not a heading\n",
        encoding="utf-8",
    )
    assert headings(page) == {"1", "1.2", "4.4b"}
