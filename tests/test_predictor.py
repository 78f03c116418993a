"""Prediction from a history: the adaptive library, the literal rule against brute force."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from naive import NaiveLibrary, naive_context_stats
from test_literal import L, R, pointer_episode

from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode
from slearn.recorders.pointer import pointer_vocabulary

POS = 10  # position k is symbol k + 10 (see test_literal.pointer_episode)


def steps(text: str):
    return pointer_episode(text).steps()


def test_abstains_on_an_empty_library_and_on_unseen_situations():
    for library in (PatternLibrary(), LiteralLibrary()):
        predictor = Predictor(library)
        assert predictor.predict(steps("3"), (R,)).abstained
        library.learn(pointer_episode("3 R 4 R 5"))
        assert predictor.predict(steps("3"), (99,)).abstained  # never issued this action
    literal = LiteralLibrary()
    literal.learn(pointer_episode("3 R 4 R 5"))
    assert Predictor(literal).predict(steps("9"), (R,)).abstained  # never observed 9
    assert Predictor(literal).predict(steps("5"), (R,)).abstained  # 5 R never seen


def test_the_adaptive_library_reads_off_what_happened_next():
    library = PatternLibrary()
    for _ in range(10):
        library.learn(pointer_episode("3 R 4 R 5 L 4 R 5 L 4 L 3 L 2"))
    prediction = Predictor(library).predict(steps("4"), (L,))
    assert prediction.observations == (3 + POS,)
    assert prediction.views[0].length >= 2  # the current observation and the action
    # an observation never seen: only the action's own context can speak
    assert Predictor(library).predict(steps("9"), (L,)).views[0].length in (-1, 1)


def test_each_channel_is_predicted_on_its_own():
    vocabulary = pointer_vocabulary()
    library = PatternLibrary(vocabulary=vocabulary)
    library.learn(Episode.from_pairs([3 + 2], [1, 1, 0], [4 + 2, 5 + 2, 4 + 2]))
    prediction = Predictor(library).predict([((), (4 + 2,))], (1,))
    assert [v.name for v in prediction.views] == ["/pointer/position"]
    assert prediction.observations == (5 + 2,)


def test_literal_reads_off_what_happened_next_longest_match_first():
    library = LiteralLibrary()
    library.learn(pointer_episode("3 R 4 R 5 L 4 R 5 L 4 L 3 L 2"))
    prediction = Predictor(library).predict(steps("4"), (L,))
    assert prediction.observations == (3 + POS,)
    assert prediction.views[0].length == 2  # the current observation and the action
    # with more history the longer context "4 R 5 L" is found inside a pattern
    prediction = Predictor(library).predict(steps("4 R 5"), (L,))
    assert prediction.observations == (4 + POS,)
    assert prediction.views[0].length == 4


def test_literal_frequent_outcome_wins_then_recent_one_breaks_ties():
    library = LiteralLibrary(max_length=1)
    for text in ("1 R 2", "1 R 2", "1 R 3"):
        library.learn(pointer_episode(text))
    predictor = Predictor(library, top_k=2)
    prediction = predictor.predict(steps("1"), (R,)).views[0]
    assert prediction.observations == (2 + POS,)
    assert [obs for obs, _ in prediction.ranked] == [(2 + POS,), (3 + POS,)]
    assert prediction.score == 2 / 3
    library.learn(pointer_episode("1 R 3"))
    assert predictor.predict(steps("1"), (R,)).observations == (3 + POS,)  # 2 vs 2: newest wins


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.integers(2, 5))
def test_literal_prediction_matches_brute_force_over_the_patterns(seed, max_length, n_obs):
    rng = np.random.default_rng(seed)
    obs = rng.integers(0, n_obs, 301)
    act = rng.integers(100, 102, 300)
    library = LiteralLibrary(max_length)
    naive = NaiveLibrary(max_length)
    train = Episode.from_pairs(obs[:1], act[:200], obs[1:201])
    library.learn(train)
    naive.learn(library.tokens.tokenize(train).tolist())
    predictor = Predictor(library)
    history = Episode.from_pairs(obs[200:201], act[200:], obs[201:]).steps()
    for t in range(1, len(history) - 1, 7):
        past, action = history[: t + 1], history[t + 1][0]
        expected = _brute_force(library, naive.patterns, past, action)
        got = predictor.predict(past, action).views[0]
        assert (got.observations, got.length - 1 if got.length > 0 else -1) == expected


def _history_tokens(library, past):
    table = library.tokens
    tokens = []
    for i in range(len(past) - 1, -1, -1):
        tokens.insert(0, table.find(0, past[i][1]))
        if i == 0:
            break
        tokens.insert(0, table.find(1, past[i][0]))
    return tokens


def _brute_force(library, patterns, past, action):
    """The longest context of history tokens + action found inside a pattern, its best outcome."""
    history = _history_tokens(library, past)
    action_token = library.tokens.find(1, action)
    best = (None, -1)
    for matched in range(1, min(len(history), 2 * library.max_length - 1) + 1):
        context = tuple(history[len(history) - matched:]) + (action_token,)
        if -1 in context:
            break
        stats = naive_context_stats(patterns, context)
        if not stats:
            break
        outcome = max(stats, key=lambda o: (stats[o][0], stats[o][1], -o))
        best = (library.tokens.symbols(outcome), matched)
    return best


def _index_contents(index):
    from slearn.core.hashtrie import path_tokens
    buf = np.zeros(64, np.int32)
    contents = {}
    for node in range(1, int(index.trie.size[0])):
        e = index.head[node]
        if e == -1:
            continue
        context = tuple(buf[:path_tokens(index.trie, node, buf)].tolist())
        outcomes = {}
        while e != -1:
            outcomes[int(index.outcome[e])] = (int(index.weight[e]), int(index.last_seen[e]))
            e = index.next[e]
        best = int(index.outcome[index.best[node]])
        assert outcomes[best][0] == max(w for w, _ in outcomes.values())
        assert int(index.total[node]) == sum(w for w, _ in outcomes.values())
        contents[context] = outcomes
    return contents


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4))
def test_literal_index_kept_in_step_with_learning_equals_one_built_afresh(seed, max_length):
    from slearn.core.context_index import index_library
    rng = np.random.default_rng(seed)
    library = LiteralLibrary(max_length)
    for _ in range(3):
        obs = rng.integers(0, 4, 150)
        episode = Episode.from_pairs(obs[:1], rng.integers(100, 102, 149), obs[1:])
        library.run(library.encode(episode), learn=True, record=True)
    n = int(library._trie.size[0])
    fresh = index_library(library._trie, library._count[:n], library._last_seen[:n], max_length)
    assert _index_contents(library.context_index()) == _index_contents(fresh)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 6))
def test_ranked_list_starts_with_the_longest_context_ranked_like_brute_force(seed, top_k):
    rng = np.random.default_rng(seed)
    obs = rng.integers(0, 6, 401)
    train = Episode.from_pairs(obs[:1], rng.integers(100, 102, 400), obs[1:])
    library = LiteralLibrary(3)
    library.learn(train)
    naive = NaiveLibrary(3)
    naive.learn(library.tokens.tokenize(train).tolist())
    history = Episode.from_pairs(obs[:1], rng.integers(100, 102, 30), obs[1:31]).steps()
    past, action = history[:-1], history[-1][0]
    prediction = Predictor(library, top_k=top_k).predict(past, action).views[0]
    if prediction.abstained:
        return
    table = library.tokens
    history = _history_tokens(library, past)
    context = history[len(history) - (prediction.length - 1):] + [table.find(1, action)]
    stats = naive_context_stats(naive.patterns, tuple(context))
    expected = sorted(stats, key=lambda o: (-stats[o][0], -stats[o][1], o))[:top_k]
    ranked = [table.find(0, observations) for observations, _ in prediction.ranked]
    assert ranked[: len(expected)] == expected
    assert len(set(ranked)) == len(ranked) <= top_k


def test_frozen_replay_agrees_with_single_predictions():
    library = PatternLibrary(max_length=3)
    library.learn(pointer_episode("1 R 2 R 3 L 2 L 1 R 2 R 3 R 4 L 3"))
    assert_single_predictions_are_the_runs(library, pointer_episode("2 R 3 L 2 R 3 R 4 L 3 L 2"))


def assert_single_predictions_are_the_runs(library, episode):
    """``Predictor.predict`` at every step of ``episode`` says what a frozen run records."""
    reports = library.run(library.encode(episode), learn=False, record=True)
    single = Predictor(library)
    history = episode.steps()
    for t in range(1, len(history)):
        got = single.predict(history[:t], history[t][0])
        token = int(reports.predicted[t])
        assert got.observations == (None if token < 0 else library.tokens.symbols(token))
