"""datasets.registry and ``slearn datasets``: each dataset builds, learns and replays."""

import hashlib
import json

import pytest
from click.testing import CliRunner
from fixtures import SHARED_MCAP

from slearn.cli import main
from slearn.datasets.registry import (
    ARM_TRIALS,
    HELDOUT_SEEDS,
    POINTER_TRIALS,
    TRAIN_SEEDS,
    build_dataset,
    list_datasets,
    sha256_of,
)
from slearn.errors import InputError
from slearn.io.bags import open_log
from slearn.io.spec import load_spec, pointer_spec
from slearn.recorders.arm import ArmConfig, arm_spec, record_arm
from slearn.recorders.pointer import CONDITIONS

PR2_LOG = (SHARED_MCAP / "robot" / "ros2_cdr"
           / "pr2_pr1012_sensors_ros2.mcap")


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def pointer_paper(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pointer-paper")
    result = _invoke("datasets", "build", "pointer-paper", "-o", folder, "--json")
    assert result.exit_code == 0, result.output
    return folder, json.loads(result.stdout)


@pytest.fixture(scope="module")
def pointer_arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pointer-arm")
    summary = build_dataset("pointer-arm", folder)
    return folder, summary


def _learn(library_path, spec, logs):
    result = _invoke("learn", *logs, "--spec", spec, "-o", library_path, "--json", "-q")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def _replay(library_path, logs):
    """Frozen ``slearn replay --json`` of held-out logs; returns its totals."""
    result = _invoke("replay", library_path, *logs, "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["totals"]


def test_list_names_every_dataset():
    names = [d.name for d in list_datasets()]
    assert names == ["pointer-arm", "pointer-paper", "pr2-sample"]
    listed = json.loads(_invoke("datasets", "list", "--json").stdout)
    assert [d["name"] for d in listed] == names and all(d["license"] for d in listed)
    text = _invoke("datasets", "list").stdout.splitlines()
    assert len(text) == 3 and text[1].startswith("pointer-paper")


def test_pointer_paper_layout_card_and_spec(pointer_paper):
    folder, summary = pointer_paper
    train = sorted(p.name for p in (folder / "train").iterdir())
    heldout = sorted(p.name for p in (folder / "heldout").iterdir())
    assert train == sorted(f"{c}-seed{s}.mcap" for c in CONDITIONS for s in TRAIN_SEEDS)
    assert heldout == sorted(f"{c}-seed{s}.mcap" for c in CONDITIONS for s in HELDOUT_SEEDS)
    assert len(summary["episodes"]) == 6 * (len(TRAIN_SEEDS) + len(HELDOUT_SEEDS))
    assert load_spec(folder / "spec.toml").to_dict() == pointer_spec().to_dict()
    card = (folder / "README.md").read_text()
    for needed in ("## What", "## How it was made", "## Channels", "## Spec", "## License",
                   "/pointer/command", "held-out seeds: 4", f"{POINTER_TRIALS:,}",
                   "`heldout/delay-seed4.mcap`", 'values = ["L", "R"]', "## Expected replay figures",
                   "Bayes ceiling", "## Limitations", "## Citation", "Rohrer", "one library per condition"):
        assert needed in card
    assert "$" not in card
    assert sha256_of(folder / "heldout" / "delay-seed4.mcap") in card
    sums = dict(line.split("  ")[::-1] for line in (folder / "SHA256SUMS").read_text().splitlines())
    assert sums["README.md"] == sha256_of(folder / "README.md") and len(sums) == 32


def test_pointer_paper_learns_and_replays(pointer_paper, tmp_path):
    folder, _ = pointer_paper
    library = tmp_path / "simple.parquet"
    learned = _learn(library, folder / "spec.toml", sorted((folder / "train").glob("simple-*")))
    assert learned["episodes"] == len(TRAIN_SEEDS) and learned["patterns"] > 100
    totals = _replay(library, sorted((folder / "heldout").glob("simple-*")))
    assert totals["events"] == POINTER_TRIALS and totals["accuracy"] > 0.99
    # the card's expected figure is what this replay printed
    row = next(line for line in (folder / "README.md").read_text().splitlines() if line.startswith("| simple |"))
    assert f"| {100 * totals['accuracy']:.1f} % |" in row


def test_pointer_arm_layout_learns_and_replays(pointer_arm, tmp_path):
    folder, summary = pointer_arm
    assert len(summary.episodes) == 4 * (len(TRAIN_SEEDS) + len(HELDOUT_SEEDS))
    card = (folder / "README.md").read_text()
    assert "/arm/joint{j}/command" in card and "`joints-4/heldout/arm4-seed4.mcap`" in card
    accuracy = {}
    for joints in (1, 2, 3, 4):
        sub = folder / f"joints-{joints}"
        assert load_spec(sub / "spec.toml").to_dict() == arm_spec(joints).to_dict()
        library = tmp_path / f"arm{joints}.parquet"
        _learn(library, sub / "spec.toml", sorted((sub / "train").iterdir()))
        totals = _replay(library, sorted((sub / "heldout").iterdir()))
        assert totals["events"] == ARM_TRIALS
        accuracy[joints] = totals["accuracy"]
    print(accuracy)
    assert min(accuracy.values()) > 0.99  # per-joint views: no curse of dimensionality


def test_episodes_are_reproducible_bit_for_bit(tmp_path):
    config = ArmConfig(3, ARM_TRIALS // 10, HELDOUT_SEEDS[0])
    digests = set()
    for name in ("a.mcap", "b.mcap"):
        record_arm(config, tmp_path / name)
        digests.add(hashlib.sha256((tmp_path / name).read_bytes()).hexdigest())
    assert len(digests) == 1


def test_pr2_sample_without_a_log_tells_the_user(tmp_path):
    result = _invoke("datasets", "build", "pr2-sample", "-o", tmp_path / "pr2")
    assert result.exit_code == 0, result.output
    assert "copy your PR2 logs" in result.stdout and "--source" in result.stdout
    assert load_spec(tmp_path / "pr2" / "spec.toml").mode == "change"
    assert list((tmp_path / "pr2" / "train").iterdir()) == []
    card = (tmp_path / "pr2" / "README.md").read_text()
    assert "laser_tilt_mount_joint" in card and "No log was given" in card


@pytest.mark.shared
def test_pr2_sample_with_source_splits_it_and_learns_and_replays(tmp_path):
    folder = tmp_path / "pr2"
    summary = build_dataset("pr2-sample", folder, source=PR2_LOG)
    train, heldout = summary.episodes
    assert (train.split, heldout.split) == ("train", "heldout")
    card = (folder / "README.md").read_text()
    assert "`train/pr2_pr1012_sensors_ros2-train.mcap`" in card and "## Expected replay figures" in card
    assert "fewer than 1,000" in card and "## Citation" in card and "Rohrer" in card
    for episode in (train, heldout):
        assert sha256_of(episode.path) in card
        with open_log(episode.path) as log:
            assert log.profile == "ros2"
    library = tmp_path / "pr2.parquet"
    learned = _learn(library, folder / "spec.toml", sorted(str(p) for p in (folder / "train").glob("*.mcap")))
    assert learned["steps"] > 50
    assert _replay(library, [heldout.path])["events"] > 10


def test_pr2_source_that_does_not_fit_is_refused(tmp_path):
    log = tmp_path / "arm.mcap"
    record_arm(ArmConfig(1, 10), log)
    with pytest.raises(InputError, match=r"--source .*arm.mcap: the pr2-sample spec does not fit"):
        build_dataset("pr2-sample", tmp_path / "pr2", source=log)
    assert list((tmp_path / "pr2" / "heldout").iterdir()) == []
    assert list((tmp_path / "pr2" / "train").iterdir()) == []


def test_build_errors(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "mine.txt").write_text("keep")
    refused = _invoke("datasets", "build", "pr2-sample", "-o", tmp_path / "full")
    assert refused.exit_code == 1 and refused.stdout == ""
    assert "is not empty: pass --force" in refused.stderr
    forced = _invoke("datasets", "build", "pr2-sample", "-o", tmp_path / "full", "--force")
    assert forced.exit_code == 0 and (tmp_path / "full" / "mine.txt").read_text() == "keep"
    unknown = _invoke("datasets", "build", "nope", "-o", tmp_path / "x")
    assert unknown.exit_code == 1 and "choose one of pointer-arm, pointer-paper, pr2-sample" in unknown.stderr
    with pytest.raises(InputError, match="--source is for pr2-sample"):
        build_dataset("pointer-arm", tmp_path / "y", source=tmp_path / "full" / "mine.txt")
    assert not (tmp_path / "y").exists()


def test_a_source_that_cannot_serve_touches_no_folder(tmp_path):
    out = tmp_path / "ds"
    result = CliRunner().invoke(main, ["datasets", "build", "pr2-sample", "-o", str(out),
                                       "--source", str(tmp_path / "missing.mcap")])
    assert result.exit_code == 1 and "no such log" in result.stderr.splitlines()[-1]
    assert not out.exists()  # (the spec and empty split folders were written first)


@pytest.mark.shared
@pytest.mark.skipif(not PR2_LOG.exists(), reason="needs ../shared")
def test_a_truncated_source_is_salvaged_with_a_warning_and_exit_3(tmp_path):
    cut = tmp_path / "cut.mcap"
    data = PR2_LOG.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    result = CliRunner().invoke(main, ["datasets", "build", "pr2-sample", "-o", str(tmp_path / "ds"),
                                       "--source", str(cut)])
    assert result.exit_code == 3, result.output
    assert "truncated or corrupt log" in result.stderr and "the dataset holds what could be salvaged" in result.stderr
    assert (tmp_path / "ds" / "SHA256SUMS").exists()
