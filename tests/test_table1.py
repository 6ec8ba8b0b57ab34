import re

import pytest

from envs import ENV_SPECS
from replicate.cli.main import main
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
    from replicate.figures.table1 import EXPERT_TARGETS, table1_rows

    rows = {r["env_id"]: r for r in table1_rows()}
    for env_id, target in EXPERT_TARGETS.items():
        row = rows[env_id]
        mean = row["demo"]["expert_return_mean"]
        assert row["target"]["value"] == target
        assert row["target"]["met"] == (mean >= target)
        assert row["target"]["short_by"] == pytest.approx(max(0.0, 1 - mean / target))
    assert rows["MountainCarContinuous-v0"]["target"] is None


def test_a_wrong_dimension_in_the_env_table_is_one_line_and_exit_2(monkeypatch, capsys):
    import dataclasses

    import envs
    from replicate.cli.main import main

    spec = envs.ENV_SPECS["MountainCarContinuous-v0"]
    wrong = dataclasses.replace(spec, obs_dim=spec.obs_dim + 1)
    monkeypatch.setitem(envs.ENV_SPECS, "MountainCarContinuous-v0", wrong)
    assert main(["table1", "--out", "/nonexistent-unused"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "obs_dim=2" in err[0] and "MountainCarContinuous-v0" in err[0]
