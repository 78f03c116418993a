"""bench/bench_predict.py measures what it says: the predictor's answers (one call at a
time, new predictors, distinct queries) are the batch's, the dict model is a model of the
same order, and the share of repeated queries it prints is the stream's."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_predict  # noqa: E402

from slearn.core.library import PatternLibrary  # noqa: E402
from slearn.core.predictor import Predictor  # noqa: E402
from slearn.recorders.pointer import PointerConfig, simulate  # noqa: E402


def test_the_bench_prints_every_figure_with_its_anchor():
    result = bench_predict.measure("delay", train=600, queries=300, repeat=1, text_chars=2000, step_train=1000)
    assert 0.0 < result["repeated_share"] < 1.0
    for rate in ("predict_per_s", "predict_new_per_s", "dict_model_per_s", "dict_model_new_per_s",
                 "batch_per_s", "replay_core_per_s"):
        assert result[rate] > 0
    assert 0.3 < result["batch_accuracy"] <= 1.0 and 0.3 < result["dict_model_accuracy"] <= 1.0
    text = bench_predict.render(result)
    assert "every query new" in text and "queries asked before" in text and "SequenceModel.predict_many" in text
    assert result["step_first_per_s"] > 0 and result["step_again_per_s"] > 0 and result["step_dict_per_s"] > 0
    assert 0.3 < result["step_accuracy"] <= 1.0 and "predict_step" in text


def test_the_step_dict_model_predicts_a_deterministic_walk():
    """The step form's anchor is a model of the same order: on a walk it has seen, the next
    observations follow from the last positions and the commands."""
    steps = bench_predict.joint_walk(2, 3000, 0)
    naive = bench_predict.StepDictModel(6)
    naive.learn(steps)
    held = bench_predict.joint_walk(2, 200, 1)
    said = [(naive.predict(held[i - 6:i], held[i][0]), held[i][1]) for i in range(6, len(held))]
    assert all(guess == truth for guess, truth in said if guess)  # a context seen says the walk
    assert sum(bool(guess) for guess, _ in said) > 0.8 * len(said)
    assert naive.predict([], {"j0": 1, "j1": 0}) == {}


def test_a_new_predictor_answers_as_the_batch_does():
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("delay", trials=500, seed=1)).to_episode())
    held_out = simulate(PointerConfig("delay", trials=100, seed=2)).to_episode()
    steps, h = held_out.steps(), library.max_length
    calls = [(steps[e - h:e], steps[e][0]) for e in range(h, len(held_out))]
    predictor = bench_predict.new_predictor(library, calls[0])
    assert predictor._answers == {}  # nothing remembered before the timed queries
    said = bench_predict.queries_of(predictor, calls)()
    batch = Predictor(library).predict_batch(held_out, [e - h for e in range(h, len(held_out))],
                                             list(range(h, len(held_out))))
    assert said == [predictor.prediction(batch, i) for i in range(len(calls))]


def test_the_sequence_api_figures_come_with_their_anchor():
    result = bench_predict.measure_sequences(chars=3000, repeat=1)
    assert result["queries"] == 3000 - int(3000 * 0.8) - 5
    for rate in ("sequence_predict_per_s", "sequence_many_per_s", "item_dict_per_s"):
        assert result[rate] > 0
    # an order-2 source: both models learn it; neither can beat its 70 % ceiling by much
    assert 0.5 < result["sequence_accuracy"] < 0.8 and 0.5 < result["item_dict_accuracy"] < 0.8
