"""The change detector (slearn.core.mixer): an alarm soon after a switch, the change point it
estimates, fresh counts seeded from the occurrences since then, and that state kept on
the run's clock by merges and across library files."""

import json
import math

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401  (pa.compute)
import pyarrow.parquet as pq
import pytest

from slearn.core.library import PatternLibrary
from slearn.core.mixer import (
    CALM,
    CLOCK_FIELDS,
    CUSUM,
    DETECTOR_FIELDS,
    DROPS,
    FALSE_ALARM,
    MISSES,
    START,
    TRIALS,
    detect,
    new_mixer,
)
from slearn.core.stream import Episode
from slearn.io.library_file import METADATA_KEY, LoadedLibrary, library_params, load_library, save_library
from slearn.jobs.merge import merge_libraries
from slearn.recorders.pointer import PointerConfig, simulate

SWITCH = 5000
PROVENANCE = {"slearn_version": "test", "inputs": [], "time": "2020-01-01T00:00:00Z",
              "time_unix": 1577836800, "time_source": "test"}


def test_a_sudden_change_is_detected_by_the_steepest_test_and_dated_at_its_first_miss():
    mixer = new_mixer(1, 2)
    weights, detector = mixer.weight, mixer.detector
    clock = 0
    for _ in range(50):  # calm: the expert hits as often as it says
        assert not detect(weights, detector, 0, True, 0.75, clock)
        clock += 1
    first_miss = clock
    misses = 0
    while not detect(weights, detector, 0, False, 0.75, clock):
        clock += 1
        misses += 1
    steepest = math.log((1 - 0.75 / max(DROPS)) / 0.25)
    assert misses + 1 == math.ceil(math.log(len(DROPS) / FALSE_ALARM) / steepest)
    assert detector[0, START] == first_miss  # Page's estimate: after the last zero
    assert np.all(detector[0, CUSUM:CUSUM + len(DROPS)] == 0)
    assert np.all(detector[0, CALM:CALM + len(DROPS)] == clock + 1)
    assert detector[0, MISSES] == detector[0, TRIALS] == 0


def test_calm_noise_raises_no_alarm():
    rng = np.random.default_rng(0)
    mixer = new_mixer(1, 2)
    alarms = sum(detect(mixer.weight, mixer.detector, 0, bool(hit), 0.6, clock)
                 for clock, hit in enumerate(rng.random(20_000) < 0.6))
    assert alarms == 0


def learned_online(episode: Episode) -> tuple[PatternLibrary, np.ndarray]:
    library = PatternLibrary()
    codes = library.encode(episode)
    reports = library.run(codes, learn=True, record=True, top_k=1)
    return library, reports.predicted == codes.token


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_a_noisy_reversal_the_library_predicts_almost_as_one_learned_from_the_switch(seed):
    """Fresh counts restart at the estimated change point, not at the alarm: the thousand after
    the switch is within the detection delay of a library learned from empty on the same
    trials (slearn before the change-point seeding: 0.9-1.4 points below)."""
    episode = simulate(PointerConfig("reversal+error", seed=seed, trials=SWITCH + 1000)).to_episode()
    library, correct = learned_online(episode)
    after = correct[SWITCH + 1:].mean()
    _, fresh = learned_online(Episode.from_steps(episode.steps()[SWITCH:]))
    assert library.mixer.epoch[0] == 1
    assert SWITCH - 8 <= library.mixer.detector[0, START] <= SWITCH + 1  # the switch: step 5001
    assert after >= fresh[1:].mean() - 0.008


def test_fresh_counts_are_seeded_from_the_occurrences_since_the_change_point():
    episode = simulate(PointerConfig("reversal", seed=0, trials=SWITCH + 30)).to_episode()
    library, _ = learned_online(episode)
    start = library.mixer.detector[0, START]
    assert library.mixer.epoch[0] == 1 and abs(start - (SWITCH + 1)) <= 1
    export = library.export()
    seen_since = export["last_seen"] >= start
    assert np.all(export["fresh"][~seen_since] == 0)  # what only the old dynamics showed
    assert np.all(export["fresh"][seen_since] >= 1)
    assert np.all(export["fresh"] <= export["count"])


def named(library: PatternLibrary) -> LoadedLibrary:
    from test_library import naming  # the names of a library learned without a vocabulary
    return LoadedLibrary(library, naming(), None, library_params(library), {})


def test_a_merge_moves_the_later_librarys_change_point_onto_the_runs_clock():
    before = simulate(PointerConfig("simple", seed=0, trials=2000)).to_episode()
    switched = simulate(PointerConfig("reversal", seed=1, trials=3000, switch_trial=1000)).to_episode()
    a, b = PatternLibrary(), PatternLibrary()
    a.learn(before)
    b.learn(switched)
    assert b.mixer.epoch[0] >= 1
    merged = merge_libraries(named(a), named(b)).library
    shifted = b.mixer.detector[0].copy()
    shifted[list(CLOCK_FIELDS)] += a.clock
    np.testing.assert_array_equal(merged.mixer.detector[0], shifted)
    assert merged.mixer.epoch[0] == b.mixer.epoch[0]


def as_format_2(path, out):
    """``path`` rewritten as format 2 wrote it: one test per view (cusum, misses, trials)."""
    table = pq.read_table(path)
    column = table.column("view_detector").to_pylist()
    old = [None if row is None else [row[CUSUM], row[MISSES], row[TRIALS]] for row in column]
    i = table.schema.get_field_index("view_detector")
    table = table.set_column(i, table.schema.field(i), pa.array(old, table.schema.field(i).type))
    info = json.loads(table.schema.metadata[METADATA_KEY])
    info["version"] = 2
    table = table.replace_schema_metadata({METADATA_KEY: json.dumps(info)})
    with pq.ParquetWriter(out, table.schema) as writer:  # a row group per table, as written
        for name in ("vocabulary", "token", "view", "pattern"):
            rows = table.filter(pa.compute.equal(table.column("table"), name))
            if rows.num_rows:
                writer.write_table(rows)
    return out


def test_a_format_2_library_is_upgraded_with_its_clocks_at_the_librarys_clock(tmp_path):
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("reversal+error", seed=0, trials=6000)).to_episode())
    path = tmp_path / "lib.parquet"
    save_library(path, library, named(library).vocabulary, spec=None, params=library_params(library),
                 provenance=PROVENANCE)
    old = load_library(as_format_2(path, tmp_path / "old.parquet"))
    detector = old.library.mixer.detector
    assert old.format_version == 2 and detector.shape == (1, DETECTOR_FIELDS)
    want = library.mixer.detector
    assert detector[0, CUSUM] == want[0, CUSUM] and np.all(detector[0, CUSUM + 1:CALM] == 0)
    assert (detector[0, MISSES], detector[0, TRIALS]) == (want[0, MISSES], want[0, TRIALS])
    assert np.all(detector[0, list(CLOCK_FIELDS)] == library.clock)
    np.testing.assert_array_equal(old.library.export()["fresh"], library.export()["fresh"])
