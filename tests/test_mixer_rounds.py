"""The experts' weights age: each view counts its rounds, and every log-weight halves when
they reach a power of two (:mod:`slearn.core.mixer`), so the early mistakes of a context
whose counts were thin weigh less than its later record."""

from __future__ import annotations

import numba
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from slearn import SequenceModel
from slearn.core.mixer import FREQUENT, N_KINDS, RECENT, new_mixer, update
from slearn.errors import LibraryFormatError
from slearn.io.library_file import load_library
from slearn.jobs.merge import merge_libraries


@numba.njit
def rounds_of_updates(weight, rounds, cand, n, truth, times):
    for _ in range(times):
        update(weight, rounds, 0, cand, n, truth)


def cands(n: int, said: list[int]) -> np.ndarray:
    """Every expert of contexts ``1..n`` awake; context ``k``'s experts say ``said[k - 1]``."""
    cand = np.full((7, N_KINDS), -1, np.int32)
    for k in range(1, n + 1):
        cand[k, FREQUENT] = cand[k, RECENT] = said[k - 1]
    return cand


def test_log_weights_halve_when_the_rounds_reach_a_power_of_two():
    mixer = new_mixer(1, 6)
    w = mixer.weight
    w[0, :, :2] = np.exp(-np.arange(12).reshape(6, 2) / 4)  # a leader at 1, the others below it
    start = np.log(w[0, :, :2]).copy()
    right = cands(6, [5] * 6)  # every expert right: the Hedge step changes nothing
    rounds_of_updates(w, mixer.rounds, right, 6, 5, 3)  # rounds 1, 2 (a power of two: halve), 3
    assert mixer.rounds[0] == 3
    np.testing.assert_allclose(np.log(w[0, :, :2]), start / 2, rtol=1e-12)
    rounds_of_updates(w, mixer.rounds, right, 6, 5, 1)  # round 4
    np.testing.assert_allclose(np.log(w[0, :, :2]), start / 4, rtol=1e-12)
    rounds_of_updates(w, mixer.rounds, right, 6, 5, 3)  # rounds 5-7: no power of two
    np.testing.assert_allclose(np.log(w[0, :, :2]), start / 4, rtol=1e-12)
    order = np.argsort(-start.ravel(), kind="stable")
    assert np.array_equal(np.argsort(-np.log(w[0, :, :2]).ravel(), kind="stable"), order)  # the ranking stays
    assert not w[0, :, 2].any()  # sleeping FRESH experts stay asleep


def test_a_round_without_an_awake_expert_does_not_count():
    mixer = new_mixer(1, 6)
    before = mixer.weight.copy()
    rounds_of_updates(mixer.weight, mixer.rounds, cands(0, []), 0, 5, 10)
    assert mixer.rounds[0] == 0 and np.array_equal(mixer.weight, before)


def test_an_expert_that_learns_overtakes_an_early_leader():
    # order 1 is right 7 rounds in 10 from the start; order 2 is wrong for its first 40
    # rounds (its contexts are new), then right 8 in 10: 28 mistakes behind after 40
    # rounds, 26 made up by round 300. Weighing every mistake alike, order 2 still trails
    # (by 0.2 nats); with the old mistakes halved at rounds 64, 128 and 256 it leads
    mixer = new_mixer(1, 2)
    w = mixer.weight
    for t in range(300):
        cand = np.full((3, N_KINDS), -1, np.int32)
        cand[1, FREQUENT] = 1 if t % 10 < 7 else 2
        cand[2, FREQUENT] = 1 if t >= 40 and t % 10 < 8 else 3
        rounds_of_updates(w, mixer.rounds, cand, 2, 1, 1)
    assert w[0, 1, FREQUENT] > w[0, 0, FREQUENT]
    assert mixer.rounds[0] == 300


def stream_model(seed: int, n: int = 3000) -> SequenceModel:
    model = SequenceModel()
    items = np.random.default_rng(seed).integers(0, 5, n).tolist()
    model.learn(items)
    return model


def test_rounds_are_saved_and_a_merge_takes_them_with_the_weights(tmp_path):
    a, b = stream_model(1), stream_model(2, 1000)
    assert a.library.mixer.rounds[0] > 2000  # about one round per item
    a.save(tmp_path / "a.parquet")
    b.save(tmp_path / "b.parquet")
    la, lb = load_library(tmp_path / "a.parquet"), load_library(tmp_path / "b.parquet")
    assert np.array_equal(la.library.mixer.rounds, a.library.mixer.rounds)
    merged = merge_libraries(la, lb).library.mixer
    assert np.array_equal(merged.weight, lb.library.mixer.weight)
    assert np.array_equal(merged.rounds, lb.library.mixer.rounds)  # the age of the weights taken


def test_a_merge_takes_the_weights_of_a_view_the_later_library_predicted_in(tmp_path):
    # b predicted once, and was right: its weights are still the untrained ones, yet they
    # are the latest (a merge that compared the weights with untrained ones kept a's)
    a, b = stream_model(4), SequenceModel()
    b.learn([0, 0, 0])
    assert b.library.mixer.rounds.tolist() == [1]
    a.save(tmp_path / "a.parquet")
    b.save(tmp_path / "b.parquet")
    merged = merge_libraries(load_library(tmp_path / "a.parquet"), load_library(tmp_path / "b.parquet"))
    assert merged.library.mixer.rounds.tolist() == [1]
    assert np.array_equal(merged.library.mixer.weight, b.library.mixer.weight)


def test_negative_rounds_are_refused_naming_the_file(tmp_path):
    stream_model(3).save(tmp_path / "lib.parquet")
    source = pq.ParquetFile(tmp_path / "lib.parquet")
    with pq.ParquetWriter(tmp_path / "bad.parquet", source.schema_arrow) as out:
        for group in range(source.num_row_groups):
            table = source.read_row_group(group)
            index = table.schema.get_field_index("view_rounds")
            column = [None if r is None else -r - 1 for r in table.column(index).to_pylist()]
            out.write_table(table.set_column(index, table.schema.field(index),
                                             pa.array(column, pa.int64())))
    with pytest.raises(LibraryFormatError, match=r"bad\.parquet: a view's rounds are negative"):
        load_library(tmp_path / "bad.parquet")


def test_a_missing_contexts_expert_answers_for_what_its_shorter_twin_says():
    # Contexts 1..2 found, 3..6 missing: experts 3..6 back off to context 2 and say what it
    # says. When it is wrong they lose as it does (a heavy long expert cannot lend its
    # weight to a short twin without answering for it); a kind with no twin found sleeps.
    mixer = new_mixer(1, 6)
    w = mixer.weight
    w[0, :, FREQUENT] = [0.2, 0.3, 1.0, 0.9, 0.8, 0.7]
    cand = np.full((7, N_KINDS), -1, np.int32)
    cand[1, FREQUENT], cand[2, FREQUENT] = 4, 5  # context 2 says 5, context 1 says 4
    before = w.copy()
    rounds_of_updates(w, mixer.rounds, cand, 2, 4, 1)  # the truth is 4
    lost = np.log(w[0, :, FREQUENT] / before[0, :, FREQUENT])
    assert lost[0] > lost[1] + 0.05  # context 1 was right, context 2 wrong
    np.testing.assert_allclose(lost[1:], lost[1], atol=1e-12)  # 3..6 said what 2 said
    assert not w[0, :, 2].any()  # no FRESH expert was awake: they stay asleep
