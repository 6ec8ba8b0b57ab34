"""The front door, reports/index.html: every claim's verdict per profile from the reports'
own summaries, links that lead somewhere, and a page that still builds when a summary is
missing, torn or foreign."""

import html
import json
import re
import shutil
from pathlib import Path

import pytest

from replicate.figures.registry import describe
from replicate.reports.frontdoor import find_reports, verdict_table, write_front_door

ROOT = Path(__file__).resolve().parents[1]
REPORTS = ROOT / "reports"


@pytest.fixture
def reports_copy(tmp_path):
    copy = tmp_path / "reports"
    shutil.copytree(REPORTS, copy, ignore=shutil.ignore_patterns("bench"))
    return copy


def test_verdicts_equal_the_reports_own(reports_copy):
    page = write_front_door(reports_copy, describe).read_text()
    profiles, rows = verdict_table(find_reports(reports_copy, describe))
    assert profiles == ["quick", "reduced"]
    for profile in profiles:
        base = reports_copy / ("" if profile == "quick" else profile)
        fig3 = json.loads((base / "fig3" / "summary.json").read_text())
        fig4 = json.loads((base / "fig4" / "summary.json").read_text())
        own = {c["id"]: c["verdict"].split(":")[0] for c in fig3["claims"]}
        own[5] = fig4["claim"]["verdict"].split(":")[0]
        assert {row["id"]: row["cells"][profile]["verdict"] for row in rows} == own
    for href in re.findall(r'href="([^"#]+)', page):  # every link leads to a file
        assert (reports_copy / href).is_file(), href


def test_the_committed_front_door_is_current():
    """reports/index.html names the same verdicts and reports as one rebuilt now."""
    committed = (REPORTS / "index.html").read_text()
    profiles, rows = verdict_table(find_reports(REPORTS, describe))
    for row in rows:
        for profile, cell in row["cells"].items():
            shown = html.escape(cell["verdict"], quote=True).replace("&#x27;", "&#39;")
            assert f'href="{cell["href"]}">{shown}</a>' in committed, (row["id"], profile)


def test_a_missing_torn_or_foreign_summary_marks_that_report_unavailable(reports_copy):
    (reports_copy / "fig4" / "summary.json").unlink()
    (reports_copy / "rlfd" / "summary.json").write_text('{"profile": "quick", "cells": [')
    (reports_copy / "ablate-threshold" / "summary.json").write_text('["not", "ours"]')
    page = write_front_door(reports_copy, describe).read_text()
    assert "unavailable: no summary.json" in page
    assert "unavailable: summary.json unreadable (JSONDecodeError)" in page
    assert "unavailable: summary.json is not a report summary of this harness" in page
    assert 'href="reduced/fig3/index.html#claim-2">inconclusive' in page or "reduced" in page


def test_report_command_writes_it_and_exits_0_over_a_torn_summary(
    reports_copy, monkeypatch, capsys
):
    from replicate.cli.main import main

    (reports_copy / "rlfd" / "summary.json").write_text("{")
    store = reports_copy.parent / "empty-store"
    store.mkdir()
    assert (
        main(["report", "--profile", "quick", "--store", str(store), "--out", str(reports_copy)])
        == 0
    )
    assert "front door:" in capsys.readouterr().out
    assert "unavailable" in (reports_copy / "index.html").read_text()


def test_a_dry_run_leaves_the_front_door_alone(tmp_path, monkeypatch):
    import replicate.reports.frontdoor as frontdoor
    from replicate.cli.main import main

    written = []
    monkeypatch.setattr(frontdoor, "write_front_door", lambda root, describe: written.append(root))
    assert main(["fig3", "--profile", "quick", "--dry-run", "--store", str(tmp_path)]) == 0
    assert written == []
