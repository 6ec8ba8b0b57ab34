import json

from replicate.cli import main


def test_fig4_pairs_seeds_with_identical_starts(smoke_fig3, tmp_path, capsys):
    store, _ = smoke_fig3  # the smoke Fig. 3 already holds these very runs
    out = tmp_path / "fig4"
    assert main(["fig4", "--profile", "smoke", "--env", "MountainCarContinuous-v0",
                 "--seeds", "2", "--store", str(store), "--out", str(out)]) == 0
    assert "training 0 runs" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert [r["seed"] for r in summary["rows"]] == [0, 1]
    assert all(r["same_start"] for r in summary["rows"])  # same seed, same initial weights
    assert summary["paired"] is not None and summary["claim"] is None  # claim 5 is about Ant
    html = (out / "index.html").read_text()
    assert "data:image/png;base64," in html and 'id="smoke-warning"' in html


def test_fig4_without_demonstrations_says_how_to_make_them(tmp_path, capsys, monkeypatch):
    from replicate import demos

    monkeypatch.setattr(demos, "default_demo_path", lambda env_id: tmp_path / "missing.npz")
    code = main(["fig4", "--profile", "smoke", "--env", "HalfCheetah-v5",
                 "--store", str(tmp_path), "--out", str(tmp_path / "out")])
    assert code == 2
    assert "nox -s experts -- --env HalfCheetah-v5" in capsys.readouterr().err
