"""Human-readable renderings of a replay: a text table and one self-contained HTML file."""

from __future__ import annotations

import base64
import html
import json
import math
import os

from slearn.io.files import write_atomic
from slearn.replay.evaluation import Evaluation
from slearn.replay.metrics import BASELINES


def _pct(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.2f} %"


def _lift(points: float) -> str:
    return "-" if math.isnan(points) else f"{points:+.2f} pts"


def _span(interval: list[float] | None, scale: float = 100.0, signed: bool = False) -> str:
    """``[a, b]`` of a 95 % interval (rates in percent, lifts in points)."""
    if interval is None:
        return "-"
    fmt = "{:+.2f}" if signed else "{:.2f}"
    a, b = (fmt.format(scale * x) for x in interval)
    return f"[{a}, {b}]"


def _abstained(channel: dict) -> float | None:
    """A channel's share of events the library abstained on (``None`` without events)."""
    return channel["abstained"] / channel["events"] if channel["events"] else None


def _summary_rows(e: Evaluation) -> list[tuple[str, str, str, str, str, str]]:
    """``(predictor, accuracy, its 95 % interval, abstained, lift, the lift's interval)`` rows."""
    t, h = e.totals, (e.honest.to_dict() if e.honest is not None else None)
    rows = [("library", _pct(t.accuracy), _span(h and h["accuracy_interval"]),
             _pct(t.rate("abstained")), "", "")]
    for name in BASELINES:
        b = h["baselines"][name] if h else None
        accuracy, abstained = t.rate(name), t.rate(f"{name}_abstained")
        lift = 100 * (t.accuracy - t.rate(name))
        rows.append((f"{name} baseline", _pct(accuracy), _span(b and b["accuracy_interval"]),
                     _pct(abstained), _lift(lift), _span(b and b["lift_interval_points"], 1.0, True)))
    return rows


def format_table(evaluation: Evaluation) -> str:
    """The replay as a plain-text report for a terminal."""
    e, t = evaluation, evaluation.totals
    library = (e.setup.get("library") or {}).get("path") or "(empty library)"
    h = e.honest.to_dict() if e.honest is not None else None
    lines = [f"replay of {library}: {e.mode}, {len(e.episodes)} episode(s), {t.events} predicted steps "
             f"(every channel of a step right: the whole-step accuracy; per channel below), top-{e.top_k}, "
             f"windows of {e.window} steps", ""]
    lines.append(f"  {'predictor':<22} {'accuracy':>10} {'95 % interval':>17} {'abstained':>10} "
                 f"{'lift':>11} {'95 % interval':>17}")
    lines += [f"  {p:<22} {a:>10} {i:>17} {b:>10} {c:>11} {d:>17}" for p, a, i, b, c, d in _summary_rows(e)]
    lines.append(f"  {'library top-' + str(e.top_k):<22} {_pct(t.rate('top_k')):>10} "
                 f"{_span(h and h['top_k_interval']):>17}")
    head = "".join(f" {name:>11}" for name in BASELINES)
    channels = e.channels.to_list()
    wide = max([32, *(len(c["channel"]) for c in channels)])  # (ROS joint channels run long)
    lines += ["", f"  {'channel':<{wide}} {'events':>9} {'library':>10} {'95 % interval':>17} "
                  f"{'abstained':>10}{head}"]
    by_channel = {c["channel"]: c for c in (h["channels"] if h else [])}
    for c in channels:
        extra = by_channel.get(c["channel"], {})
        cells = "".join(f" {_pct(c[f'{name}_accuracy']):>11}" for name in BASELINES)
        lines.append(f"  {c['channel']:<{wide}} {c['events']:>9} {_pct(c['accuracy']):>10} "
                     f"{_span(extra.get('accuracy_interval')):>17} {_pct(_abstained(c)):>10}{cells}")
    logs = [os.path.basename(ep.name) + (" (truncated)" if ep.truncated else "") for ep in e.episodes]
    wide = max([40, *map(len, logs)])
    lines += ["", f"  {'log':<{wide}} {'events':>9} {'library':>10} {'abstained':>10}{head}"]
    for ep, log in zip(e.episodes, logs):
        cells = "".join(f" {_pct(ep.tally.rate(name)):>11}" for name in BASELINES)
        lines.append(f"  {log:<{wide}} {ep.tally.events:>9} "
                     f"{_pct(ep.tally.accuracy):>10} {_pct(ep.tally.rate('abstained')):>10}{cells}")
    if e.confusions:
        lines += ["", "  most frequent confusions (predicted -> actual):"]
        lines += [f"  {n:>9}  {p} -> {a}" for p, a, n in e.confusions]
    lines += [""] + [f"  note: {n}" for n in e.notes]
    lines.append("  intervals: Wilson 95 % for accuracies, Newcombe's paired 95 % for lifts "
                 "(steps of a log are not independent: read them as the least uncertainty)")
    lines.append(f"  {e.predictions:,} predictions, {e.predictions_per_s:,.0f} predictions/s "
                 f"(evaluation core)")
    return "\n".join(lines)


_CSS = """body{font-family:system-ui,sans-serif;max-width:60em;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{padding:0.2em 0.8em;border-bottom:1px solid #ddd;
text-align:right}td:first-child,th:first-child{text-align:left}pre{background:#f5f5f5;padding:0.8em;
overflow-x:auto}img{max-width:100%}.note{color:#555}"""


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def render_html(evaluation: Evaluation, curves_png: bytes | None = None) -> str:
    """One self-contained HTML page: parameters, provenance, scores, curves, confusions.

    Args:
        curves_png: the learning curves as PNG (default: drawn by :mod:`slearn.replay.plots`).
    """
    from slearn.replay.plots import curves_png as draw

    e, t = evaluation, evaluation.totals
    png = curves_png if curves_png is not None else draw(e)
    image = base64.b64encode(png).decode("ascii")
    parts = [f"<h1>slearn replay ({html.escape(e.mode)})</h1>",
             f"<p>{len(e.episodes)} log(s), {t.events} predicted steps (whole-step accuracy), "
             f"top-{e.top_k}, windows of {e.window} steps.</p>",
             "<h2>Accuracy</h2>",
             _table(["predictor", "accuracy", "95 % interval", "abstained", "lift of the library",
                     "95 % interval"],
                    [list(r) for r in _summary_rows(e)]
                    + [[f"library top-{e.top_k}", _pct(t.rate("top_k")), "", "", "", ""]]),
             f'<img alt="learning curves" src="data:image/png;base64,{image}">',
             "<h2>Channels</h2>",
             _table(["channel", "events", "library", "abstained", *BASELINES],
                    [[c["channel"], c["events"], _pct(c["accuracy"]), _pct(_abstained(c)),
                      *(_pct(c[f"{name}_accuracy"]) for name in BASELINES)]
                     for c in e.channels.to_list()]),
             "<h2>Logs</h2>",
             _table(["log", "events", "library", "abstained", *BASELINES, "truncated"],
                    [[ep.name, ep.tally.events, _pct(ep.tally.accuracy),
                      _pct(ep.tally.rate("abstained")),
                      *(_pct(ep.tally.rate(name)) for name in BASELINES),
                      "yes" if ep.truncated else ""]
                     for ep in e.episodes]),
             "<h2>Most frequent confusions</h2>",
             _table(["count", "predicted", "actual"], [[n, p, a] for p, a, n in e.confusions])
             if e.confusions else "<p>none</p>",
             "<h2>Notes</h2>",
             "".join(f'<p class="note">{html.escape(n)}</p>' for n in e.notes + e.warnings),
             "<h2>Parameters and provenance</h2>",
             f"<pre>{html.escape(json.dumps(_setup(e), indent=2, default=str))}</pre>"]
    return (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>slearn replay</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")


def _setup(evaluation: Evaluation) -> dict:
    return {"mode": evaluation.mode, "top_k": evaluation.top_k, "window": evaluation.window,
            "scoring": evaluation.scoring,
            "baselines": {"fit": evaluation.baseline_fit, "max_length": evaluation.baseline_order},
            **evaluation.setup}


def write_html(evaluation: Evaluation, path: str | os.PathLike) -> None:
    """Write :func:`render_html` to ``path``, atomically (an existing file is replaced).

    Raises:
        InputError: the file cannot be written (an existing one is left as it was).
    """
    write_atomic(path, render_html(evaluation), overwrite=True)
