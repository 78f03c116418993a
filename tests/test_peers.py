"""bench/peers.py: VOM, AKOM, PPM and the per-channel peer against plain-Python twins; the C
VOM gives the same predictions."""

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from slearn.core.stream import Episode
from slearn.core.tokens import TokenTable
from slearn.recorders.arm import ArmConfig, arm_vocabulary, simulate_arm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_vom_speed  # noqa: E402
import peers  # noqa: E402


def _order2_episode(steps=4000, seed=0, symbols=5):
    """obs_i = obs_{i-1} + obs_{i-2} + act_i (mod symbols): order 2 given the actions."""
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, 3, steps)
    obs = [0, 1]
    for a in actions[1:]:
        obs.append((obs[-1] + obs[-2] + a) % symbols)
    return Episode.from_pairs([100 + obs[0]], 10 + actions, [100 + o for o in obs[1:]])


def test_an_order_2_source_is_learned_by_vom_2_and_not_by_vom_1():
    result = peers.prequential_correct(_order2_episode())
    late = result.vom[-1000:].mean(axis=0)
    assert late[1] == 1.0 and late[0] < 0.6
    assert (late[2:] == 1.0).all()  # longer contexts hold the same answer once seen
    assert result.akom[-1000:].mean() == 1.0


class NaiveCounts:
    """The specification: a dict of context tuples -> outcome counts, in plain Python."""

    def __init__(self, max_order):
        self.max_order = max_order
        self.counts = defaultdict(dict)  # context -> {outcome: [count, last seen]}
        self.order = defaultdict(list)  # context -> outcomes, newest first seen first
        self.alphabet = []
        self.clock = 0

    def events(self, obs, act, i):
        """The history read backwards from ``A_i``: ``A_i, O_{i-1}, A_{i-1}, O_{i-2}, ...``."""
        out = [act[i]]
        for m in range(1, min(self.max_order, i) + 1):
            out += ([act[i - m + 1]] if m > 1 else []) + [obs[i - m]]
        return out

    def contexts(self, obs, act, i):
        """The step-aligned contexts of orders 0.. (1, 2, 4, 6, ... newest events)."""
        events = self.events(obs, act, i)
        return [tuple(events[:max(1, 2 * j)]) for j in range(0, min(self.max_order, i) + 1)]

    def event_vom(self, obs, act, i, tokens):
        """The longest seen context of at most ``tokens`` newest events speaks."""
        events = self.events(obs, act, i)
        seen = [c for c in (tuple(events[:m]) for m in range(1, min(tokens, len(events)) + 1))
                if c in self.counts]
        if not seen:
            return -1
        table = self.counts[seen[-1]]
        return max(table, key=lambda y: (table[y][0], table[y][1]))

    def vom(self, obs, act, i, k):
        seen = [c for c in self.contexts(obs, act, i)[:k + 1] if c in self.counts]
        if not seen:
            return -1, -1
        table = self.counts[seen[-1]]
        return max(table, key=lambda y: (table[y][0], table[y][1])), len(seen) - 1

    def ppm(self, obs, act, i, order, method="C"):
        dist, excluded, weight = {}, set(), 1.0
        for context in reversed(self.contexts(obs, act, i)[:order + 1]):
            if context not in self.counts:
                continue
            table = {y: v[0] for y, v in self.counts[context].items() if y not in excluded}
            n, t = sum(table.values()), len(table)
            if t == 0:
                continue
            denom = n + t if method == "C" else 2 * n
            for y, c in table.items():
                dist[y] = weight * (c if method == "C" else 2 * c - 1) / denom
            weight *= t / denom
            excluded |= set(table)
        rest = [y for y in self.alphabet if y not in excluded]
        for y in rest:
            dist[y] = weight / (len(rest) + 1)
        return dist, weight / (len(rest) + 1)

    def learn(self, obs, act, i):
        y = obs[i]
        events = self.events(obs, act, i)
        for context in (tuple(events[:m]) for m in range(1, len(events) + 1)):
            entry = self.counts[context].setdefault(y, [0, 0])
            entry[0] += 1
            entry[1] = self.clock
        if y not in self.alphabet:
            self.alphabet.append(y)
        self.clock += 1


def _random_episode(steps, seed, symbols=4, actions=2):
    rng = np.random.default_rng(seed)
    obs = rng.integers(0, symbols, steps + 1)
    obs[1::3] = obs[0:-1:3]  # some structure, so long contexts repeat
    return Episode.from_pairs([obs[0]], symbols + rng.integers(0, actions, steps), obs[1:])


@pytest.mark.parametrize("seed", [0, 1])
def test_vom_and_akom_follow_the_specification_step_by_step(seed):
    obs, act = peers.step_tokens(_random_episode(600, seed))
    found = peers.CountModel(4).run(obs, act, ppm=None)
    naive = NaiveCounts(4)
    o, a = obs.tolist(), act.tolist()
    for i in range(1, len(o)):
        for k in range(1, 5):
            expected, deepest = naive.vom(o, a, i, k)
            assert found.vom[i - 1, k - 1] == expected
        for k in range(1, 4):
            assert found.half[i - 1, k - 1] == naive.event_vom(o, a, i, 2 * k + 1)
        assert found.deepest[i - 1] == naive.vom(o, a, i, 4)[1]
        naive.learn(o, a, i)
    akom = found.akom(3)
    assert ((akom == -1) == (found.deepest < 1)).all()
    assert (akom[found.deepest >= 1] == found.vom[found.deepest >= 1, 2]).all()


@pytest.mark.parametrize("method", ["C", "D"])
def test_ppm_is_a_distribution_and_follows_the_specification(method):
    obs, act = peers.step_tokens(_random_episode(300, 3, symbols=6, actions=3))
    naive = NaiveCounts(3)
    o, a = obs.tolist(), act.tolist()
    for i in range(1, len(o)):
        if i % 7 == 0:
            dist, novel = _model_after(obs, act, i - 1).ppm_distribution(obs[:i], act[:i + 1],
                                                                          method)
            assert abs(dist.sum() + novel - 1.0) < 1e-12
            expected, expected_novel = naive.ppm(o, a, i, 3, method)
            assert abs(novel - expected_novel) < 1e-12
            for y, p in expected.items():
                assert abs(dist[y] - p) < 1e-12
            assert dist[[y for y in range(len(dist)) if y not in expected]].sum() == 0
        naive.learn(o, a, i)


def _model_after(obs, act, steps):
    """A model that counted steps ``1..steps``."""
    model = peers.CountModel(3)
    model.learn(obs[:steps + 1], act[:steps + 1])
    return model


def test_ppm_predicts_the_argmax_of_its_distribution():
    obs, act = peers.step_tokens(_random_episode(400, 5, symbols=5, actions=2))
    found = peers.CountModel(3).run(obs, act, ppm="C", ppm_order=3)
    for i in (50, 150, 399):
        model = _model_after(obs, act, i - 1)
        dist, _ = model.ppm_distribution(obs[:i], act[:i + 1], "C")
        assert dist[found.ppm[i - 1]] == dist.max()


def test_tables_grow_without_changing_predictions():
    obs, act = peers.step_tokens(_random_episode(12_000, 7, symbols=40, actions=3))
    model = peers.CountModel(3)
    found = model.run(obs, act, ppm=None)
    assert len(model.counts.keys) > 4096 and len(model.counts.total) > 1024
    naive = NaiveCounts(3)
    o, a = obs.tolist(), act.tolist()
    for i in range(1, len(o)):
        assert found.vom[i - 1, 2] == naive.vom(o, a, i, 3)[0]
        naive.learn(o, a, i)


def test_sequences_without_actions_use_the_last_items():
    sequence = [1, 2, 3, 1, 2, 4, 1, 2, 4]
    episode = Episode.from_steps([((), (x,)) for x in sequence])
    obs, act = peers.step_tokens(episode)
    assert len(set(act[1:].tolist())) == 1  # the empty action token
    found = peers.CountModel(2).run(obs, act, ppm=None)
    assert found.vom[-1, 1] == obs[-1]  # "1 2 -> ?": 3 and 4 once each, 4 is newer
    assert found.vom[-1, 0] == obs[-1]  # "2 -> ?" likewise


def test_per_channel_peer_learns_every_joint_of_the_arm():
    joints = 3
    run = simulate_arm(ArmConfig(joints=joints, trials=5000, seed=1, sensors="all"))
    episode = run.to_episode()
    result = peers.per_channel_correct(episode, peers.channel_map(arm_vocabulary(joints)), order=1)
    assert result.step[-1000:].mean() >= 0.99  # a rare position may still be new
    assert sorted(result.channels) == [1, 3, 5]  # the position channels
    for steps, ok in result.channels.values():
        assert len(steps) == 5000 and ok[-1000:].mean() >= 0.99
    whole = peers.prequential_correct(episode)
    assert whole.vom[-1000:, 0].mean() < 0.5  # tuples of three joints rarely repeat


def test_per_channel_peer_on_event_driven_sensors():
    run = simulate_arm(ArmConfig(joints=2, trials=3000, seed=2, sensors="moved"))
    result = peers.per_channel_correct(run.to_episode(), peers.channel_map(arm_vocabulary(2)))
    steps = [len(s) for s, _ in result.channels.values()]
    assert sum(steps) == 3000  # each step, only the moved joint reports
    assert result.step[-500:].mean() == 1.0


def test_the_c_vom_gives_the_same_predictions(tmp_path):
    vom = peers.load_c_vom(tmp_path)
    if vom is None:
        pytest.skip("no C compiler")
    episode = _random_episode(5000, 11, symbols=8, actions=3)
    tokens = TokenTable().tokenize(episode)
    obs, act = peers.step_tokens(episode)
    found = peers.CountModel(4).run(obs, act, ppm=None)
    for k in (1, 2, 4):
        np.testing.assert_array_equal(vom(tokens, k), found.vom[:, k - 1])


def test_speed_bench_smoke():
    speed = bench_vom_speed
    result = speed.measure(trials=2000, condition="simple", repeat=1)
    assert result["steps"] == 2000 and result["slearn"] > 0
    assert set(result["numba_vom"]) == set(speed.ORDERS)
    assert len(speed.render(result).splitlines()) == 2 + len(speed.ORDERS)
