"""The demo's Figure 2 as a PNG (matplotlib, no display needed)."""

from __future__ import annotations

import os
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from slearn.io.files import atomic_write  # noqa: E402
from slearn.jobs.demo import DemoResult  # noqa: E402

# The paper's line styles: simple bold solid, hard stop dotted, scramble fine solid,
# reversal fine dashed, random error dashed, random delay dash-dot.
STYLES = {
    "simple": dict(linestyle="-", linewidth=2.6, color="black"),
    "hardstop": dict(linestyle=":", linewidth=2.0, color="tab:gray"),
    "scramble": dict(linestyle="-", linewidth=1.0, color="tab:blue"),
    "reversal": dict(linestyle="--", linewidth=1.0, color="tab:red"),
    "error": dict(linestyle="--", linewidth=1.8, color="tab:green"),
    "delay": dict(linestyle="-.", linewidth=1.8, color="tab:purple"),
}
LABELS = {"simple": "Simple system", "hardstop": "Hard nonlinearity", "scramble": "Sensor scramble",
          "reversal": "Gain reversal", "error": "Random error", "delay": "Random delay"}


def plot_figure2(result: DemoResult, path: str | os.PathLike, *, overwrite: bool = False) -> None:
    """One line per condition (default scoring) plus the ceilings of the stochastic ones.

    Raises:
        InputError: ``path`` exists without ``overwrite``, or cannot be written.
    """
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    for condition in result.conditions:
        curve = condition.accuracy["adaptive"]
        x = range(1, len(curve) + 1)
        style: dict[str, Any] = STYLES.get(condition.condition, {})
        ax.plot(x, curve, label=LABELS.get(condition.condition, condition.condition), **style)
        if condition.condition in ("error", "delay"):
            ax.plot(x, condition.ceiling, color=style.get("color"), linewidth=0.8, alpha=0.6,
                    linestyle=(0, (1, 3)), label=f"{LABELS[condition.condition]}: ceiling")
    ax.set_xlabel("Nth thousand trials")
    ax.set_ylabel("Percent accurate predictions")
    ax.set_ylim(0, 100)
    ax.set_xticks(range(1, len(result.conditions[0].ceiling) + 1))
    ax.set_yticks(range(0, 101, 10))
    ax.grid(alpha=0.3)
    ax.set_title(f"S-learning on the rotary pointer (mean over {len(result.seeds)} seeds)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    try:
        with atomic_write(path, overwrite=overwrite) as out:
            fig.savefig(out.file, format="png")
    finally:
        plt.close(fig)
