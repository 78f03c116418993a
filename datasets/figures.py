"""Expected replay figures for the dataset cards, computed when a dataset is built.

Each figure is what ``slearn learn`` on the dataset's ``train/`` episodes followed by a
frozen ``slearn replay`` of its ``heldout/`` episodes prints, with the same slearn
version: the simulated datasets are learned from the very episodes written to disk (the
recorded MCAP files read back to the same steps), a log given with ``--source`` through
``learn_files`` and ``replay_logs`` themselves. Next to the library: the frequency and
persistence baselines, a Wilson 95 % interval, and for the pointer the Bayes ceiling of
the held-out episode (:mod:`slearn.recorders.pointer_oracle`).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

from slearn.core.library import PatternLibrary
from slearn.recorders.arm import ArmConfig, arm_vocabulary, simulate_arm
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate
from slearn.recorders.pointer_oracle import oracle_correct
from slearn.replay.baselines import Baselines
from slearn.replay.evaluation import Evaluation, evaluate
from slearn.replay.intervals import wilson

HEADER = ("| {what} | events | library (frozen) | 95 % interval | frequency | persistence | {last} |\n"
          "|---|---|---|---|---|---|---|")


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _row(what: str, result: Evaluation, last: str) -> str:
    t, honest = result.totals, result.honest.to_dict()
    lo, hi = wilson(t.correct, t.events)
    return (f"| {what} | {t.events:,} | {_pct(t.accuracy)} | {100 * lo:.1f}-{100 * hi:.1f} % | "
            f"{_pct(t.rate('frequency'))} | {_pct(honest['baselines']['persistence']['accuracy'])} "
            f"| {last} |")


def _frozen(train: list, heldout, vocabulary) -> tuple[Evaluation, int]:
    """The frozen replay, baselines counted on the training episodes as ``slearn replay``
    does; and the library's size."""
    library = PatternLibrary(vocabulary=vocabulary)
    baselines = Baselines(library)
    for episode in train:
        codes = library.encode(episode)
        library.run(codes, learn=True, record=False)
        baselines.learn(codes)
    result = evaluate(library, [("heldout", heldout, None)], vocabulary, baselines=baselines)
    return result, len(library)


def pointer_figures(conditions: tuple[str, ...], train_seeds: tuple[int, ...], heldout_seed: int,
                    trials: int) -> str:
    """A Markdown table: per condition, the frozen replay of the held-out episode."""
    rows = [HEADER.format(what="condition", last="Bayes ceiling")]
    for condition in conditions:
        train = [simulate(PointerConfig(condition, trials, s)).to_episode() for s in train_seeds]
        run = simulate(PointerConfig(condition, trials, heldout_seed))
        result, _ = _frozen(train, run.to_episode(), pointer_vocabulary())
        ceiling = float(oracle_correct(run).mean())
        rows.append(_row(condition, result, _pct(ceiling)))
    return "\n".join(rows)


def arm_figures(max_joints: int, train_seeds: tuple[int, ...], heldout_seed: int, trials: int) -> str:
    """A Markdown table: per joint count, the frozen replay of the held-out episode."""
    rows = [HEADER.format(what="joints", last="patterns")]
    for joints in range(1, max_joints + 1):
        train = [simulate_arm(ArmConfig(joints, trials, s, "moved")).to_episode() for s in train_seeds]
        heldout = simulate_arm(ArmConfig(joints, trials, heldout_seed, "moved")).to_episode()
        result, patterns = _frozen(train, heldout, arm_vocabulary(joints))
        rows.append(_row(str(joints), result, f"{patterns:,}"))
    return "\n".join(rows)


def log_figures(train: str | os.PathLike, heldout: str | os.PathLike, spec: str | os.PathLike) -> str:
    """A Markdown table and notes: ``slearn learn`` on ``train``, frozen replay of ``heldout``."""
    from slearn.io.spec import load_spec
    from slearn.jobs.learn import learn_files
    from slearn.replay.replay_logs import replay_logs

    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the warnings that matter are in the result
        library = Path(folder) / "library.parquet"
        learn_files([train], library, spec=load_spec(spec))
        result = replay_logs([heldout], library=library, baseline_logs=[train])
    lines = [HEADER.format(what="log", last="patterns"),
             _row(f"`{Path(heldout).name}`", result, f"{result.setup['library']['patterns']:,}")]
    lines += [""] + [f"- {w}" for w in result.warnings if "only" in w or "outside" in w]
    return "\n".join(lines)
