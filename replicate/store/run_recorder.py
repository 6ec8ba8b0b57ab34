"""The files a run writes while it trains (spec.json, curve.csv, segments.json and, when it
lands, provenance.json): see ``replicate.store.runner`` for what each holds."""

from __future__ import annotations

import csv
import json
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from baselines.common.context import EvalPoint
from baselines.common.device import describe_device
from baselines.registry import get_algorithm
from replicate.store import provenance
from replicate.store.runs import CURVE_COLUMNS

if TYPE_CHECKING:
    from replicate.store.spec import PreparedRun

SEGMENTS_FILE = "segments.json"  # one entry per uninterrupted stretch of a run's training
EARLIER_SEGMENTS_FILE = "sittings.json"  # the same list in stores written before 2026-12-04


def read_segments(directory: Path) -> list[dict[str, Any]]:
    """The stretches of training recorded in a run's or a batch's directory (none yet: [])."""
    for name in (SEGMENTS_FILE, EARLIER_SEGMENTS_FILE):
        if (directory / name).is_file():
            return json.loads((directory / name).read_text())
    return []


def write_segments(directory: Path, segments: list[dict[str, Any]]) -> None:
    (directory / SEGMENTS_FILE).write_text(json.dumps(segments, indent=1) + "\n")
    (directory / EARLIER_SEGMENTS_FILE).unlink(missing_ok=True)


def write_json(path: Path, payload: dict[str, Any]) -> None:
    path.write_text(json.dumps(payload, indent=2, sort_keys=True, default=str) + "\n")


class RunRecorder:
    """Writes one run's files while it trains: spec.json, curve.csv (rewritten whole: a
    resumed algorithm re-emits the points it had, which keep the wall time they were first
    written with), segments.json (the stretches of training) after every point, and
    provenance.json at the end."""

    def __init__(
        self, prepared: PreparedRun, run_dir: Path, device: str, batch: dict[str, Any] | None = None
    ):
        self.prepared, self.run_dir, self.device, self.batch = prepared, run_dir, device, batch
        self.earlier = read_segments(run_dir)
        self.started = time.time()
        self.started_iso = datetime.now(timezone.utc).isoformat(timespec="seconds")
        self.resumed_from = 0
        self.earlier_walls: dict[int, str] = {}
        self.earlier_wall = sum(s["wall_time_s"] for s in self.earlier)
        self.curve_file: Any = None

    def open(self) -> None:
        write_json(self.run_dir / "spec.json", self.prepared.resolved)
        curve_path = self.run_dir / "curve.csv"
        if curve_path.is_file():
            with open(curve_path, newline="") as handle:
                self.earlier_walls = {
                    int(row["step"]): row["wall_s"] for row in csv.DictReader(handle)
                }
        self.curve_file = open(curve_path, "w", newline="")
        self.writer = csv.writer(self.curve_file)
        self.writer.writerow(CURVE_COLUMNS)

    def on_resume(self, step: int) -> None:
        self.resumed_from = step

    def record_segment(self) -> None:
        """This stretch of training (from its start or resume to now) after the earlier
        ones, in segments.json."""
        segment = {
            "started_utc": self.started_iso,
            "resumed_from_step": self.resumed_from,
            "wall_time_s": round(time.time() - self.started, 3),
            "git_revision": provenance.code_revision(),
            "device": describe_device(self.device),
        }
        if self.batch is not None:
            segment["batch"] = self.batch["id"]
        write_segments(self.run_dir, self.earlier + [segment])

    def on_eval(self, point: EvalPoint) -> None:
        kept = point.step <= self.resumed_from and point.step in self.earlier_walls
        self.writer.writerow(
            [
                point.step,
                f"{point.mean_return:.6g}",
                f"{np.std(point.returns):.6g}",
                ";".join(f"{r:.6g}" for r in point.returns),
                f"{point.guided_fraction:.6g}",
                "" if point.gate_open is None else int(point.gate_open),
                f"{point.train_return:.6g}",
                self.earlier_walls[point.step]
                if kept
                else f"{self.earlier_wall + time.time() - self.started:.3f}",
            ]
        )
        self.curve_file.flush()
        self.record_segment()

    def close(self) -> None:
        if self.curve_file is not None:
            self.curve_file.close()

    def finish(self) -> None:
        """The last stretch of training and provenance.json: the run is complete."""
        self.record_segment()
        prepared, spec = self.prepared, self.prepared.spec
        segments = read_segments(self.run_dir)
        wall = sum(s["wall_time_s"] for s in segments)
        payload = {
            "run_id": prepared.run_id,
            "spec_hash": prepared.resolved["spec_hash"],
            "seed": spec.seed,
            "started_utc": segments[0]["started_utc"],
            "wall_time_s": round(wall, 3),
            "segments": segments,
            "env_steps_per_s": round(spec.total_steps / wall, 2) if wall > 0 else None,
            "git_revision": provenance.code_revision(),
            "versions": provenance.package_versions(),
            "machine": provenance.machine(),
            "device": describe_device(self.device),
            "demos": None
            if prepared.demos is None
            else {
                "sha256": prepared.demos.sha256,
                "path": prepared.resolved["demos_path"],
                "expert_return_mean": prepared.demos.mean_return,
                "expert": prepared.demos.metadata.get("expert"),
            },
        }
        algorithm = get_algorithm(spec.algo)
        # the code path that trained it: the SAC family's one trainer, or the algorithm's own
        payload["trainer"] = (
            "baselines.offpolicy.run_off_policy" if algorithm.batchable else algorithm.module
        )
        if self.batch is not None:
            # the batch's wall time is shared by its members: the rate is per member
            payload["batch"] = {**self.batch, "device": describe_device(self.device)}
        write_json(self.run_dir / "provenance.json", payload)
