"""The smoke profile end to end: grid -> run store -> statistics -> figure -> HTML."""

import json
import re

from replicate.cli import main


def test_smoke_profile_produces_a_self_contained_report(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "report"
    code = main(["fig3", "--profile", "smoke", "--store", str(store), "--out", str(out)])
    assert code == 0
    html = (out / "index.html").read_text()
    for section in ("claims", "figure", "final-returns", "budgets", "demonstrations", "runs",
                    "provenance", "smoke-warning"):
        assert f'id="{section}"' in html
    image = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    assert image and len(image.group(1)) > 1000
    assert "http://" not in html and "https://" not in html  # nothing fetched at view time
    assert "not judged (smoke profile" in html
    summary = json.loads((out / "summary.json").read_text())
    assert {f["algo"] for f in summary["final_returns"]} == {"sac", "drl-eg"}
    assert len(summary["runs"]) == 4 and not summary["failed"]
    assert all(len(f["finals"]) == 2 for f in summary["final_returns"])

    # a second invocation trains nothing and rebuilds the same numbers from the store
    capsys.readouterr()
    assert main(["fig3", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    assert "4 already in" in capsys.readouterr().out
    again = json.loads((out / "summary.json").read_text())
    assert again["final_returns"] == summary["final_returns"]
    assert again["claim"] == summary["claim"]
