"""The predictor's fast paths (one compiled call per query, and batches) against the step
loop itself: the query's steps run as an episode of their own on scratch streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.mixer import FRESH
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode
from slearn.core.views import UNKNOWN, StepCodes, new_view_state
from slearn.errors import ParameterError
from slearn.recorders.arm import ArmConfig, arm_vocabulary, simulate_arm


def reference(library, steps, top_k, unknown_views=None):
    """What ``library.run`` predicts for the last step of ``steps`` replayed from scratch
    (the per-call path before the fast one): rows per view."""
    steps = list(steps[:-1]) + [(tuple(steps[-1][0]), ())]
    codes = library.encode(Episode.from_steps(steps), intern=False, unknown_views=unknown_views) \
        if unknown_views is not None else library.encode(Episode.from_steps(steps), intern=False)
    n_views = len(library.view_names)
    offsets = codes.offsets.copy()
    offsets[-1] = offsets[-2] + n_views
    codes = StepCodes(codes.action, offsets,
                      np.concatenate((codes.view[: offsets[-2]], np.arange(n_views, dtype=np.int32))),
                      np.concatenate((codes.token[: offsets[-2]], np.full(n_views, UNKNOWN, np.int32))))
    scratch = new_view_state(n_views, library.max_context, library.streams.root)
    out = library.run(codes, learn=False, record=True, top_k=top_k, streams=scratch)
    rows = slice(int(offsets[-2]), int(offsets[-1]))
    return out.predicted[rows], out.score[rows], out.length[rows], out.kind[rows], out.top[rows], out.top_p[rows]


def assert_batch_matches(predictor, episode, starts, ends):
    batch = predictor.predict_batch(episode, starts, ends)
    steps = episode.steps()
    for i, (s, e) in enumerate(zip(starts, ends)):
        token, score, length, kind, top, top_p = reference(predictor.library, steps[s:e + 1], predictor.top_k)
        assert batch.token[i].tolist() == token.tolist()
        assert batch.score[i].tolist() == score.tolist()
        assert batch.length[i].tolist() == length.tolist() and batch.kind[i].tolist() == kind.tolist()
        assert batch.top[i].tolist() == top.tolist() and batch.top_p[i].tolist() == top_p.tolist()
        assert predictor.predict(steps[s:e], steps[e][0]) == predictor.prediction(batch, i)
    return batch


def random_episode(rng, n, observations=5, actions=(100, 101, 102)):
    obs = rng.integers(0, observations, n + 1)
    return Episode.from_pairs(obs[:1], rng.choice(actions, n), obs[1:])


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 5), st.integers(1, 4))
def test_joint_library_batch_equals_the_step_loop(seed, max_length, top_k):
    rng = np.random.default_rng(seed)
    library = PatternLibrary(max_length=max_length)
    library.learn(random_episode(rng, 300))
    held_out = random_episode(rng, 60, observations=6, actions=(100, 101, 102, 103))  # unseen ones too
    ends = rng.integers(0, len(held_out), 30)
    starts = np.maximum(0, ends - rng.integers(0, 3 * max_length, 30))
    batch = assert_batch_matches(Predictor(library, top_k=top_k), held_out, starts, ends)
    assert (batch.token >= 0).any() and batch.top.shape == (30, 1, top_k)


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 3))
def test_factored_library_batch_equals_the_step_loop(seed, joints):
    library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(joints))
    library.learn(simulate_arm(ArmConfig(joints=joints, trials=400, seed=seed % 1000)).to_episode())
    held_out = simulate_arm(ArmConfig(joints=joints, trials=40, seed=seed % 1000 + 1)).to_episode()
    rng = np.random.default_rng(seed)
    ends = rng.integers(0, len(held_out), 20)
    starts = np.maximum(0, ends - rng.integers(0, 12, 20))
    batch = assert_batch_matches(Predictor(library), held_out, starts, ends)
    assert batch.token.shape == (20, joints) and (batch.token >= 0).any()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 5), st.sampled_from([1, 3, 4]))
@example(105579, 2, 3)  # needs both the longer contexts' experts and their rankings
def test_contexts_longer_than_the_leaders_are_skipped_only_when_they_cannot_speak(seed, max_length, top_k):
    """A query looks up the contexts up to the longest holding an expert of top weight, and
    longer ones only when their experts could outweigh the one chosen or the ranking needs
    them: with expert weights drawn from a few values (ties, a leader of any length, experts
    asleep, FRESH ones among them), every answer is still the full lookup's (library.run)."""
    rng = np.random.default_rng(seed)
    library = PatternLibrary(max_length=max_length)
    library.learn(random_episode(rng, 200, observations=3))
    library.mixer.epoch[:] += 1  # an alarm: FRESH experts sleep until their context is counted again
    fresh_steps = int(rng.choice([0, 10, 100]))
    if fresh_steps:
        library.learn(random_episode(rng, fresh_steps, observations=3))
    weight = library.mixer.weight  # ties everywhere, one top weight at a random length
    weight[:] = rng.choice([0.0, 0.25, 0.5], weight.shape, p=[0.1, 0.3, 0.6])
    lead = rng.integers(1, weight.shape[1] + 1)
    weight[0, lead - 1, FRESH if rng.random() < 0.7 else rng.integers(0, 2)] = 1.0
    held_out = random_episode(rng, 60, observations=3)
    ends = rng.integers(0, len(held_out), 30)
    starts = np.maximum(0, ends - rng.integers(0, 3 * max_length, 30))
    assert_batch_matches(Predictor(library, top_k=top_k), held_out, starts, ends)


def test_values_never_seen_match_the_step_loop():
    library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(2))
    library.learn(simulate_arm(ArmConfig(joints=2, trials=300, seed=4)).to_episode())
    steps = simulate_arm(ArmConfig(joints=2, trials=10, seed=5)).to_episode().steps()
    fresh = len(library.vocabulary)
    steps[-2] = (steps[-2][0], (fresh,))  # a value of view 1 never seen
    unknown = np.array([1], np.int32)
    got = Predictor(library).predict_unknown(steps, unknown)
    token = reference(library, steps, 3, unknown)[0]
    assert [library.tokens.symbols(t) if t >= 0 else None for t in token.tolist()] == \
        [v.observations for v in got.views]


def test_a_predictor_follows_the_library_as_it_learns():
    rng = np.random.default_rng(7)
    library = PatternLibrary(max_length=3)
    predictor = Predictor(library)
    episode = random_episode(rng, 200)
    assert predictor.predict(episode.steps()[:5], (100,)).abstained
    library.learn(episode)
    library.learn(random_episode(rng, 200, observations=8))  # new tokens: the dictionaries renew
    assert_batch_matches(predictor, random_episode(rng, 30, observations=8), np.arange(0, 20), np.arange(5, 25))


def test_literal_library_batch_is_its_single_predictions():
    rng = np.random.default_rng(3)
    library = LiteralLibrary(3)
    library.learn(random_episode(rng, 300))
    held_out = random_episode(rng, 40)
    predictor = Predictor(library, top_k=2)
    batch = predictor.predict_batch(held_out, np.arange(0, 30), np.arange(4, 34))
    steps = held_out.steps()
    for i in range(30):
        assert predictor.prediction(batch, i) == predictor.predict(steps[i:i + 4], steps[i + 4][0])
    assert (batch.token >= 0).any()


@pytest.mark.parametrize("starts, ends", [([0, 1], [1]), ([2], [1]), ([-1], [0]), ([0], [40])])
def test_bad_query_bounds_are_refused(starts, ends):
    library = PatternLibrary()
    library.learn(random_episode(np.random.default_rng(0), 50))
    with pytest.raises(ParameterError):
        Predictor(library).predict_batch(random_episode(np.random.default_rng(1), 39), starts, ends)


def test_a_batch_of_one_is_not_overwritten_by_later_calls():
    rng = np.random.default_rng(5)
    library = PatternLibrary(max_length=2)
    library.learn(random_episode(rng, 200))
    predictor = Predictor(library)
    held_out = random_episode(rng, 20)
    batch = predictor.predict_batch(held_out, [0], [4])
    kept = batch.token.copy(), batch.top_p.copy()
    for t in range(1, 15):
        predictor.predict(held_out.steps()[t:t + 3], held_out.steps()[t + 3][0])
    assert batch.token.tolist() == kept[0].tolist() and batch.top_p.tolist() == kept[1].tolist()


def test_the_token_dictionary_holds_only_the_librarys_tokens():
    rng = np.random.default_rng(9)
    library = PatternLibrary(max_length=2)
    library.learn(random_episode(rng, 100))
    predictor = Predictor(library)
    for value in range(1000, 1300):  # values never seen: nothing to remember
        steps = [((), (value,)), ((100,), ())]
        said = predictor.predict_unknown(steps).views[0]
        assert said.length == reference(library, steps, 3)[2][0] <= 1  # only the action matched
    assert len(predictor._token_of) <= len(library.tokens)


def test_a_symbol_both_action_and_observation_is_refused_without_a_vocabulary():
    library = PatternLibrary(max_length=2)
    library.learn(random_episode(np.random.default_rng(2), 100))
    with pytest.raises(ParameterError, match="both as an action and as an observation"):
        Predictor(library).predict([((), (100,))], (100,))


def test_predict_through_the_step_cache_equals_the_general_path(monkeypatch):
    """``predict`` encodes steps through a bounded cache of step codes and a kept address
    table; its answers equal ``predict_unknown``'s (which encodes every step) while the
    library keeps learning (new tokens, a grown tree): steps asked before their values
    were learned and after, as tuples and as lists."""
    import slearn.core.predictor as predictor_module
    rng = np.random.default_rng(5)
    library = PatternLibrary(max_length=3)
    library.learn(random_episode(rng, 50, observations=2))
    predictor = Predictor(library)

    def same_answers(steps):
        for e in range(3, 60):
            history, actions = steps[e - 3:e], steps[e][0]
            general = predictor.predict_unknown(list(history) + [(actions, ())])
            assert predictor.predict(history, actions) == general
            as_lists = [(list(a), list(o)) for a, o in history]
            assert predictor.predict(as_lists, list(actions)) == general

    for round_ in range(4):
        episode = random_episode(rng, 300, observations=3 + 2 * round_)  # new values each round
        same_answers(episode.steps())  # values not learned yet
        library.learn(episode)
        same_answers(episode.steps())
    monkeypatch.setattr(predictor_module, "_STEP_CODES", 8)
    same_answers(random_episode(rng, 300, observations=9).steps())
    assert len(predictor._step_codes) <= 8
    with pytest.raises(ParameterError, match="both as an action and as an observation"):
        predictor.predict([((100,), (1,)), ((101,), (101,))], (102,))


def test_a_query_asked_again_gets_the_same_answer_until_the_library_learns(monkeypatch):
    """``predict`` remembers its answers (a stream's queries repeat): the same query gets the
    same object back, and after the library learned, the answer a new predictor gives.
    Answers are immutable, so sharing them is safe; the memory is bounded."""
    import slearn.core.predictor as predictor_module
    rng = np.random.default_rng(11)
    library = PatternLibrary(max_length=3)
    library.learn(random_episode(rng, 300, observations=3))
    predictor = Predictor(library)
    queries = random_episode(rng, 80, observations=3).steps()
    before = [predictor.predict(queries[e - 3:e], queries[e][0]) for e in range(3, 80)]
    assert all(predictor.predict(queries[e - 3:e], queries[e][0]) is said
               for e, said in zip(range(3, 80), before))
    library.learn(random_episode(rng, 300, observations=3, actions=(100,)))  # no new tokens
    after = [predictor.predict(queries[e - 3:e], queries[e][0]) for e in range(3, 80)]
    fresh = Predictor(library)
    assert after == [fresh.predict(queries[e - 3:e], queries[e][0]) for e in range(3, 80)]
    assert after != before  # the library changed its answers, and the predictor followed
    monkeypatch.setattr(predictor_module, "_ANSWER_CACHE", 8)
    for e in range(3, 80):
        predictor.predict(queries[e - 3:e], (101,))
    assert len(predictor._answers) <= 8 and len(predictor._made) <= 8


def test_answers_are_immutable_and_equal_to_ones_built_field_by_field():
    import dataclasses

    from slearn.core.predictor import Prediction, ViewPrediction, _prediction, _view_prediction
    library = PatternLibrary(max_length=2)
    library.learn(random_episode(np.random.default_rng(4), 200))
    said = Predictor(library).predict([((), (1,)), ((100,), (2,))], (101,))
    view = said.views[0]
    assert isinstance(said.views, tuple) and isinstance(view.ranked, tuple) and view.ranked
    with pytest.raises(dataclasses.FrozenInstanceError):
        view.score = 0.0  # type: ignore[misc]
    built = ViewPrediction(view.view, view.name, view.observations, view.score, view.length, view.kind,
                           view.ranked)
    assert view == built and hash(view) == hash(built) and repr(view) == repr(built)
    assert _view_prediction(*dataclasses.astuple(built)) == built
    assert said == Prediction((built,)) == _prediction((built,)) and hash(said) == hash(Prediction((built,)))


@pytest.mark.parametrize("joints", [1, 3])
def test_a_batch_remembers_answers_by_context_exactly(joints):
    """A batch answers a context it answered before from memory (a direct-mapped table of
    contexts, by view): on a stream whose contexts repeat, with more contexts than slots
    (they collide) and queries of every length of history, each answer is the step loop's."""
    if joints == 1:
        library = PatternLibrary(max_length=4)
        library.learn(random_episode(np.random.default_rng(3), 600, observations=3, actions=(100, 101)))
        piece = random_episode(np.random.default_rng(4), 40, observations=3, actions=(100, 101)).steps()
    else:
        library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(joints))
        library.learn(simulate_arm(ArmConfig(joints=joints, trials=300, seed=3)).to_episode())
        piece = simulate_arm(ArmConfig(joints=joints, trials=20, seed=4)).to_episode().steps()
    steps = piece * 10  # every context comes back
    held_out = Episode.from_steps(steps)
    rng = np.random.default_rng(joints)
    ends = rng.integers(1, len(held_out), 500)
    starts = np.maximum(0, ends - rng.integers(0, 8, 500))
    batch = Predictor(library).predict_batch(held_out, starts, ends)
    for i, (s, e) in enumerate(zip(starts, ends)):
        token, score, length, kind, top, top_p = reference(library, steps[s:e + 1], 3)
        assert batch.token[i].tolist() == token.tolist() and batch.top[i].tolist() == top.tolist()
        assert batch.score[i].tolist() == score.tolist() and batch.top_p[i].tolist() == top_p.tolist()
        assert batch.length[i].tolist() == length.tolist() and batch.kind[i].tolist() == kind.tolist()
    contexts = {tuple(steps[s:e]) + (steps[e][0],) for s, e in zip(starts.tolist(), ends.tolist())}
    assert 100 < len(contexts) < 400  # most queries were asked before; more contexts than the 512 slots hold apart
    assert (batch.token >= 0).mean() > 0.25  # answers, not only abstentions


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.sampled_from([None, 40, 120]))
@example(seed=4_294_967_294, top_k=3, max_patterns=40)  # a fresh expert of length 1 chosen
def test_rankings_remembered_by_the_chosen_context_equal_the_step_loop(seed, top_k, max_patterns):
    """A batch remembers the ranking of a chosen context and expert when that context and the
    shorter ones fill it: queries that end in other longer contexts but choose the same one
    get the step loop's answer. When they do not fill it (a fresh expert ranks its context
    by fresh counts, where outcomes counted before the epoch are missing; few outcomes;
    top_k 4), the longer contexts found rank the rest, and nothing is remembered."""
    rng = np.random.default_rng(seed)
    library = PatternLibrary(max_length=3, max_patterns=max_patterns)
    library.learn(random_episode(rng, 400, observations=4, actions=(100, 101)))
    held_out = Episode.from_steps(random_episode(rng, 30, observations=4, actions=(100, 101)).steps() * 4)
    ends = rng.integers(1, len(held_out), 60)
    starts = np.maximum(0, ends - rng.integers(0, 6, 60))
    assert_batch_matches(Predictor(library, top_k=top_k), held_out, starts, ends)


def test_a_history_longer_than_the_single_querys_buffer_grows_it():
    rng = np.random.default_rng(12)
    library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(2))
    library.learn(simulate_arm(ArmConfig(joints=2, trials=300, seed=6)).to_episode())
    steps = simulate_arm(ArmConfig(joints=2, trials=600, seed=7)).to_episode().steps()
    predictor = Predictor(library)
    for length in (2, 40, 150, 3, 399):  # the buffer starts at 64 codes
        e = int(rng.integers(length, len(steps)))
        history, actions = steps[e - length:e], steps[e][0]
        expected = reference(library, steps[e - length:e + 1], 3)
        said = predictor.predict(history, actions)
        assert [v.observations for v in said.views] == \
            [library.tokens.symbols(t) if t >= 0 else None for t in expected[0].tolist()]
        assert [v.score for v in said.views] == expected[1].tolist()
        assert said == predictor.predict_unknown(list(history) + [(actions, ())])
    assert len(predictor._single.query.flat) >= 4 * 399


def test_long_histories_are_answered_but_not_remembered():
    """A remembered query keeps its steps: only histories of up to _KEY_STEPS steps are
    remembered, so asking with a whole growing history keeps the memory flat."""
    from slearn.core.predictor import _KEY_STEPS
    rng = np.random.default_rng(13)
    library = PatternLibrary(max_length=3)
    library.learn(random_episode(rng, 300))
    steps = random_episode(rng, 400).steps()
    predictor = Predictor(library)
    for e in range(_KEY_STEPS + 1, 400, 7):
        said = predictor.predict(steps[:e], steps[e][0])
        assert said == predictor.predict_unknown(steps[:e] + [(steps[e][0], ())])
    assert predictor._answers == {}
    predictor.predict(steps[:_KEY_STEPS], steps[_KEY_STEPS][0])
    assert len(predictor._answers) == 1


def test_what_a_predictor_remembers_is_bounded_by_views(monkeypatch):
    """An answer of many views is as large as many answers: the bound counts views."""
    import slearn.core.predictor as predictor_module
    monkeypatch.setattr(predictor_module, "_ANSWER_CACHE", 30)
    library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(3))
    library.learn(simulate_arm(ArmConfig(joints=3, trials=300, seed=8)).to_episode())
    steps = simulate_arm(ArmConfig(joints=3, trials=300, seed=9)).to_episode().steps()
    predictor = Predictor(library)
    sizes = set()
    for e in range(4, 300):
        predictor.predict(steps[e - 4:e], steps[e][0])
        sizes.add((len(predictor._answers), len(predictor._made)))
    assert max(a for a, _ in sizes) == 10 and max(m for _, m in sizes) <= 10


def test_memos_stay_within_their_byte_budget(monkeypatch):
    """A memo larger than a core's cache misses on every probe (issue 12): a memo is a power
    of two of slots within ``MEMO_BYTES`` whatever the queries, context length or ranking
    length; a predictor keeps the largest that fits for its single queries and its
    batches; a budget of two slots answers as the step loop does."""
    import slearn.core.queries as queries
    library = PatternLibrary(max_length=3, vocabulary=arm_vocabulary(3))
    library.learn(simulate_arm(ArmConfig(joints=3, trials=300, seed=3)).to_episode())
    for n, top_k in ((1, 3), (5, 3), (100, 1), (10**5, 3), (10**5, 40)):
        slot = sum(a.nbytes for a in queries.new_memo(1, library.max_context, top_k))
        for memo, wanted in ((queries.new_buffers(library, n, top_k).memo, 3 * n),
                             (queries.kept_buffers(library, n, top_k).memo, 10**9)):
            slots = len(memo.depth)
            assert slots & (slots - 1) == 0 and sum(a.nbytes for a in memo) <= queries.MEMO_BYTES
            assert slots >= min(wanted, queries.MEMO_BYTES // (2 * slot))  # the largest power of two within it
    assert len(queries.new_buffers(library, 10**5, 3).memo.depth) < 3 * 10**5
    predictor = Predictor(library)
    predictor.predict_batch(simulate_arm(ArmConfig(joints=3, trials=5, seed=4)).to_episode(), [0], [1])
    for memo in (predictor._single.memo, predictor._batch.memo):
        assert queries.MEMO_BYTES // 2 < sum(a.nbytes for a in memo) <= queries.MEMO_BYTES
    slot = sum(a.nbytes for a in queries.new_memo(1, library.max_context, 3))
    monkeypatch.setattr(queries, "MEMO_BYTES", 3 * slot)  # two slots: contexts collide all the time
    assert len(queries.new_buffers(library, 500, 3).memo.depth) == 2
    held_out = simulate_arm(ArmConfig(joints=3, trials=40, seed=4)).to_episode()
    ends = np.arange(1, len(held_out))
    predictor = Predictor(library)
    assert_batch_matches(predictor, held_out, np.maximum(0, ends - 4), ends)
    assert len(predictor._batch.memo.depth) == len(predictor._single.memo.depth) == 2


def test_batches_share_what_they_remember_until_the_library_learns():
    """A predictor keeps its batches' scratch streams and memo (a batch of a few queries
    cost a millisecond of allocations and addresses before) and encodes only the steps the
    queries read: a batch asked again, or a part of it, answers as the step loop does; after
    the library learned (no new tokens: the dictionaries stay), as a new predictor does."""
    rng = np.random.default_rng(21)
    library = PatternLibrary(max_length=3)
    library.learn(random_episode(rng, 400, observations=3))
    predictor = Predictor(library)
    held_out = random_episode(rng, 120, observations=3)
    ends = np.arange(3, 120)
    before = assert_batch_matches(predictor, held_out, ends - 3, ends)
    assert_batch_matches(predictor, held_out, ends[40:50] - 2, ends[40:50])
    assert_batch_matches(predictor, held_out, ends - 3, ends)
    library.learn(random_episode(rng, 400, observations=3, actions=(100,)))  # no new tokens
    after = assert_batch_matches(predictor, held_out, ends - 3, ends)
    fresh = Predictor(library).predict_batch(held_out, ends - 3, ends)
    assert all(np.array_equal(a, b) for a, b in zip(after, fresh))
    assert not np.array_equal(after.token, before.token) or not np.array_equal(after.score, before.score)


def test_a_slice_of_steps_is_the_episode_of_those_steps():
    episode = random_episode(np.random.default_rng(5), 30)
    steps = episode.steps()
    for start, stop in ((0, 31), (0, 0), (3, 4), (7, 20), (29, 31)):
        part = episode.slice_steps(start, stop)
        assert part.steps() == steps[start:stop] and len(part) == stop - start
        assert np.array_equal(part.symbols, Episode.from_steps(steps[start:stop]).symbols)
