"""Rankings as probabilities: PPM's method C from the prediction's context down, checked
against counts made here from the training sequences (every occurrence of a context is
counted, so the library's counts are these)."""

from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slearn import SequenceModel
from slearn.core.predictor import Predictor

MAX_LENGTH = 3
ALL = 50  # a ranking long enough for every item


def counts_after(sequences: list[str], context: str) -> Counter:
    """What followed ``context`` in ``sequences``, every occurrence."""
    out: Counter = Counter()
    n = len(context)
    for seq in sequences:
        for i in range(n, len(seq)):
            if seq[i - n:i] == context:
                out[seq[i]] += 1
    return out


def expected_ranking(sequences: list[str], history: str, length: int) -> dict:
    """Item -> probability: the context of ``length`` items, then shorter ones, each giving
    the mass left times count / (total + distinct) to items not ranked yet."""
    out: dict = {}
    mass = 1.0
    for k in range(length, 0, -1):
        counts = counts_after(sequences, history[-k:])
        total, distinct = sum(counts.values()), len(counts)
        if not total:
            continue
        for item, c in counts.items():
            out.setdefault(item, mass * c / (total + distinct))
        mass *= distinct / (total + distinct)
    return out


def ranking(model: SequenceModel, history: str):
    steps = [((), (model.vocabulary.get_symbol("item", c),)) for c in history]
    view = Predictor(model.library, top_k=ALL).predict(steps, ()).views[0]
    return view, [(model.vocabulary.name(s[0])[1], p) for s, p in view.ranked]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.text("abc", min_size=2, max_size=40), min_size=1, max_size=4),
       st.lists(st.text("abc", min_size=MAX_LENGTH, max_size=MAX_LENGTH), min_size=1, max_size=8))
def test_a_ranking_is_ppm_c_from_the_chosen_context_down_and_sums_to_at_most_one(sequences, histories):
    model = SequenceModel(max_length=MAX_LENGTH)
    for seq in sequences:
        model.learn(seq)
    for history in histories:
        if any(model.vocabulary.get_symbol("item", c) is None for c in history):
            continue
        view, ranked = ranking(model, history)
        if view.abstained or view.kind == "hold":  # (a plain sequence holds no reading)
            assert (ranked == []) == view.abstained and model.predict(history) is None
            assert model.rank(history, k=3) == []
            continue
        assert ranked[0][0] == model.predict(history) == model.rank(history, k=1)[0][0]
        assert [p for _, p in ranked[1:]] == sorted((p for _, p in ranked[1:]), reverse=True)
        assert sum(p for _, p in ranked) <= 1 + 1e-12
        assert len({item for item, _ in ranked}) == len(ranked)
        assert [item for item, _ in model.rank(history, k=3)] == [item for item, _ in ranked[:3]]
        if view.kind == "persist":  # the last item again, q on it and 1 - q on the context's ranking
            expected = expected_ranking(sequences, history, view.length)
            last = history[-1]
            rest = (1 - ranked[0][1]) / (1 - expected.get(last, 0.0))  # 1 - q, from p(last) = q + (1 - q) p
            assert ranked[0][0] == last and 0 < rest < 0.5
            assert dict(ranked[1:]) == pytest.approx({i: rest * p for i, p in expected.items() if i != last},
                                                     rel=1e-9)
        elif view.kind != "fresh":  # (fresh experts count since the view's last alarm)
            expected = expected_ranking(sequences, history, view.length)
            assert dict(ranked) == pytest.approx(expected, rel=1e-12)


def test_a_context_passes_on_what_it_never_saw():
    # "yx" was followed by a 8 times; "x" by a 8 times and b 16 times: after "yx", a gets
    # 8/9 and the escape 1/9 goes to "x", which gives b 1/9 * 16/26 (a is ranked already)
    model = SequenceModel(max_length=2)
    for seq in ["yxa", "zxb", "zxb"] * 8:
        model.learn(seq)
    view, ranked = ranking(model, "yx")
    assert view.length == 2
    assert ranked == [("a", pytest.approx(8 / 9)), ("b", pytest.approx(1 / 9 * 16 / 26))]


def test_the_recent_experts_prediction_leads_its_ranking():
    # after "x", a 5 times, then b 3 times: the latest outcome was right where the counts
    # lagged, so it speaks (b); the ranking still gives each item its probability by the
    # counts: b 3/10, a 5/10
    model = SequenceModel()
    for seq in ["xa"] * 5 + ["xb"] * 3:
        model.learn(seq)
    assert model.rank("x", k=3) == [("b", pytest.approx(0.3)), ("a", pytest.approx(0.5))]
    assert model.predict("x") == "b"
    tied = SequenceModel()  # experts that never disagreed where it mattered: the counts speak
    for seq in ["xa", "xa", "xb"]:
        tied.learn(seq)
    assert tied.rank("x", k=3) == [("a", pytest.approx(0.4)), ("b", pytest.approx(0.2))]


def test_literal_rankings_are_shares_of_the_longest_match():
    model = SequenceModel(scoring="literal")
    for _ in range(5):
        model.learn("abcabcabd")
    ranked = model.rank("ab", k=3)
    assert [item for item, _ in ranked] == ["c", "d"] and ranked[0][1] > ranked[1][1] > 0
    assert sum(p for _, p in ranked) == pytest.approx(1.0)
