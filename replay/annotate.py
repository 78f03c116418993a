"""Annotated logs: a replayed MCAP file copied with the library's predictions beside it.

The output holds every channel of the source log (raw messages, schemas, encodings,
sequence numbers and times as they were) plus three JSON channels with jsonschema
schemas, one message each per predicted observation event, at the log time of the
observation it predicted (so in Foxglove the prediction lines up with what happened):

* ``/slearn/prediction`` (``slearn.replay.Prediction``): ``step``, ``predicted`` and
  ``actual`` as ``channel=value`` labels, ``correct``, ``abstained``, ``score``,
  ``matched_length`` (history tokens matched) and the ranked guesses ``top``;
* ``/slearn/correct`` (``slearn.replay.Correct``): ``correct`` and ``value`` (1 or 0), to plot;
* ``/slearn/surprise`` (``slearn.replay.Surprise``): ``bits``, ``-log2`` of the
  probability the library gave what happened (see
  :meth:`slearn.replay.evaluate.EpisodeOutcome.surprise_bits`), and that ``probability``.

A metadata record ``slearn.replay`` names the library, the mode and the accuracy.
Files are written atomically (:class:`~slearn.recorders.mcap_episode.EpisodeWriter`).
"""

from __future__ import annotations

import copy
import json
import os
from array import array
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from slearn.errors import InputError, SlearnError
from slearn.mcap_read import ChannelInfo, McapLog, RawMessage
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.replay.evaluate import Evaluation, EpisodeOutcome
from slearn.replay.metrics import ChannelDecoder
from slearn.spec import Spec
from slearn.vocabulary import Vocabulary

PREDICTION_TOPIC = "/slearn/prediction"
CORRECT_TOPIC = "/slearn/correct"
SURPRISE_TOPIC = "/slearn/surprise"

PREDICTION_SCHEMA = {
    "title": "slearn.replay.Prediction",
    "description": "What the pattern library predicted for one observation event, and what happened.",
    "type": "object",
    "properties": {
        "step": {"type": "integer", "description": "step of the episode"},
        "predicted": {"type": "string", "description": "channel=value, or (abstained)"},
        "actual": {"type": "string", "description": "channel=value"},
        "correct": {"type": "boolean"},
        "abstained": {"type": "boolean"},
        "score": {"type": "number", "description": "share of the chosen context's weight"},
        "matched_length": {"type": "integer", "description": "history tokens matched (1 = the current observation), -1 abstained"},
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

    Logs of the same name get ``-2``, ``-3``, ... Call it before replaying to fail early.

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
        stem = Path(log).stem
        seen[stem] += 1
        suffix = f"-{seen[stem]}" if seen[stem] > 1 else ""
        paths.append(out / f"{stem}{suffix}.annotated.mcap")
    return paths


def write_annotated(evaluation: Evaluation, out: str | os.PathLike, *, overwrite: bool = False,
                    inputs: list[str | os.PathLike] = ()) -> list[AnnotateSummary]:
    """Write an annotated copy of every replayed log (see :func:`annotated_paths`).

    ``evaluation`` must have been made with ``keep_outcomes=True`` from logs on disk.

    Raises:
        InputError: an output exists (without ``overwrite``), is one of the replayed logs
            or ``inputs`` (always), or cannot be written.
    """
    if len(evaluation.outcomes) != len(evaluation.episodes) or evaluation.spec is None:
        raise SlearnError("annotated logs need a replay of logs on disk kept with keep_outcomes=True")
    targets = annotated_paths([e.name for e in evaluation.episodes], out)
    decoder = ChannelDecoder(evaluation.tokens, evaluation.vocabulary)
    sources = [*inputs, *(e.name for e in evaluation.episodes)]
    return [_annotate_one(evaluation, outcome, target, decoder, overwrite, sources)
            for outcome, target in zip(evaluation.outcomes, targets)]


def _annotate_one(evaluation: Evaluation, outcome: EpisodeOutcome, target: Path,
                  decoder: ChannelDecoder, overwrite: bool, sources: list) -> AnnotateSummary:
    times = step_times(outcome.name, evaluation.spec, evaluation.vocabulary)
    if len(times) != len(outcome) + outcome.first_step:
        raise SlearnError(f"{outcome.name}: read {len(times)} steps for the annotated copy but "
                          f"{len(outcome) + outcome.first_step} when replaying; was the log changed?")
    steps = np.flatnonzero(outcome.evaluated)
    at_ns = times[steps + outcome.first_step]
    payloads = _payloads(outcome, steps, decoder)
    copied = 0
    with _CopyWriter(target, overwrite=overwrite, inputs=sources) as out:
        out.add_metadata("slearn.replay", {
            "source": outcome.name, "mode": evaluation.mode,
            "library": str((evaluation.setup.get("library") or {}).get("path")),
            "accuracy": f"{evaluation.accuracy:.6f}",
            "surprise": "lower bound (online: 1 - score when wrong)" if evaluation.mode == "online"
                        else "-log2 of the chosen context's share of what happened"})
        topics = [out.register_channel(t, s["title"], s) for t, s in
                  ((PREDICTION_TOPIC, PREDICTION_SCHEMA), (CORRECT_TOPIC, CORRECT_SCHEMA),
                   (SURPRISE_TOPIC, SURPRISE_SCHEMA))]
        pending = 0
        for message in _iter_source(outcome.name):
            while pending < len(steps) and at_ns[pending] < message.log_time_ns:
                _write_annotation(out, topics, int(at_ns[pending]), payloads, pending)
                pending += 1
            out.copy_message(message)
            copied += 1
        for i in range(pending, len(steps)):
            _write_annotation(out, topics, int(at_ns[i]), payloads, i)
    return AnnotateSummary(str(target), outcome.name, copied, len(steps))


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
    top = outcome.top.tolist()
    out = []
    for s in steps.tolist():
        key = (predicted[s], actual[s], score[s], matched[s], tuple(top[s]))
        body = bodies.get(key)
        if body is None:
            body = bodies[key] = _encode({
                "predicted": label(key[0]), "actual": label(key[1]), "correct": key[0] == key[1],
                "abstained": key[0] < 0, "score": key[2], "matched_length": key[3],
                "top": [label(t) for t in key[4] if t >= 0]})[1:]
        surprise = surprises.get(bits[s])
        if surprise is None:
            surprise = surprises[bits[s]] = _encode({"bits": bits[s],
                                                     "probability": round(2.0 ** -bits[s], 6)})
        out.append((b'{"step":%d,' % (s + outcome.first_step) + body,
                    _CORRECT[key[0] == key[1]], surprise))
    return out


_CORRECT = {True: b'{"correct":true,"value":1}', False: b'{"correct":false,"value":0}'}


def _encode(message: dict) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode()


def _write_annotation(out: "_CopyWriter", topics: list[int], at_ns: int, payloads: list[tuple],
                      i: int) -> None:
    for channel_id, data in zip(topics, payloads[i]):
        out.write_encoded(channel_id, at_ns, data)


def _iter_source(path: str) -> Iterator[RawMessage]:
    with McapLog(path) as log:
        yield from log.iter_messages()


class _CopyWriter(EpisodeWriter):
    """An :class:`EpisodeWriter` that also copies raw messages of other channels as they are."""

    def __enter__(self) -> "_CopyWriter":
        super().__enter__()
        self._copied: dict[int, int] = {}
        return self

    def copy_message(self, message: RawMessage) -> None:
        """Write ``message`` on a copy of its channel (registered on first use)."""
        channel_id = self._copied.get(message.channel.id)
        if channel_id is None:
            channel_id = self._copied[message.channel.id] = self._copy_channel(message.channel)
        with self._writing():
            self._active().add_message(channel_id, log_time=message.log_time_ns, data=message.data,
                                       publish_time=message.publish_time_ns, sequence=message.sequence)

    def _copy_channel(self, channel: ChannelInfo) -> int:
        writer = self._active()
        schema_id = 0
        with self._writing():
            if channel.schema is not None:
                s = channel.schema
                key = ("copied", s.name, s.encoding, s.data)
                schema_id = self._schemas.get(key) or writer.register_schema(s.name, s.encoding, s.data)
                self._schemas[key] = schema_id
            return writer.register_channel(channel.topic, channel.message_encoding, schema_id,
                                           dict(channel.metadata))


# --- when each step happened ----------------------------------------------------------------

def step_times(path: str, spec: Spec, vocabulary: Vocabulary) -> np.ndarray:
    """Log time (ns) of each step of the episode :func:`slearn.serialize.read_episodes` makes
    of ``path``: the time of its observations, or of its actions when it has none.

    The log is read again through the same path as :mod:`slearn.serialize` (its step
    builder, with the times kept), so steps match one for one.
    """
    from slearn import serialize

    vocabulary = copy.deepcopy(vocabulary)
    values = serialize.iter_field_values(path, spec)
    events = serialize._symbolize(values, spec, vocabulary, path)
    if spec.mode == "tick":
        return _tick_times(events, spec.tick_ns)
    if spec.mode == "change":
        events = serialize._only_changes(events)
    builder = _timed_builder(serialize)
    for log_time, _, symbol, action in events:
        builder.add(log_time, symbol, action)
    builder.build()
    return np.frombuffer(builder.times, np.int64).copy()


def _tick_times(events, tick_ns: int) -> np.ndarray:
    events = iter(events)
    first = next(events, None)
    if first is None:
        return np.zeros(0, np.int64)
    last = first[0]
    for event in events:
        last = event[0]
    n = -(-(last - first[0]) // tick_ns) + 1  # the ticks before the last event, then one more
    return first[0] + tick_ns * np.arange(n, dtype=np.int64)


def _timed_builder(serialize):
    class TimedSteps(serialize._StepBuilder):
        def __init__(self) -> None:
            super().__init__()
            self.times = array("q")

        def close(self) -> None:
            if self.open:
                self.times.append(self.obs_time if self.obs_time is not None else self.action_time)
            super().close()

    return TimedSteps()
