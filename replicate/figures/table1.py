"""Table 1: environment dimensions, the paper's beside the harness's, and the demonstrations."""

from __future__ import annotations

from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from envs import ENV_SPECS, make_env
from replicate.claims.published import EXPERT_TARGETS
from replicate.demos import default_demo_path, load_demos
from replicate.errors import DemoError, HarnessError
from replicate.reports.templating import report_environment


def table1_rows() -> list[dict[str, Any]]:
    """One row per env of the spec table, its dims checked against the live env."""
    rows = []
    for spec in ENV_SPECS.values():
        env = make_env(spec.env_id)
        live = (env.observation_space.shape[0], env.action_space.shape[0])
        env.close()
        if live != (spec.obs_dim, spec.act_dim):
            raise HarnessError(
                f"{spec.env_id}: the env table (envs/__init__.py, ENV_SPECS) says "
                f"{spec.obs_dim} observation and {spec.act_dim} action dims, but the env has "
                f"{live[0]} and {live[1]}",
                f"set its row to obs_dim={live[0]}, act_dim={live[1]}",
            )
        row = asdict(spec)
        differs = spec.paper_obs_dim is not None and spec.paper_obs_dim != spec.obs_dim
        row["note"] = (
            "-v5 drops the always-zero contact forces of -v2"
            if differs
            else "not in the paper"
            if spec.paper_env_id is None
            else ""
        )
        path = default_demo_path(spec.env_id)
        row["demo"], row["demo_missing"], row["target"] = None, None, None
        if path.is_file():
            try:
                meta = load_demos(path, spec.env_id).metadata
                row["demo"] = dict(meta, file=path.name)
                target = EXPERT_TARGETS.get(spec.env_id)
                row["target"] = (
                    None
                    if target is None
                    else {
                        "value": target,
                        "met": meta["expert_return_mean"] >= target,
                        "short_by": max(0.0, 1 - meta["expert_return_mean"] / target),
                    }
                )
            except DemoError as exc:
                row["demo_missing"] = f"committed file refused: {exc}"
        else:
            row["demo_missing"] = (
                "no demonstrations yet: `nox -s experts -- --env "
                f"{spec.env_id}`, then `nox -s demos`"
            )
        rows.append(row)
    return rows


def write_table1_report(out_dir: Path) -> Path:
    """Write ``out_dir/index.html`` (self-contained)."""
    environment = report_environment()
    html = environment.get_template("table1.html").render(
        title="Table 1 replication: environments and demonstrations",
        rows=table1_rows(),
        generated=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    from replicate.reports.pages import _atomic_write

    out = Path(out_dir) / "index.html"
    _atomic_write(out, html.encode())
    return out
