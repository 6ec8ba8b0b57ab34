"""Reports as plug-ins: every report is registered once; `nox -s report` and the front door
loop over the registry; the guided-share figure, added as a plug-in, rebuilds from
a store."""

import json

from replicate.figures.registry import describe, figures
from replicate.reports.frontdoor import write_front_door


def test_every_report_is_registered_once():
    names = set(figures())
    assert {
        "fig3",
        "fig4",
        "rlfd",
        "ablate-threshold",
        "ablate-threshold-ant",
        "ablate-threshold-walker2d",
        "guided-share",
        "random-start",
    } <= names


def test_the_guided_share_plug_in_rebuilds_from_a_store_and_joins_the_front_door(
    smoke_fig3, tmp_path
):
    store, _ = smoke_fig3
    reports = tmp_path / "reports"
    out = reports / "smoke-guided"
    assert figures()["guided-share"].rebuild("smoke", store, out, None) is not None
    summary = json.loads((out / "summary.json").read_text())
    assert {row["algo"] for row in summary["rows"]} == {"drl-eg", "drl-eg-gmm"}
    assert all(0 <= share <= 1 for row in summary["rows"] for share in row["shares"])
    assert summary["run_ids"] and all((store / r).is_dir() for r in summary["run_ids"])
    # under its registered name the front door describes it
    (reports / "guided-share").mkdir(parents=True)
    for name in ("index.html", "summary.json"):
        (reports / "guided-share" / name).write_bytes((out / name).read_bytes())
    page = write_front_door(reports, describe).read_text()
    assert "How often DRL-EG&#39;s guider acts over training" in page
    assert figures()["guided-share"].rebuild("quick", tmp_path / "empty", out, None) is None


def test_the_command_line_takes_each_figures_command_from_the_registry(
    monkeypatch, capsys, tmp_path
):
    import argparse

    from replicate.cli import main as cli
    from replicate.figures import registry as figure_registry
    from replicate.figures.figure import FigureReport
    from replicate.figures.registry import figure_commands
    from replicate.grids.options import Command

    names = [command.name for command in figure_commands()]
    assert names == ["fig3", "fig4", "compare-rlfd", "ablate-threshold", "random-start"]

    def declare(sub: argparse._SubParsersAction) -> None:
        sub.add_parser("my-figure", help="a figure registered by a plug-in")

    def run(args: argparse.Namespace) -> int:
        print("my figure ran")
        return 0

    plug_in = FigureReport(
        "my-figure", lambda *a: None, lambda s: {}, Command("my-figure", declare, run)
    )
    monkeypatch.setattr(figure_registry, "PLUG_INS", (*figure_registry.PLUG_INS, plug_in))
    monkeypatch.chdir(tmp_path)  # the front door it refreshes is this directory's
    (tmp_path / "reports").mkdir()
    assert cli.main(["my-figure"]) == 0
    assert "my figure ran" in capsys.readouterr().out
    assert (tmp_path / "reports" / "index.html").is_file()  # a figure command refreshes it
