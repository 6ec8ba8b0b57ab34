import re

import pytest

from envs import ENV_SPECS
from replicate.cli import main
from replicate.demos import default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR


def test_table1_shows_paper_and_harness_dims_and_the_demonstrations(tmp_path):
    assert main(["table1", "--out", str(tmp_path)]) == 0
    html = (tmp_path / "index.html").read_text()
    ant = re.search(
        r"<code>Ant-v5</code></td><td>Ant-v2</td>\s*<td class=\"num\">(\d+) / (\d+)", html
    )
    assert ant and ant.groups() == ("111", "105")
    meta = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR).metadata
    shown = (
        f"{meta['expert_return_mean']:.1f} &plusmn; {meta['expert_return_std']:.1f} "
        f"({meta['expert_episodes']})"
    )
    assert "MountainCarContinuous-v0.v1.npz" in html and shown in html
    demo_section = html[html.index('id="demonstrations"') :]
    assert demo_section.count("<tr><td><code>") == len(ENV_SPECS)  # every env has a row
    assert "http://" not in html and "https://" not in html


def test_table1_states_each_mujoco_expert_against_its_target():
    from replicate.table1 import EXPERT_TARGETS, table1_rows

    rows = {r["env_id"]: r for r in table1_rows()}
    for env_id, target in EXPERT_TARGETS.items():
        row = rows[env_id]
        mean = row["demo"]["expert_return_mean"]
        assert row["target"]["value"] == target
        assert row["target"]["met"] == (mean >= target)
        assert row["target"]["short_by"] == pytest.approx(max(0.0, 1 - mean / target))
    assert rows["MountainCarContinuous-v0"]["target"] is None
