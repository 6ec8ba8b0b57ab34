"""Reports and the front door read the run store without torch and without running git at
import time: they load fast, and on a machine that only reads results."""

import subprocess
import sys

CHECK = """
import subprocess, sys
calls = []
real = subprocess.run
subprocess.run = lambda *a, **k: calls.append(a) or real(*a, **k)
import replicate.store.runs, replicate.reports.pages, replicate.reports.frontdoor
heavy = sorted(m for m in sys.modules if m == "torch" or m.startswith("baselines"))
print(repr((heavy, calls)))
"""


def test_report_modules_import_no_torch_and_run_no_git():
    out = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, check=True
    ).stdout
    heavy, calls = eval(out)  # noqa: S307 (our own repr)
    assert heavy == [] and calls == []
