"""Facts about the committed run store that the docs quote: how many runs record a
'+dirty' revision, which torch versions the runs used, how many curves lack the
train_return column, and which runs name no CPU model. Each is computed from runs/ here and
compared with the sentence that states it, so that a new run in the store that changes a
fact fails this test until the docs say the new fact. Each failure says what the store
holds now."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import tomllib
from collections import Counter
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
REPRODUCIBILITY = DOCS / "reproducibility.md"
# The commit that made '+dirty' count only the code a run executes (1b1aa23): a run whose
# training began before it may carry the mark for an edit to the docs alone.
DIRTY_RULE_CHANGED_UTC = "2026-12-04T08:03:02+00:00"
LABELS = {  # in the order the docs list them
    "sac": "SAC",
    "drl-eg": "DRL-EG",
    "drl-eg-gmm": "DRL-EG-GMM",
    "ibrl": "IBRL",
    "jsrl": "JSRL",
    "rlpd": "RLPD",
    "ppo": "PPO",
    "ppo-bc": "PPO+BC",
    "ddpgfd": "DDPGfD",
}
WORDS = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven", 8: "eight"}


@dataclass(frozen=True)
class StoredRun:
    run_id: str
    provenance: dict
    curve_columns: tuple[str, ...]

    @property
    def algo(self) -> str:
        return self.run_id.split("__")[0]

    @property
    def env(self) -> str:
        return self.run_id.split("__")[1]

    @property
    def dirty(self) -> bool:
        return self.provenance["git_revision"].endswith("+dirty")

    @property
    def torch(self) -> str:
        return self.provenance["versions"]["torch"]


@cache
def committed_runs() -> tuple[StoredRun, ...]:
    """Every finished run git tracks in runs/ (a run that landed but is not committed, and
    the carried checkpoints under runs/carry/, are not counted)."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "runs"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    runs = []
    for name in listed:
        parts = name.split("/")
        if len(parts) != 3 or parts[2] != "provenance.json":
            continue
        directory = ROOT / "runs" / parts[1]
        with open(directory / "curve.csv", newline="") as handle:
            columns = tuple(next(csv.reader(handle)))
        provenance = json.loads((directory / "provenance.json").read_text())
        runs.append(StoredRun(parts[1], provenance, columns))
    assert runs, "no committed run in runs/"
    return tuple(runs)


def flat(path: Path) -> str:
    """The text with every run of whitespace as one space: prose wraps anywhere."""
    return " ".join(path.read_text().split())


def section(path: Path, heading: str) -> str:
    """One '## ' section of a Markdown file, whitespace flattened."""
    text = path.read_text()
    start = text.index(f"\n## {heading}\n")
    end = text.find("\n## ", start + 1)
    return " ".join(text[start : end if end >= 0 else None].split())


def count_words(n: int) -> tuple[str, ...]:
    """How a doc may write ``n``: digits, or a word for a small number."""
    return (str(n), WORDS[n]) if n in WORDS else (str(n),)


def assert_states(text: str, options: tuple[str, ...] | str, where: str) -> None:
    options = (options,) if isinstance(options, str) else options
    assert any(o in text for o in options), (
        f"{where} should state '{options[0]}' (what the committed store holds now)"
    )


def report_run_ids(report: str) -> set[str]:
    """The run directories a committed report's summary names, wherever they sit in it."""
    text = (ROOT / report / "summary.json").read_text()
    return set(re.findall(r"[\w.+-]+__[\w.+-]+__s\d+__[0-9a-f]{12}", text))


# --- '+dirty' revisions --------------------------------------------------------------------


def test_the_docs_count_the_dirty_runs():
    dirty = [r for r in committed_runs() if r.dirty]
    n = len(dirty)
    assert_states(
        flat(REPRODUCIBILITY),
        f"In all, {n} committed runs record a revision marked `+dirty`",
        "reproducibility.md",
    )
    # reproducibility.md places them: this many in the reduced Fig. 3, that many in the
    # comparison, all of the comparison's on the sparse dm-control tasks
    ids = {r.run_id for r in dirty}
    fig3 = len(ids & report_run_ids("reports/reduced/fig3"))
    in_rlfd = ids & report_run_ids("reports/reduced/rlfd")
    rlfd = len(in_rlfd)
    assert fig3 + rlfd == n, (
        f"{n - fig3 - rlfd} '+dirty' runs are in neither reports/reduced/fig3 nor "
        f"reports/reduced/rlfd: reproducibility.md should say where they are"
    )
    assert_states(
        flat(REPRODUCIBILITY),
        tuple(
            f"{w} of the reduced Fig. 3 runs and {rlfd} of the reduced comparison's runs, "
            "all on the sparse dm-control tasks"
            for w in count_words(fig3)
        ),
        "reproducibility.md",
    )
    off_sparse = sorted(r for r in in_rlfd if not r.split("__")[1].startswith("dm_control"))
    assert not off_sparse, f"'+dirty' comparison runs off the sparse dm-control tasks: {off_sparse}"


def test_every_dirty_run_trained_under_the_older_rule():
    """The docs say every '+dirty' run trained while the mark also counted docs edits."""
    later = [
        r.run_id
        for r in committed_runs()
        if r.dirty
        and max(s["started_utc"] for s in r.provenance["segments"]) >= DIRTY_RULE_CHANGED_UTC
    ]
    assert not later, (
        f"{later} carry '+dirty' from after {DIRTY_RULE_CHANGED_UTC}, when it meant an edit "
        "to the code: reproducibility.md says every '+dirty' run is older"
    )


# --- torch versions -----------------------------------------------------------------------


def pinned_torch() -> str:
    dependencies = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (pin,) = [d for d in dependencies if d.replace(" ", "").startswith("torch==")]
    return pin.replace(" ", "").split("==")[1]


def test_the_docs_name_the_torch_versions_the_runs_used():
    pins = section(REPRODUCIBILITY, "Pins")
    pin = pinned_torch()
    assert_states(pins, f"`torch=={pin}`", "reproducibility.md, Pins")

    versions = Counter(r.torch for r in committed_runs())
    cpu_build = f"{pin}+cpu"
    assert set(versions) == {cpu_build, "2.11.0"}, (
        f"the committed runs record torch {dict(versions)}: reproducibility.md's Pins name "
        f"{cpu_build} and 2.11.0 only"
    )
    assert_states(
        pins,
        tuple(f"record {w} torch versions" for w in count_words(len(versions))),
        "reproducibility.md, Pins",
    )
    assert_states(pins, f"{cpu_build}, the pin's CPU build", "reproducibility.md, Pins")
    assert_states(
        pins, f"for the {versions['2.11.0']} runs trained there", "reproducibility.md, Pins"
    )
    # which machines: the pin's build on the 2-core machines, 2.11.0 on the 16-core GPU ones
    cores = {
        version: Counter(
            r.provenance["machine"]["cpu_count"] for r in committed_runs() if r.torch == version
        )
        for version in versions
    }
    assert set(cores[cpu_build]) == {2}, (
        f"{cpu_build} runs on machines of {dict(cores[cpu_build])} cores"
    )
    assert set(cores["2.11.0"]) == {16}, f"2.11.0 runs on machines of {dict(cores['2.11.0'])} cores"


# --- curves without train_return ------------------------------------------------------------


def test_the_docs_count_the_curves_without_train_return():
    lacking = [r for r in committed_runs() if "train_return" not in r.curve_columns]
    by_algo = Counter(r.algo for r in lacking)
    assert set(by_algo) <= set(LABELS), f"label the algorithms {set(by_algo) - set(LABELS)}"
    breakdown = ", ".join(f"{LABELS[a]} {by_algo[a]}" for a in LABELS if by_algo[a])
    text = flat(REPRODUCIBILITY)
    assert_states(
        text, f"{len(lacking)} committed runs have no `train_return` column", "reproducibility.md"
    )
    assert_states(text, f"({breakdown}:", "reproducibility.md")


# --- the CPU model ---------------------------------------------------------------------------


def test_the_docs_say_which_runs_name_no_cpu_model():
    unnamed = [r for r in committed_runs() if not r.provenance["machine"].get("cpu_model")]
    n = len(unnamed)
    assert {r.env for r in unnamed} <= {"MountainCarContinuous-v0"}, (
        "the docs call the runs without a CPU model the earliest MountainCar ones; now also "
        f"{sorted({r.env for r in unnamed} - {'MountainCarContinuous-v0'})}"
    )
    assert_states(
        flat(REPRODUCIBILITY), f"its CPU model except in {n} committed runs", "reproducibility.md"
    )
    # reproducibility.md lists them by algorithm and seeds
    seeds: dict[str, list[int]] = {}
    for r in unnamed:
        seeds.setdefault(r.algo, []).append(int(r.run_id.split("__")[2][1:]))
    listed = []
    for algo in LABELS:
        found = sorted(seeds.get(algo, []))
        if not found:
            continue
        assert found == list(range(found[0], found[-1] + 1)), f"{algo}: seeds {found}"
        span = f"{found[0]}-{found[-1]}" if len(found) > 1 else str(found[0])
        listed.append(f"{LABELS[algo]} {span}")
    assert_states(
        flat(REPRODUCIBILITY), f"(seeds by algorithm: {', '.join(listed)})", "reproducibility.md"
    )
