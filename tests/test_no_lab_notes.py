"""The product states what is true now: no lab notes (numbered work periods, narratives of what
was tried and when) in the README, docs, source, benchmarks, notebooks or tests. History
belongs to git; a design choice cites the benchmark JSON that measured it."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PHRASES = re.compile("|".join((
    r"\bsessions? \d+",
    r"\bsince session\b",
    r"\bwork periods?\b",
    r"\b(?:we|was|were|been) tried\b",
    r"\b(?:it|this|that|they|which) used to\b",
    r"\bused to (?:be|fail|assume|draw|stop|accept|give|fall|ignore|differ)\b",
    r"\bin (?:an|the) earlier (?:run|version|attempt|probe)\b",
)), re.IGNORECASE)


def product_files():
    yield ROOT / "README.md"
    yield ROOT / "DEVELOPERS.md"
    yield from sorted((ROOT / "docs").rglob("*.md"))
    yield from sorted((ROOT / "src").rglob("*.py"))
    yield from sorted((ROOT / "benchmarks").glob("*.py"))
    yield from sorted((ROOT / "notebooks").glob("*.ipynb"))
    yield from (p for p in sorted((ROOT / "tests").glob("*.py")) if p.name != Path(__file__).name)


def lab_notes(text: str) -> list[str]:
    return [m.group(0) for m in PHRASES.finditer(text)]


def test_no_lab_notes_in_the_product():
    found = [f"{p.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}"
             for p in product_files() if p.is_file()
             for text in [p.read_text(errors="replace")] for m in PHRASES.finditer(text)]
    assert not found, "lab notes in the product (say what is true now; cite the benchmark):\n" \
        + "\n".join(found)


@pytest.mark.parametrize("text", [
    "measured in session " + "24 on the demo model",  # split: the file itself stays clean
    "A proposal fitted to half the ensemble was tried at the demo size",
    "decode used to assume 30 fps",
    "Since session " + "19 the default adds an independence step",
])
def test_the_check_finds_planted_lab_notes(text):
    assert lab_notes(text)


@pytest.mark.parametrize("text", [
    "The session's chain file can be resumed",
    "the moves used to cross the ridges are exact",
    "max R-hat 1.010 at 6,000 steps (results/posterior_convergence.json)",
])
def test_the_check_leaves_plain_statements_alone(text):
    assert not lab_notes(text)
