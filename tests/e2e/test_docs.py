"""The documentation holds together: a short README, every page linked, every link and SPEC
reference resolving inside the repository, every abbreviation in the glossary.

The README is the newcomer's page (what railstop is, the two set-up commands, a tour, how to
model a station, where to read on); everything else lives in ``docs/``. The command examples of
both are run by ``tests/e2e/test_readme_tour.py``.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
DOC_PAGES = sorted(DOCS.rglob("*.md"))
PAGES = [README, *DOC_PAGES]
SPEC = DOCS / "spec.md"
GLOSSARY = DOCS / "glossary.md"

#: The most lines the README may have (issue 38: the rest belongs in docs/).
README_MAX_LINES = 300
#: The README's first code block: the two set-up commands, nothing else.
SETUP_COMMANDS = ["make run", "make test"]
#: Abbreviations and terms a reader meets in the docs and the code: each needs a glossary entry.
GLOSSARY_TERMS = (
    "TASC",
    "ATO",
    "ATS",
    "ATC",
    "ATP",
    "PSD",
    "PSC",
    "CPCS",
    "WPCS",
    "DMC",
    "DOA",
    "DOC",
    "DCC",
    "ZVR",
    "WSP",
    "CBTC",
    "ZC",
    "MA",
    "GEBR",
    "EB",
    "Pp",
    "Pc",
    "B1",
    "B7",
    "Notch",
    "PWM",
    "ECU",
    "AW0",
    "AW3",
    "Davis resistance",
    "GNSS",
    "Holdover",
    "Track circuit",
    "Jointless track circuit",
    "WCC",
    "EN 50159",
    "IEEE 1474.1",
    "railML",
    "ADU",
    "DDU",
    "TCMS",
    "FSK",
    "EMU",
    "HMAC-SHA256",
    "CRC",
)

_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _prose(path: Path) -> list[tuple[int, str]]:
    """The page's lines outside fenced code blocks, with their numbers."""
    lines = []
    fenced = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            lines.append((number, line))
    return lines


def _links(path: Path) -> list[tuple[int, str]]:
    """Every markdown link target of the page's prose (inline code spans left out)."""
    found = []
    for number, line in _prose(path):
        text = re.sub(r"`[^`]*`", "", line)
        found.extend((number, target) for target in _LINK.findall(text))
    return found


def _relative_file_links(path: Path) -> list[tuple[int, str, Path]]:
    """The links to files of the repository: (line, link, the file it names)."""
    result = []
    for number, target in _links(path):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue  # http(s), mailto, ...; an anchor on the same page
        file_part = target.split("#", 1)[0].split("?", 1)[0]
        result.append((number, target, (path.parent / file_part).resolve()))
    return result


def test_the_readme_is_short() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"


def test_the_readme_starts_with_the_two_setup_commands() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    opening = next(i for i, line in enumerate(lines) if line.startswith("```"))
    before = [line for line in lines[:opening] if line.strip()]
    assert len(before) == 1, f"only the title comes before the set-up commands: {before}"
    assert before[0].startswith("# "), before
    closing = next(i for i in range(opening + 1, len(lines)) if lines[i].startswith("```"))
    commands = [" ".join(shlex.split(line, comments=True)) for line in lines[opening + 1 : closing]]
    assert [c for c in commands if c] == SETUP_COMMANDS, lines[opening : closing + 1]


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {file for _, _, file in _relative_file_links(README)}
    missing = [_rel(page) for page in DOC_PAGES if page.resolve() not in linked]
    assert not missing, f"README.md links no {missing}"


@pytest.mark.parametrize("page", PAGES, ids=[_rel(p) for p in PAGES])
def test_every_relative_link_names_a_file_that_exists(page: Path) -> None:
    broken = [
        f"{_rel(page)} line {n}: {target}"
        for n, target, file in _relative_file_links(page)
        if not file.exists()
    ]
    assert not broken, "\n".join(broken)


def _spec_sections() -> set[int]:
    return {int(m) for m in re.findall(r"^## SPEC §(\d+)\b", SPEC.read_text(encoding="utf-8"), re.M)}


def test_every_spec_reference_resolves_in_the_digest() -> None:
    sections = _spec_sections()
    assert sections >= {1, 2, 3, 4, 5}, sections
    unresolved = [
        f"{_rel(page)} line {n}: SPEC §{section}"
        for page in PAGES
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), start=1)
        for section in re.findall(r"SPEC §(\d+)", line)
        if int(section) not in sections
    ]
    assert not unresolved, "\n".join(unresolved)


def _glossary_entries() -> set[str]:
    """The terms of the glossary: each entry is a list item that starts with **TERM** (several
    terms of one entry separated by commas or slashes)."""
    names = re.findall(r"^- \*\*(.+?)\*\*", GLOSSARY.read_text(encoding="utf-8"), re.M)
    return {term.strip().lower() for name in names for term in re.split(r"[,/]", name) if term.strip()}


def test_every_abbreviation_has_a_glossary_entry() -> None:
    entries = _glossary_entries()
    missing = [term for term in GLOSSARY_TERMS if term.lower() not in entries]
    assert not missing, f"docs/glossary.md has no entry for {missing}"


def test_the_link_finder() -> None:
    page = "see [a](docs/a.md), ![b](b.png) and [c](https://x.org) `[d](no.md)`"
    text = re.sub(r"`[^`]*`", "", page)
    assert _LINK.findall(text) == ["docs/a.md", "b.png", "https://x.org"]
