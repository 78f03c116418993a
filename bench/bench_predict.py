"""Python API prediction speed, each figure against its anchor in the same run.

On a pointer log (``--condition``, ``--train`` trials learned, queries from a held-out
episode of ``--queries`` trials; each query is the last ``max_length`` steps and the next
action):

- ``Predictor.predict``, one call at a time (issue 12: >= 200,000/s), against a pure-Python
  dict model of the same order (the longest context seen, its most frequent outcome: one
  dict lookup per length). A predictor remembers its answers, and a stream's queries repeat,
  so each repeat starts a new predictor, the share of queries asked before is printed, and
  so is the rate on the distinct queries alone (every query new to its predictor);
- ``Predictor.predict_batch``, all queries in one call (issue 12: >= 2,000,000/s; a new
  predictor each repeat, as a predictor's batches share what they remember), against
  the frozen replay core (``library.run`` over the held-out episode, one prediction per step,
  the path ``slearn replay`` takes);
- ``SequenceModel.predict`` and ``predict_many`` (the sequence API) on a text of
  ``--text-chars`` characters from a random source of order 2 (seeded), histories of 5
  items, against a dict model of contexts of 1..5 items (its most frequent next item);
- ``SequenceModel.predict_step`` (the step form: ``(actions, observations)`` dicts) on a
  random walk of ``--joints`` joints of 12 positions, each step's commands drawn, histories of
  6 steps, against a dict model of contexts of 1..6 steps (its most frequent next
  observations): a first pass over held-out steps (most steps new to the model) and a
  pass asked again.

Rates are in CPU time of this process (the machine may be shared); best of ``--repeat``.
Run: ``python bench/bench_predict.py [--train 20000] [--queries 20000] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter

import numpy as np

from slearn.core.library import PatternLibrary
from slearn.core.predictor import Predictor
from slearn.recorders.pointer import PointerConfig, simulate


class DictModel:
    """The anchor: contexts of 1..order steps (observation, action, ..., action) -> counts."""

    def __init__(self, order: int) -> None:
        self.order = order
        self.best: dict[tuple, tuple] = {}

    def learn(self, steps: list) -> None:
        counts: dict[tuple, Counter] = {}
        for t in range(1, len(steps)):
            for k in range(1, min(self.order, t) + 1):
                context = tuple(x for s in steps[t - k:t] for x in s[1]) + tuple(steps[t][0]) + (k,)
                counts.setdefault(context, Counter())[steps[t][1]] += 1
        self.best = {c: counter.most_common(1)[0][0] for c, counter in counts.items()}

    def predict(self, history: list, actions: tuple):
        for k in range(min(self.order, len(history)), 0, -1):
            context = tuple(x for s in history[-k:] for x in s[1]) + tuple(actions) + (k,)
            found = self.best.get(context)
            if found is not None:
                return found
        return None


def best_rate(function, items: int, repeat: int, setup=None) -> float:
    """Items per CPU second, the best of ``repeat`` runs (``setup()`` before each, untimed,
    makes the function to time)."""
    best = float("inf")
    for _ in range(repeat):
        if setup is not None:
            function = setup()
        started = time.process_time()
        function()
        best = min(best, time.process_time() - started)
    return items / best


def queries_of(predictor: Predictor, calls: list):
    """A function asking ``predictor`` every query in ``calls``, one call at a time."""
    return lambda: [predictor.predict(x, a) for x, a in calls]


def batch_of(predictor: Predictor, episode, starts, ends):
    """A function asking ``predictor`` every query in one batch."""
    return lambda: predictor.predict_batch(episode, starts, ends)


def new_predictor(library, warm_up: tuple) -> Predictor:
    """A predictor that has compiled and sized its buffers (on ``warm_up``), nothing more."""
    predictor = Predictor(library)
    predictor.predict_unknown(list(warm_up[0]) + [(warm_up[1], ())])
    return predictor


def measure(condition: str, train: int, queries: int, repeat: int, text_chars: int = 100_000,
            joints: int = 3, step_train: int = 10_000) -> dict:
    library = PatternLibrary()
    train_episode = simulate(PointerConfig(condition, trials=train, seed=1)).to_episode()
    library.learn(train_episode)
    held_out = simulate(PointerConfig(condition, trials=queries, seed=2)).to_episode()
    steps, h = held_out.steps(), library.max_length
    ends = np.arange(h, len(held_out))
    starts = ends - h
    calls = [(steps[e - h:e], steps[e][0]) for e in ends.tolist()]
    distinct = list({(tuple(x), a): (x, a) for x, a in calls}.values())
    predictor = Predictor(library)
    predictor.predict(*calls[0])
    predictor.predict_batch(held_out, starts[:2], ends[:2])
    naive = DictModel(h)
    naive.learn(train_episode.steps())
    codes = library.encode(held_out, intern=False)
    out = {"condition": condition, "train_trials": train, "queries": len(calls),
           "repeated_share": 1 - len(distinct) / len(calls),
           "predict_per_s": best_rate(None, len(calls), repeat,
                                      lambda: queries_of(new_predictor(library, calls[0]), calls)),
           "predict_new_per_s": best_rate(None, len(distinct), repeat,
                                          lambda: queries_of(new_predictor(library, calls[0]), distinct)),
           "dict_model_per_s": best_rate(lambda: [naive.predict(x, a) for x, a in calls], len(calls), repeat),
           "dict_model_new_per_s": best_rate(lambda: [naive.predict(x, a) for x, a in distinct], len(distinct),
                                             repeat),
           "batch_per_s": best_rate(None, len(calls), repeat,
                                    lambda: batch_of(new_predictor(library, calls[0]), held_out, starts, ends)),
           "replay_core_per_s": best_rate(lambda: library.run(codes, learn=False, record=True),
                                          codes.n_reports, repeat)}
    batch = predictor.predict_batch(held_out, starts, ends)
    said = [predictor.prediction(batch, i).observations for i in range(len(calls))]
    truth = [steps[e][1] for e in ends.tolist()]
    out["batch_accuracy"] = float(np.mean([s == t for s, t in zip(said, truth)]))
    text = measure_sequences(text_chars, repeat)
    out.update({k if k != "queries" else "queries_text": v for k, v in text.items()})
    out.update(measure_steps(joints, step_train, min(queries, 4000), repeat))
    out["dict_model_accuracy"] = float(np.mean([naive.predict(x, a) == t for (x, a), t in zip(calls, truth)]))
    return out


def source_text(chars: int, seed: int = 0) -> str:
    """Characters of a random source of order 2 over 20 letters (each pair of letters has
    three likely successors)."""
    rng = np.random.default_rng(seed)
    letters = "abcdefghijklmnopqrst"
    successors = rng.integers(0, len(letters), (len(letters), len(letters), 3))
    out = [0, 1]
    for _ in range(chars - 2):
        options = successors[out[-2], out[-1]]
        out.append(int(options[0] if rng.random() < 0.7 else options[rng.integers(1, 3)]))
    return "".join(letters[i] for i in out)


class ItemDictModel:
    """The anchor of the sequence API: contexts of 1..order items -> the most frequent next."""

    def __init__(self, order: int) -> None:
        self.order = order
        self.best: dict[tuple, object] = {}

    def learn(self, items) -> None:
        counts: dict[tuple, Counter] = {}
        for t in range(1, len(items)):
            for k in range(1, min(self.order, t) + 1):
                counts.setdefault(tuple(items[t - k:t]), Counter())[items[t]] += 1
        self.best = {c: counter.most_common(1)[0][0] for c, counter in counts.items()}

    def predict(self, history):
        for k in range(min(self.order, len(history)), 0, -1):
            found = self.best.get(tuple(history[-k:]))
            if found is not None:
                return found
        return None


class StepDictModel:
    """The anchor of the step form, :class:`DictModel` over dicts: the observations of the last
    1..order steps and the next actions -> the most frequent next observations (the longest
    context seen speaks)."""

    def __init__(self, order: int) -> None:
        self.order = order
        self.best: dict[tuple, tuple] = {}

    def learn(self, steps: list) -> None:
        items = [(tuple(a.items()), tuple(o.items())) for a, o in steps]
        counts: dict[tuple, Counter] = {}
        for t in range(1, len(items)):
            for k in range(1, min(self.order, t) + 1):
                context = tuple(o for _, o in items[t - k:t]) + (items[t][0],)
                counts.setdefault(context, Counter())[items[t][1]] += 1
        self.best.update({c: counter.most_common(1)[0][0] for c, counter in counts.items()})

    def predict(self, history: list, actions: dict) -> dict:
        observed, acts = [tuple(o.items()) for _, o in history], tuple(actions.items())
        for k in range(min(self.order, len(observed)), 0, -1):
            found = self.best.get(tuple(observed[-k:]) + (acts,))
            if found is not None:
                return dict(found)
        return {}


def joint_walk(joints: int, steps: int, seed: int) -> list:
    """Steps ``({"j0": command, ...}, {"p0": position, ...})`` of ``joints`` joints on 12
    positions, each moved by a command drawn from -1, 0, 1."""
    rng = np.random.default_rng(seed)
    position, out = np.zeros(joints, np.int64), []
    for command in rng.integers(-1, 2, (steps, joints)).tolist():
        position = (position + command) % 12
        out.append(({f"j{i}": c for i, c in enumerate(command)},
                    {f"p{i}": p for i, p in enumerate(position.tolist())}))
    return out


def measure_steps(joints: int, train: int, queries: int, repeat: int) -> dict:
    from slearn import SequenceModel

    model, naive, order = SequenceModel(), StepDictModel(6), 6
    for seed in range(max(train // 500, 1)):
        episode = joint_walk(joints, 500, seed)
        model.learn_steps(episode)
        naive.learn(episode)
    held_out = joint_walk(joints, queries + order, 1000)
    calls = [(held_out[i - order:i], held_out[i][0]) for i in range(order, len(held_out))]
    truth = [held_out[i][1] for i in range(order, len(held_out))]
    model.predict_step(*calls[0])
    started = time.process_time()
    said = [model.predict_step(x, a) for x, a in calls]  # the first pass: most steps new
    first = len(calls) / (time.process_time() - started)
    return {"joints": joints, "queries_steps": len(calls), "step_first_per_s": first,
            "step_again_per_s": best_rate(lambda: [model.predict_step(x, a) for x, a in calls], len(calls),
                                          repeat),
            "step_dict_per_s": best_rate(lambda: [naive.predict(x, a) for x, a in calls], len(calls), repeat),
            "step_accuracy": float(np.mean([s == t for s, t in zip(said, truth)])),
            "step_dict_accuracy": float(np.mean([naive.predict(x, a) == t for (x, a), t in zip(calls, truth)]))}


def measure_sequences(chars: int, repeat: int) -> dict:
    from slearn import SequenceModel

    text = source_text(chars)
    cut = int(len(text) * 0.8)
    model, naive = SequenceModel(), ItemDictModel(5)
    model.learn(text[:cut])
    naive.learn(text[:cut])
    held_out = text[cut:]
    histories = [held_out[i - 5:i] for i in range(5, len(held_out))]
    truth = [held_out[i] for i in range(5, len(held_out))]
    model.predict(histories[0])
    said = model.predict_many(histories)
    return {"chars": chars, "queries": len(histories),
            "sequence_predict_per_s": best_rate(lambda: [model.predict(h) for h in histories], len(histories),
                                                repeat),
            "sequence_many_per_s": best_rate(lambda: model.predict_many(histories), len(histories), repeat),
            "item_dict_per_s": best_rate(lambda: [naive.predict(h) for h in histories], len(histories), repeat),
            "sequence_accuracy": float(np.mean([s == t for s, t in zip(said, truth)])),
            "item_dict_accuracy": float(np.mean([naive.predict(h) == t for h, t in zip(histories, truth)]))}


def render(r: dict) -> str:
    return "\n".join([
        f"pointer {r['condition']}: {r['train_trials']:,} trials learned, {r['queries']:,} queries "
        f"(accuracy: slearn {r['batch_accuracy']:.3f}, dict model {r['dict_model_accuracy']:.3f})",
        f"predict, one call at a time {r['predict_per_s']:>12,.0f}/s   dict model "
        f"{r['dict_model_per_s']:>10,.0f}/s   ratio {r['predict_per_s'] / r['dict_model_per_s']:.3f}   "
        f"target 200,000/s ({r['predict_per_s'] / 200_000:.2f} of it; "
        f"{r['repeated_share']:.0%} of the queries asked before)",
        f"... every query new         {r['predict_new_per_s']:>12,.0f}/s   dict model "
        f"{r['dict_model_new_per_s']:>10,.0f}/s   ratio {r['predict_new_per_s'] / r['dict_model_new_per_s']:.3f}",
        f"predict_batch               {r['batch_per_s']:>12,.0f}/s   replay core "
        f"{r['replay_core_per_s']:>9,.0f}/s   ratio {r['batch_per_s'] / r['replay_core_per_s']:.3f}   "
        f"target 2,000,000/s ({r['batch_per_s'] / 2_000_000:.2f} of it)",
        f"sequence API, {r['queries_text']:,} next characters of a text (accuracy: slearn "
        f"{r['sequence_accuracy']:.3f}, dict model {r['item_dict_accuracy']:.3f})",
        f"SequenceModel.predict       {r['sequence_predict_per_s']:>12,.0f}/s   dict model "
        f"{r['item_dict_per_s']:>10,.0f}/s   ratio {r['sequence_predict_per_s'] / r['item_dict_per_s']:.3f}",
        f"SequenceModel.predict_many  {r['sequence_many_per_s']:>12,.0f}/s   dict model "
        f"{r['item_dict_per_s']:>10,.0f}/s   ratio {r['sequence_many_per_s'] / r['item_dict_per_s']:.3f}",
        f"step form, {r['joints']} joints, {r['queries_steps']:,} next steps (accuracy: slearn "
        f"{r['step_accuracy']:.3f}, dict model {r['step_dict_accuracy']:.3f})",
        f"SequenceModel.predict_step  {r['step_first_per_s']:>12,.0f}/s first pass, "
        f"{r['step_again_per_s']:,.0f}/s asked again   dict model {r['step_dict_per_s']:,.0f}/s   ratio "
        f"{r['step_first_per_s'] / r['step_dict_per_s']:.3f} / {r['step_again_per_s'] / r['step_dict_per_s']:.3f}"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--condition", default="simple")
    parser.add_argument("--train", type=int, default=20_000)
    parser.add_argument("--queries", type=int, default=20_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--text-chars", type=int, default=100_000)
    parser.add_argument("--joints", type=int, default=3, help="joints of the step form's walk")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    result = measure(args.condition, args.train, args.queries, args.repeat, args.text_chars, args.joints)
    print(json.dumps(result, indent=2) if args.json else render(result))


if __name__ == "__main__":
    main()
