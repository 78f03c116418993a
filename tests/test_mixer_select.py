"""Who speaks: the leader's kind, at the longest context less than a mistake behind it."""

import numba
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_predictor import assert_single_predictions_are_the_runs

from slearn.core.library import PatternLibrary
from slearn.core.mixer import BETA, ETA, FREQUENT, N_KINDS, RECENT, SAME, new_mixer
from slearn.core.mixer import select as select_helper
from slearn.core.stream import Episode


@numba.njit
def select(w, v, cand, n):  # helpers are called from compiled code only
    return select_helper(w, v, cand, n)


def awake(n: int) -> np.ndarray:
    cand = np.full((7, N_KINDS), -1, np.int32)
    cand[1:n + 1, FREQUENT] = cand[1:n + 1, RECENT] = np.arange(1, n + 1)
    return cand


def test_the_longest_context_less_than_a_mistake_behind_the_leader_speaks():
    w = new_mixer(1, 6).weight
    w[0, :, FREQUENT] = [1.0, 0.5, 0.5, 0.5, 0.5, np.exp(-ETA / 2)]  # half a mistake behind
    w[0, :, RECENT] = 0.1
    assert select(w, 0, awake(6), 6) == (6, FREQUENT, 1.0)
    w[0, 5, FREQUENT] = np.exp(-2 * ETA)  # two mistakes behind: the leader speaks
    assert select(w, 0, awake(6), 6) == (1, FREQUENT, 1.0)
    w[0, 3, FREQUENT] = BETA  # a whole mistake behind: told apart
    assert select(w, 0, awake(6), 6) == (1, FREQUENT, 1.0)
    w[0, 3, FREQUENT] = BETA ** 0.99
    assert select(w, 0, awake(6), 6) == (4, FREQUENT, 1.0)
    # contexts 4..6 beyond the history: only experts whose own context was found may
    # speak for the leader (a missing one's weight lent to its twin is not its twin's record)
    assert select(w, 0, awake(3), 3) == (1, FREQUENT, 1.0)


def test_experts_that_never_disagreed_leave_it_to_the_shortest_context():
    # equal records: the weights differ by the prior only (new_mixer), so the simplest speaks
    w = new_mixer(1, 6).weight
    assert select(w, 0, awake(6), 6) == (1, FREQUENT, w[0, 0, FREQUENT])
    w[0, 5, FREQUENT] *= 1 - SAME / 2
    assert select(w, 0, awake(6), 6)[0] == 1
    w[0, 5, FREQUENT] = np.exp(-ETA / 4)  # a quarter of a mistake behind: a record of its own
    assert select(w, 0, awake(6), 6)[0] == 6


def test_the_tolerance_stays_within_the_leaders_kind():
    # a context's latest outcome must not outvote its counts because it is longer
    w = new_mixer(1, 6).weight
    w[0, :, FREQUENT] = [1.0, 0.1, 0.1, 0.1, 0.1, 0.1]
    w[0, :, RECENT] = [0.1, 0.1, 0.1, 0.1, 0.1, 0.99]
    assert select(w, 0, awake(6), 6) == (1, FREQUENT, 1.0)


def test_a_missing_long_context_lends_its_weight_to_the_leader_only():
    # context 6 is missing: it lends its weight to its longest shorter twin found (5) in
    # choosing the leader, but context 5's own record is what lets it speak for the leader
    w = new_mixer(1, 6).weight
    w[0, :, FREQUENT] = [0.98, 0.2, 0.2, 0.2, 0.2, 1.0]
    w[0, :, RECENT] = 0.1
    cand = awake(6)
    cand[6] = -1
    assert select(w, 0, cand, 6) == (5, FREQUENT, 1.0)  # 5 leads with 6's weight
    w[0, 5, FREQUENT] = 0.97
    assert select(w, 0, cand, 6) == (1, FREQUENT, 0.98)  # 1 leads; 5's own 0.2 is far behind it


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_frozen_batch_predictions_agree_with_the_run_under_near_ties(seed):
    # the frozen batch path looks up longer contexts only when their experts could speak;
    # with weights a fraction of a mistake apart, or tied, it must still choose as the run does
    rng = np.random.default_rng(seed)
    obs = rng.integers(0, 2, 301)  # two readings, one command: long contexts recur
    library = PatternLibrary(max_length=6)
    library.learn(Episode.from_pairs(obs[:1], np.full(300, 100), obs[1:]))
    w = library.mixer.weight
    w[:, :, :2] = np.exp(-ETA * rng.uniform(0, 3, w[:, :, :2].shape))
    w[:, :, :2] /= w[:, :, :2].max(axis=(1, 2), keepdims=True)
    tied = rng.random(w[:, :, :2].shape) < 0.3  # some experts share the leader's record
    w[:, :, :2][tied] = (1 - SAME * rng.uniform(0, 0.5, tied.sum()))
    assert_single_predictions_are_the_runs(
        library, Episode.from_pairs(obs[:1], np.full(60, 100), rng.integers(0, 2, 60)))
