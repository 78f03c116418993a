"""Action scopes: a view that sees only the actions that drive it (slearn.core.action_scopes,
views, the spec's ``actions``, ``SequenceModel(action_scopes=...)``)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slearn import SequenceModel
from slearn.core.action_scopes import suggest_scopes
from slearn.core.library import PatternLibrary
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, LibraryFormatError, ParameterError, SpecError
from slearn.io.library_file import METADATA_KEY, LoadedLibrary, library_params, load_library, save_library
from slearn.io.spec import _build_spec, spec_from_options
from slearn.jobs.merge import merge_libraries

BINS = 8


def busy_walk(joints: int, seed: int, steps: int, drive=None) -> list:
    """Steps of an arm whose every joint gets a command (-1, 0, +1) at every step; joint
    ``j`` moves by ``drive(j, commands)`` (default: its own command)."""
    rng = np.random.default_rng(seed)
    drive = drive or (lambda j, cmd: cmd[j])
    position, out = [int(p) for p in rng.integers(BINS, size=joints)], []
    for _ in range(steps):
        cmd = [int(c) for c in rng.integers(-1, 2, size=joints)]
        position = [min(BINS - 1, max(0, p + drive(j, cmd))) for j, p in enumerate(position)]
        out.append(({f"c{j}": cmd[j] for j in range(joints)}, {f"p{j}": position[j] for j in range(joints)}))
    return out


def own(joints: int) -> dict:
    return {f"p{j}": [f"c{j}"] for j in range(joints)}


def accuracy(model: SequenceModel, steps: list, history: int = 6) -> float:
    right = [model.predict_step(steps[i - history:i], steps[i][0]).get(channel) == value
             for i in range(history, len(steps)) for channel, value in steps[i][1].items()]
    return float(np.mean(right))


def learned(joints: int, scopes, train: int = 3000, seed: int = 0) -> SequenceModel:
    model = SequenceModel(action_scopes=scopes)
    model.learn_steps(busy_walk(joints, seed, train))
    return model


def test_joints_commanded_at_once_are_learned_from_their_own_commands(tmp_path):
    held_out = busy_walk(5, 9, 600)
    scoped, whole = learned(5, own(5)), learned(5, None)
    assert accuracy(scoped, held_out) == 1.0  # deterministic: each joint from its command
    # 243 command tuples: contexts rarely repeat, and where they were never seen only the
    # persistence specialist's last reading is right, for the joints a 0 command left (0.87)
    assert accuracy(whole, held_out) < 0.9
    whole.save(tmp_path / "whole.parquet")
    counts_only = SequenceModel.load(tmp_path / "whole.parquet")  # without it: the counts alone
    counts_only.library.mixer = counts_only.library.mixer._replace(persist=np.ones_like(whole.library.mixer.persist))
    assert accuracy(counts_only, held_out) < 0.8
    assert len(scoped.library) < len(whole.library) / 2


def test_the_choice_finds_each_joints_own_command_and_nothing_where_none_drives():
    model = learned(4, None, train=10)  # a vocabulary of the channels
    walk = busy_walk(4, 1, 4000)
    episode = Episode.from_steps([model._step_symbols(s, learn=True) for s in walk])
    assert suggest_scopes([episode], model.vocabulary) == {f"p{j}": (f"c{j}",) for j in range(4)}

    def pairs(j, cmd):  # joints 0 and 1 both follow command 0; 2 and 3 follow 2 and 3
        return cmd[0] if j < 2 else cmd[j]

    walk = busy_walk(4, 2, 4000, drive=pairs)
    episode = Episode.from_steps([model._step_symbols(s, learn=True) for s in walk])
    assert suggest_scopes([episode], model.vocabulary) == {
        "p0": ("c0",), "p1": ("c0",), "p2": ("c2",), "p3": ("c3",)}


def test_no_scope_is_suggested_where_every_action_matters_or_none_is_there():
    vocabulary = Vocabulary()
    vocabulary.add_channel("c", "action")
    vocabulary.add_channel("p", "observation")
    rng = np.random.default_rng(0)
    steps, p = [], 0
    for c in rng.integers(-1, 2, size=2000).tolist():
        p = min(BINS - 1, max(0, p + c))
        steps.append(((vocabulary.symbol("c", c),), (vocabulary.symbol("p", p),)))
    assert suggest_scopes([Episode.from_steps(steps)], vocabulary) == {}  # the one action drives it
    assert suggest_scopes([], vocabulary) == {}


def test_a_reading_no_command_drives_gets_an_empty_scope():
    def still(j, cmd):
        return cmd[j] if j == 0 else 0

    model = learned(2, None, train=10)
    walk = busy_walk(2, 3, 3000, drive=still)
    episode = Episode.from_steps([model._step_symbols(s, learn=True) for s in walk])
    assert suggest_scopes([episode], model.vocabulary) == {"p0": ("c0",), "p1": ()}


def one_joint_at_a_time(joints: int, positions: int, seed: int, steps: int) -> list:
    """Steps of an arm that moves one random joint by -1 or +1 per step (every joint's
    command is given, 0 for those that stay): the pointer arm's way, on a wrapped dial."""
    rng = np.random.default_rng(seed)
    position, out = [0] * joints, []
    for _ in range(steps):
        j, d = int(rng.integers(joints)), int(rng.choice([-1, 1]))
        position[j] = (position[j] + d) % positions
        out.append(({f"c{i}": d if i == j else 0 for i in range(joints)},
                    {f"p{i}": position[i] for i in range(joints)}))
    return out


def test_the_choice_finds_own_commands_when_a_reading_takes_many_values():
    """36 positions, 3 of which follow any one: the choice must not charge a context for
    the 33 it never meets (BIC, which does, kept every joint from its command)."""
    model = SequenceModel()
    walk = one_joint_at_a_time(3, 36, 0, 4000)
    model.learn_steps(walk[:10])
    episode = Episode.from_steps([model._step_symbols(s, learn=True) for s in walk])
    assert suggest_scopes([episode], model.vocabulary) == {f"p{j}": (f"c{j}",) for j in range(3)}


def test_a_view_that_sees_no_actions_predicts_from_its_own_readings():
    """Half the steps move the joint, so its best guess without the commands is that it
    stays: a view of no actions holds that frozen (a constant action token in its stream
    made the newest reading after it the answer, right online and wrong frozen: 0.06)."""
    train, held_out = one_joint_at_a_time(2, 12, 0, 5000), one_joint_at_a_time(2, 12, 1, 1000)
    blind = SequenceModel(action_scopes={"p0": [], "p1": ["c1"]})
    blind.learn_steps(train)
    stays = right = 0
    for i in range(6, len(held_out)):
        said = blind.predict_step(held_out[i - 6:i], held_out[i][0])
        truth, before = held_out[i][1], held_out[i - 1][1]
        stays += truth["p0"] == before["p0"]
        right += said["p0"] == truth["p0"]
        assert said["p1"] == truth["p1"]  # the joint that sees its command: exact
    assert right >= stays > 0.4 * (len(held_out) - 6)
    assert blind.library.n_scopes == 1  # no scope's tokens for a view that sees no action


def test_single_batch_and_replay_paths_agree_on_a_scoped_library():
    model = learned(3, own(3), train=1500)
    library = model.library
    walk = busy_walk(3, 5, 300)
    rows = [model._step_symbols(s, learn=False) for s in walk]
    episode = Episode.from_steps(rows)
    predictor = Predictor(library)
    ends = np.arange(6, len(rows))
    batch = predictor.predict_batch(episode, ends - 6, ends)
    for i, end in enumerate(ends):
        single = predictor.predict(rows[end - 6:end], rows[end][0])
        assert single == predictor.prediction(batch, i)
        assert [v.observations for v in single.views] == [(s,) for s in rows[end][1]]  # all right
    codes = library.encode(episode)
    reports = library.run(codes, learn=False, record=True)  # one walk: the same contexts
    for i, end in enumerate(ends):
        assert reports.predicted[codes.offsets[end]:codes.offsets[end + 1]].tolist() == batch.token[i].tolist()


def test_scopes_are_saved_loaded_and_predict_the_same(tmp_path):
    model = learned(3, own(3), train=1500)
    model.save(tmp_path / "m.parquet")
    again = SequenceModel.load(tmp_path / "m.parquet")
    assert again.library.action_scopes == {f"p{j}": (f"c{j}",) for j in range(3)}
    walk = busy_walk(3, 6, 200)
    for i in range(6, len(walk)):
        assert again.predict_step(walk[i - 6:i], walk[i][0]) == model.predict_step(walk[i - 6:i], walk[i][0])
    info = json.loads(pq.read_schema(tmp_path / "m.parquet").metadata[METADATA_KEY])
    assert info["version"] == 6 and info["params"]["action_scopes"] == {f"p{j}": [f"c{j}"] for j in range(3)}


def test_a_format_2_library_still_loads_and_a_broken_scope_is_refused(tmp_path):
    model = learned(2, None, train=300)
    model.save(tmp_path / "m.parquet")
    table = pq.read_table(tmp_path / "m.parquet")
    info = json.loads(table.schema.metadata[METADATA_KEY])

    def edited(change, name):  # the same row groups (one per table), another header
        doc = json.loads(json.dumps(info))
        change(doc)
        source = pq.ParquetFile(tmp_path / "m.parquet")
        since = {"view_calibration": 4, "view_rounds": 5, "view_persist": 6}
        kept = [c for c in table.column_names if doc["version"] >= since.get(c, 0)]
        schema = pa.schema([table.schema.field(c) for c in kept]).with_metadata({METADATA_KEY: json.dumps(doc)})
        with pq.ParquetWriter(tmp_path / name, schema) as out:
            for group in range(source.num_row_groups):
                out.write_table(source.read_row_group(group, columns=kept).cast(schema))
        return tmp_path / name

    old = load_library(edited(lambda d: d.update(version=2), "v2.parquet"))
    assert old.format_version == 2 and old.library.action_scopes == {}
    assert not old.library.mixer.calibration.any()  # older files have none: it starts from none
    assert old.library.mixer.rounds.tolist() == [old.library.clock] * len(old.library.view_names)  # their age
    assert np.all(old.library.mixer.persist == 1.0)  # untrained persistence: the answers speak
    bad = edited(lambda d: d["params"].update(action_scopes={"p0": ["p1"]}), "bad.parquet")
    with pytest.raises(LibraryFormatError, match="params.action_scopes.*'p1' has the role observation"):
        load_library(bad)
    shape = edited(lambda d: d["params"].update(action_scopes={"p0": "c0"}), "shape.parquet")
    with pytest.raises(LibraryFormatError, match="params.action_scopes.p0"):
        load_library(shape)


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 4), st.integers(0, 1000))
def test_merging_scoped_libraries_equals_one_run(parts, seed):
    vocabulary = learned(2, None, train=5).vocabulary
    episodes = [busy_walk(2, seed + k, 40) for k in range(parts + 1)]

    def run(chosen):
        library = PatternLibrary(max_length=2, vocabulary=vocabulary, action_scopes={"p0": ("c0",)})
        for steps in chosen:
            library.learn(Episode.from_steps([_symbols(vocabulary, s) for s in steps]))
        return LoadedLibrary(library, vocabulary, None, library_params(library), {})

    one = run(episodes).library
    merged = merge_libraries(run(episodes[:1]), run(episodes[1:])).library
    assert merged.action_scopes == one.action_scopes
    a, b = one.export(), merged.export()
    for key in ("view", "pattern_offsets", "pattern_tokens", "count", "last_seen"):
        assert np.array_equal(a[key], b[key]), key


def _symbols(vocabulary: Vocabulary, step) -> tuple:
    acts, obs = step
    return (tuple(vocabulary.symbol(c, v) for c, v in acts.items()),
            tuple(vocabulary.symbol(c, v) for c, v in obs.items()))


def test_libraries_of_other_scopes_do_not_merge(tmp_path):
    a, b = learned(2, {"p0": ["c0"]}, train=100), learned(2, None, train=100)
    for model, name in ((a, "a"), (b, "b")):
        model.save(tmp_path / f"{name}.parquet")
    with pytest.raises(Exception, match="action_scopes"):
        merge_libraries(load_library(tmp_path / "a.parquet"), load_library(tmp_path / "b.parquet"))


def test_a_scope_naming_a_channel_no_step_has_is_warned_about_once():
    model = SequenceModel(action_scopes={"p0": ["c9"]})
    with pytest.warns(DataWarning, match="'c9'"):
        model.learn_steps(busy_walk(2, 0, 20))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.learn_steps(busy_walk(2, 1, 20))  # said once
        learned(2, own(2), train=20)            # names that are there: nothing to say


def test_bad_scopes_are_refused_in_one_line():
    with pytest.raises(ParameterError, match="map observation channel names"):
        SequenceModel(action_scopes="p0")
    with pytest.raises(ParameterError, match="map observation channel names"):
        SequenceModel(action_scopes={"p0": "c0"})
    with pytest.raises(ParameterError, match="adaptive scoring"):
        SequenceModel(scoring="literal", action_scopes={"p0": ["c0"]})
    with pytest.raises(ParameterError, match="need a vocabulary"):
        PatternLibrary(action_scopes={"p0": ("c0",)})
    model = SequenceModel(action_scopes={"p0": ["p1"]})
    with pytest.raises(ParameterError, match="'p1' has the role observation, not action"):
        model.learn_steps(busy_walk(2, 0, 20))


def spec_text(extra: str, role: str = "observation") -> dict:
    import tomllib

    return tomllib.loads(f"""
[[channel]]
topic = "/cmd"
field = "data[0]"
role = "action"
[[channel]]
topic = "/cmd"
field = "data[1]"
role = "action"
[[channel]]
topic = "/state"
field = "position[0]"
role = "{role}"
{extra}
""")


def test_a_spec_declares_scopes_by_entry_name_and_checks_them():
    spec = _build_spec(spec_text('actions = ["/cmd:data[1]"]'), "arm.toml")
    assert spec.action_scopes() == {"/state": ("/cmd:data[1]",)}
    assert _build_spec(spec.to_dict(), "again").action_scopes() == spec.action_scopes()
    for extra, role, message in (
            ('actions = ["/cmd:data[7]"]', "observation", r"names '/cmd:data\[7\]', which is no entry"),
            ('actions = ["/state"]', "observation", "which is an observation entry"),
            ('actions = "/cmd:data[0]"', "observation", "must be a list of action entry names"),
            ('actions = ["/cmd:data[0]"]', "action", "belongs to observation entries")):
        with pytest.raises(SpecError, match=message):
            _build_spec(spec_text(extra, role), "arm.toml")



def test_the_command_line_shorthand_declares_scopes_too():
    spec = spec_from_options(["/cmd:data[0]:action:values=[-1;0;1]", "/cmd:data[1]:action:values=[-1;0;1]",
                              "/state:position[0]:observation:actions=[/cmd:data[1]],values=[0;1;2]",
                              "/state:position[1]:observation:actions=[],values=[0;1;2]"])
    assert spec.action_scopes() == {"/state:position[0]": ("/cmd:data[1]",), "/state:position[1]": ()}

def test_save_writes_format_3_only_with_its_scopes(tmp_path):
    vocabulary = learned(2, None, train=5).vocabulary
    library = PatternLibrary(max_length=2, vocabulary=vocabulary)
    library.learn(Episode.from_steps([_symbols(vocabulary, s) for s in busy_walk(2, 0, 30)]))
    save_library(tmp_path / "plain.parquet", library, vocabulary, spec=None, params={}, provenance={})
    info = json.loads(pq.read_schema(tmp_path / "plain.parquet").metadata[METADATA_KEY])
    assert "action_scopes" not in info["params"]


def test_info_of_a_scoped_library_names_each_views_actions(tmp_path):
    from click.testing import CliRunner

    from slearn.cli import main

    learned(2, {"p0": ["c0"], "p1": []}, train=100).save(tmp_path / "m.parquet")
    shown = CliRunner().invoke(main, ["info", str(tmp_path / "m.parquet")])
    assert shown.exit_code == 0, shown.output
    assert "p0 sees the actions of: c0" in shown.output and "p1 sees the actions of: none" in shown.output


def test_the_bench_finds_the_scopes_and_beats_the_dict_peers_on_a_busy_arm():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    import bench_scopes

    row = bench_scopes.measure(6, 3000, 0)
    assert row["found"]  # each joint exactly its own command, from the data
    assert row["scoped"] == row["last+own"] == 1.0  # the ceiling of a deterministic walk
    assert row["tuple"] < row["scoped"] and row["last+tuple"] < row["scoped"]
    assert row["scoped_patterns"] < row["tuple_patterns"] / 2
    slipping = bench_scopes.measure(5, 3000, 0, slip=0.2)  # moves one position off at times
    assert slipping["found"]
    assert slipping["scoped"] >= slipping["last+own"] - 0.01  # within a point of the ceiling
    assert slipping["last+own"] < 0.9 and slipping["last+tuple"] < slipping["scoped"] - 0.03
