"""``slearn demo``: the paper's Figure 2, reproduced from MCAP logs in a few seconds.

For each of the six pointer conditions: record an episode to MCAP, read it back through
the same path ``slearn learn`` uses, run prequential predict-then-learn from an empty
library with the default (``adaptive``) and the paper's ``literal`` scoring, and compare
with the ceiling of an optimal predictor that knows the dynamics. Accuracy is per
thousand trials, abstentions counted as wrong, averaged over ``seeds`` seeds; the logs and
libraries written are those of the first seed. Scramble and reversal switch halfway.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, cast

import numpy as np

from slearn import __version__
from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.io.serialize import read_episodes
from slearn.io.spec import pointer_spec
from slearn.recorders.pointer import CONDITIONS, PointerConfig, pointer_vocabulary, simulate
from slearn.recorders.pointer_oracle import oracle_correct
from slearn.recorders.record_pointer import write_pointer_mcap

RULES = ("adaptive", "literal")
WINDOW = 1000

PAPER = {
    "simple": "100 % after 2000 trials",
    "hardstop": "like simple",
    "scramble": "learning transient repeated after trial 5000",
    "reversal": "marked drop at 5000, recovered within 4000 trials",
    "error": "slightly above 50 %, rising to near 70 %",
    "delay": "slightly above 25 %, just over 45 % at 10,000",
}
"""What the paper's section IV says of each curve of its Figure 2."""


@dataclass
class ConditionResult:
    """One condition's curves (percent per window of 1000 trials, mean over seeds)."""

    condition: str
    accuracy: dict[str, list[float]]
    per_seed: dict[str, list[list[float]]]
    ceiling: list[float]
    abstained: list[float]
    patterns: int
    library_bytes: int
    literal_patterns: int = 0
    log_path: str = ""
    library_path: str = ""
    library_file_bytes: int = 0
    seconds: float = 0.0


@dataclass
class DemoResult:
    """Everything ``slearn demo`` reports."""

    out_dir: str
    seeds: list[int]
    trials: int
    conditions: list[ConditionResult] = field(default_factory=list)
    figure_path: str = ""
    summary_path: str = ""
    seconds: float = 0.0

    def to_dict(self) -> dict:
        """A JSON-ready summary."""
        return {
            "slearn_version": __version__, "out_dir": self.out_dir, "seeds": self.seeds,
            "trials": self.trials, "window": WINDOW, "figure": self.figure_path,
            "seconds": round(self.seconds, 3),
            "conditions": {c.condition: _condition_dict(c) for c in self.conditions},
        }


def _condition_dict(result: ConditionResult) -> dict:
    return {
        "accuracy_percent": result.accuracy, "accuracy_percent_per_seed": result.per_seed,
        "ceiling_percent": result.ceiling, "abstained_percent": result.abstained,
        "paper": PAPER[result.condition], "patterns": result.patterns,
        "literal_patterns": result.literal_patterns,
        "library_bytes_in_memory": result.library_bytes, "library_file": result.library_path,
        "library_file_bytes": result.library_file_bytes, "log": result.log_path,
        "seconds": round(result.seconds, 3),
    }


def windowed_percent(hits: np.ndarray, window: int = WINDOW) -> list[float]:
    """Percent of hits per consecutive window (the last one may be shorter)."""
    return [round(100.0 * float(hits[i:i + window].mean()), 2) for i in range(0, len(hits), window)]


def run_condition(condition: str, seeds: list[int], trials: int, out_dir: Path,
                  save: Callable | None) -> ConditionResult:
    """Record, replay and evaluate one condition over several seeds."""
    started = time.perf_counter()
    curves: dict[str, list[list[float]]] = {rule: [] for rule in RULES}
    ceiling, abstained = [], []
    first: tuple | None = None  # the first seed's adaptive library, vocabulary and log
    literal_patterns: int | None = None
    for seed in seeds:
        run = simulate(PointerConfig(condition, trials=trials, seed=seed, switch_trial=trials // 2))
        if first is None:
            log_path = out_dir / "logs" / f"{condition}.mcap"
            write_pointer_mcap(run, log_path)
            vocabulary = Vocabulary()
            (_, episode, _), = read_episodes([log_path], pointer_spec(), vocabulary)
        else:
            episode, vocabulary = run.to_episode(), pointer_vocabulary()
        for rule in RULES:
            library, correct, abstain = predict_then_learn(rule, episode, vocabulary)
            curves[rule].append(windowed_percent(correct))
            if rule == RULES[0]:
                abstained.append(windowed_percent(abstain))
                if first is None:
                    first = (library, vocabulary, log_path)
            elif literal_patterns is None:
                literal_patterns = len(library)
        ceiling.append(windowed_percent(oracle_correct(run)))
    library, vocabulary, log_path = cast(tuple, first)  # seeds is never empty
    out = ConditionResult(condition, {r: _mean(c) for r, c in curves.items()}, curves, _mean(ceiling),
                          _mean(abstained), len(library), library.nbytes(), literal_patterns or 0,
                          str(log_path))
    if save is not None:
        out.library_path = str(out_dir / "libraries" / f"{condition}.parquet")
        out.library_file_bytes = save(out.library_path, library, vocabulary, log_path, seeds[0])
    out.seconds = time.perf_counter() - started
    return out


def predict_then_learn(rule: str, episode, vocabulary: Vocabulary):
    """``(library, correct, abstained)``: each trial predicted from an empty library of
    ``rule`` (``adaptive`` or ``literal``), then learned; per trial after the first reading."""
    library = PatternLibrary(vocabulary=vocabulary) if rule == "adaptive" else LiteralLibrary()
    codes = library.encode(episode)
    reports = library.run(codes, learn=True, record=True)
    trials = reports.context
    return library, (reports.predicted == codes.token)[trials], (reports.predicted < 0)[trials]


def _mean(curves: list[list[float]]) -> list[float]:
    return [round(float(x), 2) for x in np.mean(np.asarray(curves, dtype=float), axis=0)]


def save_library_file(path: str, library: PatternLibrary | LiteralLibrary,
                      vocabulary: Vocabulary, log: Path, seed: int) -> int:
    """Store a demo library like ``slearn learn`` would; return the file's size in bytes."""
    from slearn.io.library_file import save_library
    from slearn.jobs.learn import build_provenance

    provenance = build_provenance([str(log)])
    provenance["demo_seed"] = seed
    summary = save_library(path, library, vocabulary, spec=pointer_spec(),
                           params={"scoring": RULES[0]}, provenance=provenance)
    return summary.size_bytes


def run_demo(out_dir: str | Path, seeds: list[int], trials: int = 10_000,
             conditions: tuple[str, ...] = CONDITIONS, save: Callable | None = save_library_file,
             on_condition: Callable[[ConditionResult], None] | None = None) -> DemoResult:
    """Run every condition; ``save(path, library, vocabulary, log, seed) -> bytes`` stores libraries."""
    started = time.perf_counter()
    out_dir = Path(out_dir)
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    if save is not None:
        (out_dir / "libraries").mkdir(exist_ok=True)
    result = DemoResult(str(out_dir), list(seeds), trials)
    for condition in conditions:
        result.conditions.append(run_condition(condition, list(seeds), trials, out_dir, save))
        if on_condition is not None:
            on_condition(result.conditions[-1])
    result.seconds = time.perf_counter() - started
    return result
