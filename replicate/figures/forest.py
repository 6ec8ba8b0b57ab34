"""A claim's checks at a glance: a forest plot, one row per check, grouped by part. Each row
has its own scale (a return, a difference of returns, an instability): the estimate and its
interval, the threshold (a line) or the band (shaded) it is judged against, and, around a
threshold, the smallest effect of interest (hatched); coloured by the check's state."""

from __future__ import annotations

import textwrap
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from replicate.figures.plots import FIGURE_WIDTH_IN, png_bytes, set_theme

STATE_COLORS = {
    "holds": "#009e73",  # bluish green
    "fails": "#d55e00",  # vermillion
    "equivalent": "#d55e00",  # a claimed difference found negligible contradicts the claim
    "inconclusive": "#555555",
}
FADED = "#aaaaaa"  # not testable, or no runs
ROW_HEIGHT_IN = 0.46
PART_GAP_IN = 0.34


def _color(check: dict[str, Any]) -> str:
    if check["verdict"] == "equivalent" and check.get("band"):
        return STATE_COLORS["holds"]
    return STATE_COLORS.get(check["verdict"], FADED)


def _limits(check: dict[str, Any]) -> tuple[float, float]:
    """The row's x range: the estimate, its interval, the threshold or band, the smallest
    effect, with a margin."""
    values = [check["estimate"], check["low"], check["high"]]
    if check.get("threshold") is not None:
        values.append(check["threshold"])
        if check.get("smallest_effect"):
            values += [
                check["threshold"] - check["smallest_effect"],
                check["threshold"] + check["smallest_effect"],
            ]
    if check.get("band"):
        values += list(check["band"])
    finite = [v for v in values if v is not None and np.isfinite(v)]
    if not finite:
        return -1.0, 1.0
    low, high = min(finite), max(finite)
    pad = 0.08 * (high - low) if high > low else max(abs(low), 1.0) * 0.1
    return low - pad, high + pad


def _state_label(
    fig: plt.Figure, at: tuple[float, float], check: dict[str, Any], color: str
) -> None:
    """A row's state, right-aligned before its plot."""
    words = _state_words(check["verdict"])
    fig.text(*at, words, fontsize=9, color=color, va="center", ha="right")


def _state_words(state: str) -> str:
    return "not testable" if state.startswith("not testable") else state


def _short(what: str) -> str:
    """A check's words for its row: the env's short name, and no more than fits."""
    env, _, rest = what.partition(": ")
    if rest:
        what = env.removeprefix("dm_control/").rsplit("-v", 1)[0].replace("Continuous", "")
        what += ": " + rest
    return what if len(what) <= 60 else what[:57] + "..."


def forest_png(claim: dict[str, Any]) -> bytes | None:
    """The claim's forest plot as PNG bytes; None for a claim with no judged check."""
    parts = [p for p in claim.get("parts", []) if p.get("checks")]
    rows = [(p, c) for p in parts for c in p["checks"]]
    if not rows:
        return None
    set_theme()
    height = ROW_HEIGHT_IN * len(rows) + PART_GAP_IN * len(parts) + 0.5
    fig = plt.figure(figsize=(FIGURE_WIDTH_IN, height))
    label_share, top = 0.52, 1 - 0.15 / height
    y = top
    row_h, gap = ROW_HEIGHT_IN / height, PART_GAP_IN / height
    for part in parts:
        y -= gap
        state = part.get("state") or ""
        fig.text(
            0.01,
            y + gap * 0.3,
            f"{part['id']}  {part['statement']}  [{state}]",
            fontsize=10.5,
            fontweight="bold",
            color=STATE_COLORS["fails"] if state == "contradicted" else "0.15",
        )
        for check in part["checks"]:
            y -= row_h
            ax = fig.add_axes((label_share, y + row_h * 0.18, 0.98 - label_share, row_h * 0.64))
            fig.text(0.02, y + row_h * 0.45, _short(check["what"]), fontsize=8.5, va="center")
            state_at = (label_share - 0.012, y + row_h * 0.45)

            if check["estimate"] is None or not np.isfinite(check["estimate"]):
                ax.axis("off")  # nothing measured: say why in the row
                why = textwrap.fill(check.get("decide_short") or "", 90)
                ax.text(0, 0.5, why, fontsize=7.5, va="center", transform=ax.transAxes)
                _state_label(fig, state_at, check, FADED)
                continue
            low, high = _limits(check)
            ax.set_xlim(low, high)
            ax.set_ylim(-1, 1)
            ax.set_yticks([])
            ax.tick_params(axis="x", labelsize=8, pad=1, length=2)
            ax.grid(False)
            if check.get("band"):
                ax.axvspan(*check["band"], color=STATE_COLORS["holds"], alpha=0.12, lw=0)
            if check.get("threshold") is not None:
                threshold = check["threshold"]
                effect = check.get("smallest_effect")
                if effect:
                    ax.axvspan(
                        threshold - effect, threshold + effect, color="0.85", hatch="///", lw=0
                    )
                ax.axvline(threshold, color="0.2", lw=1.2)
            color = _color(check)
            estimate = check["estimate"]
            if check.get("low") is not None and np.isfinite(check["low"]):
                ax.plot([check["low"], check["high"]], [0, 0], color=color, lw=2.4)
            if estimate is not None and np.isfinite(estimate):
                ax.plot([estimate], [0], "o", color=color, ms=6.5)
            _state_label(fig, state_at, check, color)
    return png_bytes(fig)


def forest_images(claims: list[dict[str, Any]]) -> dict[int, str]:
    """Each judged claim's forest plot, base64 PNG by claim id (for a report's page)."""
    import base64

    images = {}
    for claim in claims:
        png = forest_png(claim)
        if png:
            images[claim["id"]] = base64.b64encode(png).decode()
    return images
