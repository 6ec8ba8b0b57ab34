"""How well does DRL-EG's functional guider G(s) control an env on its own? It acts on every
step (what a T2 wide enough to admit every state does while the gate is open): the nearest
demonstration state's action plus N(0, sigma^2), clipped, as in ``baselines.drl_eg``.

    python benchmarks/guider_alone.py OUT.json [--envs Ant-v5 Walker2d-v5] [--episodes 3]

Writes, per env, each episode's return and length and the median distance from the visited
states to their nearest demonstration state, beside the demonstrations' mean return.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from baselines.drl_eg import demo_state_spacing, functional_guider  # noqa: E402
from envs import make_env  # noqa: E402
from replicate.demos import default_demo_path, load_demos  # noqa: E402


def guider_episodes(env_id: str, episodes: int, noise_std: float) -> dict:
    demos = load_demos(default_demo_path(env_id), env_id)
    states = np.asarray(demos.observations, dtype=np.float64)
    actions = np.asarray(demos.actions, dtype=np.float64)
    tree = cKDTree(states)
    env = make_env(env_id)  # the adapter training uses (float32 observations)
    low, high = env.action_space.low, env.action_space.high
    rng = np.random.default_rng(0)
    rows = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        total, distances, done = 0.0, [], False
        while not done:
            distance, index = tree.query(obs)
            distances.append(distance)
            action = functional_guider(actions, int(index), noise_std, rng, low, high)
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        rows.append(
            {
                "return": total,
                "length": len(distances),
                "median_distance": float(np.median(distances)),
            }
        )
    env.close()
    return {
        "env_id": env_id,
        "demo_return": float(demos.mean_return),
        "noise_std": noise_std,
        "spacing": demo_state_spacing(states),
        "episodes": rows,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--envs", nargs="+", default=["Ant-v5", "Walker2d-v5"])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--noise-std", type=float, default=0.1)
    args = parser.parse_args()
    results = [guider_episodes(env_id, args.episodes, args.noise_std) for env_id in args.envs]
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    for r in results:
        print(
            r["env_id"],
            "demonstrations",
            round(r["demo_return"]),
            "guider alone",
            [(round(e["return"]), e["length"]) for e in r["episodes"]],
        )


if __name__ == "__main__":
    main()
