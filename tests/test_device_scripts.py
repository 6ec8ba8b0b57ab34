"""The lent-machine shell scripts: what they pack, and a detached job across two calls."""

from __future__ import annotations

import subprocess
import tarfile
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def packed_names(archive: Path) -> set[str]:
    with tarfile.open(archive) as tar:
        return {name.removeprefix("./") for name in tar.getnames()} - {"."}


def make_store(store: Path) -> None:
    (store / "finished").mkdir(parents=True)
    (store / "finished" / "provenance.json").write_text("{}")
    (store / "finished" / "checkpoint.pt").write_text("big")
    (store / ".partial-training").mkdir()
    (store / ".partial-training" / "curve.csv").write_text("step\n")
    (store / ".lock-finished").write_text("")


def test_pack_runs_keeps_finished_runs_and_leaves_the_rest(tmp_path):
    store, out = tmp_path / "store", tmp_path / "out"
    make_store(store)
    out.mkdir()
    subprocess.run([BENCHMARKS / "pack_runs.sh", store, out], check=True)
    assert packed_names(out / "runs.tgz") == {"finished", "finished/provenance.json"}
    assert sorted(p.name for p in out.iterdir()) == ["runs.tgz"]  # no temporary left

    failed = subprocess.run([BENCHMARKS / "pack_runs.sh", tmp_path / "missing", out],
                            stderr=subprocess.DEVNULL)
    assert failed.returncode == 1
    assert packed_names(out / "runs.tgz") == {"finished", "finished/provenance.json"}
    assert sorted(p.name for p in out.iterdir()) == ["runs.tgz"]


def test_a_detached_job_runs_on_between_calls_against_a_copy_of_the_store(tmp_path):
    repo, state, out = tmp_path / "repo", tmp_path / "state", tmp_path / "out"
    gate = tmp_path / "go"
    make_store(repo / "runs")
    out.mkdir()
    script = str(BENCHMARKS / "device_detached.sh")
    missing = subprocess.run([script, "wait", state, out, "5"], capture_output=True, text=True)
    assert missing.returncode == 2 and "no job was started" in missing.stderr

    # the job lands a run once the test opens the gate, and logs beside job.log
    land = ('while [ ! -e "$0" ]; do sleep 0.05; done; mkdir "$REPLICATE_STORE/landed"; '
            'echo {} > "$REPLICATE_STORE/landed/p"; echo done > "$1/extra.log"; echo out')
    started = subprocess.run([script, "start", state, "sh", "-c", land, gate, state], cwd=repo,
                             capture_output=True, text=True, check=True)
    assert "started pid" in started.stdout

    again = subprocess.run([script, "start", state, "true"], cwd=repo, capture_output=True,
                           text=True)
    assert again.returncode == 2 and "already running" in again.stderr

    first = subprocess.run([script, "wait", state, out, "0"], capture_output=True, text=True,
                           check=True)
    assert first.stdout.strip() == "running"
    assert packed_names(out / "runs.tgz") == {"finished", "finished/provenance.json"}

    gate.touch()
    second = subprocess.run([script, "wait", state, out, "60"], capture_output=True,
                            text=True, check=True, timeout=90)
    assert second.stdout.strip() == "ended, exit status 0"
    assert packed_names(out / "runs.tgz") == {"finished", "finished/provenance.json",
                                              "landed", "landed/p"}
    assert (out / "job.log").read_text() == "out\n"
    assert (out / "extra.log").read_text() == "done\n"
    assert not (repo / "runs" / "landed").exists()  # the job wrote to its own copy
