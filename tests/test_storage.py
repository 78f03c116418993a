"""Library files: round trip, determinism, atomic writes, bad inputs, describe, merge."""

import json
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.stream import Episode
from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError, LibraryFormatError, SpecError
from slearn.io.library_file import METADATA_KEY, load_library, read_info, save_library
from slearn.io.library_header import FORMAT_VERSION
from slearn.io.library_info import describe
from slearn.io.spec import Bins, Categorical, ChannelSpec, Spec
from slearn.jobs.merge import merge_libraries

PARAMS = {"scoring": "literal"}
PROVENANCE = {"slearn_version": "test", "inputs": [{"path": "a.mcap", "size_bytes": 1, "sha256": "0" * 64}],
              "time": "2020-01-01T00:00:00Z", "time_unix": 1577836800, "time_source": "test"}


def mixed_spec() -> Spec:
    return Spec((
        ChannelSpec("/cmd", "name", "action", "cmd", Categorical()),
        ChannelSpec("/flag", "on", "action", "flag", Categorical()),
        ChannelSpec("/pos", "x", "observation", "pos", Bins(range=(0.0, 4.0), count=4)),
        ChannelSpec("/label", "text", "observation", "label", Categorical()),
        ChannelSpec("/pair", "xy", "observation", "pair", Categorical()),
        ChannelSpec("/temp", "t", "observation", "temp", Categorical()),
    ), mode="message")


def mixed_vocabulary() -> Vocabulary:
    """Values of every storable type; symbols 0.. in this order."""
    vocabulary = Vocabulary()
    for entry in mixed_spec().channels:
        vocabulary.add_channel(entry.name, entry.role)
    values = [("cmd", "go"), ("cmd", "stop"), ("flag", True), ("flag", False), ("pos", 0), ("pos", 1),
              ("pos", 2), ("pos", 3), ("label", "a b"), ("label", ""), ("pair", (1, 2)),
              ("pair", ("x", (3, 4.5))), ("temp", 21.5), ("temp", -0.0), ("temp", 7),
              ("cmd", 2 ** 70)]
    for channel, value in values:
        vocabulary.symbol(channel, value)
    return vocabulary


def random_episode(rng: np.random.Generator, steps: int) -> Episode:
    """Steps with 0-2 actions (symbols 0-3) and 0-2 observations (4-14)."""
    pairs = []
    for i in range(steps):
        actions = tuple(rng.integers(0, 4, rng.integers(0, 3))) if i else ()
        observations = tuple(rng.integers(4, 15, rng.integers(0, 3)))
        pairs.append((tuple(map(int, actions)), tuple(map(int, observations))))
    return Episode.from_steps(pairs)


def learned(seed: int = 0, episodes: int = 3, steps: int = 400, max_patterns=None) -> PatternLibrary:
    rng = np.random.default_rng(seed)
    library = PatternLibrary(4, max_patterns, has_actions=True)
    for _ in range(episodes):
        library.learn(random_episode(rng, steps))
    return library


def learned_literal(seed: int = 0, episodes: int = 3, steps: int = 400) -> LiteralLibrary:
    """The paper's rule on the same episodes as :func:`learned`."""
    rng = np.random.default_rng(seed)
    library = LiteralLibrary(4)
    for _ in range(episodes):
        library.learn(random_episode(rng, steps))
    return library


def save(path, library, vocabulary=None, spec=None, **kwargs):
    vocabulary = mixed_vocabulary() if vocabulary is None else vocabulary
    return save_library(path, library, vocabulary, spec=spec or mixed_spec(),
                        params=PARAMS, provenance=PROVENANCE, **kwargs)


def assert_same_library(a: PatternLibrary, b: PatternLibrary) -> None:
    ea, eb = a.export(), b.export()
    assert set(ea) == set(eb)
    for key in ea:
        np.testing.assert_array_equal(ea[key], eb[key], err_msg=key)
    for x, y in zip(a.tokens.export(), b.tokens.export()):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(getattr(a, "mixer", None) or (), getattr(b, "mixer", None) or ()):
        np.testing.assert_array_equal(x, y)
    assert (a.clock, a.forgotten, a.max_length, a.max_patterns, a.view_names) == (
        b.clock, b.forgotten, b.max_length, b.max_patterns, b.view_names)


# --- round trip ---------------------------------------------------------------------------

def test_round_trip_keeps_everything(tmp_path):
    library = learned(max_patterns=200)
    assert library.forgotten > 0
    summary = save(tmp_path / "lib.parquet", library)
    loaded = load_library(tmp_path / "lib.parquet")
    assert summary.n_patterns == len(library) == len(loaded.library)
    assert summary.size_bytes == (tmp_path / "lib.parquet").stat().st_size
    assert_same_library(library, loaded.library)
    assert loaded.library.patterns() == library.patterns()
    assert loaded.spec.to_dict() == mixed_spec().to_dict()
    assert loaded.params == {"scoring": "adaptive", "max_length": 4, "max_patterns": 200,
                             "factored": False, "has_actions": True}
    assert loaded.provenance == PROVENANCE and loaded.format_version == FORMAT_VERSION


def test_vocabulary_values_keep_their_types(tmp_path):
    vocabulary = mixed_vocabulary()
    save(tmp_path / "lib.parquet", learned(), vocabulary)
    loaded = load_library(tmp_path / "lib.parquet").vocabulary
    assert loaded.roles == vocabulary.roles
    got, want = list(loaded.items()), list(vocabulary.items())
    assert got == want
    assert [type(v) for _, _, v in got] == [type(v) for _, _, v in want]
    assert loaded.name(11) == ("pair", ("x", (3, 4.5)))
    assert loaded.get_symbol("cmd", 2 ** 70) == 15


def test_a_loaded_library_keeps_learning_like_the_original(tmp_path):
    original = learned(max_patterns=300)
    save(tmp_path / "lib.parquet", original)
    loaded = load_library(tmp_path / "lib.parquet").library
    rng = np.random.default_rng(9)
    for _ in range(3):
        episode = random_episode(rng, 300)
        original.learn(episode)
        loaded.learn(episode)
    assert original.forgotten > 0
    assert_same_library(original, loaded)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 31), st.integers(1, 3), st.integers(1, 60), st.integers(1, 5))
def test_round_trip_is_exact_for_any_stream(tmp_path_factory, seed, episodes, steps, max_length):
    rng = np.random.default_rng(seed)
    library = PatternLibrary(max_length, has_actions=True)
    for _ in range(episodes):
        library.learn(random_episode(rng, steps))
    path = tmp_path_factory.mktemp("h") / "lib.parquet"
    save(path, library)
    assert_same_library(library, load_library(path).library)


def test_an_empty_library_round_trips(tmp_path):
    save(tmp_path / "empty.parquet", PatternLibrary(), Vocabulary(), Spec(mixed_spec().channels[:1]))
    loaded = load_library(tmp_path / "empty.parquet")
    assert len(loaded.library) == 0 and len(loaded.vocabulary) == 0
    assert describe(tmp_path / "empty.parquet")["patterns"] == 0


def test_a_library_without_a_spec_round_trips(tmp_path):
    save_library(tmp_path / "lib.parquet", learned(), mixed_vocabulary(), spec=None, params={},
                 provenance={})
    assert load_library(tmp_path / "lib.parquet").spec is None


# --- file layout and writing --------------------------------------------------------------

def test_file_layout_patterns_are_token_lists_of_a_view(tmp_path):
    library = PatternLibrary(1, has_actions=True)
    library.learn(Episode.from_steps([((), (5,)), ((1,), (6, 7)), ((), (5,))]))
    save(tmp_path / "lib.parquet", library)
    schema = pq.read_schema(tmp_path / "lib.parquet")
    assert schema.field("pattern").type == pa.list_(pa.field("item", pa.int32(), nullable=False))
    info = json.loads(schema.metadata[METADATA_KEY])
    assert (info["format"], info["version"]) == ("slearn-library", 6)
    rows = pq.read_table(tmp_path / "lib.parquet").to_pylist()
    assert [r["table"] for r in rows] == sorted((r["table"] for r in rows),
                                                key=["vocabulary", "token", "view", "pattern"].index)
    tokens = {i: (r["token_kind"], tuple(r["token_symbols"]))
              for i, r in enumerate(r for r in rows if r["table"] == "token")}
    patterns = [([tokens[t] for t in r["pattern"]], r["count"], r["view"])
                for r in rows if r["table"] == "pattern"]
    obs, act = 0, 1
    # every context of at most one step before each observation: the action alone, then the
    # observation before it too; a step with two observations is one token of the joint view
    assert patterns == [([(act, (1,)), (obs, (6, 7))], 1, 0),
                        ([(obs, (5,)), (act, (1,)), (obs, (6, 7))], 1, 0),
                        ([(act, ()), (obs, (5,))], 1, 0),
                        ([(obs, (6, 7)), (act, ()), (obs, (5,))], 1, 0)]
    [view] = [r for r in rows if r["table"] == "view"]
    assert view["channel"] == "*" and len(view["view_weights"]) == 2 * 3
    assert pq.ParquetFile(tmp_path / "lib.parquet").metadata.num_row_groups == 4


def test_the_same_library_gives_the_same_bytes(tmp_path):
    save(tmp_path / "a.parquet", learned(seed=3))
    save(tmp_path / "b.parquet", learned(seed=3))
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()


def test_save_refuses_to_overwrite_and_leaves_no_temp_file(tmp_path):
    path = tmp_path / "lib.parquet"
    path.write_bytes(b"precious")
    with pytest.raises(InputError, match="already exists: pass --force"):
        save(path, learned())
    assert path.read_bytes() == b"precious"
    save(path, learned(), overwrite=True)
    assert len(load_library(path).library) == len(learned())
    assert os.listdir(tmp_path) == ["lib.parquet"]


def test_a_failed_save_does_not_touch_the_existing_file(tmp_path):
    path = tmp_path / "lib.parquet"
    save(path, learned())
    before = path.read_bytes()
    vocabulary = mixed_vocabulary()
    vocabulary.symbol("label", frozenset({1}))  # not storable
    with pytest.raises(InputError, match="cannot store value frozenset"):
        save(path, learned(), vocabulary, overwrite=True)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["lib.parquet"]


def test_a_write_that_breaks_midway_does_not_touch_the_existing_file(tmp_path, monkeypatch):
    import errno

    import slearn.io.library_file as storage

    path = tmp_path / "lib.parquet"
    save(path, learned())
    before = path.read_bytes()

    def disk_full(sink, tables, metadata):
        sink.write(b"PAR1 half a file")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(storage, "_write_parquet", disk_full)
    with pytest.raises(InputError, match=f"{path}: cannot write: No space left on device"):
        save(path, learned(seed=1), overwrite=True)
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["lib.parquet"]


def test_a_written_file_that_does_not_read_back_is_not_kept(tmp_path, monkeypatch):
    import slearn.io.library_file as storage

    path = tmp_path / "lib.parquet"
    save(path, learned())
    before = path.read_bytes()
    monkeypatch.setattr(storage, "_write_parquet", lambda sink, tables, metadata: sink.write(b"junk"))
    with pytest.raises(LibraryFormatError, match="does not read back"):
        save(path, learned(seed=1), overwrite=True)
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["lib.parquet"]


def test_save_into_a_missing_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        save(tmp_path / "nope" / "lib.parquet", learned())


# --- bad files ----------------------------------------------------------------------------

@pytest.fixture
def good(tmp_path):
    path = tmp_path / "good.parquet"
    save(path, learned(episodes=6))
    return path


def one_line(err) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize("keep", [0, 10, 0.5, -8, -1])
def test_a_truncated_library_is_refused(good, tmp_path, keep):
    data = good.read_bytes()
    cut = tmp_path / "cut.parquet"
    cut.write_bytes(data[: int(len(data) * keep) if isinstance(keep, float) else keep % len(data)])
    with pytest.raises(LibraryFormatError) as err:
        load_library(cut)
    assert one_line(err).startswith(f"{cut}: not a readable Parquet file")


def test_corrupted_pages_are_refused(good, tmp_path):
    data = bytearray(good.read_bytes())
    footer = pq.read_metadata(good)
    group = footer.row_group(2)
    start = group.column(9).data_page_offset  # the pattern column's data
    for i in range(start + 40, start + 60):
        data[i] ^= 0x5A
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(bytes(data))
    with pytest.raises(LibraryFormatError) as err:
        load_library(bad)
    assert one_line(err).startswith(f"{bad}: corrupted pattern library")


def test_a_parquet_file_that_is_not_a_library_is_refused(tmp_path):
    other = tmp_path / "table.parquet"
    pq.write_table(pa.table({"x": [1, 2, 3]}), other)
    with pytest.raises(LibraryFormatError) as err:
        load_library(other)
    assert one_line(err) == (f"{other}: a Parquet file, but not a slearn pattern library (no "
                             f"'slearn' metadata): make libraries with `slearn learn`")
    with pytest.raises(LibraryFormatError, match="not a slearn pattern library"):
        describe(other)


def with_metadata(good, tmp_path, change):
    table = pq.read_table(good)
    info = json.loads(table.schema.metadata[METADATA_KEY])
    change(info)
    path = tmp_path / "edited.parquet"
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(info)}), path)
    return path


def test_a_library_from_a_newer_format_version_is_refused(good, tmp_path):
    newer = with_metadata(good, tmp_path, lambda info: info.update(version=FORMAT_VERSION + 1))
    with pytest.raises(LibraryFormatError) as err:
        load_library(newer)
    assert f"library format version {FORMAT_VERSION + 1} is newer than this slearn" in one_line(err)
    assert "upgrade slearn" in one_line(err)


def test_another_format_name_is_refused(good, tmp_path):
    other = with_metadata(good, tmp_path, lambda info: info.update(format="something-else"))
    with pytest.raises(LibraryFormatError, match="not a slearn pattern library"):
        load_library(other)


def test_metadata_that_disagrees_with_the_rows_is_refused(good, tmp_path):
    wrong = with_metadata(good, tmp_path, lambda info: info["library"]["rows"].update(token=1))
    with pytest.raises(LibraryFormatError) as err:
        load_library(wrong)
    assert str(wrong) in one_line(err)


def test_a_missing_file_is_refused(tmp_path):
    with pytest.raises(LibraryFormatError, match="no such library file"):
        load_library(tmp_path / "none.parquet")


def test_read_info_is_the_small_metadata(good):
    info = read_info(good)
    assert info["params"]["max_length"] == 4 and info["provenance"] == PROVENANCE


# --- describe -----------------------------------------------------------------------------

def test_describe_gives_counts_histogram_and_decoded_top_patterns(tmp_path):
    vocabulary = Vocabulary()
    vocabulary.add_channel("cmd", "action")
    vocabulary.add_channel("pos", "observation")
    for value in ("L", "R"):
        vocabulary.symbol("cmd", value)
    for k in range(1, 7):
        vocabulary.symbol("pos", k)
    library = LiteralLibrary()
    # positions 1..6 are symbols 2..7; "3 R 4 R 5 L 4 R 5 L 4 L 3 L 2" (the paper's example)
    library.learn(Episode.from_pairs([4], [1, 1, 0, 1, 0, 0, 0], [5, 6, 5, 6, 5, 4, 3]))
    save_library(tmp_path / "p.parquet", library, vocabulary, spec=None, params={}, provenance={})
    doc = describe(tmp_path / "p.parquet")
    assert doc["patterns"] == 6 and doc["length_histogram"] == {"1": 5, "2": 1}
    assert doc["total_count"] == 7 and doc["clock"] == 7
    assert doc["top_patterns"][0]["pattern"] == "4 R 5" and doc["top_patterns"][0]["count"] == 2
    assert doc["top_patterns"][0]["tokens"] == [{"pos": 4}, {"cmd": "R"}, {"pos": 5}]
    assert doc["bytes_per_pattern"] == pytest.approx((tmp_path / "p.parquet").stat().st_size / 6)
    assert doc["vocabulary"]["channels"][1] == {"channel": "pos", "role": "observation",
                                                "n_values": 6, "values": [1, 2, 3, 4, 5, 6]}
    json.dumps(doc.to_dict())
    assert "4 R 5" in doc.render()


# --- merge --------------------------------------------------------------------------------

def pointer_vocab(order) -> Vocabulary:
    vocabulary = Vocabulary()
    vocabulary.add_channel("cmd", "action")
    vocabulary.add_channel("pos", "observation")
    for channel, value in order:
        vocabulary.symbol(channel, value)
    return vocabulary


def learn_named(vocabulary: Vocabulary, walks: list[str]) -> LiteralLibrary:
    """Walks like ``"3 R 4 L 3"`` learned by the paper's rule with the vocabulary's symbols."""
    library = LiteralLibrary()
    for walk in walks:
        words = walk.split()
        steps = [((), (vocabulary.symbol("pos", int(words[0])),))]
        steps += [((vocabulary.symbol("cmd", a),), (vocabulary.symbol("pos", int(o)),))
                  for a, o in zip(words[1::2], words[2::2])]
        library.learn(Episode.from_steps(steps))
    return library


def named_patterns(loaded) -> dict[tuple, tuple[int, int]]:
    """Pattern spelled with values -> (count, age: steps before the end of learning)."""
    out = {}
    library, vocabulary = loaded.library, loaded.vocabulary
    for p in library.iter_patterns():
        key = tuple(vocabulary.name(s)[1] for t in p.tokens for s in library.tokens.symbols(t))
        out[key] = (p.count, library.clock - p.last_seen)
    return out


def loaded(vocabulary, library, spec=None, path=None):
    from slearn.io.library_file import LoadedLibrary, library_params
    return LoadedLibrary(library, vocabulary, spec, library_params(library), dict(PROVENANCE), 2, path)


def test_merge_adds_counts_takes_recency_on_one_clock_and_remaps_symbols():
    walks_a = ["3 R 4 R 5 L 4 R 5 L 4 L 3", "4 R 5 L 4"]
    walks_b = ["5 L 4 R 5 R 6 L 5", "3 R 4 R 5"]
    va = pointer_vocab([("cmd", "L"), ("cmd", "R")])
    vb = pointer_vocab([("pos", 6), ("cmd", "R"), ("pos", 5), ("cmd", "L")])  # other symbols
    a, b = loaded(va, learn_named(va, walks_a)), loaded(vb, learn_named(vb, walks_b))
    merged = merge_libraries(a, b)
    assert merged.library.clock == a.library.clock + b.library.clock
    pa_, pb, pm = named_patterns(a), named_patterns(b), named_patterns(merged)
    assert set(pm) == set(pa_) | set(pb)
    for key, (count, age) in pm.items():  # as one run over a's episodes, then b's
        ca, aa = pa_.get(key, (0, None))
        cb, ab = pb.get(key, (0, None))
        assert count == ca + cb
        assert age == (ab if ab is not None else aa + b.library.clock)
    assert merged.vocabulary.get_symbol("pos", 6) is not None
    assert merged.provenance["inputs"] == PROVENANCE["inputs"] * 2
    # the merged library keeps learning like any library
    merged.library.learn(Episode.from_steps([((), (merged.vocabulary.symbol("pos", 3),))]))


def test_merge_equals_learning_both_when_parses_do_not_interact():
    va = pointer_vocab([])
    walks = ["1 R 2 R 3", "7 L 6 L 5 R 6"]
    both = learn_named(va, walks)
    merged = merge_libraries(loaded(va, learn_named(va, walks[:1])), loaded(va, learn_named(va, walks[1:])))
    assert {k: v[0] for k, v in named_patterns(merged).items()} == {
        k: v[0] for k, v in named_patterns(loaded(va, both)).items()}


def test_merge_refuses_another_max_length():
    v = pointer_vocab([])
    short = PatternLibrary(3)
    with pytest.raises(SpecError, match="cannot merge a.parquet and library B: max_length 6 vs 3"):
        merge_libraries(loaded(v, PatternLibrary(), path="a.parquet"), loaded(v, short))
    with pytest.raises(SpecError, match=r"learn one again with the other's \(`slearn info --json` shows them\)$"):
        merge_libraries(loaded(v, PatternLibrary(), path="a.parquet"), loaded(v, short))


@pytest.mark.parametrize("change, reason", [
    (lambda c: [c[0], ChannelSpec("/p", "x", "observation", "other", c[1].symbolizer)], "different channels"),
    (lambda c: [c[0], ChannelSpec("/p", "x", "action", "pos", c[1].symbolizer)], "role differ"),
    (lambda c: [c[0], ChannelSpec("/p", "x", "observation", "pos", Bins(edges=(0.5, 2.0)))], "bins differ"),
])
def test_merge_refuses_incompatible_specs_with_a_reason(change, reason):
    channels = [ChannelSpec("/c", "c", "action", "cmd", Categorical(("L", "R"))),
                ChannelSpec("/p", "x", "observation", "pos", Bins(edges=(0.5, 1.5)))]
    v = pointer_vocab([])
    a = loaded(v, PatternLibrary(), Spec(tuple(channels)))
    b = loaded(v, PatternLibrary(), Spec(tuple(change(channels))))
    with pytest.raises(SpecError, match=reason):
        merge_libraries(a, b)


def test_token_table_find_all_matches_find():
    table = TokenTable()
    for kind, symbols in [(0, (1, 2)), (1, ()), (0, (3,)), (1, (4, 5, 6))]:
        table.intern(kind, symbols)
    found = table.find_all(np.array([0, 1, 0, 1, 1], np.int8), np.array([1, 2, 3, 4, 5, 6, 3]),
                           np.array([0, 2, 2, 3, 6, 7]))
    assert found.tolist() == [0, 1, 2, 3, -1]


def test_tables_split_over_many_row_groups_round_trip(tmp_path, monkeypatch):
    import slearn.io.library_file as storage

    monkeypatch.setattr(storage, "ROW_GROUP_ROWS", 7)
    library = learned(seed=5)
    save(tmp_path / "lib.parquet", library)
    assert pq.ParquetFile(tmp_path / "lib.parquet").metadata.num_row_groups > 20
    loaded = load_library(tmp_path / "lib.parquet")
    assert_same_library(library, loaded.library)
    assert list(loaded.vocabulary.items()) == list(mixed_vocabulary().items())


def rewrite(source, target, change):
    """Copy a library file with ``change(table)`` applied, one row group per table as saved."""
    table = change(pq.read_table(source))
    names = table.column("table").to_pylist()
    with pq.ParquetWriter(target, table.schema) as writer:
        for name in ("vocabulary", "token", "view", "pattern"):
            rows = [i for i, n in enumerate(names) if n == name]
            if rows:
                writer.write_table(table.slice(rows[0], len(rows)))


def test_parent_column_names_each_pattern_prefix_and_is_only_a_hint(tmp_path):
    library = learned_literal(seed=4)
    save(tmp_path / "lib.parquet", library)
    rows = pq.read_table(tmp_path / "lib.parquet").to_pylist()
    patterns = [r for r in rows if r["table"] == "pattern"]
    for row in patterns:
        if row["parent"] >= 0:
            prefix = patterns[row["parent"]]
            assert len(prefix["pattern"]) == len(row["pattern"]) - 2
            assert row["pattern"][: len(prefix["pattern"])] == prefix["pattern"]
        else:
            assert len(row["pattern"]) == 3

    def scramble(table):
        parent = np.asarray(table.column("parent").fill_null(0))
        noise = np.random.default_rng(0).integers(-1, len(patterns), len(parent)).astype(np.int32)
        scrambled = np.where(np.asarray(table.column("table")) == "pattern", noise, parent)
        index = table.schema.get_field_index("parent")
        return table.set_column(index, "parent", pa.array(scrambled, pa.int32()))

    rewrite(tmp_path / "lib.parquet", tmp_path / "scrambled.parquet", scramble)
    assert_same_library(library, load_library(tmp_path / "scrambled.parquet").library)


def test_wrong_parent_hints_that_undercount_nodes_still_rebuild_exactly():
    library = learned_literal(seed=6, episodes=4, steps=2_000)
    arrays = library.export()
    right = LiteralLibrary.from_export({**arrays, "pattern_parent": library.pattern_parents()},
                                       library.tokens, library.clock, library.max_length)
    assert_same_library(library, right)
    # 1 pattern O A O then 2,000 unrelated O A O A O patterns, all "hinted" to the first:
    # the hints pass the length check, so the node estimate is far too small
    n = 2_000
    tokens = np.arange(5 * n).reshape(n, 5)
    flat = np.concatenate([[0, 1, 2], tokens.ravel() + 3]).astype(np.int32)
    synthetic = {"pattern_offsets": np.concatenate([[0], 3 + 5 * np.arange(n + 1)]).astype(np.int64),
                 "pattern_tokens": flat, "count": np.arange(n + 1) + 1, "last_seen": np.arange(n + 1)}
    hints = np.concatenate([[-1], np.zeros(n, np.int64)])
    plain = LiteralLibrary.from_export(synthetic, TokenTable(), n + 1, 2)
    hinted = LiteralLibrary.from_export({**synthetic, "pattern_parent": hints}, TokenTable(), n + 1, 2)
    assert_same_library(plain, hinted)
    assert len(hinted) == n + 1 and hinted.export()["count"].tolist() == list(range(1, n + 2))


@pytest.mark.parametrize("damage", ["more hits than trials", "negative", "cells missing"])
def test_damaged_calibration_counts_are_refused_naming_the_file(tmp_path, damage):
    library = learned(seed=2)
    save(tmp_path / "lib.parquet", library)
    assert load_library(tmp_path / "lib.parquet").library.mixer.calibration.sum() > 0

    def corrupt(table):
        column = table.column("view_calibration").to_pylist()
        edited = []
        for cells in column:
            if cells is not None:
                cells = list(cells)
                if damage == "more hits than trials":
                    cells[0] = cells[1] + 1
                elif damage == "negative":
                    cells[1] = -1
                else:
                    cells = cells[:-2]
            edited.append(cells)
        index = table.schema.get_field_index("view_calibration")
        return table.set_column(index, table.schema.field(index), pa.array(edited, table.schema.field(index).type))

    rewrite(tmp_path / "lib.parquet", tmp_path / "bad.parquet", corrupt)
    with pytest.raises(LibraryFormatError, match=r"bad\.parquet: the view table's calibration counts"):
        load_library(tmp_path / "bad.parquet")
