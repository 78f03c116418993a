"""bench/bench_variants.py: windows, switches, the slearn column and the tables."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_variants as bench  # noqa: E402
import slearn_adapter  # noqa: E402

from slearn.recorders.pointer import PointerConfig, simulate  # noqa: E402


def test_there_are_at_least_twelve_variants_and_the_six_conditions():
    names = [v.name for v in bench.VARIANTS]
    assert len(names) == len(set(names)) and len(names) - 6 >= 12
    assert [v.name for v in bench.DEFAULTS] == ["simple", "hardstop", "scramble", "reversal",
                                                "error", "delay"]
    for variant in bench.VARIANTS:
        variant.config(0)  # every variant is a valid configuration


@pytest.mark.parametrize("options, steady, switches", [
    ({"condition": "delay"}, [(5000, 10000)], []),
    ({"condition": "scramble", "switch_trial": 8000}, [(5000, 8000)], [8000]),
    ({"condition": "reversal"}, [(7000, 10000)], [5000]),
    ({"condition": "reversal", "switch_trial": 3000, "switch_back_trial": 6000},
     [(5000, 6000), (8000, 10000)], [3000, 6000]),
    ({"condition": "delay", "trials": 50000}, [(25000, 50000)], []),
])
def test_steady_state_leaves_out_the_trials_after_each_switch(options, steady, switches):
    config = PointerConfig(**options)
    expected = np.zeros(config.trials, bool)
    for low, high in steady:
        expected[low:high] = True
    np.testing.assert_array_equal(bench.steady_mask(config), expected)
    assert bench.switches(config) == switches


def test_demo_window():
    assert np.flatnonzero(bench.demo_mask(PointerConfig("scramble"))).tolist() == list(range(5000, 6000))
    assert bench.demo_mask(PointerConfig("error")).sum() == 5000


def test_the_slearn_column_is_the_current_predictor():
    episode = simulate(PointerConfig("simple", trials=3000)).to_episode()
    correct = slearn_adapter.slearn_correct(episode)
    assert correct.dtype == bool and len(correct) == 3000 and correct[-1000:].all()
    assert not slearn_adapter.slearn_correct(episode, scoring="literal")[:10].all()


def test_a_run_gives_every_column_and_the_tables(capsys):
    chosen = [v for v in bench.VARIANTS if v.name in ("reversal @3000 back @6000", "delay")]
    results = bench.run(chosen, [0])
    back, delay = results
    assert [s["trial"] for s in back["switches"]] == [3000, 6000]
    assert "demo" in delay and "demo" not in back
    for figures in (back["steady"], delay["steady"], delay["demo"]):
        assert set(bench.COLUMNS) <= set(figures)
        assert all(0 <= figures[c] <= 100 for c in bench.COLUMNS)
    assert back["steady"]["ceiling"] == 100.0 and back["steady"]["VOM2"] > 99.5
    assert 45 <= delay["steady"]["ceiling"] <= 55
    assert delay["steady"]["best_vom_order"] == "1.5"  # the command before the position matters
    assert back["switches"][0]["first_thousand"]["slearn"] > 85
    # an empty library from each switch on learns the same thousand trials as from scratch
    assert all(85 < s["empty_at_switch"] <= 100 for s in back["switches"])
    assert "slearn new" in bench.render(results, [0])
    text = bench.render(results, [0])
    assert text.count("reversal @3000 back @6000") == 3 and "delay" in text
    json.dumps(results)


def test_arm_columns():
    from slearn.recorders.arm import ArmConfig

    figures = bench.measure_arm(ArmConfig(3, 3000, 0, "all"))
    assert set(figures) >= {"slearn", "ceiling", "VOM1", "channel VOM1", "channel VOM3"}
    assert figures["channel VOM1"][-500:].mean() > 0.95 > figures["VOM1"][-500:].mean()
    assert figures["ceiling"].all()
    row = {"condition": "simple", "sensors": "all", "joints": 3, "VOM": 9.0, "VOM order": 1,
           **{c: 50.0 for c in bench.ARM_COLUMNS if c not in ("VOM", "VOM order")}}
    assert bench.render_arm([row]).splitlines()[-1].split()[:3] == ["simple", "all", "3"]
