"""The pattern library: every occurrence counted (against a dict model), views, forgetting,
exact merging, determinism, export round trips."""

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule
from naive import NaiveOccurrences

from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.core.tokens import ACTION
from slearn.core.vocabulary import ACTION as ACTION_ROLE
from slearn.core.vocabulary import OBSERVATION, Vocabulary
from slearn.errors import ParameterError, SlearnError
from slearn.io.library_file import LoadedLibrary, library_params
from slearn.jobs.merge import merge_libraries


def two_channel_vocabulary() -> Vocabulary:
    """``cmd`` (action: 0, 1), ``a`` (observation: 2..5), ``b`` (observation: 6..9)."""
    vocabulary = Vocabulary()
    vocabulary.add_channel("cmd", ACTION_ROLE)
    vocabulary.add_channel("a", OBSERVATION)
    vocabulary.add_channel("b", OBSERVATION)
    for channel, values in (("cmd", "LR"), ("a", range(4)), ("b", range(4))):
        for value in values:
            vocabulary.symbol(channel, value)
    return vocabulary


VIEW_OF = {s: 0 for s in range(2, 6)} | {s: 1 for s in range(6, 10)}


def steps_strategy(max_steps=25):
    step = st.tuples(st.lists(st.sampled_from([0, 1]), max_size=1).map(tuple),
                     st.lists(st.sampled_from(list(range(2, 10))), max_size=2, unique_by=lambda s: VIEW_OF[s])
                     .map(lambda xs: tuple(sorted(xs))))
    return st.lists(step, min_size=1, max_size=max_steps)


def decoded(library: PatternLibrary) -> dict:
    """``(view, context, outcome) -> [count, last_seen]`` with tokens as ``(kind, symbols)``."""
    def name(token):
        kind = "A" if library.tokens.kind(token) == ACTION else "O"
        return kind, library.tokens.symbols(token)
    return {(p.view, tuple(name(t) for t in p.context), name(p.outcome)): [p.count, p.last_seen]
            for p in library.patterns()}


class OccurrencesAgainstNaive(RuleBasedStateMachine):
    """Random two-channel episodes learned by the library and by the dict model."""

    def __init__(self):
        super().__init__()
        self.library = PatternLibrary(max_length=2, vocabulary=two_channel_vocabulary())
        self.naive = NaiveOccurrences(4, VIEW_OF, has_actions=True)

    @rule(steps=steps_strategy())
    def learn_episode(self, steps):
        steps = [((), obs) if i == 0 else (acts, obs) for i, (acts, obs) in enumerate(steps)]
        self.library.learn(Episode.from_steps(steps))
        self.naive.learn(steps)

    @invariant()
    def same_patterns_counts_and_recency(self):
        assert decoded(self.library) == self.naive.patterns
        assert self.library.clock == self.naive.clock

    @invariant()
    def fresh_counts_equal_counts_without_an_alarm(self):
        export = self.library.export()
        for v, epoch in enumerate(self.library.mixer.epoch if self.library.mixer is not None else []):
            if epoch == 0:
                rows = export["view"] == v
                assert np.array_equal(export["fresh"][rows], export["count"][rows])


    @invariant()
    def node_sums_are_those_of_the_entries(self):
        assert_fresh_sums(self.library)


def assert_fresh_sums(library: PatternLibrary) -> None:
    """Each node's ``fresh_total`` and ``fresh_outcomes`` are its entries' fresh counts summed
    and counted (what the detector's hit probability reads instead of walking them)."""
    if library.tree is None:
        return
    tree = library.tree
    n, m = int(tree.size[0]), int(tree.size[1])
    owner, fresh = tree.owner[:m], tree.fresh[:m]
    assert np.array_equal(tree.fresh_total[:n], np.bincount(owner, weights=fresh, minlength=n).astype(np.int64))
    assert np.array_equal(tree.fresh_outcomes[:n], np.bincount(owner[fresh > 0], minlength=n))


TestOccurrencesAgainstNaive = OccurrencesAgainstNaive.TestCase
TestOccurrencesAgainstNaive.settings = settings(max_examples=40, stateful_step_count=8, deadline=None)


def pointer_like(rng: np.random.Generator, n: int, bins: int = 8) -> Episode:
    """A deterministic walk (``R`` +1, ``L`` -1) over ``bins`` positions, symbols 2.."""
    commands = rng.integers(0, 2, n)
    positions = (rng.integers(bins) + np.cumsum(np.where(commands == 1, 1, -1))) % bins
    start = (positions[0] - (1 if commands[0] else -1)) % bins
    return Episode.from_pairs([int(start) + 2], commands, positions + 2)


def test_a_deterministic_walk_is_predicted_perfectly_once_seen():
    library = PatternLibrary()
    episode = pointer_like(np.random.default_rng(0), 4000)
    codes = library.encode(episode)
    reports = library.run(codes, learn=True, record=True)
    right = reports.predicted[2000:] == codes.token[2000:]
    assert right.all()


def test_every_context_up_to_max_length_is_stored():
    library = PatternLibrary(max_length=3)
    library.learn(Episode.from_pairs([2], [0, 1, 0, 1], [3, 2, 3, 2]))
    lengths = sorted({len(p.context) for p in library.patterns()})
    assert lengths == [1, 2, 3, 4, 5, 6]  # actions alone up to three whole steps before


def test_no_action_streams_use_observations_only():
    library = PatternLibrary(max_length=2)
    library.learn(Episode.from_steps([((), (s,)) for s in (5, 6, 5, 6, 5)]))
    assert not library.has_actions
    assert {len(p.context) for p in library.patterns()} == {1, 2}
    assert all(library.tokens.kind(t) != ACTION for p in library.patterns() for t in p.context)


def test_same_stream_gives_the_same_library_byte_for_byte():
    exports = []
    for _ in range(2):
        library = PatternLibrary(max_length=3)
        library.learn(pointer_like(np.random.default_rng(7), 3000))
        exports.append(library.export())
    for key in exports[0]:
        assert exports[0][key].tobytes() == exports[1][key].tobytes()


def naming(n: int = 40) -> Vocabulary:
    """Symbols 0, 1 as actions ``cmd``, 2.. as observations ``pos``."""
    vocabulary = Vocabulary()
    vocabulary.add_channel("cmd", ACTION_ROLE)
    vocabulary.add_channel("pos", OBSERVATION)
    for s in range(n):
        vocabulary.symbol("cmd" if s < 2 else "pos", s)
    return vocabulary


def loaded(library: PatternLibrary, vocabulary: Vocabulary | None = None) -> LoadedLibrary:
    return LoadedLibrary(library, vocabulary or naming(), None, library_params(library), {})


@settings(max_examples=25, deadline=None)
@given(st.lists(steps_strategy(40), min_size=2, max_size=5), st.integers(1, 4))
def test_merging_separately_learned_libraries_equals_one_run(episodes, cut):
    cut = min(cut, len(episodes) - 1)
    vocabulary = two_channel_vocabulary()

    def learned(chosen):
        library = PatternLibrary(max_length=2, vocabulary=vocabulary)
        for steps in chosen:
            library.learn(Episode.from_steps(steps))
        return library

    one = learned(episodes)
    merged = merge_libraries(loaded(learned(episodes[:cut]), vocabulary),
                             loaded(learned(episodes[cut:]), vocabulary)).library
    a, b = one.export(), merged.export()
    for key in ("view", "pattern_offsets", "pattern_tokens", "count", "last_seen"):
        assert np.array_equal(a[key], b[key]), key
    assert merged.clock == one.clock
    assert_fresh_sums(merged)


def _state(library: PatternLibrary) -> dict:
    """Everything a saved library holds, and what learning on would change."""
    out = {f"export.{k}": v.tobytes() for k, v in library.export().items()}
    out |= {f"mixer.{i}": a.tobytes() for i, a in enumerate(library.mixer)}
    return out | {"clock": library.clock, "views": tuple(library.view_names), "tokens": len(library.tokens)}


def _merged_by_rebuilding(la: LoadedLibrary, lb: LoadedLibrary) -> PatternLibrary:
    """The merge rule spelled out (merge.py's module docstring): ``a`` rebuilt from its
    export with the merged state, its fresh counts dropped in the views where ``b`` raised
    an alarm, then ``b``'s patterns counted in."""
    from slearn.jobs.merge import _merged_mixer, _merged_tokens, _merged_vocabulary

    a, b = la.library, lb.library
    vocabulary, symbol_map = _merged_vocabulary(la.vocabulary, lb.vocabulary)
    tokens, token_map = _merged_tokens(a.tokens, b.tokens, symbol_map)
    names = list(a.view_names) + [v for v in b.view_names if v not in a.view_names]
    view_map = np.array([names.index(v) for v in b.view_names], np.int32)
    alarmed = np.zeros(len(names), bool)
    alarmed[view_map] = b.mixer.epoch[:len(view_map)] > 0
    ea = a.export()
    ea["fresh"] = np.where(alarmed[ea["view"]], 0, ea["fresh"])
    merged = PatternLibrary.from_export(ea, tokens=tokens, clock=a.clock + b.clock, view_names=names,
                                        mixer=_merged_mixer(a, b, names, view_map), max_length=a.max_length,
                                        vocabulary=vocabulary, has_actions=True)
    eb = b.export()
    merged.add_export({**eb, "view": view_map[eb["view"]], "pattern_tokens": token_map[eb["pattern_tokens"]]},
                      shift=a.clock)
    return merged


def test_a_view_neither_library_trained_merges_untrained():
    # b brings a view it never predicted in (rounds 0): one run over both would leave its
    # scoring state as a new library has it, the tie-breaking prior included (until
    # 2026-12-07 its weights merged as zeros)
    from types import SimpleNamespace

    from slearn.core.mixer import new_mixer
    from slearn.jobs.merge import _merged_mixer

    trained = new_mixer(1, 3)
    trained.weight[:] = 0.5
    trained.rounds[:] = 7
    b_mixer = new_mixer(2, 3)
    b_mixer.weight[0] = 0.25
    b_mixer.rounds[0] = 3
    a = SimpleNamespace(mixer=trained, view_names=["x"], max_context=3)
    b = SimpleNamespace(mixer=b_mixer, view_names=["x", "y"], max_context=3)
    merged = _merged_mixer(a, b, ["x", "y"], np.array([0, 1], np.int32))
    untrained = new_mixer(1, 3)
    np.testing.assert_array_equal(merged.weight[0], b_mixer.weight[0])  # b trained x last
    assert merged.rounds[0] == 3
    for field, fresh in zip(merged, untrained):
        np.testing.assert_array_equal(field[1], fresh[0])


@pytest.mark.parametrize("case", ["pointer", "alarms", "new view", "live first"])
def test_a_merge_in_place_is_the_rebuilt_merge(case):
    # merge_libraries rebases the first library (consume=True: in place, else a copy) instead of
    # rebuilding it: the same patterns, fresh counts, weights and clock as the rule spelled out,
    # and learning on gives the same
    rng = np.random.default_rng(11)
    vocabulary = naming(60)

    def learned(pairs, names=vocabulary):
        library = PatternLibrary(max_length=3, vocabulary=names)
        for commands, positions in pairs:
            library.learn(Episode.from_pairs([2], commands, positions))
        return library

    def stream(n, symbols):
        return rng.integers(0, 2, n), rng.integers(2, symbols, n)

    def walk(n, sign):  # a pointer of 7 positions, each command one step (sign: its direction)
        commands = rng.integers(0, 2, n)
        return commands, 2 + (np.cumsum(sign * (2 * commands - 1)) % 7)

    first = [stream(1500, 9), stream(800, 9)] if case != "alarms" else [walk(1500, 1)]
    second = [stream(1200, 9)] if case != "alarms" else [walk(3000, 1), walk(3000, -1)]  # b reverses: alarms
    later = stream(700, 9)
    names_b = vocabulary
    if case == "new view":  # b names a channel a never saw
        names_b = naming(60)
        names_b.add_channel("other", OBSERVATION)
        names_b.symbol("other", 0)
    second_learned = learned(second, names_b)
    if case == "alarms":
        assert second_learned.mixer.epoch.max() > 0
    expected = _merged_by_rebuilding(loaded(learned(first), vocabulary), loaded(second_learned, names_b))
    kept = learned(first)
    before = _state(kept)
    copied = merge_libraries(loaded(kept, vocabulary), loaded(learned(second, names_b), names_b))
    assert _state(kept) == before  # without consume the first library is left as it was
    a = learned(first)
    if case != "live first":  # as merge_files has it: the first library loaded from its file
        a = PatternLibrary.from_export(a.export(), tokens=a.tokens, clock=a.clock, view_names=a.view_names,
                                       mixer=a.mixer, max_length=3, vocabulary=vocabulary, has_actions=True)
    in_place = merge_libraries(loaded(a, vocabulary), loaded(learned(second, names_b), names_b), consume=True)
    assert in_place.library is a and copied.library is not kept
    for merged in (copied.library, in_place.library):
        assert _state(merged) == _state(expected)
        assert_fresh_sums(merged)
    for merged in (expected, copied.library, in_place.library):
        merged.learn(Episode.from_pairs([2], *later))
    assert _state(in_place.library) == _state(copied.library) == _state(expected)


def test_merge_keeps_the_order_of_first_sight_and_shifts_recency():
    first, second = PatternLibrary(max_length=1), PatternLibrary(max_length=1)
    first.learn(Episode.from_pairs([2], [0], [3]))
    second.learn(Episode.from_pairs([2], [0], [3]))
    second.learn(Episode.from_pairs([3], [1], [2]))
    merged = merge_libraries(loaded(first), loaded(second)).library
    counts = {(p.context, p.outcome): (p.count, p.last_seen) for p in merged.patterns()}
    assert len(merged.patterns()) == 4
    assert merged.clock == first.clock + second.clock == 6  # steps, the first reading included
    assert max(c for c, _ in counts.values()) == 2
    assert max(seen for _, seen in counts.values()) == 5  # second's last step, after first's two


def test_export_round_trip_keeps_patterns_and_learning_state():
    rng = np.random.default_rng(3)
    library = PatternLibrary(max_length=3)
    library.learn(pointer_like(rng, 2000))
    again = PatternLibrary.from_export(library.export(), tokens=library.tokens, clock=library.clock,
                                       view_names=library.view_names, mixer=library.mixer,
                                       max_length=3, has_actions=True)
    assert again.patterns() == library.patterns()
    assert_fresh_sums(again)
    follow_up = pointer_like(rng, 500)
    library.learn(follow_up)
    again.learn(follow_up)
    assert again.patterns() == library.patterns()
    assert_fresh_sums(again)


def test_node_sums_follow_alarms_and_forgetting():
    # an iid stream over many symbols: its contexts seen once raise alarms (new epochs)
    rng = np.random.default_rng(5)
    library = PatternLibrary(max_length=3, max_patterns=3000)
    for _ in range(3):
        library.learn(Episode.from_pairs([2], rng.integers(0, 2, 3000), rng.integers(2, 60, 3000)))
    assert library.mixer is not None and library.mixer.epoch.max() > 0 and library.forgotten > 0
    assert_fresh_sums(library)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(16, 300))
def test_forgetting_bounds_the_library_and_keeps_contexts_consistent(seed, bound):
    library = PatternLibrary(max_length=3, max_patterns=bound)
    rng = np.random.default_rng(seed)
    library.learn(Episode.from_pairs([2], rng.integers(0, 2, 1500), rng.integers(2, 9, 1500)))
    assert len(library) <= bound
    assert library.forgotten > 0
    by_context = {(p.view, p.context, p.outcome): p.count for p in library.patterns()}
    for (view, context, outcome), count in by_context.items():
        if len(context) > 1:  # a longer context is never kept without its shorter one
            assert by_context.get((view, context[1:], outcome), 0) >= count


def test_forgetting_drops_rare_patterns_first():
    library = PatternLibrary(max_length=2, max_patterns=60)
    for _ in range(20):
        library.learn(Episode.from_pairs([2], [0], [3]))  # old but frequent
    rng = np.random.default_rng(1)
    library.learn(Episode.from_pairs([4], rng.integers(0, 2, 400), rng.integers(4, 20, 400)))
    assert library.forgotten > 100
    assert any(p.count == 20 for p in library.patterns())


def test_frozen_runs_change_nothing():
    library = PatternLibrary()
    library.learn(pointer_like(np.random.default_rng(4), 3000))
    before = (library.export(), [a.copy() for a in library.mixer], library.clock)
    codes = library.encode(pointer_like(np.random.default_rng(5), 500))
    library.run(codes, learn=False, record=True)
    after = (library.export(), library.mixer, library.clock)
    for key in before[0]:
        assert np.array_equal(before[0][key], after[0][key])
    for a, b in zip(before[1], after[1]):
        assert np.array_equal(a, b)
    assert before[2] == after[2]


def test_bad_parameters_are_refused_with_a_slearn_error_that_is_a_value_error():
    for kwargs in ({"max_length": 0}, {"max_length": 10 ** 9}, {"max_patterns": 3},
                   {"max_length": True}, {"max_patterns": 10 ** 20}):
        with pytest.raises(ParameterError) as err:
            PatternLibrary(**kwargs)
        assert isinstance(err.value, ValueError) and isinstance(err.value, SlearnError)


def test_a_symbol_used_as_action_and_observation_needs_a_vocabulary():
    library = PatternLibrary()
    with pytest.raises(ParameterError):
        library.learn(Episode.from_pairs([1], [1], [2]))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.lists(st.integers(0, 9), max_size=3), st.lists(st.integers(0, 9), max_size=3)),
                min_size=1, max_size=12))
def test_the_joint_mapping_is_every_observed_symbol_and_refuses_shared_ones(steps):
    from slearn.core.views import NO_VIEW, joint_mapping
    episode = Episode.from_steps([(tuple(a), tuple(o)) for a, o in steps])
    acted = {s for a, _ in steps for s in a}
    observed = {s for _, o in steps for s in o}
    if acted & observed:
        with pytest.raises(ParameterError, match="both as an action and as an observation"):
            joint_mapping(episode)
        return
    mapping = joint_mapping(episode)
    size = max(acted | observed) + 1 if acted | observed else 0
    assert mapping.tolist() == [0 if s in observed else NO_VIEW for s in range(size)]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([None, 30, 100]), st.integers(1, 4))
def test_a_contexts_outcomes_include_those_of_every_longer_context_through_it(seed, max_patterns, max_length):
    """Every occurrence is counted at every length, and forgetting drops longer contexts
    first: an outcome counted after a context is counted after its shorter suffix (its
    parent, unless that is a view's root) too. The predictor ranks a chosen context's
    outcomes, then the shorter ones', and when they fill the ranking it remembers it for
    every query that chooses the same context, whatever longer contexts it found."""
    rng = np.random.default_rng(seed)
    library = PatternLibrary(max_length=max_length, max_patterns=max_patterns)
    for _ in range(3):
        obs = rng.integers(0, 4, 151)
        library.learn(Episode.from_pairs(obs[:1], rng.integers(100, 102, 150), obs[1:]))
    tree = library.tree
    counted = {(int(tree.owner[e]), int(tree.outcome[e])) for e in range(int(tree.size[1]))
               if tree.owner[e] >= 0 and tree.count[e] > 0}
    longer = [(node, outcome) for node, outcome in counted if tree.parent[tree.parent[node]] >= 0]
    assert longer or max_length == 1
    for node, outcome in longer:
        assert (int(tree.parent[node]), outcome) in counted


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="reads this process's RSS")
def test_a_trees_unused_room_is_not_resident_and_grown_out_arrays_go_back():
    """The room of a tree is reserved, not written: resident memory follows the hash slots
    (written whole) and what is held, not the capacity; growing frees the old arrays."""
    import gc

    from slearn.core import context_tree

    def resident_mb() -> float:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    library = PatternLibrary(max_length=2)
    library.learn(Episode.from_pairs(np.array([0]), np.full(20_000, 7), np.arange(20_000) % 5))
    gc.collect()
    before = resident_mb()  # after compiling
    tree = context_tree.new_tree(4_000_000, 4_000_000)  # 256 MB of room, 64 MB of slots
    room_mb = sum(getattr(tree, name).nbytes for name in tree._fields if not name.endswith("slots")) / 2**20
    slots_mb = (tree.node_slots.nbytes + tree.entry_slots.nbytes) / 2**20
    assert room_mb > 200
    assert resident_mb() - before < slots_mb + 0.25 * room_mb
    grown_from = library.tree
    library.tree = context_tree.grow(library.tree, 3_000_000, 3_000_000)
    assert library.tree is not grown_from and library.tree.size.tolist() == grown_from.size.tolist()
    del grown_from, tree
    gc.collect()
    assert resident_mb() - before < slots_mb + 0.25 * room_mb  # the old and the unused went back


def test_a_rebuilt_node_table_is_the_one_learning_built_and_needs_parents_first():
    """Nodes are placed by path hash as they are added, in id order; rebuilding the table
    (as growing and forgetting do) places them the same way, slot for slot. A node
    numbered before its parent cannot be placed (its path is not known yet): refused."""
    from slearn.core.context_tree import rebuild_nodes
    from slearn.recorders.pointer import PointerConfig, simulate

    library = PatternLibrary()
    library.learn(simulate(PointerConfig("error", trials=3000, seed=3)).to_episode())
    tree, n = library.tree, int(library.tree.size[0])
    slots = tree.node_slots.copy()
    rebuild_nodes(slots, tree.parent, tree.token, n)
    assert np.array_equal(slots, tree.node_slots) and n > 1000
    parent = tree.parent[:n].copy()
    parent[5] = 7  # node 5 below a later node
    with pytest.raises(ValueError, match="numbered before its parent"):
        rebuild_nodes(slots, parent, tree.token, n)


def test_a_rebuilt_entry_table_is_the_one_learning_built():
    """Entries are placed by the hash of (node, outcome) as they are added; rebuilding (which
    takes the first empty slot from each entry's home, and looks ahead) places them the same
    way, slot for slot, whatever was in the table before."""
    from slearn.core import hashtable
    from slearn.recorders.pointer import PointerConfig, simulate

    library = PatternLibrary()
    library.learn(simulate(PointerConfig("delay", trials=3000, seed=4)).to_episode())
    tree, m = library.tree, int(library.tree.size[1])
    slots = np.random.default_rng(0).integers(-1, m, len(tree.entry_slots)).astype(np.int32)
    hashtable.rebuild(slots, tree.owner, tree.outcome, 0, m)
    assert np.array_equal(slots, tree.entry_slots) and m > hashtable.AHEAD * 100



def test_experts_that_always_agreed_leave_the_prediction_to_the_all_time_counts():
    # A 400 times, then B, then C: a context's latest outcome (A -> B, once) and its most
    # frequent (A -> A, 399 times) never disagreed where it mattered, so their weights tie;
    # the counts speak, and a held-out run of A's is predicted (it was 0 % when ties went
    # to the latest outcome)
    library = PatternLibrary()
    stream = [0] * 400 + [1] * 400 + [2] * 400
    library.learn(Episode.from_steps([((), (s,)) for s in stream]))
    held_out = Episode.from_steps([((), (0,))] * 50)
    codes = library.encode(held_out, intern=False)
    out = library.run(codes, learn=False, record=True)
    said = out.predicted[out.context]
    assert len(said) == 49 and (said == codes.token[out.context]).all()


def test_merging_a_library_twice_or_a_log_learned_twice_is_warned_about(tmp_path):
    import warnings as w

    from slearn.errors import DataWarning
    from slearn.jobs.learn import learn_files
    from slearn.jobs.merge import merge_files
    from slearn.recorders.pointer import PointerConfig
    from slearn.recorders.record_pointer import record_pointer

    logs = [tmp_path / f"s{s}.mcap" for s in (0, 1)]
    for seed, log in enumerate(logs):
        record_pointer(PointerConfig("simple", trials=300, seed=seed), log)
    learn_files([logs[0]], tmp_path / "a.parquet")
    learn_files([logs[1]], tmp_path / "b.parquet")
    learn_files(logs, tmp_path / "ab.parquet")
    (tmp_path / "copy.parquet").write_bytes((tmp_path / "a.parquet").read_bytes())
    cases = [(["a", "a"], "a.parquet: given twice"), (["a", "copy"], f"the bytes of {tmp_path / 'a.parquet'}"),
             (["ab", "b"], "s1.mcap: was learned before by another of the merged libraries"), (["a", "b"], None)]
    for names, expected in cases:
        with w.catch_warnings(record=True) as caught:
            w.simplefilter("always")
            merge_files([tmp_path / f"{n}.parquet" for n in names], tmp_path / "m.parquet", overwrite=True)
        said = [str(c.message) for c in caught if issubclass(c.category, DataWarning)]
        assert (expected is None and said == []) or (len(said) == 1 and expected in said[0]), said
