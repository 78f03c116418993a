"""recorders.stream and ``slearn record stream``: formats, episodes, roles, errors."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from fixtures import online_correct
from mcap.reader import make_reader

from slearn.cli import main
from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError
from slearn.io.serialize import read_episodes
from slearn.io.spec import load_spec
from slearn.recorders.record_stream import convert_stream, detect_format, stream_spec


def _steps(paths, spec):
    vocabulary = Vocabulary()
    out = []
    for _, episode, _ in read_episodes(paths, spec, vocabulary):
        out.append([([vocabulary.name(a)[1] for a in acts], [vocabulary.name(o)[1] for o in obs])
                    for acts, obs in episode.steps()])
    return out


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _metadata(path):
    with open(path, "rb") as f:
        return {m.name: m.metadata for m in make_reader(f).iter_metadata()}


def test_tokens_one_episode_per_line_with_named_channels_and_roles(tmp_path):
    src = _write(tmp_path, "seq.txt", "# pointer\npos=3 cmd=R pos=4 cmd=L pos=3\n\npos=1 cmd=L pos=36\n")
    summary = convert_stream(src, tmp_path / "out.mcap", roles={"cmd": "action"})
    assert summary.format == "tokens" and summary.episodes == 2
    assert summary.paths == [str(tmp_path / "out.mcap")]
    assert summary.channels == {"pos": "observation", "cmd": "action"}
    assert _steps(summary.paths, stream_spec(summary)) == [
        [([], [3]), (["R"], [4]), (["L"], [3])],
        [([], [1]), (["L"], [36])]]
    assert _metadata(summary.paths[0])["slearn.stream"]["sequences"] == "2"
    with open(summary.paths[0], "rb") as f:
        markers = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages()
                   if c.topic == "/slearn/episode"]
    assert markers == [{"episode": 0, "name": "seq.txt:2"}, {"episode": 1, "name": "seq.txt:4"}]


def test_per_file_makes_one_episode_that_continues_in_time(tmp_path):
    src = _write(tmp_path, "seq.txt", "a b\nc\n")
    summary = convert_stream(src, tmp_path / "one.mcap", per_file=True)
    assert summary.paths == [str(tmp_path / "one.mcap")]
    assert _steps(summary.paths, stream_spec(summary)) == [[([], ["a"]), ([], ["b"]), ([], ["c"])]]


def test_spmf_itemsets_share_a_tick_and_item_names_apply(tmp_path):
    src = _write(tmp_path, "db.spmf", "@CONVERTED_FROM_TEXT\n@ITEM=1=cmd=R\n"
                 "2 -1 1 -1 3 4 -1 -2\n5 -1 <7> 6 -1 -2\n")
    assert detect_format(src) == "spmf"
    summary = convert_stream(src, tmp_path / "db.mcap", roles={"cmd": "action"})
    assert len(summary.paths) == 1 and summary.episodes == 2
    first, second = _steps(summary.paths, stream_spec(summary))
    assert first == [([], [2]), (["R"], [3, 4])]
    assert second == [([], [5]), ([], [6])]


def test_spmf_line_end_also_ends_a_sequence(tmp_path):
    src = _write(tmp_path, "db.txt", "1 -1 -2\n2 -1 3\n-2\n")
    summary = convert_stream(src, tmp_path / "x.mcap", fmt="spmf")
    assert _steps(summary.paths, stream_spec(summary)) == [[([], [1])], [([], [2]), ([], [3])]]


def test_csv_episodes_roles_and_numeric_values(tmp_path):
    src = _write(tmp_path, "log.csv", "time,channel,value,role,episode\n"
                 "0,pos,3,observation,a\n0.1,cmd,R,action,a\n0.15,pos,4,,a\n"
                 "0,pos,0.5,,b\n")
    summary = convert_stream(src, tmp_path / "log.mcap")
    assert summary.channels == {"pos": "observation", "cmd": "action"}
    assert _steps(summary.paths, stream_spec(summary)) == [[([], [3]), (["R"], [4])], [([], [0.5])]]


def test_jsonl_with_time_ns(tmp_path):
    rows = [{"time_ns": 0, "channel": "/s", "value": True},
            {"time_ns": 5, "channel": "/c", "value": "go", "role": "action"},
            {"time_ns": 9, "channel": "/s", "value": False}]
    src = _write(tmp_path, "ev.jsonl", "\n".join(json.dumps(r) for r in rows) + "\n")
    summary = convert_stream(src, tmp_path / "ev.mcap")
    assert summary.format == "jsonl" and summary.paths == [str(tmp_path / "ev.mcap")]
    assert _steps(summary.paths, stream_spec(summary)) == [[([], [True]), (["go"], [False])]]


@pytest.mark.parametrize("name, text, message", [
    ("bad.csv", "time,channel\n0,a\n", r"bad.csv:1: missing value"),
    ("bad.csv", "time,channel,value\n0,a,1\nx,a,2\n", r"bad.csv:3: time 'x' is not a number"),
    ("bad.csv", "time,channel,value\n0,a\n", r"bad.csv:2: 2 fields"),
    ("bad.csv", "time,channel,value\n-1,a,1\n", r"bad.csv:2: time .* out of range"),
    ("bad.jsonl", '{"time": 0, "channel": "a", "value": 1}\n{oops\n', r"bad.jsonl:2: not JSON"),
    ("bad.jsonl", '{"time": 0, "channel": "a", "value": [1]}\n', r"bad.jsonl:1: .*list"),
    ("bad.jsonl", '{"time": 0, "channel": "a", "value": 1, "role": "x"}\n', r"bad.jsonl:1: role"),
    ("bad.csv", "time,channel,value,role\n0,a,1,action\n1,a,2,observation\n",
     r"bad.csv:3: channel 'a' is observation here but action on line 2"),
    ("empty.txt", "\n# nothing\n", r"no events found"),
    ("nan.csv", "time,channel,value\n0,a,1\n1,a,nan\n",
     r"nan.csv:3: value nan is not a finite number: leave a missing reading out \(no event\)"),
])
def test_malformed_input_names_the_line(tmp_path, name, text, message):
    with pytest.raises(InputError, match=message):
        convert_stream(_write(tmp_path, name, text), tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()


def test_existing_outputs_are_refused_before_anything_is_written(tmp_path):
    src = _write(tmp_path, "s.txt", "a\nb\n")
    (tmp_path / "o.mcap").write_bytes(b"keep")
    with pytest.raises(InputError, match="already exists"):
        convert_stream(src, tmp_path / "o.mcap")
    assert (tmp_path / "o.mcap").read_bytes() == b"keep"
    convert_stream(src, tmp_path / "o.mcap", overwrite=True)
    assert (tmp_path / "o.mcap").read_bytes() != b"keep"


def test_role_option_for_an_unknown_channel_is_an_error(tmp_path):
    with pytest.raises(InputError, match="'cmd', which has no event"):
        convert_stream(_write(tmp_path, "s.txt", "a b\n"), tmp_path / "o.mcap",
                       roles={"cmd": "action"})


def test_cli_writes_files_spec_and_json_summary(tmp_path):
    src = _write(tmp_path, "walk.txt", " ".join(f"pos={i % 5} cmd=R" for i in range(40)) + " pos=0\n")
    spec_path = tmp_path / "walk.toml"
    args = ["record", "stream", str(src), "-o", str(tmp_path / "walk.mcap"), "--role",
            "cmd=action", "--spec-out", str(spec_path), "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["channels"] == {"pos": "observation", "cmd": "action"}
    library = PatternLibrary()
    [(_, episode, _)] = read_episodes(summary["paths"], load_spec(spec_path), Vocabulary())
    assert online_correct(library, episode)[-20:].all()
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 1 and "already exists: pass --force" in again.stderr
    assert CliRunner().invoke(main, args + ["--force"]).exit_code == 0


def test_cli_malformed_line_is_one_line_on_stderr(tmp_path):
    src = _write(tmp_path, "x.csv", "time,channel,value\n0,a,\n")
    result = CliRunner().invoke(main, ["record", "stream", str(src), "-o", str(tmp_path / "x.mcap")])
    assert result.exit_code == 1 and result.stdout == ""
    assert result.stderr.strip() == f"slearn: error: {src}:2: channel 'a' has no value"


def test_converted_stream_learns_and_replays_with_the_cli(tmp_path):
    walk = [(i * 7) % 5 for i in range(300)]
    lines = [" ".join(f"pos={p} cmd=R" for p in walk[k:k + 60]) + f" pos={walk[k + 60]}"
             for k in range(0, 240, 60)]
    src = _write(tmp_path, "walks.txt", "\n".join(lines) + "\n")
    out = tmp_path / "mcap"
    out.mkdir()
    recorded = CliRunner().invoke(main, ["record", "stream", str(src), "-o", str(out), "--role",
                                         "cmd=action", "--spec-out", str(tmp_path / "spec.toml")])
    assert recorded.exit_code == 0, recorded.output
    [log] = [str(p) for p in out.iterdir()]
    library = str(tmp_path / "walks.parquet")
    # the four sequences lie one after the other: the first 75 % of the time holds three
    learned = CliRunner().invoke(main, ["learn", log, "--spec", str(tmp_path / "spec.toml"),
                                        "-o", library, "-q", "--split", "0.75", "--json"])
    assert learned.exit_code == 0, learned.output
    assert json.loads(learned.stdout)["episodes"] == 3
    replayed = CliRunner().invoke(main, ["replay", library, log, "--split", "0.75", "--json"])
    assert replayed.exit_code == 0, replayed.output
    doc = json.loads(replayed.stdout)
    assert [e["name"] for e in doc["episodes"]] == [f"{log}#3"]
    assert doc["totals"]["accuracy"] == 1.0 and doc["baselines"]["fit"] == "training"


def test_a_thousand_sequences_go_into_one_file_and_learn_as_a_thousand_episodes(tmp_path):
    rng = np.random.default_rng(0)
    lines = []
    for _ in range(1000):
        pos, tokens = int(rng.integers(0, 10)), []
        for _ in range(int(rng.integers(2, 8))):
            step = int(rng.choice([-1, 1]))
            tokens += [f"pos={pos}", f"cmd={'LR'[step > 0]}"]
            pos = (pos + step) % 10
        lines.append(" ".join(tokens + [f"pos={pos}"]))
    src = _write(tmp_path, "db.txt", "\n".join(lines) + "\n")
    out, spec_path, library = tmp_path / "db.mcap", tmp_path / "db.toml", tmp_path / "db.parquet"
    recorded = CliRunner().invoke(main, ["record", "stream", str(src), "-o", str(out), "--role",
                                         "cmd=action", "--spec-out", str(spec_path), "--json"])
    assert recorded.exit_code == 0, recorded.output
    summary = json.loads(recorded.stdout)
    assert summary["paths"] == [str(out)] and summary["episodes"] == 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["db.mcap", "db.toml", "db.txt"]
    learned = CliRunner().invoke(main, ["learn", str(out), "--spec", str(spec_path), "-o",
                                        str(library), "--json"])
    assert learned.exit_code == 0, learned.output
    doc = json.loads(learned.stdout)
    assert doc["episodes"] == 1000
    assert doc["steps"] == sum(line.count("cmd=") + 1 for line in lines)


def test_an_episode_that_resumes_after_another_is_refused_naming_the_row(tmp_path):
    """Files are converted as they are read, so an episode's rows come together."""
    src = _write(tmp_path, "log.csv", "time,channel,value,episode\n0,pos,1,a\n0,pos,2,b\n0.1,pos,3,a\n")
    with pytest.raises(InputError, match=r"log.csv:4: episode 'a' resumes after other episodes began: "
                                         r"give each episode's rows together"):
        convert_stream(src, tmp_path / "log.mcap")
    assert not (tmp_path / "log.mcap").exists()
    src = _write(tmp_path, "ev.jsonl", json.dumps({"time": 0, "channel": "a", "value": 1, "episode": [1]}) + "\n")
    with pytest.raises(InputError, match=r"ev.jsonl:1: episode \[1\] is not a name or a number"):
        convert_stream(src, tmp_path / "ev.mcap")


@pytest.mark.parametrize("fmt", ["tokens", "spmf", "csv one episode", "csv episodes"])
def test_memory_does_not_grow_with_the_events(tmp_path, monkeypatch, fmt):
    """Every event was held until the file was written: 200 bytes of Python allocations per
    event of a token file, 535 of a CSV file (636 MB of RSS for a 6 MB token file). Now the
    file is read twice and only a few numbers per episode are kept: a file ten times as
    long adds under 25 bytes per event (with 16 KiB chunks, so that both sizes fill many:
    the writer holds one chunk), and nothing when it is one episode."""
    import functools
    import tracemalloc

    from slearn.recorders import live
    from slearn.recorders.mcap_episode import EpisodeWriter

    monkeypatch.setattr(live, "EpisodeWriter", functools.partial(EpisodeWriter, chunk_size=1 << 14))
    texts = {"tokens": lambda n: "a b c a b\n" * n,
             "spmf": lambda n: "1 -1 2 -1 3 -2 4 -1 5 -2\n" * n,
             "csv one episode": lambda n: "time,channel,value\n" + "".join(
                 f"{i * 0.1:.1f},pos,{i % 5}\n" for i in range(5 * n)),
             "csv episodes": lambda n: "time,channel,value,episode\n" + "".join(
                 f"{i % 7 * 0.1:.1f},pos,{i % 5},{i // 7}\n" for i in range(5 * n))}

    def peak(lines: int) -> int:
        src = _write(tmp_path, f"{lines}.{'csv' if fmt.startswith('csv') else 'txt'}", texts[fmt](lines))
        tracemalloc.start()
        try:
            summary = convert_stream(src, tmp_path / f"{lines}.mcap")
            assert summary.events == 5 * lines
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    small, large = peak(500), peak(5_000)
    assert large - small < 25 * 5 * 4_500, (small, large)
    if fmt == "csv one episode":
        assert large < 1.5 * small, (small, large)


@pytest.mark.parametrize("change", ["fewer events", "another channel", "more sequences"])
def test_a_file_that_changes_between_the_two_reads_is_refused_and_nothing_written(tmp_path, monkeypatch, change):
    from slearn.recorders import record_stream

    src = _write(tmp_path, "seq.txt", "a b c\nc b a\n")
    read, calls = record_stream.read_events, []

    def changing(*args, **kwargs):
        calls.append(1)
        events = list(read(*args, **kwargs))
        if len(calls) == 2:
            if change == "fewer events":
                events = events[:-1]
            elif change == "another channel":
                events[-1].channel = "/other"
            else:
                events[-1].sequence = 2
        return iter(events)

    monkeypatch.setattr(record_stream, "read_events", changing)
    with pytest.raises(InputError, match="seq.txt: the file changed while it was being converted"):
        convert_stream(src, tmp_path / "seq.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq.txt"]
