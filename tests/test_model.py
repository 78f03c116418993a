"""SequenceModel: the small Python API, its two forms, files and bad input."""

import numpy as np
import pytest

from slearn import SequenceModel
from slearn.errors import ParameterError, SlearnError

TEXT = "the cat sat on the mat. the dog sat on the log. " * 30


def test_learns_a_text_and_predicts_the_next_character():
    model = SequenceModel()
    model.learn(TEXT)
    assert model.predict("the ca") == "t"
    assert model.predict("the do") == "g"
    ranked = model.rank("on the ", k=3)
    assert len(ranked) == 3 and {"m", "l"} & {item for item, _ in ranked}
    assert all(0 < p <= 1 for _, p in ranked)
    assert model.predict_many(["the ca", "the do"]) == ["t", "g"]


def test_any_hashable_items():
    model = SequenceModel(max_length=2)
    for _ in range(5):
        model.learn([("a", 1), ("b", 2), ("c", 3), ("a", 1), ("b", 2)])
    assert model.predict([("a", 1)]) == ("b", 2)


def test_unseen_items_and_empty_histories_abstain():
    model = SequenceModel()
    assert model.predict("abc") is None  # nothing learned yet
    model.learn("abcabcabc")
    assert model.predict("") is None
    assert model.predict("xyz") is None
    assert model.rank("zzz") == []


def test_a_history_longer_than_any_context_uses_its_tail():
    model = SequenceModel(max_length=3)
    model.learn("abcdabcdabcd")
    assert model.predict("zzzzzzzzzzzzzzzzzzzzab") == "c"


def test_an_empty_sequence_learns_nothing():
    model = SequenceModel()
    model.learn([])
    assert model.library is None


def test_unhashable_items_are_refused_with_a_clear_error():
    model = SequenceModel()
    with pytest.raises(ParameterError, match="not hashable"):
        model.learn([[1, 2], [3]])
    with pytest.raises(SlearnError):
        model.learn([{"a": 1}])


def test_save_and_load_give_the_same_predictions(tmp_path):
    model = SequenceModel()
    model.learn(TEXT)
    path = tmp_path / "text.parquet"
    model.save(path)
    again = SequenceModel.load(path)
    for history in ("the ca", "on the ", "sat o", "q"):
        assert again.rank(history) == model.rank(history)
    with pytest.raises(SlearnError, match="already exists"):
        model.save(path)


def test_the_step_form_predicts_each_channel():
    model = SequenceModel()
    for _ in range(5):
        model.learn_steps([({}, {"pos": 3, "light": "off"}), ({"cmd": "R"}, {"pos": 4, "light": "off"}),
                           ({"cmd": "R"}, {"pos": 5, "light": "on"}), ({"cmd": "L"}, {"pos": 4, "light": "off"})])
    history = [({}, {"pos": 3, "light": "off"}), ({"cmd": "R"}, {"pos": 4, "light": "off"})]
    assert model.predict_step(history, {"cmd": "R"}) == {"pos": 5, "light": "on"}
    ranked = model.rank_step(history, {"cmd": "R"}, k=2)
    assert set(ranked) == {"pos", "light"}


def test_forms_do_not_mix():
    model = SequenceModel()
    model.learn("abc")
    with pytest.raises(ParameterError, match="matching methods"):
        model.learn_steps([({}, {"x": 1})])


def test_bad_parameters():
    with pytest.raises(ParameterError, match="scoring"):
        SequenceModel(scoring="best")
    with pytest.raises(ParameterError, match="max_length"):
        SequenceModel(max_length=0).learn("abc")


def test_the_literal_scoring_is_available():
    model = SequenceModel(scoring="literal", max_length=5)
    model.learn(TEXT)
    assert model.predict("the ca") == "t"


@pytest.mark.parametrize("scoring", ["adaptive", "literal"])
def test_predict_many_answers_what_predict_answers(scoring):
    """One batched call, the same answers as one call per history: histories shorter and
    longer than a context, empty, with items never seen, and a model still learning."""
    import random

    rng = random.Random(7)
    model = SequenceModel(max_length=3, scoring=scoring)
    assert model.predict_many(["ab"]) == [None]  # nothing learned yet
    alphabet = "abcde"
    for round_ in range(3):
        for _ in range(20):
            model.learn([rng.choice(alphabet[: 3 + round_]) for _ in range(rng.randint(1, 30))])
        histories = [[rng.choice(alphabet + "xz") for _ in range(rng.randint(0, 8))] for _ in range(200)]
        histories += [[], ["x"], ["z", "z"], list(alphabet) * 3]
        assert model.predict_many(histories) == [model.predict(h) for h in histories]
        assert model.predict_many(iter(histories[:5])) == [model.predict(h) for h in histories[:5]]
    assert model.predict_many([]) == []
    with pytest.raises(ParameterError, match="not hashable"):
        model.predict_many([["a", ["b"]]])


@pytest.mark.parametrize("scoring", ["adaptive", "literal"])
def test_rank_of_known_items_equals_the_general_path(scoring, monkeypatch):
    """Histories of items seen before go the predictor's path for steps it may have cached;
    they rank what the general path (a symbol per item looked up, every step encoded)
    ranks, for every k, and an unhashable item is refused on either path."""
    import random

    rng = random.Random(3)
    model = SequenceModel(max_length=3, scoring=scoring)
    for _ in range(30):
        model.learn([rng.choice("abcd") for _ in range(rng.randint(1, 25))])
    histories = [[rng.choice("abcd") for _ in range(rng.randint(0, 7))] for _ in range(150)]
    fast = {k: [model.rank(h, k) for h in histories] for k in (1, 3)}
    assert any(fast[3])
    for ranked in fast[3]:
        ranked.append(("mutated", 1.0))  # a caller's list: answers asked again are not changed
    assert {k: [model.rank(h, k) for h in histories] for k in (1, 3)} == {1: fast[1], 3: [r[:-1] for r in fast[3]]}
    fast[3] = [r[:-1] for r in fast[3]]
    monkeypatch.setattr(SequenceModel, "_known_steps", lambda self, items: None)
    assert {k: [model.rank(h, k) for h in histories] for k in (1, 3)} == fast
    monkeypatch.undo()
    model.learn(list("dcba" * 40))  # the model learns: remembered rankings are not reused
    again = [model.rank(h, 3) for h in histories]
    monkeypatch.setattr(SequenceModel, "_known_steps", lambda self, items: None)
    assert [model.rank(h, 3) for h in histories] == again != fast[3]
    monkeypatch.undo()
    with pytest.raises(ParameterError, match="not hashable"):
        model.predict(["a", ["b"]])


@pytest.mark.parametrize("scoring", ["adaptive", "literal"])
def test_predict_answers_the_top_of_rank(scoring):
    """predict's own path for items seen before answers the first item rank(k=1) answers:
    strings, lists and tuples, histories longer than a context, empty and with unseen
    items, calls mixed with rank(k=3) (another predictor), and after more learning."""
    import random

    rng = random.Random(11)
    model = SequenceModel(max_length=3, scoring=scoring)
    assert model.predict("ab") is None  # nothing learned yet
    for round_ in range(2):
        for _ in range(25):
            model.learn([rng.choice("abcde"[: 4 + round_]) for _ in range(rng.randint(1, 30))])
        histories = ["".join(rng.choice("abcdex") for _ in range(rng.randint(0, 7))) for _ in range(150)]
        histories += [list(h) for h in histories[:30]] + [tuple(h) for h in histories[30:60]]
        said = []
        for i, history in enumerate(histories):
            said.append(model.predict(history))
            if i % 7 == 0:
                model.rank(history, k=3)
        top = [ranked[0][0] if ranked else None for ranked in (model.rank(h, k=1) for h in histories)]
        assert said == top
        assert any(x is not None for x in said) and None in said


@pytest.mark.parametrize("scoring", ["adaptive", "literal"])
@pytest.mark.parametrize("max_patterns", [None, 40])
def test_kept_predictors_follow_learning(scoring, max_patterns):
    """A model keeps one predictor per k across calls and learning (forgetting too); its
    answers after each sequence learned equal those of a twin that asks through new
    predictors only."""
    import random

    rng = random.Random(5)
    options = {"max_length": 3, "scoring": scoring, "max_patterns": max_patterns}
    model, twin = SequenceModel(**options), SequenceModel(**options)
    histories = ["".join(rng.choice("abcdx") for _ in range(rng.randint(0, 5))) for _ in range(40)]
    for _ in range(12):
        sequence = [rng.choice("abcd") for _ in range(rng.randint(1, 20))]
        model.learn(sequence)
        twin.learn(sequence)
        for history in histories:
            twin._predictors = {}
            expected = (twin.predict(history), twin.rank(history, k=2))
            twin._predictors = {}
            assert (model.predict(history), model.rank(history, k=2)) == (expected[0], expected[1])
            assert model.rank(history, k=1) == twin.rank(history, k=1)
    assert set(model._predictors) == {1, 2}


def test_steps_seen_before_rank_what_the_general_path_ranks(monkeypatch):
    """predict_step and rank_step take the predictor's path when every step is a pair of
    dicts of known values; they answer what the general path answers, for every k, and
    other steps (values never seen, lists, other mappings, channel order) still work."""
    import random
    from types import MappingProxyType

    rng = random.Random(9)
    model = SequenceModel(max_length=3)

    def step(cmd, pos):
        return ({"a": cmd, "b": -cmd}, {"p": pos, "q": pos % 3})

    for _ in range(15):
        pos, steps = 0, []
        for _ in range(rng.randint(1, 30)):
            cmd = rng.choice((-1, 1))
            pos = (pos + cmd) % 7
            steps.append(step(cmd, pos))
        model.learn_steps(steps)
    histories = [[step(rng.choice((-1, 1)), rng.randint(0, 7)) for _ in range(rng.randint(0, 5))]
                 for _ in range(120)]
    histories += [[({"b": 1, "a": -1}, {"q": 1, "p": 4})], [[{"a": 1, "b": -1}, {"p": 2, "q": 2}]],
                  [(MappingProxyType({"a": 1, "b": -1}), {"p": 2, "q": 2})], (step(1, 3), step(1, 4))]
    actions = [rng.choice(({"a": 1, "b": -1}, {"a": -1, "b": 1}, {"a": 5, "b": 1})) for _ in histories]
    fast = [(model.predict_step(h, a), model.rank_step(h, a, k=1), model.rank_step(h, a, k=3))
            for h, a in zip(histories, actions)]
    assert sum(bool(said) for said, _, _ in fast) > 60
    assert sum(model._known_step_query(h, a, 3) is not None for h, a in zip(histories, actions)) > 60
    fast[0][2].setdefault("p", []).append(("mutated", 1.0))  # a caller's lists: not the model's
    monkeypatch.setattr(SequenceModel, "_known_step_query", lambda self, history, actions, k: None)
    general = [(model.predict_step(h, a), model.rank_step(h, a, k=1), model.rank_step(h, a, k=3))
               for h, a in zip(histories, actions)]
    monkeypatch.undo()
    fast[0][2]["p"].pop()
    assert fast == general
    assert model.rank_step(histories[0], actions[0], k=3) == general[0][2]


def test_bad_containers_channels_and_k_are_refused_in_one_line():
    """Issue 11's bad input, past single items: what is not a sequence, a step or a mapping,
    a channel the model never learned (or learned in the other role), a k that is not a
    count: one line naming what was expected, never a Python traceback of the internals."""
    model = SequenceModel()
    items = [(lambda: model.learn(None), "a sequence of items must be iterable, not NoneType"),
             (lambda: model.learn(5), "must be iterable, not int")]
    for call, message in items:
        with pytest.raises(ParameterError, match=message):
            call()
    model.learn("abcabc")
    steps = SequenceModel()
    steps.learn_steps([({"cmd": "R"}, {"pos": 1}), ({"cmd": "L"}, {"pos": 2})] * 5)
    cases = [(lambda: model.predict(None), "a history of items must be iterable"),
             (lambda: model.rank("ab", k=True), "k must be an integer in 1..1000, not True"),
             (lambda: model.rank("ab", k=0), "not 0"),
             (lambda: model.predict_many(None), "histories must be iterable"),
             (lambda: model.predict_many(["ab", 5]), "a history of items must be iterable, not int"),
             (lambda: model.predict({"a", "b"}), "a history of items must be ordered .a list, tuple, str or "
              "iterator., not a set"),
             (lambda: model.rank({"a": 1, "b": 2}), "a history of items must be ordered .* not a dict"),
             (lambda: model.predict_many({"ab", "ba"}), "histories must be ordered .* not a set"),
             (lambda: model.learn(frozenset("ab")), "a sequence of items must be ordered .* not a frozenset"),
             (lambda: steps.predict_step({({}, {"pos": 1}).__repr__()}, {"cmd": "R"}),
              "a history of steps must be ordered .* not a set"),
             (lambda: steps.learn_steps(None), "steps must be iterable"),
             (lambda: steps.predict_step(None, {"cmd": "R"}), "a history of steps must be iterable"),
             (lambda: steps.predict_step([5], {"cmd": "R"}), "a step is .actions, observations."),
             (lambda: steps.predict_step([({}, {"pos": 1})], None), "actions must be a mapping"),
             (lambda: steps.predict_step([({}, {"pso": 1})], {"cmd": "R"}),
              "observation channel 'pso' was never learned .the model's observation channels: 'pos'."),
             (lambda: steps.predict_step([({}, {"pos": 1})], {"cdm": "R"}), "action channel 'cdm' was never learned"),
             (lambda: steps.predict_step([({}, {"cmd": "R"})], {"cmd": "R"}),
              "channel 'cmd' was learned as an action channel, not as an observation channel"),
             (lambda: steps.rank_step([({}, {"pos": 1})], {"cmd": "R"}, k=2.0), "k must be an integer"),
             (lambda: steps.predict_step([({}, {"pos": [1]})], {"cmd": "R"}), "pos value .1. is not hashable"),
             (lambda: steps.rank_step([({}, {"pos": 1})], {"cmd": ["R"]}), "cmd value .'R'. is not hashable"),
             (lambda: SequenceModel(max_length="6"), "max_length must be an integer"),
             (lambda: SequenceModel(max_patterns=3), "max_patterns must be an integer")]
    for call, message in cases:
        with pytest.raises(ParameterError, match=message) as raised:
            call()
        assert "\n" not in str(raised.value)
    for call, methods in ((lambda: steps.predict("ab"), "learn_steps, predict_step and rank_step"),
                          (lambda: steps.predict_many(["ab"]), "learn_steps, predict_step and rank_step"),
                          (lambda: model.predict_step([], {}), "learn, predict, rank and predict_many")):
        with pytest.raises(ParameterError, match=f"use {methods} \\(the matching methods\\)"):
            call()
    assert steps.predict_step([({}, {"pos": 2})], {"cmd": "R"}) == {"pos": 1}
    assert steps.predict_step([({}, {"pos": 99})], {"cmd": "L"}) == {"pos": 2}  # a value never seen is no error


def test_a_nan_to_learn_is_refused_and_leaves_the_model_as_it_was():
    model = SequenceModel()
    model.learn([1.0, 2.0, 1.0, 2.0])
    for bad in ([1.0, float("nan")], list(np.array([2.0, np.nan])), [(1, float("nan"))]):
        with pytest.raises(ParameterError, match="NaN, which never equals itself") as raised:
            model.learn(bad)
        assert "\n" not in str(raised.value)
    assert len(model.vocabulary) == 2 and model.library.clock == 4
    assert model.predict([float("nan")]) is None  # never learned: unseen
    assert model.predict([1.0]) == 2.0
    steps = SequenceModel()
    with pytest.raises(ParameterError, match="pos value nan"):
        steps.learn_steps([({"cmd": "R"}, {"pos": 1}), ({"cmd": "R"}, {"pos": float("nan")})])
    assert steps.library is None and len(steps.vocabulary) == 0


def test_the_order_of_a_steps_keys_does_not_matter():
    import random
    rng = random.Random(0)
    pairs = [(rng.randint(0, 1), rng.randint(0, 1)) for _ in range(200)]
    ordered, shuffled = SequenceModel(), SequenceModel()
    ordered.learn_steps([({"a": a, "b": b}, {"pos": a + 2 * b, "lit": a}) for a, b in pairs])
    shuffled.learn_steps([(({"a": a, "b": b} if i % 2 else {"b": b, "a": a}),
                           ({"pos": a + 2 * b, "lit": a} if i % 3 else {"lit": a, "pos": a + 2 * b}))
                          for i, (a, b) in enumerate(pairs)])
    assert len(shuffled.library.tokens) == len(ordered.library.tokens)
    history = [({}, {"pos": 0, "lit": 0})]
    for a, b in [(0, 0), (0, 1), (1, 0), (1, 1)]:
        answers = []
        for model in (ordered, shuffled):
            for actions in ({"a": a, "b": b}, {"b": b, "a": a}):
                answers.append(model.predict_step(history, actions))
                answers.append(model.predict_step([({}, {"lit": 0, "pos": 0})], actions))
                answers.append(model.rank_step([({"b": 0, "a": 0}, {"lit": 0, "pos": 0})], actions, k=2))
        assert answers[0] == {"pos": a + 2 * b, "lit": a}
        assert all(x == answers[0] for x in answers[0::3]) and all(x == answers[1] for x in answers[1::3])
        assert all(x == answers[2] for x in answers[2::3])


def test_literal_steps_of_several_channels_are_predicted_per_channel():
    model = SequenceModel(scoring="literal")
    episode = [({"c": i % 2}, {"o": i % 3, "p": (i + 1) % 3}) for i in range(60)]
    for _ in range(5):
        model.learn_steps(episode)
    history = episode[:5]
    truth = {"o": 5 % 3, "p": 6 % 3}
    assert model.predict_step(history, {"c": 1}) == truth
    ranked = model.rank_step(history, {"c": 1}, k=2)
    assert set(ranked) == {"o", "p"} and {c: r[0][0] for c, r in ranked.items()} == truth
    assert all(0 < p <= 1 for r in ranked.values() for _, p in r)


def test_an_item_that_only_ended_sequences_has_nothing_after_it():
    model = SequenceModel()
    model.learn("ab")
    assert model.predict("b") is None and model.rank("b") == [] and model.predict_many(["b", "a"]) == [None, "b"]
    steps = SequenceModel()  # a step's channel is sampled and held: it predicts its reading again
    steps.learn_steps([({}, {"pos": 1}), ({}, {"pos": 2})])
    assert steps.predict_step([({}, {"pos": 2})], {}) == {"pos": 2}


def test_a_learn_call_that_raises_leaves_the_model_as_it_was(tmp_path):
    a, b = SequenceModel(), SequenceModel()
    a.learn("abab")
    b.learn("abab")
    with pytest.raises(ParameterError, match="not hashable"):
        b.learn(["a", "q", "r", ["x"]])
    with pytest.raises(ParameterError):
        b.learn_steps([({}, {"item2": 1}), ({}, {"o": [1]})])
    assert list(b.vocabulary.items()) == list(a.vocabulary.items()) and b.vocabulary.roles == a.vocabulary.roles
    a.save(tmp_path / "a.parquet")
    b.save(tmp_path / "b.parquet")
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()
    fresh = SequenceModel()
    with pytest.raises(ParameterError):
        fresh.learn([[1]])
    fresh.learn([])
    fresh.learn_steps([({}, {"o": 1}), ({}, {"o": 2})])  # neither fixed the form
    assert fresh.predict_step([({}, {"o": 1})], {}) == {"o": 2}


def test_values_a_file_stores_round_trip_and_others_are_refused_in_one_line(tmp_path):
    import numpy as np

    from slearn.errors import DataWarning
    items = ["a", None, "a", None, (np.int64(1), None, "x"), 2.5, True, "a"]
    model = SequenceModel()
    model.learn(items)
    model.save(tmp_path / "m.parquet")
    again = SequenceModel.load(tmp_path / "m.parquet")
    for history in (["a"], [None], [(1, None, "x")], [2.5], [True]):
        assert again.rank(history) == model.rank(history)
    for odd in (frozenset([1]), "\ud800", b"bytes", 1j):
        kept = SequenceModel()
        with pytest.warns(DataWarning, match="cannot be saved in a library file"):
            kept.learn(["a", odd, "a", odd])
        assert kept.predict(["a"]) == odd  # it works in memory
        with pytest.raises(SlearnError, match=r"cannot store value .* map the values to these") as err:
            kept.save(tmp_path / "odd.parquet")
        assert "\n" not in str(err.value) and not (tmp_path / "odd.parquet").exists()


@pytest.mark.parametrize("path", [None, 123, b"m.parquet"])
def test_a_path_that_is_not_text_is_refused_in_one_line(path):
    model = SequenceModel()
    model.learn("abab")
    with pytest.raises(ParameterError, match="path must be a str or an os.PathLike"):
        model.save(path)
    with pytest.raises(ParameterError, match="path must be a str or an os.PathLike"):
        SequenceModel.load(path)
