"""The persistence specialist (:mod:`slearn.core.mixer`): per context length, the view's last
reading again against the answer of that length, as two experts of their own Hedge."""

from __future__ import annotations

import numba
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from test_predictor_batch import assert_batch_matches

from slearn import SequenceModel
from slearn.core.library import PatternLibrary
from slearn.core.mixer import BETA, SPREAD, new_mixer, update_persist
from slearn.core.mixer import persists as persists_helper
from slearn.core.online import PERSIST, REPORT_KINDS
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode
from slearn.errors import LibraryFormatError
from slearn.io.library_file import load_library
from slearn.jobs.merge import merge_libraries

LAST, OTHER = 7, 8


@numba.njit
def persists(persist, v, length, last):  # helpers are called from compiled code only
    return persists_helper(persist, v, length, last)


@numba.njit
def rounds(persist, counted, length, said, last, truth, times):
    for _ in range(times):
        counted[0] += 1
        update_persist(persist, counted, 0, length, said, last, truth)


def test_it_speaks_after_it_was_right_where_the_answer_was_wrong():
    mixer = new_mixer(1, 4)
    p, counted = mixer.persist, np.array([8], np.int64)  # rounds 9-13: no power of two
    assert not persists(p, 0, 2, LAST)  # untrained: a tie leaves the answer
    rounds(p, counted, 2, OTHER, LAST, LAST, 1)  # the last reading was right, the answer wrong
    assert p[0, 1] == pytest.approx(1 / BETA) and persists(p, 0, 2, LAST)
    assert not persists(p, 0, 1, LAST) and not persists(p, 0, 2, -1)  # other lengths; no reading
    rounds(p, counted, 2, LAST, LAST, LAST, 1)  # both right, then both wrong: no change
    rounds(p, counted, 2, OTHER, LAST, 9, 1)
    assert p[0, 1] == pytest.approx(1 / BETA)
    rounds(p, counted, 2, 9, LAST, 9, 2)  # the answer right twice: it falls below
    assert not persists(p, 0, 2, LAST) and p[0, 1] == pytest.approx(BETA)


def test_its_weight_stays_within_the_spread_and_halves_at_powers_of_two():
    mixer = new_mixer(1, 3)
    p, counted = mixer.persist, np.array([4], np.int64)
    rounds(p, counted, 1, OTHER, LAST, LAST, 200)  # rounds 5..204 (8, 16, .. 128 halve)
    after_128 = np.exp(SPREAD)  # the bound, reached again after the last halving at 128
    assert p[0, 0] == pytest.approx(after_128)
    counted[0] = 255
    rounds(p, counted, 1, LAST, LAST, LAST, 1)  # round 256: halved, then a tie
    assert np.log(p[0, 0]) == pytest.approx(SPREAD / 2)
    rounds(p, counted, 1, OTHER, -1, LAST, 1)  # no last reading: nothing but a halving (none at 257)
    assert np.log(p[0, 0]) == pytest.approx(SPREAD / 2) and p[0, 1:].tolist() == [1.0, 1.0]


def sticky_episode(seed: int, steps: int, stay: float, bins: int = 30, commands: int = 20) -> Episode:
    """A reading that keeps its value with probability ``stay`` whatever the command, else
    jumps to a random bin: most (reading, command) pairs are rare, and the reading stays."""
    rng = np.random.default_rng(seed)
    reading, out = int(rng.integers(bins)), [((), (0,))]
    for _ in range(steps):
        command = 100 + int(rng.integers(commands))
        if rng.random() >= stay:
            reading = int(rng.integers(bins))
        out.append(((command,), (reading,)))
    return Episode.from_steps(out)


def frozen_reports(library: PatternLibrary, episode: Episode):
    codes = library.encode(episode, intern=False)
    return codes, library.run(codes, learn=False, record=True, top_k=3)


def test_a_reading_that_stays_is_predicted_where_its_contexts_were_never_seen():
    library = PatternLibrary(3, has_actions=True)
    library.learn(sticky_episode(0, 600, stay=0.6))
    assert persists(library.mixer.persist, 0, 1, LAST)  # a command alone says nothing of the reading
    codes, out = frozen_reports(library, sticky_episode(1, 2000, stay=0.6))
    right = out.context & (out.predicted == codes.token)
    spoke = out.kind == PERSIST
    assert spoke.mean() > 0.3 and right[spoke].mean() > 0.5
    untrained = PatternLibrary.from_export(library.export(), tokens=library.tokens, clock=library.clock,
                                           view_names=library.view_names,
                                           mixer=library.mixer._replace(persist=np.ones_like(library.mixer.persist)),
                                           max_length=3, has_actions=True)
    codes, plain = frozen_reports(untrained, sticky_episode(1, 2000, stay=0.6))
    assert not (plain.kind == PERSIST).any()
    assert right.mean() > (plain.context & (plain.predicted == codes.token)).mean() + 0.1


def test_it_stays_silent_where_readings_never_stay():
    rng = np.random.default_rng(3)
    readings = np.cumsum(rng.integers(1, 4, 3001)) % 17  # every reading moves on
    library = PatternLibrary(3, has_actions=True)
    library.learn(Episode.from_pairs(readings[:1], rng.choice([100, 101], 3000), readings[1:]))
    assert not np.any(library.mixer.persist > 1.0)
    _, out = frozen_reports(library, Episode.from_pairs(readings[:1], rng.choice([100, 101], 500), readings[1:501]))
    assert not (out.kind == PERSIST).any()


def test_frozen_batches_answer_as_the_step_loop_with_persistence():
    library = PatternLibrary(2, has_actions=True)
    library.learn(sticky_episode(4, 400, stay=0.7))
    episode = sticky_episode(5, 300, stay=0.7)
    ends = np.arange(1, 300)
    batch = assert_batch_matches(Predictor(library, top_k=3), episode, np.maximum(ends - 6, 0), ends)
    spoke = batch.kind == REPORT_KINDS.index("persist")
    assert spoke.any()
    top_p = batch.top_p[spoke]
    assert np.all(top_p[:, 0] > 0.5) and np.all(top_p.sum(axis=1) <= 1 + 1e-12)


def sticky_model(seed: int, steps: int, stay: float) -> SequenceModel:
    model = SequenceModel(max_length=3)
    model.learn_steps([({"c": a[0] if a else 0}, {"p": o[0]}) for a, o in sticky_episode(seed, steps, stay).steps()])
    return model


def test_it_is_saved_and_merged_with_the_later_weights(tmp_path):
    a, b = sticky_model(6, 500, 0.6), sticky_model(7, 300, 0.9)
    a.save(tmp_path / "a.parquet")
    b.save(tmp_path / "b.parquet")
    la, lb = load_library(tmp_path / "a.parquet"), load_library(tmp_path / "b.parquet")
    assert la.library.mixer.persist.tobytes() == a.library.mixer.persist.tobytes()
    assert not np.array_equal(a.library.mixer.persist, b.library.mixer.persist)
    merged = merge_libraries(la, lb).library.mixer
    assert np.array_equal(merged.persist, b.library.mixer.persist)  # as the weights: the later library's


@pytest.mark.parametrize("damage", [lambda r: [-x for x in r], lambda r: r[:-1], lambda r: [float("nan")] * len(r)])
def test_damaged_persistence_weights_are_refused_naming_the_file(tmp_path, damage):
    sticky_model(6, 200, 0.6).save(tmp_path / "a.parquet")
    source = pq.ParquetFile(tmp_path / "a.parquet")
    with pq.ParquetWriter(tmp_path / "bad.parquet", source.schema_arrow) as out:
        for group in range(source.num_row_groups):
            table = source.read_row_group(group)
            index = table.schema.get_field_index("view_persist")
            column = [None if r is None else damage(r) for r in table.column(index).to_pylist()]
            out.write_table(table.set_column(index, table.schema.field(index),
                                             pa.array(column, table.schema.field(index).type)))
    with pytest.raises(LibraryFormatError, match=r"bad\.parquet: the view table's persistence weights"):
        load_library(tmp_path / "bad.parquet")


@pytest.mark.parametrize(("column", "damage", "message"), [
    ("view_weights", lambda r: [float("nan")] * len(r), "expert weights"),
    ("view_weights", lambda r: [float("inf")] * len(r), "expert weights"),
    ("view_weights", lambda r: [0.0] * len(r), "expert weights"),
    ("view_weights", lambda r: [2.0] * len(r), "expert weights"),
    ("view_detector", lambda r: [float("nan")] * len(r), "change detectors"),
    ("view_detector", lambda r: [-1.0] * len(r), "change detectors"),
])
def test_damaged_weights_and_detectors_are_refused_not_run(tmp_path, column, damage, message):
    """NaN weights crashed the compiled kernels (a segfault in replay, a division by zero in
    --resume), and merge copied them on: load refuses them, naming the file."""
    sticky_model(6, 200, 0.6).save(tmp_path / "a.parquet")
    source = pq.ParquetFile(tmp_path / "a.parquet")
    with pq.ParquetWriter(tmp_path / "bad.parquet", source.schema_arrow) as out:
        for group in range(source.num_row_groups):
            table = source.read_row_group(group)
            index = table.schema.get_field_index(column)
            values = [None if r is None else damage(r) for r in table.column(index).to_pylist()]
            out.write_table(table.set_column(index, table.schema.field(index),
                                             pa.array(values, table.schema.field(index).type)))
    with pytest.raises(LibraryFormatError, match=rf"bad\.parquet: the view table's {message}"):
        load_library(tmp_path / "bad.parquet")
