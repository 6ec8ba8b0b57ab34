"""How reports speak of budgets and seeds, and the words the front door gives each built-in
report (what it covers, its budget, its seeds), read from the report's summary."""

from __future__ import annotations

from typing import Any


def steps_words(n: int) -> str:
    """50k, 1M: how budgets are spoken of."""
    if n >= 1_000_000 and n % 1_000_000 == 0:
        return f"{n // 1_000_000}M"
    return f"{n / 1000:g}k" if n >= 1000 else str(n)


def budget_words(steps: list[int]) -> str:
    """The range of budgets, e.g. '20k to 200k', or one budget alone; '' for none."""
    if not steps:
        return ""
    return " to ".join(dict.fromkeys(steps_words(s) for s in (min(steps), max(steps))))


def seed_words(counts: list[int]) -> str:
    if not counts:
        return ""
    low, high = min(counts), max(counts)
    return f"{low} seeds" if low == high else f"{low}-{high} seeds"


def describe_fig3(summary: dict[str, Any]) -> dict[str, str]:
    envs = {f["env_id"] for f in summary["final_returns"]}
    return {
        "covers": f"Fig. 3: learning curves on {len(envs)} env(s), claims 1-4"
        if envs
        else "Fig. 3: no runs yet",
        "budget": ", ".join(
            f"{env.split('-v')[0].split('Continuous')[0]} {steps_words(steps)}"
            for env, steps in summary.get("budgets", {}).items()
        ),
        "seeds": seed_words([len(f["seeds"]) for f in summary["final_returns"]]),
    }


def describe_fig4(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": f"Fig. 4: SAC and DRL-EG on {summary['env_id']} from shared seeds, claim 5",
        "budget": steps_words(summary["steps"]) if summary.get("steps") else "",
        "seeds": f"{len(summary['rows'])} pairs",
    }


def describe_rlfd(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": "DRL-EG against IBRL, RLPD, JSRL, SAC and DDPGfD on shared demonstrations",
        "budget": budget_words([steps for steps, _ in summary.get("budgets", {}).values()]),
        "seeds": seed_words([c["n"] for c in summary["cells"]]),
    }


def describe_ablation(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": f"DRL-EG's threshold T2 swept on {summary['env_id']}",
        "budget": steps_words(summary["steps"]) if summary.get("steps") else "",
        "seeds": seed_words([len(r["runs"]) for r in summary["rows"]]),
    }
