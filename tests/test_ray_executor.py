"""The Ray executor against a Ray head started on loopback by the test."""

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from replicate.cli.main import main
from replicate.figures.fig3 import FIG3_ALGORITHMS

PORT = "6391"


@pytest.fixture
def ray_head():
    ray_cli = shutil.which("ray") or str(Path(sys.executable).parent / "ray")
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", MUJOCO_GL="disable")
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's sockets live here
    start = [
        ray_cli,
        "start",
        "--head",
        "--node-ip-address",
        "127.0.0.1",
        "--port",
        PORT,
        "--num-cpus",
        "2",
        "--include-dashboard",
        "false",
        "--disable-usage-stats",
        "--temp-dir",
        temp_dir,
    ]
    subprocess.run(start, check=True, env=env, capture_output=True, timeout=120)
    try:
        yield f"127.0.0.1:{PORT}"
    finally:
        import ray

        ray.shutdown()
        subprocess.run([ray_cli, "stop", "--force"], env=env, capture_output=True, timeout=120)
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_smoke_figure_on_a_local_ray_cluster(ray_head, smoke_fig3, tmp_path):
    store, out = tmp_path / "runs", tmp_path / "report"
    assert (
        main(
            [
                "fig3",
                "--profile",
                "smoke",
                "--executor",
                "ray",
                "--address",
                ray_head,
                "--store",
                str(store),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["runs"]) == 2 * len(FIG3_ALGORITHMS) and not summary["failed"]
    # the same runs as the local executor's, by address and by result
    local = json.loads((smoke_fig3[1] / "summary.json").read_text())
    assert summary["runs"] == local["runs"]
    assert summary["final_returns"] == local["final_returns"]
