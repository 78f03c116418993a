"""Learning curves of a replay as PNG (matplotlib, Agg backend, no global pyplot state).

One line per log; a single log with several observation channels gets one line per
channel instead. Whenever there are several lines, a thick ``all`` line shows the
accuracy over every event of the window. With a single log, the baselines are drawn
dashed beside the library. Windows are sized to the data
(:func:`slearn.replay.windows.data_window`), so each point averages enough events.
"""

from __future__ import annotations

import io
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from slearn.io.files import write_atomic
from slearn.replay.evaluation import Evaluation

OVERALL = "all"


def curves_png(evaluation: Evaluation, *, width_in: float = 8.0, height_in: float = 4.5) -> bytes:
    """The learning curves as PNG bytes."""
    figure = Figure(figsize=(width_in, height_in), dpi=110)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    for label, x, y, style in _lines(evaluation):
        width = 2.6 if label == OVERALL else 1.4 if style == "-" else 1.0
        axes.plot(x, 100 * y, style, label=label, linewidth=width,
                  color="black" if label == OVERALL else None)
    axes.set_xlabel(f"step (windows of {evaluation.window} steps)")
    axes.set_ylabel("accuracy (%)")
    axes.set_ylim(-2, 102)
    axes.grid(True, alpha=0.3)
    axes.set_title(f"{evaluation.mode} replay: accuracy per window")
    if axes.lines:
        axes.legend(loc="lower right", fontsize="small")
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()


def write_curves(evaluation: Evaluation, path: str | os.PathLike) -> None:
    """Write :func:`curves_png` to ``path``, atomically (an existing file is replaced).

    Raises:
        InputError: the file cannot be written (an existing one is left as it was).
    """
    write_atomic(path, curves_png(evaluation), overwrite=True)


def _lines(evaluation: Evaluation) -> list[tuple[str, np.ndarray, np.ndarray, str]]:
    """``(label, x, accuracy in [0, 1], style)`` per line."""
    lines = []
    episodes = evaluation.episodes
    channels = evaluation.channels.channels
    for episode in episodes:
        curve = episode.curve
        x = curve.start + curve.window / 2
        name = os.path.basename(episode.name)
        if len(episodes) == 1 and len(channels) > 1:
            by_channel = curve.channel_accuracy()
            lines += [(c, x, by_channel[:, i], "-") for i, c in enumerate(channels)]
            lines.append((OVERALL, x, curve.accuracy(), "-"))
        else:
            lines.append((name if len(episodes) > 1 else "library", x, curve.accuracy(), "-"))
        if len(episodes) == 1:
            lines.append(("frequency baseline", x, curve.accuracy("frequency"), "--"))
            lines.append((f"Markov baseline (<= {evaluation.baseline_order} steps)", x,
                          curve.accuracy("markov"), ":"))
            lines.append(("persistence baseline", x, curve.accuracy("persistence"), "-."))
    if len(episodes) > 1:
        lines.append(_overall(episodes))
    return lines


def _overall(episodes) -> tuple[str, np.ndarray, np.ndarray, str]:
    """Accuracy over all logs per window position (logs aligned at their first step)."""
    n = max(len(e.curve.start) for e in episodes)
    events, correct = np.zeros(n), np.zeros(n)
    for e in episodes:
        k = len(e.curve.start)
        events[:k] += e.curve.events
        correct[:k] += e.curve.correct
    longest = max(episodes, key=lambda e: len(e.curve.start)).curve
    with np.errstate(invalid="ignore", divide="ignore"):
        accuracy = correct / np.where(events > 0, events, np.nan)
    return OVERALL, longest.start + longest.window / 2, accuracy, "-"
