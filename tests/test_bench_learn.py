"""bench/bench_learn.py: the C reference of the learning rule builds slearn's library byte
for byte (patterns, counts, recency, fresh counts, weights, detectors, epochs), so the
speed ratio it prints compares the same work; so does its variant with prefetches, which
must change no result. Skipped without a C compiler."""

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_learn  # noqa: E402

from slearn.recorders.arm import ArmConfig, arm_vocabulary, simulate_arm  # noqa: E402
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate  # noqa: E402

pytestmark = pytest.mark.skipif(not any(shutil.which(c) for c in ("cc", "gcc", "clang")),
                                reason="no C compiler")


@pytest.fixture(scope="module")
def c_learns(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clearn")
    return {"c": bench_learn.load_c_learn(folder), "cp": bench_learn.load_c_learn(folder, prefetch=True)}


@pytest.mark.parametrize("config", [
    PointerConfig("delay", trials=3000, seed=0),
    PointerConfig("reversal", trials=3000, seed=1, switch_trial=1500),  # a change alarm
    PointerConfig("error", trials=3000, seed=2),
])
def test_the_c_rule_builds_the_pointer_library_byte_for_byte(c_learns, config):
    episode = simulate(config).to_episode()
    row = bench_learn.measure(config.condition, episode, pointer_vocabulary(), c_learns, repeat=1)
    assert row["differences"] == [] and row["patterns"] > 1000 and {"c_s", "cp_s"} <= set(row)
    if config.condition == "reversal":  # the detector's alarm is part of what is compared
        library = bench_learn.PatternLibrary(vocabulary=pointer_vocabulary())
        library.learn(episode)
        assert library.mixer.epoch[0] >= 1


def test_a_library_past_the_caches_is_learned_with_prefetches_to_the_same_bytes(c_learns):
    """slearn prefetches only tables past ``FETCH_SLOTS``: on a stream that grows them past
    it (the streams above stay below), the library is still the plain C loop's."""
    from slearn.core.context_tree import FETCH_SLOTS

    episode = simulate(PointerConfig("error", trials=60_000, seed=5)).to_episode()
    row = bench_learn.measure("error", episode, pointer_vocabulary(), c_learns, repeat=1)
    assert row["differences"] == [] and row["patterns"] > FETCH_SLOTS // 2
    library = bench_learn.PatternLibrary(vocabulary=pointer_vocabulary())
    library.learn(episode)
    assert min(len(library.tree.node_slots), len(library.tree.entry_slots)) > FETCH_SLOTS


def test_the_c_rule_builds_the_arm_library_byte_for_byte(c_learns):
    episode = simulate_arm(ArmConfig(3, 2000, 0, "all")).to_episode()
    row = bench_learn.measure("arm", episode, arm_vocabulary(3), c_learns, repeat=1)
    assert row["differences"] == []


@pytest.mark.parametrize("variant", ["c", "cp"])
def test_a_difference_is_reported(c_learns, variant):
    """The comparison can fail: a library learned on other trials differs."""
    episode = simulate(PointerConfig("delay", trials=500, seed=0)).to_episode()
    template = bench_learn.PatternLibrary(vocabulary=pointer_vocabulary())
    codes = template.encode(episode)
    c_built = bench_learn.c_library(c_learns[variant], template, codes, 50_000, 50_000)
    other = bench_learn.PatternLibrary(vocabulary=pointer_vocabulary())
    other.learn(simulate(PointerConfig("delay", trials=500, seed=1)).to_episode())
    assert bench_learn.same_library(other, c_built) != []
