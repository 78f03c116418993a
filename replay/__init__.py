"""Replay: evaluate pattern libraries on held-out logs, next to baselines (``slearn replay``)."""

from slearn.replay.baselines import Baselines
from slearn.replay.evaluation import Checkpoint, Evaluation, evaluate, iter_evaluation
from slearn.replay.replay_logs import replay_logs

__all__ = ["Baselines", "Checkpoint", "Evaluation", "evaluate", "iter_evaluation", "replay_logs"]
