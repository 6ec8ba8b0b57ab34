"""The product speaks of its users' world (a laptop, a GPU box, a cluster), not of how the
project was built: no tracked file outside the run store uses the words listed here."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Each phrase with a space or a character class in the middle, so that this file does not
# match its own pattern and needs no exception of its own.
PHRASES = (
    r"\bl[o]ans?\b",
    r"\bl[e]nt\b",
    r"working[ ]sessions?",
    r"borrowed[ ]GPU",
    r"machine[ ]time",
    r"\bsitt[i]ngs?\b(?!\.json)",  # "interrupted and resumed"; older stores' file keeps its name
    r"\bissue[ ]\d+",  # the project's tracker is not the user's
)
WORDS = re.compile("|".join(PHRASES), re.IGNORECASE)
SKIPPED = ("runs/",)  # the run store: committed provenance records as they were written


def tracked_files() -> list[Path]:
    try:
        listed = subprocess.run(
            ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / name for name in listed if not name.startswith(SKIPPED)]


def test_no_tracked_file_speaks_of_loans_or_working_sessions():
    found = []
    for path in tracked_files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, FileNotFoundError):  # binary data, or deleted unstaged
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if WORDS.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not found, "\n".join(found)


# A rule fixed after the runs it judges must not be called declared in advance: the
# declaration's git history says when each rule was fixed (docs/rule-changes.md records it).
ADVANCE = re.compile(r"pre-declared|before any run (?:was|is) judged|before the runs were judged")


def test_no_report_or_guide_calls_a_rule_declared_in_advance():
    found = [
        str(path.relative_to(ROOT))
        for path in tracked_files()
        if path.suffix in (".html", ".md", ".py", ".toml")
        and path.name != "test_wording.py"
        and path.is_file()
        and ADVANCE.search(path.read_text(errors="ignore"))
    ]
    assert not found, found
