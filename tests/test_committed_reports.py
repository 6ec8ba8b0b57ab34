"""The committed reports rebuild, number for number, from the committed run store alone."""

import json
import re
from pathlib import Path

import pytest

from replicate.reports.pages import summary_run_ids

ROOT = Path(__file__).resolve().parents[1]
STORE = ROOT / "runs"
# Reports committed before the run store was, whose runs were never committed, so that they
# cannot be rebuilt; none now: the quick Fig. 4 and the quick threshold ablation were
# retrained into the store.
PREDATE_THE_STORE: set[str] = set()


def _tracked() -> set[Path]:
    """The files under reports/ that git tracks (a report written into the tree by a user's
    command is not a committed one); every file there outside a git checkout."""
    import subprocess

    try:
        listed = subprocess.run(
            ["git", "ls-files", "reports"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return set((ROOT / "reports").rglob("*"))
    return {ROOT / name for name in listed}


def _committed() -> list[Path]:
    tracked = _tracked()
    return sorted(
        p.parent
        for p in (ROOT / "reports").rglob("summary.json")
        if "smoke" not in p.parts and "bench" not in p.parts and p in tracked
    )


def test_every_committed_report_has_its_runs_committed_unless_it_predates_the_store():
    missing = {}
    for report in _committed():
        summary = json.loads((report / "summary.json").read_text())
        absent = [r for r in summary_run_ids(summary) if not (STORE / r / "curve.csv").is_file()]
        if absent:
            missing[report.relative_to(ROOT / "reports").as_posix()] = len(absent)
    assert set(missing) == PREDATE_THE_STORE, missing


def test_committed_reports_and_runs_name_no_directory_of_the_machine_that_made_them():
    absolute = re.compile(r"(?<![\w.:/])/(?:work|tmp|home|root|Users|scratch)/")
    files = [
        p
        for p in (ROOT / "reports").rglob("*")
        if p.suffix in (".html", ".json") and "smoke" not in p.parts and "bench" not in p.parts
    ]  # a bench records its command
    files += [p for p in STORE.glob("*/*.json")]
    offending = [p.relative_to(ROOT).as_posix() for p in files if absolute.search(p.read_text())]
    assert not offending, offending


@pytest.mark.parametrize(
    "report",
    [
        p
        for p in _committed()
        if p.relative_to(ROOT / "reports").as_posix() not in PREDATE_THE_STORE
    ],
    ids=lambda p: p.relative_to(ROOT / "reports").as_posix(),
)
def test_a_committed_report_rebuilds_from_the_committed_runs(report, tmp_path):
    from replicate.figures.registry import figures

    committed = json.loads((report / "summary.json").read_text())
    path = figures()[report.name].rebuild(committed["profile"], STORE, tmp_path, None)
    assert path is not None
    rebuilt = json.loads((tmp_path / "summary.json").read_text())
    for key in ("generated", "git_revisions"):  # when, and by which checkout, it was written
        committed.pop(key, None)
        rebuilt.pop(key, None)
    assert rebuilt == committed


def _no_constants(name: str):
    raise ValueError(f"{name} is not JSON")


def test_summaries_are_strict_json():
    import numpy as np

    from replicate.reports.pages import summary_bytes

    written = summary_bytes(
        {
            "reach": float("nan"),
            "values": [np.float64(1.5), np.int64(2)],
            "ci": (float("inf"), -1.0),
        }
    )
    assert json.loads(written, parse_constant=_no_constants) == {
        "reach": None,
        "values": [1.5, 2],
        "ci": [None, -1.0],
    }
    for report in _committed():  # what jq and a browser's JSON.parse accept
        json.loads((report / "summary.json").read_text(), parse_constant=_no_constants)


def test_reduced_fig3_shows_no_mujoco_drl_eg_before_the_t2_rule():
    from replicate.grids import drl_eg_settings

    if drl_eg_settings.MUJOCO_T2_RULE is not None:
        pytest.skip("the rule is set")
    # the store holds the ablation's 1x runs, whose spec is the spacing rule's: not shown
    summary = json.loads((ROOT / "reports" / "reduced" / "fig3" / "summary.json").read_text())
    assert not [
        f
        for f in summary["final_returns"]
        if f["algo"] in drl_eg_settings.T2_ALGORITHMS and f["env_id"] in drl_eg_settings.MUJOCO_ENVS
    ]


def test_the_mujoco_t2_rule_is_the_committed_ablations_choice():
    """MUJOCO_T2_RULE stays unset until the committed reduced ablation has every setting on
    both envs, and is then the setting its written criterion picks (docs/decisions.md: T2 on
    MuJoCo)."""
    import numpy as np

    from replicate.figures.ablation import RULE_PROFILE, choose_t2_rule, t2_rule_gains
    from replicate.grids import drl_eg_settings

    standing = choose_t2_rule(t2_rule_gains(STORE, RULE_PROFILE), np.random.default_rng(0))
    assert drl_eg_settings.MUJOCO_T2_RULE == standing["choice"], standing["leader"]


def _quantities(node, found):
    """Every stated quantity (a dict naming its ``quantity`` with an interval) in a summary."""
    if isinstance(node, dict):
        if isinstance(node.get("quantity"), str) and node["quantity"] and "low" in node:
            found.setdefault(node["quantity"], set()).add(
                (node["value"], node["low"], node["high"])
            )
        for value in node.values():
            _quantities(value, found)
    elif isinstance(node, list):
        for value in node:
            _quantities(value, found)
    return found


def test_no_quantity_appears_with_two_intervals():
    """Across every committed summary (Fig. 3 and Fig. 4 of one profile share claim 5), one
    quantity has one value and one interval wherever it is stated."""
    by_profile: dict[str, dict] = {}
    for report in _committed():
        summary = json.loads((report / "summary.json").read_text())
        _quantities(summary, by_profile.setdefault(summary["profile"], {}))
    stated = {profile: q for profile, q in by_profile.items() if q}
    assert stated, "no summary states a quantity"
    for profile, found in stated.items():
        doubled = {name: values for name, values in found.items() if len(values) > 1}
        assert not doubled, (profile, doubled)


def test_no_interval_over_few_seeds_is_just_the_seeds_range():
    """A percentile bootstrap over 3 seeds gives back their range; a t-interval over n <= 4
    seeds always reaches past it (its half width t * s / sqrt(n) exceeds the largest
    possible distance of a seed from the mean, s (n - 1) / sqrt(n)); over 5 it need not."""
    checked = 0
    for report in _committed():
        summary = json.loads((report / "summary.json").read_text())
        for cell in summary.get("final_returns", []):
            finals = cell["finals"]
            if len(finals) >= 2 and max(finals) > min(finals):
                checked += 1
                assert cell["ci95"] != [min(finals), max(finals)], cell
                if len(finals) <= 4:
                    assert cell["ci95"][0] < min(finals) and cell["ci95"][1] > max(finals), cell
    assert checked


def test_fig4_and_fig3_state_one_verdict_for_claim_5():
    for profile_dir in (ROOT / "reports", ROOT / "reports" / "reduced"):
        fig3 = json.loads((profile_dir / "fig3" / "summary.json").read_text())
        fig4 = json.loads((profile_dir / "fig4" / "summary.json").read_text())
        assert fig3["claims"][4]["verdict"] == fig4["claim"]["verdict"]


def test_no_committed_report_links_to_nowhere():
    dead = []
    for page in (ROOT / "reports").rglob("index.html"):
        if "smoke" in page.parts or "bench" in page.parts:
            continue
        for href in re.findall(r'href="([^"]+)"', page.read_text()):
            target = href.split("#")[0]
            if not target or target.startswith(("http:", "https:", "data:")):
                continue
            if not (page.parent / target).resolve().is_file():
                dead.append(f"{page.relative_to(ROOT)} -> {href}")
    assert not dead, dead


def test_every_open_check_says_what_would_decide_it():
    open_checks = 0
    for report in _committed():
        summary = json.loads((report / "summary.json").read_text())
        claims = summary.get("claims") or ([summary["claim"]] if summary.get("claim") else [])
        rows = [k for c in claims for p in c["parts"] for k in p["checks"]]
        rows += summary.get("verdicts", [])
        for row in rows:
            if row["verdict"] in ("inconclusive", "not testable at this budget"):
                open_checks += 1
                assert row.get("decide"), (report.name, row.get("what") or row.get("other"))
    assert open_checks


def test_every_judged_claim_of_reduced_fig3_has_its_parts_and_forest_plot():
    summary = json.loads((ROOT / "reports/reduced/fig3/summary.json").read_text())
    html = (ROOT / "reports/reduced/fig3/index.html").read_text()
    for claim in summary["claims"]:
        assert claim["declaration"]["file"] == "replicate/declarations/drl-eg.toml"
        assert claim["declaration"]["trained_before"] <= claim["declaration"]["runs"]
        assert all(p["state"] in ("holds", "contradicted", "open") for p in claim["parts"])
        section = html.split(f'id="claim-{claim["id"]}"', 1)[1].split("<h3", 1)[0]
        assert 'class="forest"' in section, claim["id"]
