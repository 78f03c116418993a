"""The paper's literal rule: its example, a reference model, forgetting, determinism."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule
from naive import NaiveLibrary

from slearn.core.literal import LiteralLibrary as PatternLibrary
from slearn.core.stream import Episode

L, R = 0, 1


def pointer_episode(text: str) -> Episode:
    """``"3 R 4 R 5"`` as an episode; position k is symbol k + 10."""
    words = text.split()
    actions = [{"L": L, "R": R}[w] for w in words[1::2]]
    observations = [int(w) + 10 for w in words[2::2]]
    return Episode.from_pairs([int(words[0]) + 10], actions, observations)


def spelled(library: PatternLibrary) -> dict[str, int]:
    out = {}
    for pattern in library.iter_patterns():
        words = []
        for i, token in enumerate(pattern.tokens):
            (symbol,) = library.tokens.symbols(token)
            words.append(str(symbol - 10) if i % 2 == 0 else "LR"[symbol])
        out[" ".join(words)] = pattern.count
    return out


def test_paper_example_is_cut_into_patterns_sharing_boundaries():
    library = PatternLibrary()
    library.learn(pointer_episode("3 R 4 R 5 L 4 R 5 L 4 L 3 L 2"))
    assert spelled(library) == {
        "3 R 4": 1, "4 R 5": 2, "5 L 4": 1, "4 R 5 L 4": 1, "4 L 3": 1, "3 L 2": 1,
    }


def test_paper_example_patterns_seen_again_grow():
    library = PatternLibrary()
    for text in ("3 R 4 R 5 L 4 R 5 L 4 L 3 L 2", "3 R 4 R 5 L 4 R 5 R 6", "5 L 4 R 5 R 6"):
        library.learn(pointer_episode(text))
    patterns = spelled(library)
    for grown in ("3 R 4 R 5", "4 R 5 L 4", "5 L 4 R 5 R 6"):
        assert grown in patterns
    assert patterns["5 L 4 R 5"] == 2  # counted when it was extended to 5 L 4 R 5 R 6


def test_max_length_caps_patterns_and_restarts_at_the_boundary():
    library = PatternLibrary(max_length=2)
    for _ in range(5):
        library.learn(pointer_episode("1 R 2 R 3 R 4 R 5 R 6"))
    assert max(p.n_steps for p in library.iter_patterns()) == 2
    assert spelled(library)["1 R 2 R 3"] >= 3


def test_episodes_are_not_glued_together():
    library = PatternLibrary()
    library.learn(pointer_episode("1 R 2"))
    library.learn(pointer_episode("1 R 2"))
    library.learn(pointer_episode("2 R 3"))
    # the match open at the end of an episode is counted, and the next one starts afresh
    assert spelled(library) == {"1 R 2": 2, "2 R 3": 1}


def random_tokens(rng: np.random.Generator, n_steps: int, n_obs: int, n_act: int):
    obs = rng.integers(0, n_obs, n_steps + 1)
    act = rng.integers(0, n_act, n_steps) + 1000
    return Episode.from_pairs(obs[:1], act, obs[1:])


def test_same_stream_gives_the_same_library_byte_for_byte():
    exports = []
    for _ in range(2):
        library = PatternLibrary(max_length=4)
        library.learn(random_tokens(np.random.default_rng(7), 5000, 6, 2))
        exports.append(library.export())
    for key in exports[0]:
        assert exports[0][key].tobytes() == exports[1][key].tobytes()


class LibraryAgainstNaive(RuleBasedStateMachine):
    """Random episodes learned by both the library and the dict-of-tuples model."""

    def __init__(self):
        super().__init__()
        self.library = PatternLibrary(max_length=3)
        self.naive = NaiveLibrary(max_length=3)

    @rule(obs=st.lists(st.integers(0, 3), min_size=1, max_size=30), data=st.data())
    def learn_episode(self, obs, data):
        actions = data.draw(st.lists(st.integers(100, 101), min_size=len(obs) - 1, max_size=len(obs) - 1))
        episode = Episode.from_pairs(obs[:1], actions, obs[1:])
        self.library.learn(episode)
        self.naive.learn(self.library.tokens.tokenize(episode).tolist())

    @invariant()
    def same_patterns_counts_and_recency(self):
        got = {p.tokens: [p.count, p.last_seen] for p in self.library.iter_patterns()}
        assert got == self.naive.patterns
        assert len(self.library) == len(self.naive.patterns)
        assert self.library.clock == self.naive.clock

    @invariant()
    def prefix_closed(self):
        patterns = {p.tokens for p in self.library.iter_patterns()}
        for tokens in patterns:
            if len(tokens) > 3:
                assert tokens[:-2] in patterns


TestLibraryAgainstNaive = LibraryAgainstNaive.TestCase
TestLibraryAgainstNaive.settings = settings(max_examples=60, stateful_step_count=15, deadline=None)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(16, 200))
def test_forgetting_bounds_the_library_and_keeps_it_prefix_closed(seed, bound):
    library = PatternLibrary(max_length=4, max_patterns=bound)
    library.learn(random_tokens(np.random.default_rng(seed), 3000, 8, 3))
    patterns = {p.tokens: p.count for p in library.iter_patterns()}
    assert len(patterns) <= bound
    assert library.forgotten > 0
    for tokens in patterns:
        if len(tokens) > 3:
            assert tokens[:-2] in patterns


def test_forgetting_drops_rare_patterns_first():
    library = PatternLibrary(max_length=3, max_patterns=40)
    for _ in range(5):
        library.learn(pointer_episode("1 R 2"))  # the oldest pattern, but a frequent one
    rng = np.random.default_rng(1)
    for _ in range(10):
        library.learn(random_tokens(rng, 30, 12, 3))
    assert library.forgotten > 100
    assert "1 R 2" in spelled_safe(library)
    assert min(p.last_seen for p in library.iter_patterns() if p.count == 1) > 30


def spelled_safe(library):
    out = set()
    for pattern in library.iter_patterns():
        symbols = [library.tokens.symbols(t) for t in pattern.tokens]
        if all(len(s) == 1 for s in symbols) and all(s[0] in (L, R) for s in symbols[1::2]):
            words = [str(s[0] - 10) if i % 2 == 0 else "LR"[s[0]] for i, s in enumerate(symbols)]
            out.add(" ".join(words))
    return out


def test_export_round_trip_keeps_patterns_and_learning_state():
    library = PatternLibrary(max_length=4)
    rng = np.random.default_rng(3)
    library.learn(random_tokens(rng, 2000, 5, 2))
    again = PatternLibrary.from_export(library.export(), library.tokens, library.clock, 4)
    assert list(again.iter_patterns()) == list(library.iter_patterns())
    follow_up = random_tokens(rng, 500, 5, 2)
    library.learn(follow_up)
    again.learn(follow_up)
    assert list(again.iter_patterns()) == list(library.iter_patterns())


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError):
        PatternLibrary(max_length=0)
    with pytest.raises(ValueError):
        PatternLibrary(max_patterns=3)
