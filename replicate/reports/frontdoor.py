"""The front door, ``reports/index.html``: every claim's verdict per profile on one screen,
the headline figure, one line per report and the caveats a reviewer must weigh, read from
the reports' ``summary.json`` files (it trains and recomputes nothing).

A report whose summary is missing, torn or not one of ours is listed as unavailable with
the reason; the page is still written.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

from replicate.reports.templating import report_environment
from replicate.reports.words import seed_words
from replicate.reports.words import steps_words as _steps

# The front door's words for a report, from its directory name and summary (None: a report
# this version of the harness does not know); the figure registry gives them.
Describe = Callable[[str, dict[str, Any]], "dict[str, str] | None"]

PROFILE_ORDER = ("quick", "reduced", "paper")  # columns; smoke reports mean nothing
CLAIM_IDS = (1, 2, 3, 4, 5)


@dataclass
class ReportEntry:
    """One report under reports/: what it covers, read from its summary."""

    path: str  # relative to reports/, e.g. "reduced/fig3"
    profile: str | None
    kind: str
    covers: str = ""
    budget: str = ""
    seeds: str = ""
    runs: int | None = None
    generated: str = ""
    unavailable: str | None = None  # why its summary cannot be read
    summary: dict[str, Any] = field(default_factory=dict, repr=False)


def _kind(name: str) -> str:
    """A report's kind: its registered name; the ablations share one kind."""
    if name.startswith("ablate-threshold"):
        return "ablation"
    return name


def read_report(root: Path, directory: Path, describe: Describe) -> ReportEntry:
    """The entry of one report directory; ``unavailable`` says why when its summary
    cannot be used."""
    from replicate.reports.pages import summary_run_ids

    relative = directory.relative_to(root).as_posix()
    parts = relative.split("/")
    profile = parts[0] if len(parts) > 1 else "quick"
    entry = ReportEntry(relative, profile, _kind(parts[-1]))
    summary_file = directory / "summary.json"
    if entry.kind == "table1":
        entry.covers = "Table 1: the environments' dimensions and the demonstrations"
        entry.profile = None
        return entry
    if not summary_file.is_file():
        entry.unavailable = "no summary.json"
        return entry
    try:
        summary = json.loads(summary_file.read_text())
    except (OSError, ValueError) as exc:
        entry.unavailable = f"summary.json unreadable ({type(exc).__name__})"
        return entry
    if not isinstance(summary, dict) or "profile" not in summary:
        entry.unavailable = "summary.json is not a report summary of this harness"
        return entry
    entry.summary, entry.profile = summary, summary["profile"]
    entry.generated = str(summary.get("generated", ""))[:10]
    try:
        entry.runs = len(summary_run_ids(summary))
        _describe(entry, summary, describe)
    except (KeyError, TypeError, ValueError) as exc:
        entry.unavailable = f"summary.json lacks what this page reads ({exc})"
    return entry


def _describe(entry: ReportEntry, summary: dict[str, Any], describe: Describe) -> None:
    words = describe(entry.path.split("/")[-1], summary)
    if words is None:
        entry.covers = "a report this version of the harness does not know"
        return
    entry.covers, entry.budget, entry.seeds = words["covers"], words["budget"], words["seeds"]


def find_reports(root: Path, describe: Describe) -> list[ReportEntry]:
    """Every report under ``root`` (reports/), smoke ones and benchmarks left out."""
    directories = sorted(
        {p.parent for p in root.rglob("index.html")}
        | {p.parent for p in root.rglob("summary.json")}
    )
    entries = []
    for directory in directories:
        if directory == root or {"smoke", "bench"} & set(directory.relative_to(root).parts):
            continue
        if any(part.startswith(".") for part in directory.relative_to(root).parts):
            continue  # a rebuild in progress
        entries.append(read_report(root, directory, describe))
    order = {p: k for k, p in enumerate(PROFILE_ORDER)}
    return sorted(entries, key=lambda e: (order.get(e.profile or "", -1), e.path))


def verdict_table(entries: list[ReportEntry]) -> tuple[list[str], list[dict[str, Any]]]:
    """Claims as rows, profiles as columns: each cell the verdict with its budget and seeds,
    linking to the claim's section in the report that judged it (Fig. 4 for claim 5)."""
    fig3 = {e.profile: e for e in entries if e.kind == "fig3" and not e.unavailable}
    fig4 = {e.profile: e for e in entries if e.kind == "fig4" and not e.unavailable}
    profiles = [p for p in PROFILE_ORDER if p in fig3]
    rows = []
    for claim_id in CLAIM_IDS:
        row: dict[str, Any] = {"id": claim_id, "title": "", "cells": {}}
        for profile in profiles:
            claims = {c["id"]: c for c in fig3[profile].summary.get("claims", [])}
            claim = claims.get(claim_id)
            report = fig3[profile]
            if claim_id == 5 and profile in fig4 and fig4[profile].summary.get("claim"):
                claim, report = fig4[profile].summary["claim"], fig4[profile]
            if claim is None:
                continue
            row["title"] = row["title"] or claim["title"]
            seeds = claim.get("seeds")
            row["cells"][profile] = {
                "verdict": claim["verdict"].split(":")[0],
                "href": f"{report.path}/index.html#claim-{claim_id}",
                "budget": _steps(claim["steps"]) if claim.get("steps") else "",
                "seeds": seed_words(seeds or []),
                "parts": [
                    {"id": p["id"], "state": p["state"]}
                    for p in claim.get("parts", [])
                    if p.get("state")
                ],
                "likely": claim.get("likely"),
                "confirmatory": claim.get("confirmatory", []),
                "under_way": [
                    f"{c['id']}: {c['confirmatory']['progress']['done']} of "
                    f"{c['confirmatory']['progress']['planned']} runs"
                    for p in claim.get("parts", [])
                    for c in p.get("checks", [])
                    if c.get("confirmatory") and not c["confirmatory"].get("state")
                ],
                "preconditions": [
                    p["detail"] for p in claim.get("preconditions", []) if not p["observed"]
                ],
            }
        rows.append(row)
    return profiles, rows


_FIGURE = re.compile(r'id="figure".*?<img[^>]*?src="(data:image/[^"]+)"', re.S)


def headline_figure(root: Path, entries: list[ReportEntry]) -> tuple[str | None, str | None]:
    """The largest profile's Fig. 3 image (a data URI taken from its page) and its path."""
    for profile in reversed(PROFILE_ORDER):
        for entry in entries:
            if entry.kind == "fig3" and entry.profile == profile and not entry.unavailable:
                page = root / entry.path / "index.html"
                found = _FIGURE.search(page.read_text()) if page.is_file() else None
                if found:
                    return found.group(1), entry.path
    return None, None


def write_front_door(root: Path, describe: Describe) -> Path:
    """Write ``root/index.html`` from the reports under ``root``, each described by
    ``describe`` (the figure registry's ``describe``)."""
    from replicate.reports.pages import _atomic_write

    root = Path(root)
    entries = find_reports(root, describe)
    profiles, rows = verdict_table(entries)
    figure, figure_from = headline_figure(root, entries)
    largest = next(
        (
            e
            for p in reversed(PROFILE_ORDER)
            for e in entries
            if e.kind == "fig3" and e.profile == p and not e.unavailable
        ),
        None,
    )
    caveats = largest.summary.get("threats", []) if largest else []
    html = (
        report_environment()
        .get_template("index.html")
        .render(
            profiles=profiles,
            rows=rows,
            entries=entries,
            figure=figure,
            figure_from=figure_from,
            caveats=caveats,
            caveats_from=largest.path if largest else None,
            generated=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        )
    )
    _atomic_write(root / "index.html", html.encode())
    return root / "index.html"
