"""Annotated logs: a replayed log copied with the library's predictions beside it.

The output is a faithful MCAP copy of the source log (:mod:`slearn.recorders.mcap_copy`:
its profile, channels, raw messages, schemas, encodings, sequence numbers and times, its
metadata records and attachments) plus three JSON channels with jsonschema schemas, one
message each per predicted observation event, at the log time of the observation it
predicted (so in Foxglove the prediction lines up with what happened):

* ``/slearn/prediction`` (``slearn.replay.Prediction``): ``step``, ``episode``,
  ``predicted`` and ``actual`` as ``channel=value`` labels (bins as value ranges),
  ``correct``, ``abstained``, ``score``, ``matched_length`` (history tokens matched) and
  the ranked guesses ``top``;
* ``/slearn/correct`` (``slearn.replay.Correct``): ``correct`` and ``value`` (1 or 0), to plot;
* ``/slearn/surprise`` (``slearn.replay.Surprise``): ``bits``, ``-log2`` of the
  probability the library gave what happened (see
  :meth:`slearn.replay.evaluation.EpisodeOutcome.surprise_bits`), and that ``probability``.

A metadata record ``slearn.replay`` names the library, the mode, the accuracy and the
source's header library. A log with several episodes gets one annotated copy holding all
of them. Beside each copy, ``NAME.layout.json`` is a Foxglove layout (import it in
Foxglove: Layouts, Import from file) showing the predicted against the actual value and
the surprise and correctness over time. Files are written atomically.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slearn.errors import InputError, SlearnError
from slearn.io.bags import open_log
from slearn.io.episodes import split_episode_name
from slearn.io.files import write_atomic
from slearn.io.serialize import iter_step_times
from slearn.io.slicing import slice_from_dict
from slearn.recorders.mcap_copy import CopyWriter
from slearn.replay.evaluation import EpisodeOutcome, Evaluation
from slearn.replay.metrics import ChannelDecoder

PREDICTION_TOPIC = "/slearn/prediction"
CORRECT_TOPIC = "/slearn/correct"
SURPRISE_TOPIC = "/slearn/surprise"

PREDICTION_SCHEMA = {
    "title": "slearn.replay.Prediction",
    "description": "What the pattern library predicted for one observation event, and what happened.",
    "type": "object",
    "properties": {
        "step": {"type": "integer", "description": "step of the episode"},
        "episode": {"type": "string", "description": "the episode (LOG, or LOG#k in a log of several)"},
        "predicted": {"type": "string", "description": "channel=value, or (abstained)"},
        "actual": {"type": "string", "description": "channel=value"},
        "correct": {"type": "boolean"},
        "abstained": {"type": "boolean"},
        "score": {"type": "number", "description": "share of the chosen context's weight"},
        "matched_length": {"type": "integer",
                           "description": "history tokens matched (1 = the current observation), -1 abstained"},
        "top": {"type": "array", "items": {"type": "string"}, "description": "ranked guesses"},
    },
    "required": ["step", "predicted", "actual", "correct", "abstained"],
}
CORRECT_SCHEMA = {
    "title": "slearn.replay.Correct",
    "description": "Whether the library predicted this observation event right.",
    "type": "object",
    "properties": {"correct": {"type": "boolean"}, "value": {"type": "integer", "enum": [0, 1]}},
    "required": ["correct", "value"],
}
SURPRISE_SCHEMA = {
    "title": "slearn.replay.Surprise",
    "description": "-log2 of the probability the library gave what happened (floored).",
    "type": "object",
    "properties": {"bits": {"type": "number"}, "probability": {"type": "number"}},
    "required": ["bits", "probability"],
}


@dataclass(frozen=True)
class AnnotateSummary:
    """One annotated file: where, from what, and how many messages of each kind."""

    path: str
    source: str
    copied: int
    predictions: int

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"path": self.path, "source": self.source, "copied": self.copied,
                "predictions": self.predictions}


def annotated_paths(logs: list[str], out: str | os.PathLike) -> list[Path]:
    """Output file per log: ``out`` itself for one log, else ``out/<log>.annotated.mcap``.

    Logs of the same name get ``-2``, ``-3``, ... Call it before replaying to fail early
    (with :func:`layout_path` of each, the files it will write).

    Raises:
        InputError: several logs and ``out`` is not an existing folder.
    """
    out = Path(out)
    if len(logs) == 1 and not out.is_dir():
        return [out]
    if not out.is_dir():
        raise InputError(f"--write-mcap {out}: {len(logs)} logs are replayed: give an existing "
                         "folder to write one annotated file per log into")
    paths, seen = [], Counter()
    for log in logs:
        stem = Path(log.rstrip("/")).stem
        seen[stem] += 1
        suffix = f"-{seen[stem]}" if seen[stem] > 1 else ""
        paths.append(out / f"{stem}{suffix}.annotated.mcap")
    return paths


def layout_path(annotated: str | os.PathLike) -> Path:
    """The Foxglove layout written beside an annotated file (``NAME.layout.json``)."""
    annotated = Path(annotated)
    return annotated.with_name(f"{annotated.stem}.layout.json")


def write_annotated(evaluation: Evaluation, out: str | os.PathLike, *, overwrite: bool = False,
                    inputs: list[str | os.PathLike] = ()) -> list[AnnotateSummary]:
    """Write an annotated copy of every replayed log (see :func:`annotated_paths`), and a
    Foxglove layout beside each.

    ``evaluation`` must have been made with ``keep_outcomes=True`` from logs on disk.

    Raises:
        InputError: an output exists (without ``overwrite``), is one of the replayed logs
            or ``inputs`` (always), or cannot be written.
    """
    if len(evaluation.outcomes) != len(evaluation.episodes) or evaluation.spec is None:
        raise SlearnError("annotated logs need a replay of logs on disk kept with keep_outcomes=True")
    groups = _by_log(evaluation.outcomes)
    targets = annotated_paths([log for log, _ in groups], out)
    decoder = ChannelDecoder(evaluation.tokens, evaluation.vocabulary)
    sources = [*inputs, *(log for log, _ in groups)]
    written = []
    for (log, outcomes), target in zip(groups, targets):
        written.append(_annotate_one(evaluation, log, outcomes, target, decoder, overwrite, sources))
        write_atomic(layout_path(target), json.dumps(foxglove_layout(), indent=2) + "\n",
                     overwrite=overwrite, inputs=sources)
    return written


def _by_log(outcomes: list[EpisodeOutcome]) -> list[tuple[str, list[EpisodeOutcome]]]:
    """Consecutive episodes of one log, as replayed (a log given twice is two groups)."""
    groups: list[tuple[str, list[EpisodeOutcome]]] = []
    for outcome in outcomes:
        log = split_episode_name(outcome.name)[0]
        if not groups or groups[-1][0] != log or any(o.name == outcome.name for o in groups[-1][1]):
            groups.append((log, []))
        groups[-1][1].append(outcome)
    return groups


def _annotations(evaluation: Evaluation, log: str, outcomes: list[EpisodeOutcome],
                 decoder: ChannelDecoder) -> tuple[np.ndarray, list[tuple]]:
    """Times and payloads of every annotation of one log, in time order."""
    times = dict(iter_step_times(log, evaluation.spec, evaluation.vocabulary,
                                 slice_from_dict(evaluation.setup.get("slice"))))
    at, payloads = [], []
    for outcome in outcomes:
        steps_at = times.get(outcome.name, np.zeros(0, np.int64))
        if len(steps_at) != len(outcome) + outcome.first_step:
            raise SlearnError(f"{outcome.name}: read {len(steps_at)} steps for the annotated copy "
                              f"but {len(outcome) + outcome.first_step} when replaying; was the log "
                              f"changed?")
        steps = np.flatnonzero(outcome.evaluated)
        at.append(steps_at[steps + outcome.first_step])
        payloads += _payloads(outcome, steps, decoder)
    at_ns = np.concatenate(at) if at else np.zeros(0, np.int64)
    order = np.argsort(at_ns, kind="stable")
    return at_ns[order], [payloads[i] for i in order.tolist()]


def _annotate_one(evaluation: Evaluation, log_path: str, outcomes: list[EpisodeOutcome],
                  target: Path, decoder: ChannelDecoder, overwrite: bool,
                  sources: list) -> AnnotateSummary:
    at_ns, payloads = _annotations(evaluation, log_path, outcomes, decoder)
    copied = pending = 0
    with open_log(log_path) as log, CopyWriter(target, overwrite=overwrite, inputs=sources,
                                               profile=log.profile) as out:
        out.copy_extras(log)
        out.add_metadata("slearn.replay", {
            "source": log_path, "source_profile": log.profile, "source_library": log.library,
            "mode": evaluation.mode, "episodes": str(len(outcomes)),
            "library": str((evaluation.setup.get("library") or {}).get("path")),
            "accuracy": f"{evaluation.accuracy:.6f}",
            "surprise": "lower bound (online: 1 - score when wrong)" if evaluation.mode == "online"
                        else "-log2 of the chosen context's share of what happened"})
        topics = [out.register_channel(t, s["title"], s) for t, s in
                  ((PREDICTION_TOPIC, PREDICTION_SCHEMA), (CORRECT_TOPIC, CORRECT_SCHEMA),
                   (SURPRISE_TOPIC, SURPRISE_SCHEMA))]
        for message in log.iter_messages():
            while pending < len(at_ns) and at_ns[pending] < message.log_time_ns:
                _write_annotation(out, topics, int(at_ns[pending]), payloads, pending)
                pending += 1
            out.copy_message(message)
            copied += 1
        for i in range(pending, len(at_ns)):
            _write_annotation(out, topics, int(at_ns[i]), payloads, i)
    return AnnotateSummary(str(target), log_path, copied, len(at_ns))


def _payloads(outcome: EpisodeOutcome, steps: np.ndarray, decoder: ChannelDecoder) -> list[tuple]:
    """``(prediction, correct, surprise)`` JSON payloads per step; repeated parts are cached."""
    labels: dict[int, str] = {}
    bodies: dict[tuple, bytes] = {}
    surprises: dict[float, bytes] = {}

    def label(token: int) -> str:
        if token not in labels:
            labels[token] = decoder.label(token)
        return labels[token]

    bits = np.round(outcome.surprise_bits(), 4).tolist()
    predicted, actual = outcome.predicted.tolist(), outcome.actual.tolist()
    score, matched = np.round(outcome.score, 6).tolist(), outcome.matched_length.tolist()
    top_k = outcome.top_k.tolist()
    episode = json.dumps(outcome.name).encode()
    out = []
    for s in steps.tolist():
        key = (predicted[s], actual[s], score[s], matched[s], top_k[s])
        body = bodies.get(key)
        if body is None:
            body = bodies[key] = _encode({
                "predicted": label(key[0]), "actual": label(key[1]), "correct": key[0] == key[1],
                "abstained": key[0] < 0, "score": key[2], "matched_length": key[3],
                "in_top_k": key[4]})[1:]
        surprise = surprises.get(bits[s])
        if surprise is None:
            surprise = surprises[bits[s]] = _encode({"bits": bits[s],
                                                     "probability": round(2.0 ** -bits[s], 6)})
        out.append((b'{"step":%d,"episode":%s,' % (s + outcome.first_step, episode) + body,
                    _CORRECT[key[0] == key[1]], surprise))
    return out


_CORRECT = {True: b'{"correct":true,"value":1}', False: b'{"correct":false,"value":0}'}


def _encode(message: dict) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode()


def _write_annotation(out: CopyWriter, topics: list[int], at_ns: int, payloads: list[tuple],
                      i: int) -> None:
    for channel_id, data in zip(topics, payloads[i]):
        out.write_encoded(channel_id, at_ns, data)


# --- the Foxglove layout ---------------------------------------------------------------------

def foxglove_layout() -> dict:
    """A Foxglove layout: predicted against actual (state transitions) above, surprise in
    bits and correctness (plot) below."""
    states, plot = "StateTransitions!slearn-prediction", "Plot!slearn-surprise"
    return {
        "configById": {
            states: {"paths": [
                {"value": f"{PREDICTION_TOPIC}.actual", "timestampMethod": "receiveTime", "label": "actual"},
                {"value": f"{PREDICTION_TOPIC}.predicted", "timestampMethod": "receiveTime",
                 "label": "predicted"}], "isSynced": True},
            plot: {"paths": [
                {"value": f"{SURPRISE_TOPIC}.bits", "enabled": True, "timestampMethod": "receiveTime",
                 "label": "surprise (bits)"},
                {"value": f"{CORRECT_TOPIC}.value", "enabled": True, "timestampMethod": "receiveTime",
                 "label": "correct (1/0)"}],
                "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
                "isSynced": True, "xAxisVal": "timestamp", "title": "slearn surprise"},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"first": states, "second": plot, "direction": "column", "splitPercentage": 50},
    }

