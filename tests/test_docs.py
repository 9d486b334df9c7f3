"""The documentation is reference, not a diary (docs/ARCHITECTURE.md, "Top level").

Every page says how a thing works now, in at most 25 KB; measured figures that change live
in docs/measurements/, each page headed by the ``skelasm`` command that regenerates it; no
page tells the story of a working session; every relative link resolves.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
MEASUREMENTS = sorted((DOCS / "measurements").glob("*.md"))
LINKED = [ROOT / "README.md", ROOT / "assets" / "README.md", *PAGES, *MEASUREMENTS]

#: The largest page, in bytes.
MAX_PAGE_BYTES = 25 * 1024

#: Phrases of a lab notebook: dated runs, work diaries, this machine's paths.
DIARY = [
    (re.compile(r"\b[Ss]ession of 20\d\d"), "a dated session"),
    (re.compile(r"\b(?:in one|same|this|earlier) session\b"), "a working session"),
    (re.compile(r"\bbug \d+ of issue\b|\bissue \d+\b"), "an issue's diary"),
    (re.compile(r"/work/|/tmp/bash_jobs"), "this machine's paths"),
    (re.compile(r"\bused to (?:be|cost|end|make|overflow|run|say|take|wait)\b"),
     "how it used to work"),
    (re.compile(r"(?m)\b(?:after|before) the fix\b|\bfound there and fixed\b|^\W*[Bb]efore:"),
     "a fix's story"),
]

LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("page", PAGES + MEASUREMENTS, ids=_name)
def test_no_page_is_over_25_kb(page: Path) -> None:
    size = page.stat().st_size
    assert size <= MAX_PAGE_BYTES, (
        f"{_name(page)} is {size} bytes (at most {MAX_PAGE_BYTES}): move measurements to "
        "docs/measurements/ and history to the git log")


@pytest.mark.parametrize("page", PAGES + MEASUREMENTS, ids=_name)
def test_no_page_reads_like_a_diary(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    found = [f"line {text.count(chr(10), 0, m.start()) + 1}: {what} ({m.group(0)!r})"
             for pattern, what in DIARY for m in pattern.finditer(text)]
    assert not found, f"{_name(page)}: " + "; ".join(found)


@pytest.mark.parametrize("page", MEASUREMENTS, ids=_name)
def test_a_measurement_page_names_the_command_that_regenerates_it(page: Path) -> None:
    head = "\n".join(page.read_text(encoding="utf-8").splitlines()[:20])
    assert head.startswith("# "), f"{_name(page)} has no title"
    assert re.search(r"^skelasm \w+", head, re.MULTILINE), (
        f"{_name(page)}: its first lines name no `skelasm ...` command that regenerates it")
    assert re.search(r"[Mm]achine", head), (
        f"{_name(page)}: its first lines do not say what kind of machine measured it")


@pytest.mark.parametrize("page", LINKED, ids=_name)
def test_every_relative_link_resolves(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        if not (page.parent / target).exists():
            broken.append(target)
    assert not broken, f"{_name(page)} links to missing files: {broken}"


def test_the_checks_catch_what_they_look_for(tmp_path: Path) -> None:
    """Each pattern fires on the kind of line it is meant for (so the checks can fail)."""
    diary = ("Session of 2026-11-24, same session, bug 3 of issue 10, /work/main/docs; "
             "it used to overflow; after the fix: 3 s\nBefore: 9 s")
    assert {what for pattern, what in DIARY if pattern.search(diary)} == {
        what for _, what in DIARY}
    assert not any(p.search("the UDP bridge's session token") for p, _ in DIARY)
    assert not any(p.search("the step used to integrate; the fix: a coarser grid")
                   for p, _ in DIARY)
    assert LINK.findall("[a](b.md#c) and [d](https://e)") == ["b.md", "https://e"]
