"""Replay: the evaluation core, baselines, metrics, curves, reports and annotated logs."""

from __future__ import annotations

import json
import math
import random
import shutil
from collections import Counter

import numpy as np
import pytest
from fixtures import POINTER_TOML

from slearn.core.library import PatternLibrary
from slearn.core.online import HOLD
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, OBSERVATION, Vocabulary
from slearn.io import library_file as storage
from slearn.io.spec import pointer_spec
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate
from slearn.recorders.record_pointer import record_pointer
from slearn.replay.baselines import Baselines
from slearn.replay.evaluation import FIT_PREQUENTIAL, FIT_TRAINING, SCHEMA, SURPRISE_FLOOR, evaluate, iter_evaluation
from slearn.replay.replay_logs import replay_logs
from slearn.replay.windows import data_window


def pointer_episode(condition="simple", trials=2000, seed=0, **kw):
    return simulate(PointerConfig(condition, trials=trials, seed=seed, **kw)).to_episode()


def trained(seeds=(0, 1, 2), trials=3000, baselines=True):
    """A library (and baselines) learned on pointer ``simple`` episodes; its vocabulary is the
    pointer's (``library.vocabulary``)."""
    library = PatternLibrary(vocabulary=pointer_vocabulary())
    counted = Baselines(library) if baselines else None
    for seed in seeds:
        episode = pointer_episode(trials=trials, seed=seed)
        library.learn(episode)
        if counted is not None:
            counted.learn(library.encode(episode))
    return library, counted


def held_out(*episodes):
    return [(f"episode{i}", e, None) for i, e in enumerate(episodes)]


# --- acceptance ----------------------------------------------------------------------------

def test_library_learned_on_simple_seeds_0_to_2_scores_above_99_5_on_seed_3_frozen():
    library, baselines = trained()
    n_patterns = len(library)
    result = evaluate(library, held_out(pointer_episode(trials=5000, seed=3)), pointer_vocabulary(),
                      baselines=baselines)
    assert result.mode == "frozen" and result.baseline_fit == FIT_TRAINING
    assert result.totals.events == 5000
    assert result.accuracy >= 0.995
    assert len(library) == n_patterns and library.clock == 9003  # frozen: nothing learned


def reversal_curves(online):
    library, baselines = trained(trials=3000)
    episode = pointer_episode("reversal", trials=6000, seed=5, switch_trial=2000)
    result = evaluate(library, held_out(episode), pointer_vocabulary(), online=online,
                      window=500, baselines=baselines)
    return result.episodes[0].curve.accuracy()


def test_library_learned_before_a_reversal_drops_at_the_switch_and_recovers_online():
    frozen, online = reversal_curves(False), reversal_curves(True)
    assert len(frozen) == 12
    assert frozen[:4].min() >= 0.99 and frozen[4:].max() <= 0.05  # the drop stays
    assert online[:4].min() >= 0.99
    assert online[4] < 0.95  # the drop ...
    assert online[-4:].min() >= 0.99  # ... and the recovery


# --- the generator ---------------------------------------------------------------------------

def test_iter_evaluation_yields_one_checkpoint_per_episode_with_running_totals():
    library, _ = trained(seeds=(0,), trials=2000)
    episodes = held_out(pointer_episode(trials=300, seed=3), pointer_episode(trials=500, seed=4))
    points = list(iter_evaluation(library, episodes, pointer_vocabulary()))
    assert [p.episode.name for p in points] == ["episode0", "episode1"]
    assert [p.predictions for p in points] == [300, 800]
    assert points[0].totals.events == 300 and points[1].totals.events == 800
    assert points[1].totals.correct == points[0].episode.tally.correct + points[1].episode.tally.correct
    assert len(points[0].outcome) == 300 and points[1].elapsed_s >= points[0].elapsed_s


def test_online_learns_and_frozen_does_not():
    library = PatternLibrary()
    episode = pointer_episode(trials=3000, seed=1)
    frozen = evaluate(library, held_out(episode), pointer_vocabulary())
    assert frozen.totals.abstained == 3000 and frozen.accuracy == 0 and len(library) == 0
    online = evaluate(library, held_out(episode), pointer_vocabulary(), online=True)
    assert len(library) > 0 and online.mode == "online"
    assert online.episodes[0].curve.accuracy()[-1] > 0.95


def test_windows_add_up_to_the_episode_and_hold_enough_events():
    library, _ = trained(seeds=(0,), trials=1000)
    result = evaluate(library, held_out(pointer_episode(trials=1234, seed=3)), pointer_vocabulary())
    curve = result.episodes[0].curve
    assert result.window == data_window(1234, 1234) == 100  # at least 100 events a window
    assert curve.events.sum() == result.totals.events == 1234
    assert curve.correct.sum() == result.totals.correct
    assert curve.start[-1] == 1200 and curve.events[-1] == 34


def test_top_k_counts_the_ranked_guesses():
    library, _ = trained(seeds=(0,), trials=300)
    episode = pointer_episode("error", trials=2000, seed=3, error_deg=8.0)
    one = evaluate(library, held_out(episode), pointer_vocabulary(), top_k=1, online=True)
    three = evaluate(trained(seeds=(0,), trials=300)[0], held_out(episode), pointer_vocabulary(),
                     top_k=3, online=True)
    assert one.totals.top_k == one.totals.correct
    assert three.totals.correct == one.totals.correct
    assert three.totals.top_k > three.totals.correct


# --- abstentions, unseen values, empty steps -------------------------------------------------

def two_channel_vocabulary():
    vocabulary = Vocabulary()
    vocabulary.add_channel("u", ACTION)
    vocabulary.add_channel("a", OBSERVATION)
    vocabulary.add_channel("b", OBSERVATION)
    return vocabulary


def two_channel_episode(vocabulary, steps, seed, start=0):
    """``a`` follows the action deterministically (mod 5); ``b`` is a coin flip."""
    rng = random.Random(seed)
    a = start
    out = [((), (vocabulary.symbol("a", a), vocabulary.symbol("b", rng.randint(0, 1))))]
    for _ in range(steps):
        u = rng.randint(0, 1)
        a = (a + (1 if u else -1)) % 5
        out.append(((vocabulary.symbol("u", u),),
                    (vocabulary.symbol("a", a), vocabulary.symbol("b", rng.randint(0, 1)))))
    return Episode.from_steps(out)


def test_several_observation_channels_are_scored_channel_by_channel():
    vocabulary = two_channel_vocabulary()
    library = PatternLibrary(max_length=2)
    for seed in range(3):
        library.learn(two_channel_episode(vocabulary, 3000, seed))
    result = evaluate(library, held_out(two_channel_episode(vocabulary, 4000, 9)), vocabulary)
    channels = {c["channel"]: c for c in result.channels.to_list()}
    assert list(channels) == ["a", "b"]
    assert channels["a"]["events"] == channels["b"]["events"] == 4000
    assert channels["a"]["accuracy"] > 0.99
    assert 0.4 < channels["b"]["accuracy"] < 0.6
    assert abs(result.accuracy - channels["b"]["accuracy"]) < 0.02
    assert all(label.startswith("a=") for p, a, _ in result.confusions for label in (p, a))


def test_confusions_are_counted_channel_by_channel_without_abstentions():
    """In a factored library each channel is predicted on its own, so a confusion is one
    channel's value taken for another of the same channel: a step where one channel was
    wrong and the other right is one confusion of the wrong channel, not of whole steps,
    and an abstention none (before, a replay of the PR2 log listed ten 'confusions' that
    were all one channel's abstentions next to a right prediction of another)."""
    vocabulary = two_channel_vocabulary()
    library = PatternLibrary(max_length=2, vocabulary=vocabulary)
    for seed in range(3):
        library.learn(two_channel_episode(vocabulary, 3000, seed))
    steps = two_channel_episode(vocabulary, 4000, 9).steps()
    strange = vocabulary.symbol("b", 7)  # a value of b the library never saw
    steps[100:120] = [(u, (o[0], strange)) for u, o in steps[100:120]]
    result = evaluate(library, held_out(Episode.from_steps(steps)), vocabulary)
    channels = {c["channel"]: c for c in result.channels.to_list()}
    assert channels["a"]["accuracy"] > 0.99 and 0.4 < channels["b"]["accuracy"] < 0.6
    assert result.confusions and all("," not in p and "," not in a and p.split("=")[0] == a.split("=")[0]
                                     for p, a, _ in result.confusions)
    b_wrong = channels["b"]["events"] - channels["b"]["correct"] - channels["b"]["abstained"]
    assert sum(n for p, _, n in result.confusions if p.startswith("b=")) == b_wrong
    assert "b=7" in [a for _, a, _ in result.confusions]  # predicted something else, wrong


def test_a_reading_never_seen_is_held_and_right_while_it_stays():
    """A channel of a spec holds its reading between events, so when its last value was
    never seen (a real log's slowly drifting joint, held out past the range seen in
    training: the PR2 casters) no pattern can speak, and the view predicts that reading
    again (kind ``hold``) instead of abstaining: right while the value stays, as
    persistence is."""
    vocabulary = Vocabulary()
    vocabulary.add_channel("a", OBSERVATION)
    vocabulary.add_channel("b", OBSERVATION)
    rng = random.Random(4)

    def episode(n, strange=()):
        return Episode.from_steps([((), (vocabulary.symbol("a", t % 5),
                                         vocabulary.symbol("b", 7 if t in strange else rng.randint(0, 1))))
                                   for t in range(n)])

    library = PatternLibrary(max_length=2, vocabulary=vocabulary)
    library.learn(episode(3000))
    held_out_episode = episode(400, strange=range(100, 110))
    result = evaluate(library, held_out(held_out_episode), vocabulary)
    channels = {c["channel"]: c for c in result.channels.to_list()}
    assert channels["a"]["abstained"] == channels["b"]["abstained"] == 0
    assert channels["a"]["accuracy"] > 0.99
    steps = held_out_episode.steps()
    guess = Predictor(library).predict_unknown(steps[:105] + [((), ())])
    strange = vocabulary.symbol("b", 7)
    assert guess.views[1].kind == "hold" and guess.views[1].observations == (strange,)
    assert guess.views[1].score == 0.0 and guess.views[0].kind != "hold"
    codes = library.encode(held_out_episode)
    reports = library.run(codes, learn=False, record=True)
    b = np.flatnonzero(codes.view == 1)  # one report of b per step
    held = reports.kind[b] == HOLD
    assert np.array_equal(np.flatnonzero(held), np.arange(101, 111))  # after each 7, nothing was seen
    assert (reports.predicted[b[101:111]] == codes.token[b[100]]).all()  # the 7 again:
    assert (codes.token[b[101:110]] == codes.token[b[100]]).all()  # right 9 times, wrong at 110
    # a hold has no share: right, it adds no surprise (it was 16 bits, the floor, every time)
    [point] = iter_evaluation(library, held_out(held_out_episode), vocabulary, top_k=3)
    o, floor = point.outcome, -math.log2(SURPRISE_FLOOR)
    first = o.first_step
    right = [s - first for s in range(101, 110)]
    assert (o.predicted[right] == o.actual[right]).all() and (o.surprise_bits()[right] < floor).all()
    assert o.surprise_bits()[110 - first] == floor
    assert (np.signbit(o.surprise_bits()) == False).all()  # noqa: E712 (no -0.0 bits)


def test_a_channel_whose_view_abstains_is_counted_abstained_not_wrong():
    """In a factored library one channel's view may abstain while the others speak: here a
    command never seen arrives where channel b has no reading yet (it starts reporting
    late), so b has nothing to hold, while a holds its reading. That event of b is an
    abstention, shown apart, not a wrong prediction; before, a channel was counted
    abstained only when every view was."""
    vocabulary = Vocabulary()
    vocabulary.add_channel("c", ACTION)
    vocabulary.add_channel("a", OBSERVATION)
    vocabulary.add_channel("b", OBSERVATION)
    rng = random.Random(4)
    act = [vocabulary.symbol("c", x) for x in (0, 1, 9)]

    def step(t, command, with_b=True):
        seen = (vocabulary.symbol("a", t % 5),) + ((vocabulary.symbol("b", rng.randint(0, 1)),) if with_b else ())
        return ((act[command],), seen)

    library = PatternLibrary(max_length=2, vocabulary=vocabulary)
    library.learn(Episode.from_steps([step(t, t % 2) for t in range(3000)]))
    late = [step(t, t % 2, with_b=False) for t in range(5)] + [step(5, 2)] \
        + [step(t, t % 2) for t in range(6, 300)]
    result = evaluate(library, held_out(Episode.from_steps(late)), vocabulary)
    channels = {c["channel"]: c for c in result.channels.to_list()}
    assert channels["b"]["abstained"] == 1  # command 9 never seen, and b had no reading to hold
    assert channels["a"]["abstained"] == 0  # a held its reading at that step
    assert result.totals.abstained == 0  # no step had every view abstain


def test_unseen_values_are_wrong_predictions_not_crashes():
    library, _ = trained(seeds=(0,), trials=500, baselines=False)
    vocabulary = library.vocabulary  # replay registers unseen values where the library reads them
    strange = vocabulary.symbol("/pointer/position", 99)
    steps = pointer_episode(trials=20, seed=3).steps()
    steps[10] = (steps[10][0], (strange,))
    result = evaluate(library, held_out(Episode.from_steps(steps)), vocabulary)
    assert result.totals.events == 20
    outcome = result.outcomes[0] if result.outcomes else None
    assert outcome is None
    # the unseen value itself is predicted wrong; after it only the command alone is known
    assert 17 <= result.totals.correct <= 18
    assert "/pointer/position=99" in [a for _, a, _ in result.confusions]


def test_steps_without_observations_are_not_scored():
    vocabulary = pointer_vocabulary()
    library, _ = trained(seeds=(0,), trials=500, baselines=False)
    steps = pointer_episode(trials=30, seed=3).steps()
    steps[5] = (steps[5][0], ())
    result = evaluate(library, held_out(Episode.from_steps(steps)), vocabulary)
    assert result.episodes[0].steps == 30 and result.totals.events == 29


def test_surprise_is_zero_when_sure_and_right_and_the_floor_when_abstaining():
    library, _ = trained(seeds=(0,), trials=1000)
    points = list(iter_evaluation(PatternLibrary(), held_out(pointer_episode(trials=5, seed=1)),
                                  pointer_vocabulary()))
    assert (points[0].outcome.surprise_bits() == -math.log2(SURPRISE_FLOOR)).all()
    points = list(iter_evaluation(library, held_out(pointer_episode(trials=50, seed=1)),
                                  pointer_vocabulary()))
    outcome = points[0].outcome
    right = outcome.predicted == outcome.actual
    assert right.all() and (outcome.surprise_bits() == 0).all() and outcome.evaluated.all()


# --- baselines --------------------------------------------------------------------------------

def naive_baselines(train, test, max_context, learn):
    """The three baselines on dicts of view-stream contexts (tuples of tokens), one channel:
    ``markov`` the most frequent outcome of the longest context seen, ``frequency`` of the
    context (last observation, action), ``persistence`` the last observation; ties of counts
    go to the outcome seen last."""
    counts = {}

    def stream(steps):
        tokens = [("O", steps[0][1])]
        for actions, observations in steps[1:]:
            tokens += [("A", actions), ("O", observations)]
        return tokens

    def best(context):
        seen = counts.get(context)
        return None if not seen else max(seen, key=lambda o: seen[o])[1] if False else \
            max(seen.items(), key=lambda item: (item[1][0], item[1][1]))[0]

    def count(tokens, clock):
        truth = tokens[-1]
        for k in range(1, min(len(tokens) - 1, max_context) + 1):
            entry = counts.setdefault(tuple(tokens[-1 - k:-1]), {}).setdefault(truth, [0, 0])
            entry[0] += 1
            entry[1] = clock

    clock = 0
    for steps in train:
        tokens = stream(steps)
        clock += 1  # the first reading
        for i in range(2, len(tokens), 2):
            count(tokens[:i + 1], clock)
            clock += 1
    out = []
    tokens = stream(test)
    clock += 1
    for i in range(2, len(tokens), 2):
        history = tokens[:i]
        seen = [best(tuple(history[-k:])) for k in range(1, min(len(history), max_context) + 1)]
        seen = [b for b in seen if b is not None]
        frequency = best(tuple(history[-2:]))
        out.append((frequency[1] if frequency else None, seen[-1][1] if seen else None,
                    history[-2][1]))
        if learn:
            count(tokens[:i + 1], clock)
        clock += 1
    return out


@pytest.mark.parametrize("max_length", [1, 2, 4])
@pytest.mark.parametrize("learn", [False, True])
def test_baselines_match_a_naive_model(max_length, learn):
    rng = np.random.default_rng(max_length)
    vocabulary = pointer_vocabulary()
    train = [[((), (2 + int(rng.integers(0, 3)),))] + [((int(rng.integers(0, 2)),), (2 + int(rng.integers(0, 3)),))
                                                       for _ in range(n)] for n in (300, 50)]
    test = [((), (2 + int(rng.integers(0, 4)),))] + [((int(rng.integers(0, 2)),), (2 + int(rng.integers(0, 4)),))
                                                     for _ in range(60)]  # an observation never seen
    library = PatternLibrary(max_length, vocabulary=vocabulary)
    baselines = Baselines(library)
    for steps in train:
        baselines.learn(library.encode(Episode.from_steps(steps)))
    codes = library.encode(Episode.from_steps(test))
    got = baselines.run(codes, learn=learn)
    symbols = library.tokens.symbols
    names = [tuple(None if t < 0 else symbols(int(t)) for t in (f, m, p))
             for f, m, p in zip(got.frequency, got.markov, got.persistence)][1:]
    want = naive_baselines(train, test, 2 * max_length, learn)
    assert names == want


def test_baselines_grow_past_their_first_arrays():
    episode = pointer_episode("error", trials=20000, seed=2, error_deg=9.0)
    library = PatternLibrary(vocabulary=pointer_vocabulary())
    codes = library.encode(episode)
    baselines = Baselines(library)
    guesses = baselines.run(codes, learn=True)
    assert len(baselines.counts.tree.parent) > 1024 and baselines.steps_learned == 20001
    assert (guesses.frequency[-2000:] == codes.token[-2000:]).mean() > 0.4


def test_without_training_data_baselines_are_prequential_and_say_so():
    library, _ = trained(seeds=(0,), trials=2000)
    result = evaluate(library, held_out(pointer_episode(trials=2000, seed=3)), pointer_vocabulary())
    assert result.baseline_fit == FIT_PREQUENTIAL
    assert any("lower bound" in note for note in result.notes)
    assert result.totals.frequency_abstained > 0  # they start empty
    assert result.totals.rate("frequency") > 0.9


# --- JSON, plots, report -------------------------------------------------------------------------

def small_result():
    library, baselines = trained(seeds=(0,), trials=1500)
    episode = pointer_episode("reversal", trials=1000, seed=3, switch_trial=500)
    return evaluate(library, held_out(episode, pointer_episode(trials=400, seed=4)),
                    pointer_vocabulary(), baselines=baselines, window=100)


def test_json_document_is_versioned_and_strict_json():
    doc = small_result().to_dict()
    text = json.dumps(doc, allow_nan=False)
    doc = json.loads(text)
    assert doc["schema"] == SCHEMA == "slearn.replay/3"
    assert {"mode", "top_k", "window", "totals", "baselines", "channels", "episodes", "confusions",
            "speed", "notes", "warnings"} <= set(doc)
    totals = doc["totals"]
    assert totals["events"] == 1400
    lift = 100 * (totals["accuracy"] - totals["baselines"]["markov"]["accuracy"])
    assert totals["baselines"]["markov"]["lift_points"] == pytest.approx(lift, abs=1e-3)
    assert [len(e["curve"]) for e in doc["episodes"]] == [10, 4]
    window = doc["episodes"][0]["curve"][0]
    assert window["channel_accuracy"] == [window["accuracy"]]  # one channel
    assert doc["confusions"][0]["count"] >= doc["confusions"][-1]["count"]
    assert doc["confusions"][0]["predicted"].startswith("/pointer/position=")


def test_plot_is_a_png_and_report_is_one_self_contained_html_file(tmp_path):
    from slearn.replay.plots import curves_png, write_curves
    from slearn.replay.report import format_table, render_html

    result = small_result()
    png = curves_png(result)
    assert png.startswith(b"\x89PNG")
    write_curves(result, tmp_path / "c.png")
    assert (tmp_path / "c.png").read_bytes().startswith(b"\x89PNG")
    page = render_html(result, png)
    assert page.count("data:image/png;base64,") == 1
    assert "src=\"http" not in page and "<script" not in page
    assert "frequency baseline" in page and "Most frequent confusions" in page
    table = format_table(result)
    assert "markov baseline" in table and "/pointer/position" in table



def test_the_text_tables_stay_aligned_with_long_channel_and_log_names():
    """ROS channels run long (``/joint_states:position[name=laser_tilt_mount_joint]``):
    every row of a table puts its numbers under their headers."""
    from slearn.replay.report import format_table

    vocabulary = Vocabulary()
    long_a, long_b = "/joint_states:position[name=laser_tilt_mount_joint]", "/b"
    vocabulary.add_channel(long_a, OBSERVATION)
    vocabulary.add_channel(long_b, OBSERVATION)
    steps = [((), (vocabulary.symbol(long_a, t % 5), vocabulary.symbol(long_b, t % 3))) for t in range(600)]
    library = PatternLibrary(max_length=2, vocabulary=vocabulary)
    library.learn(Episode.from_steps(steps))
    name = "/logs/" + "a_recording_with_a_long_name_" * 3 + ".mcap"
    lines = format_table(evaluate(library, [(name, Episode.from_steps(steps), None)], vocabulary)).splitlines()
    for header in ("channel", "log"):
        at = next(i for i, line in enumerate(lines) if line.startswith(f"  {header} "))
        end = lines[at].index("events") + len("events")
        rows = lines[at + 1:lines.index("", at)]
        assert len(rows) == {"channel": 2, "log": 1}[header]
        assert all(row[:end].endswith("599") for row in rows), rows  # (the first reading is not predicted)


# --- logs on disk ---------------------------------------------------------------------------------



@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Pointer logs (simple seeds 0-3, a reversal) and a library learned on seeds 0-2."""
    from slearn.io.serialize import read_episodes

    folder = tmp_path_factory.mktemp("replay")
    paths = {}
    for seed in range(4):
        paths[f"simple{seed}"] = folder / f"simple{seed}.mcap"
        record_pointer(PointerConfig("simple", trials=2500, seed=seed), paths[f"simple{seed}"])
    paths["reversal"] = folder / "reversal.mcap"
    record_pointer(PointerConfig("reversal", trials=3000, seed=9, switch_trial=1000), paths["reversal"])
    library, vocabulary, spec = PatternLibrary(), Vocabulary(), pointer_spec()
    training = [paths[f"simple{s}"] for s in range(3)]
    for _, episode, _ in read_episodes(training, spec, vocabulary):
        library.learn(episode)
    paths["library"] = folder / "library.parquet"
    storage.save_library(paths["library"], library, vocabulary, spec=spec,
                         params={"scoring": "adaptive"},
                         provenance={"inputs": [storage.file_record(p) for p in training]})
    paths["bare"] = folder / "bare.parquet"
    storage.save_library(paths["bare"], library, vocabulary, spec=None, params={}, provenance={})
    return paths


def test_replay_logs_reads_as_at_learning_and_fits_baselines_on_the_provenance_inputs(logs):
    result = replay_logs([logs["simple3"]], library=logs["library"])
    assert result.accuracy >= 0.995 and result.totals.events == 2500
    assert result.baseline_fit == FIT_TRAINING
    assert result.setup["baseline_logs"] == [str(logs[f"simple{s}"]) for s in range(3)]
    assert result.setup["library"]["patterns"] > 0 and result.setup["spec"]["mode"] == "message"
    assert not result.truncated and result.total_s >= result.elapsed_s


def test_replay_logs_without_spec_needs_one_and_with_spec_alone_learns_online(logs, tmp_path):
    from slearn.errors import InputError

    with pytest.raises(InputError, match="without a spec"):
        replay_logs([logs["simple3"]], library=logs["bare"])
    spec = tmp_path / "pointer.toml"
    spec.write_text(POINTER_TOML)
    result = replay_logs([logs["simple3"]], library=logs["bare"], spec=spec)
    assert result.accuracy >= 0.995 and result.baseline_fit == FIT_PREQUENTIAL
    empty = replay_logs([logs["simple0"], logs["simple3"]], spec=spec)
    assert empty.mode == "online" and empty.setup["library"] is None
    assert [c["channel"] for c in empty.channels.to_list()] == ["/pointer/position"]  # declared late
    assert empty.channels.events.tolist() == [5000]
    assert empty.episodes[0].tally.accuracy < empty.episodes[1].tally.accuracy


def test_annotated_log_holds_the_source_and_one_prediction_per_predicted_event(logs, tmp_path):
    from mcap.reader import make_reader

    from slearn.replay.annotate import write_annotated

    result = replay_logs([logs["reversal"]], library=logs["library"], keep_outcomes=True)
    [summary] = write_annotated(result, tmp_path / "annotated.mcap")
    assert summary.predictions == result.totals.events == 3000
    with open(tmp_path / "annotated.mcap", "rb") as f:
        reader = make_reader(f)
        messages = list(reader.iter_messages())
        schemas = {s.name: s.encoding for s in reader.get_summary().schemas.values()}
    topics = Counter(channel.topic for _, channel, _ in messages)
    assert topics == {"/pointer/command": 3000, "/pointer/position": 3001, "/pointer/angle": 3001,
                      "/slearn/prediction": 3000, "/slearn/correct": 3000, "/slearn/surprise": 3000}
    assert schemas["slearn.replay.Prediction"] == "jsonschema"
    assert schemas["slearn.pointer.Position"] == "jsonschema"
    times = {t: [m.log_time for _, c, m in messages if c.topic == t] for t in topics}
    assert times["/slearn/prediction"] == times["/pointer/position"][1:]  # aligned with the truth
    predictions = [json.loads(m.data) for _, c, m in messages if c.topic == "/slearn/prediction"]
    right = [p["correct"] for p in predictions]
    assert sum(right) == result.totals.correct
    assert all(right[:1000]) and not any(right[1000:])  # frozen: the reversal is never learned
    surprise = [json.loads(m.data)["bits"] for _, c, m in messages if c.topic == "/slearn/surprise"]
    assert max(surprise[:1000]) < 0.01 and min(surprise[1000:]) > 1
    assert predictions[0]["actual"].startswith("/pointer/position=")


def test_annotating_several_logs_needs_a_folder(logs, tmp_path):
    from slearn.errors import InputError
    from slearn.replay.annotate import write_annotated

    result = replay_logs([logs["simple3"], logs["reversal"], logs["simple3"]],
                         library=logs["library"], keep_outcomes=True)
    with pytest.raises(InputError, match="folder"):
        write_annotated(result, tmp_path / "x.mcap")
    written = write_annotated(result, tmp_path)
    assert [w.path for w in written] == [str(tmp_path / "simple3.annotated.mcap"),
                                         str(tmp_path / "reversal.annotated.mcap"),
                                         str(tmp_path / "simple3-2.annotated.mcap")]


def write_small_chunks(run, path):
    """The pointer recorder's layout in chunks of 4 KiB, so a cut file keeps whole chunks."""
    from slearn.recorders.mcap_episode import EpisodeWriter

    with EpisodeWriter(path, chunk_size=4096) as out:
        command = out.register_channel("/pointer/command", "Command", {"type": "object"})
        position = out.register_channel("/pointer/position", "Position", {"type": "object"})
        out.write(position, 0, {"position": int(run.positions[0])})
        for i, (c, p) in enumerate(zip(run.commands.tolist(), run.positions[1:].tolist())):
            out.write(command, i * 100_000_000, {"command": "LR"[c]})
            out.write(position, i * 100_000_000 + 50_000_000, {"position": p})


def test_truncated_log_scores_what_was_salvaged(logs, tmp_path):
    whole, cut = tmp_path / "whole.mcap", tmp_path / "cut.mcap"
    write_small_chunks(simulate(PointerConfig("simple", trials=2500, seed=3)), whole)
    data = whole.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    result = replay_logs([cut], library=logs["library"])
    assert result.truncated and "truncated" in result.warnings[0]
    assert 0 < result.totals.events < 2500 and result.accuracy >= 0.99


def test_a_changed_training_log_is_not_used_for_the_baselines(logs, tmp_path):
    from slearn.io.serialize import read_episodes

    copy = tmp_path / "train.mcap"
    shutil.copy(logs["simple0"], copy)
    library, vocabulary = PatternLibrary(), Vocabulary()
    for _, episode, _ in read_episodes([copy], pointer_spec(), vocabulary):
        library.learn(episode)
    storage.save_library(tmp_path / "lib.parquet", library, vocabulary, spec=pointer_spec(),
                         params={}, provenance={"inputs": [storage.file_record(copy)]})
    record_pointer(PointerConfig("simple", trials=2500, seed=7), copy, overwrite=True)
    result = replay_logs([logs["simple3"]], library=tmp_path / "lib.parquet")
    assert result.baseline_fit == FIT_PREQUENTIAL


def test_plot_draws_one_line_per_channel_for_one_log_and_per_log_for_several():
    from slearn.replay.plots import _lines

    vocabulary = two_channel_vocabulary()
    library = PatternLibrary(max_length=2)
    library.learn(two_channel_episode(vocabulary, 500, 0))
    one = evaluate(library, held_out(two_channel_episode(vocabulary, 300, 1)), vocabulary)
    assert [label for label, *_ in _lines(one)][:2] == ["a", "b"]
    several = evaluate(library, held_out(two_channel_episode(vocabulary, 300, 1),
                                         two_channel_episode(vocabulary, 300, 2)), vocabulary)
    assert [label for label, *_ in _lines(several)] == ["episode0", "episode1", "all"]


def test_relative_provenance_paths_are_found_next_to_the_library(logs, tmp_path, monkeypatch):
    folder = logs["library"].parent
    inputs = []
    for s in range(3):
        record = storage.file_record(logs[f"simple{s}"])
        inputs.append({**record, "path": f"simple{s}.mcap"})
    loaded = storage.load_library(logs["library"])
    storage.save_library(folder / "relative.parquet", loaded.library, loaded.vocabulary,
                         spec=loaded.spec, params={}, provenance={"inputs": inputs}, overwrite=True)
    monkeypatch.chdir(tmp_path)
    result = replay_logs([logs["simple3"]], library=folder / "relative.parquet")
    assert result.baseline_fit == FIT_TRAINING
    assert result.setup["baseline_logs"] == [str(folder / f"simple{s}.mcap") for s in range(3)]


@pytest.mark.parametrize("mode, tick_ns", [("message", None), ("change", None), ("tick", 100_000_000),
                                           ("tick", 30_000_000)])
def test_step_times_match_the_steps_of_every_mode(tmp_path, mode, tick_ns):
    from dataclasses import replace

    from slearn.io.serialize import iter_step_times, read_episodes

    path = tmp_path / "p.mcap"
    record_pointer(PointerConfig("simple", trials=200, seed=1), path)
    spec = replace(pointer_spec(), mode=mode, tick_ns=tick_ns)
    vocabulary = Vocabulary()
    [(_, episode, _)] = list(read_episodes([path], spec, vocabulary))
    [(name, times)] = list(iter_step_times(str(path), spec, vocabulary))
    assert name == str(path)
    assert len(times) == len(episode)
    assert times[0] == 0 and (np.diff(times) > 0).all()
    if mode != "tick":
        assert times[1] == 50_000_000 and times[-1] == 199 * 100_000_000 + 50_000_000
    else:
        assert times[1] == tick_ns


def test_frozen_surprise_uses_the_probability_of_what_happened():
    library = PatternLibrary()
    library.learn(pointer_episode("error", trials=5000, seed=0, error_deg=8.0))
    episode = pointer_episode("error", trials=3000, seed=3, error_deg=8.0)
    [point] = iter_evaluation(library, held_out(episode), pointer_vocabulary(), top_k=3)
    o = point.outcome
    right, wrong = o.predicted == o.actual, (o.predicted != o.actual) & (o.predicted >= 0)
    assert right.any() and wrong.any()
    assert np.allclose(o.truth_probability[right], o.score[right])  # the same share
    assert (o.truth_probability[wrong] <= 1 - o.score[wrong] + 1e-12).all()
    in_top = wrong & o.top_k
    assert (o.truth_probability[in_top] > 0).any()
    bits = o.surprise_bits()
    assert np.allclose(bits[in_top], -np.log2(np.maximum(o.truth_probability[in_top], SURPRISE_FLOOR)))


def test_a_frozen_library_that_ends_in_fresh_counts_is_warned_about(logs, tmp_path):
    """Learned on scramble episodes, the library ends in the last one's scrambled labels
    (its fresh counts lead); frozen on a new episode, which starts unscrambled, it predicts
    with them throughout, and replay says so; online it relearns, and says nothing."""
    from slearn.io.serialize import read_episodes

    paths = [tmp_path / f"scramble{seed}.mcap" for seed in range(3)]
    for seed, path in enumerate(paths):
        record_pointer(PointerConfig("scramble", trials=3000, seed=seed, switch_trial=1000), path)
    library, vocabulary, spec = PatternLibrary(), Vocabulary(), pointer_spec()
    for _, episode, _ in read_episodes(paths[:2], spec, vocabulary):
        library.learn(episode)
    saved = tmp_path / "scramble.parquet"
    storage.save_library(saved, library, vocabulary, spec=spec, params={"scoring": "adaptive"},
                         provenance={"inputs": [storage.file_record(p) for p in paths[:2]]})

    def fresh_warnings(result):
        return [w for w in result.warnings if "since the last change of dynamics" in w]

    frozen = replay_logs([paths[2]], library=saved)
    [warning] = fresh_warnings(frozen)
    assert "frozen, it predicts (after 3 alarms) with" in warning and "--online" in warning
    assert "\n" not in warning
    markov = frozen.to_dict()["totals"]["baselines"]["markov"]["accuracy"]
    assert frozen.accuracy < markov - 0.2  # what it warns of
    online = replay_logs([paths[2]], library=saved, online=True)
    assert not fresh_warnings(online) and online.accuracy > 0.9
    assert not fresh_warnings(replay_logs([logs["simple3"]], library=logs["library"]))
