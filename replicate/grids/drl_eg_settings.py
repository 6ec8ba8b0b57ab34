"""DRL-EG's settings where the paper is silent: T2 and sigma per env, the MuJoCo T2 rule that
the threshold ablation fixed, and where each run's T2 comes from (what reports print beside
the claims)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from replicate.errors import HarnessError
from replicate.store.runs import Run
from replicate.store.spec import RunSpec

# Per-env values of what the paper leaves open (T2 in raw state units, sigma in action units).
# An env not listed takes T2 from its demonstrations (drl_eg_env_defaults).
DRL_EG_ENV_DEFAULTS: dict[str, dict[str, float]] = {
    "MountainCarContinuous-v0": {"guide_threshold": 0.05, "guide_noise_std": 0.1},
}
DEFAULT_GUIDE_NOISE_STD = 0.1


ALWAYS_GUIDE = 1e6  # a T2 no distance reaches: every state is guided while the gate is open

# The MuJoCo default T2 is fixed from the threshold ablation on Ant and Walker2d at
# the reduced budget, by the criterion written before its runs (``ablation.T2_RULE_CRITERION``),
# before any Fig. 3 or Fig. 4 DRL-EG run at that budget trains, and not changed after them.
# The rule is one of T2_RULE_SETTINGS, as choose_t2_rule names it: a multiple of each env's
# demonstration-state spacing ("16x"), or "always". Until it is set (None) those runs wait;
# quick keeps the spacing rule (1x).
SPACING_MULTIPLES = (1, 4, 16, 64)
T2_RULE_SETTINGS = tuple(f"{m}x" for m in SPACING_MULTIPLES) + ("always",)
MUJOCO_T2_RULE: str | None = "1x"  # the committed ablation's choice (docs/decisions.md)
MUJOCO_ENVS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
RULED_PROFILES = ("reduced", "paper")  # the budgets at which the ablation's rule applies
GUIDED_ALGORITHMS = ("drl-eg", "drl-eg-gmm", "drl-eg-twin-q")  # the variants with a guider
T2_ALGORITHMS = ("drl-eg", "drl-eg-twin-q")  # the GMM variant's threshold is a quantile


def env_settings(algo: str, env_id: str, profile: str) -> dict[str, Any]:
    """What the harness sets per env where the paper is silent, for a grid's run of ``algo``:
    a DRL-EG variant's T2 and sigma; nothing for the other algorithms."""
    return drl_eg_env_defaults(env_id, profile, algo) if algo in GUIDED_ALGORITHMS else {}


def drl_eg_env_defaults(
    env_id: str, profile: str | None = None, algo: str = "drl-eg"
) -> dict[str, float]:
    """DRL-EG's T2 and sigma for ``env_id``: the table's, else T2 = the median spacing of the
    env's committed demonstration states (``baselines.drl_eg.demo_state_spacing``), written
    into the spec as a number so the run records the value it used. At the reduced and paper
    budgets a MuJoCo env takes ``MUJOCO_T2_RULE`` times that spacing (or always-guide) once
    the rule is set (not the GMM variant: its T2 is unused, and its runs need not wait);
    ``profile=None`` gives the spacing itself (the ablation's unit)."""
    if env_id in DRL_EG_ENV_DEFAULTS:
        return dict(DRL_EG_ENV_DEFAULTS[env_id])
    from baselines.drl_eg import demo_state_spacing
    from replicate.demos import default_demo_path, load_demos

    demos = load_demos(default_demo_path(env_id), env_id)
    spacing = float(f"{demo_state_spacing(demos.observations.astype(np.float64)):.4g}")
    threshold = spacing
    if MUJOCO_T2_RULE is not None and takes_t2_rule(profile, env_id, algo):
        if MUJOCO_T2_RULE not in T2_RULE_SETTINGS:
            raise HarnessError(
                f"MUJOCO_T2_RULE = {MUJOCO_T2_RULE!r} is not a setting of the ablation",
                f"set one of {', '.join(T2_RULE_SETTINGS)}",
            )
        # the ablation's own arithmetic (an int times the spacing): a ruled run is its run
        threshold = (
            ALWAYS_GUIDE if MUJOCO_T2_RULE == "always" else int(MUJOCO_T2_RULE[:-1]) * spacing
        )
    return {"guide_threshold": threshold, "guide_noise_std": DEFAULT_GUIDE_NOISE_STD}


def takes_t2_rule(profile: str | None, env_id: str, algo: str) -> bool:
    """Whether a run's T2 comes from the MuJoCo rule: DRL-EG (V-SAC or twin-Q) on MuJoCo at
    the reduced or paper budget."""
    return profile in RULED_PROFILES and env_id in MUJOCO_ENVS and algo in T2_ALGORITHMS


def waits_for_t2_rule(profile: str, env_id: str, algo: str) -> bool:
    """True for a DRL-EG run on MuJoCo at the reduced or paper budget while the MuJoCo T2
    rule is not fixed."""
    return MUJOCO_T2_RULE is None and takes_t2_rule(profile, env_id, algo)


def t2_source(profile: str, env_id: str, algo: str) -> str:
    """Where a DRL-EG run's T2 at ``profile`` on ``env_id`` comes from, in one sentence."""
    if algo not in T2_ALGORITHMS:
        return "unused: the GMM variant gates on a density quantile of the demonstrations"
    if env_id in DRL_EG_ENV_DEFAULTS:
        return (
            "the harness's value for this env (the paper gives none; the MountainCar "
            "threshold ablation, reports/ablate-threshold, sweeps it)"
        )
    spacing = "the median spacing of the demonstration states"
    if not takes_t2_rule(profile, env_id, algo):
        return f"{spacing} (the spacing rule, 1x)"
    if MUJOCO_T2_RULE is None:
        return "none yet: " + T2_WAIT_REASON
    rule = (
        "always-guide" if MUJOCO_T2_RULE == "always" else f"{MUJOCO_T2_RULE[:-1]} times {spacing}"
    )
    return (
        f"the MuJoCo rule {MUJOCO_T2_RULE} ({rule}), chosen by the threshold ablation on "
        "Ant-v5 and Walker2d-v5 before any Fig. 3 or Fig. 4 MuJoCo run of DRL-EG "
        "(reports/reduced/ablate-threshold-ant, -walker2d)"
    )


def guidance_settings(
    profile: str, runs: list[Run], specs: Sequence[RunSpec] = ()
) -> list[dict[str, Any]]:
    """Per env and DRL-EG variant among ``runs`` (and the grid's ``specs``, for cells not
    trained yet): the T2 and sigma values its runs recorded in their specs, and where T2
    comes from (``t2_source``), the share of training steps the guider took in each run,
    and whether that share is 0 in every run. What a report prints beside the claims it
    judges."""
    cells = [(s.env_id, s.algo) for s in specs] + [(r.spec["env_id"], r.spec["algo"]) for r in runs]
    used: dict[tuple[str, str], list[Run]] = {
        cell: [] for cell in cells if cell[1] in GUIDED_ALGORITHMS
    }
    for run in sorted(runs, key=lambda r: r.spec["seed"]):
        key = (run.spec["env_id"], run.spec["algo"])
        if key in used:
            used[key].append(run)
    rows = []
    for (env_id, algo), cell_runs in used.items():
        values = [
            (
                r.spec["hyperparameters"].get("guide_threshold"),
                r.spec["hyperparameters"].get("guide_noise_std"),
            )
            for r in cell_runs
        ]
        uses_t2 = algo in T2_ALGORITHMS
        t2 = sorted({t for t, _ in values if t is not None}) if uses_t2 else []
        shares = [r.guided_share for r in cell_runs]
        rows.append(
            {
                "env_id": env_id,
                "algo": algo,
                "uses_t2": uses_t2,
                "runs": len(values),
                "guided_share": shares,
                # then the guider never chose an action: the runs trained as SAC does
                "never_guided": bool(shares) and all(share == 0 for share in shares),
                "t2": t2,
                "t2_labels": ["always" if t >= ALWAYS_GUIDE else f"{t:g}" for t in t2],
                "sigma": sorted({n for _, n in values if n is not None}),
                "source": t2_source(profile, env_id, algo),
            }
        )
    return rows


T2_WAIT_REASON = (
    "waits for the MuJoCo T2 rule, fixed from `nox -s ablate-threshold -- "
    "--profile reduced --env Ant-v5` (and Walker2d-v5) before these runs train"
)
