"""Named, reproducible datasets: MCAP episodes split by episode, a card and a spec.

``build_dataset(name, folder)`` writes::

    FOLDER/README.md        the dataset card: what, how made, channels, spec, seeds, the
                            replay figures to expect, limitations, citation, license, and
                            the sha256 of every episode file
    FOLDER/spec.toml        the spec to learn it with (slearn learn --spec)
    FOLDER/train/*.mcap     training episodes, one file each
    FOLDER/heldout/*.mcap   held-out episodes (other seeds), one file each
    FOLDER/SHA256SUMS       the sha256 of every file (``sha256sum -c SHA256SUMS`` checks them)

``pointer-arm`` has one such ``joints-J/`` folder (card, spec, splits) per joint count
under one top-level card. Everything is deterministic in the seeds listed here: the same
slearn version builds the same episodes. Cards are templates shipped next to this
module (``NAME.md``, ``$placeholders`` filled in at build time); the pointer and PR2 specs
are shipped as ``NAME.toml``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import warnings
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from string import Template
from typing import Callable, NamedTuple

from slearn import __version__
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, InputError, SpecError
from slearn.io.bags import open_log
from slearn.io.files import claim_folder, release_folder, write_atomic
from slearn.io.serialize import read_episodes
from slearn.io.slicing import HELDOUT, TRAIN, TimeSlice
from slearn.io.spec import load_spec
from slearn.recorders.arm import MAX_JOINTS, ArmConfig, arm_spec, record_arm
from slearn.recorders.live import spec_toml
from slearn.recorders.mcap_copy import copy_log
from slearn.recorders.pointer import CONDITIONS, PointerConfig
from slearn.recorders.record_pointer import record_pointer

SPLITS = ("train", "heldout")
TRAIN_SEEDS = (0, 1, 2, 3)
HELDOUT_SEEDS = (4,)
POINTER_TRIALS = 10_000
ARM_TRIALS = 10_000
SPEC_FILE = "spec.toml"
CARD_FILE = "README.md"
CHECKSUM_FILE = "SHA256SUMS"
SOURCE_SPLIT = 0.7  # pr2-sample --source: the first 70 % of the log's time trains
CITATION = """If you use these data or slearn, cite the paper that defines S-learning:

> Brandon Rohrer and Steven Hulet. *A learning and control approach based on the human
> neuromotor system.* Proceedings of the IEEE/RAS-EMBS International Conference on
> Biomedical Robotics and Biomechatronics (BioRob), 2006. Sandia National Laboratories.

```bibtex
@inproceedings{rohrer2006slearning,
  author    = {Rohrer, Brandon and Hulet, Steven},
  title     = {A learning and control approach based on the human neuromotor system},
  booktitle = {IEEE/RAS-EMBS International Conference on Biomedical Robotics and Biomechatronics (BioRob)},
  year      = {2006}
}
```"""


@dataclass(frozen=True)
class EpisodeFile:
    """One written episode: where, which split, and what made it."""

    path: str
    split: str
    description: str
    seed: int | None
    trials: int | None


@dataclass
class BuildSummary:
    """What a build wrote."""

    name: str
    folder: str
    episodes: list[EpisodeFile] = field(default_factory=list)
    specs: list[str] = field(default_factory=list)
    cards: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    checksums: str | None = None
    damaged: str | None = None  # how a --source log broke (then it holds what was salvaged)

    def to_dict(self) -> dict:
        """A JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class Dataset:
    """A registered dataset: its name, one line on what it is, its license, its builder."""

    name: str
    summary: str
    license: str
    build: Callable[[Path, BuildSummary, Source | None], None]

    def to_dict(self) -> dict:
        """Name, summary and license."""
        return {"name": self.name, "summary": self.summary, "license": self.license}


def list_datasets() -> list[Dataset]:
    """Every registered dataset, in name order."""
    return [DATASETS[name] for name in sorted(DATASETS)]


def get_dataset(name: str) -> Dataset:
    """The dataset called ``name``; an :class:`InputError` naming the known ones otherwise."""
    try:
        return DATASETS[name]
    except KeyError:
        raise InputError(f"no dataset named {name!r}: choose one of "
                         f"{', '.join(sorted(DATASETS))} (see `slearn datasets list`)") from None


def build_dataset(name: str, folder: str | os.PathLike, *, overwrite: bool = False,
                  source: str | os.PathLike | None = None) -> BuildSummary:
    """Build dataset ``name`` into ``folder`` (see the module doc for the layout).

    Args:
        name: a registered dataset name.
        folder: the output folder; it must not exist or be empty unless ``overwrite``
            (or be left by a killed build, which is then redone).
        overwrite: rebuild into a non-empty folder; the dataset's own files there
            (cards, specs, split folders) are replaced, other files are left alone.
        source: a log of your own to put in ``heldout/`` (``pr2-sample`` only).

    Raises:
        InputError: unknown name, a non-empty folder without ``overwrite``, an unusable
            ``source``.
    """
    dataset = get_dataset(name)
    if source is not None and name != "pr2-sample":
        raise InputError(f"--source is for pr2-sample; {name} is simulated from seeds")
    folder = Path(folder)
    if source is not None and _inside(source, folder):
        raise InputError(f"--source {source} is inside the output folder {folder}, which the build "
                         f"replaces: copy the log elsewhere first")
    given = None if source is None else _source(Path(source))  # (refused before the folder is touched)
    claim_folder(folder, overwrite=overwrite, advice="pass --force to rebuild the dataset there")
    summary = BuildSummary(name, str(folder))
    dataset.build(folder, summary, given)
    summary.checksums = str(_write_checksums(folder))
    release_folder(folder)
    return summary


def _inside(path: str | os.PathLike, folder: Path) -> bool:
    return Path(os.path.realpath(path)).is_relative_to(os.path.realpath(folder))


def _split_folders(root: Path) -> dict[str, Path]:
    """Fresh ``train/`` and ``heldout/`` under ``root`` (stale episodes removed)."""
    folders = {}
    for split in SPLITS:
        folder = root / split
        if folder.is_dir():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        folders[split] = folder
    return folders


def _package_text(name: str) -> str:
    return resources.files("slearn.datasets").joinpath(name).read_text(encoding="utf-8")


def _write_card(path: Path, template: str, summary: BuildSummary, **values: str) -> None:
    text = Template(_package_text(template)).substitute(version=__version__, citation=CITATION,
                                                        **values)
    write_atomic(path, text, overwrite=True)
    summary.cards.append(str(path))


def _write_spec(path: Path, text: str, summary: BuildSummary) -> str:
    write_atomic(path, text, overwrite=True)
    summary.specs.append(str(path))
    return text


def sha256_of(path: str | os.PathLike) -> str:
    """The sha256 of a file, in hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _files_table(episodes: list[EpisodeFile], root: Path) -> str:
    rows = ["| file | split | episode | seed | trials | sha256 |", "|---|---|---|---|---|---|"]
    for e in episodes:
        rows.append(f"| `{Path(e.path).relative_to(root).as_posix()}` | {e.split} | "
                    f"{e.description} | {e.seed if e.seed is not None else '-'} | "
                    f"{e.trials if e.trials is not None else '-'} | `{sha256_of(e.path)}` |")
    return "\n".join(rows)


def _write_checksums(root: Path) -> Path:
    """``SHA256SUMS`` over every file of the dataset (``sha256sum -c`` format)."""
    target = root / CHECKSUM_FILE
    files = sorted(p for p in root.rglob("*") if p.is_file() and p != target
                   and not p.name.startswith("."))
    lines = [f"{sha256_of(p)}  {p.relative_to(root).as_posix()}\n" for p in files]
    write_atomic(target, "".join(lines), overwrite=True)
    return target


def _seed_splits() -> list[tuple[str, int]]:
    return [("train", s) for s in TRAIN_SEEDS] + [("heldout", s) for s in HELDOUT_SEEDS]


# --- pointer-paper ---------------------------------------------------------------------------

def _build_pointer_paper(root: Path, summary: BuildSummary, source: Source | None) -> None:
    folders = _split_folders(root)
    episodes = []
    for condition in CONDITIONS:
        for split, seed in _seed_splits():
            path = folders[split] / f"{condition}-seed{seed}.mcap"
            record_pointer(PointerConfig(condition, POINTER_TRIALS, seed), path, overwrite=True)
            episodes.append(EpisodeFile(str(path), split, condition, seed, POINTER_TRIALS))
    summary.episodes += episodes
    spec = _write_spec(root / SPEC_FILE, _package_text("pointer-paper.toml"), summary)
    figures = _figures().pointer_figures(CONDITIONS, TRAIN_SEEDS, HELDOUT_SEEDS[0], POINTER_TRIALS)
    _write_card(root / CARD_FILE, "pointer-paper.md", summary, spec=spec.strip(),
                files=_files_table(episodes, root), trials=f"{POINTER_TRIALS:,}",
                train_seeds=_listing(TRAIN_SEEDS), heldout_seeds=_listing(HELDOUT_SEEDS),
                figures=figures)


def _listing(seeds: tuple[int, ...]) -> str:
    return ", ".join(map(str, seeds))


# --- pointer-arm -----------------------------------------------------------------------------

def _build_pointer_arm(root: Path, summary: BuildSummary, source: Source | None) -> None:
    tables = []
    for joints in range(1, MAX_JOINTS + 1):
        sub = root / f"joints-{joints}"
        sub.mkdir(exist_ok=True)
        folders = _split_folders(sub)
        episodes = []
        for split, seed in _seed_splits():
            path = folders[split] / f"arm{joints}-seed{seed}.mcap"
            record_arm(ArmConfig(joints, ARM_TRIALS, seed, "moved"), path, overwrite=True)
            episodes.append(EpisodeFile(str(path), split, f"{joints} joint(s)", seed, ARM_TRIALS))
        summary.episodes += episodes
        spec = spec_toml(arm_spec(joints), f"Spec for the pointer arm with {joints} joint(s): "
                         "per joint its command (action) and position (observation).")
        _write_spec(sub / SPEC_FILE, spec, summary)
        tables.append(_files_table(episodes, root))
    _write_card(root / CARD_FILE, "pointer-arm.md", summary, files="\n\n".join(tables),
                spec=spec_toml(arm_spec(2)).strip(), trials=f"{ARM_TRIALS:,}",
                train_seeds=_listing(TRAIN_SEEDS), heldout_seeds=_listing(HELDOUT_SEEDS),
                figures=_figures().arm_figures(MAX_JOINTS, TRAIN_SEEDS, HELDOUT_SEEDS[0], ARM_TRIALS))


def _figures():
    """The figures module, imported when a dataset is built: it learns, so it compiles
    kernels, and ``slearn datasets list`` must not pay for that."""
    from slearn.datasets import figures

    return figures


# --- pr2-sample ------------------------------------------------------------------------------

def _build_pr2_sample(root: Path, summary: BuildSummary, source: Source | None) -> None:
    folders = _split_folders(root)
    spec_text = _write_spec(root / SPEC_FILE, _package_text("pr2-sample.toml"), summary)
    if source is None:
        summary.notes.append(f"no log is included: copy your PR2 logs (ROS 2 MCAP with "
                             f"/joint_states) into {folders['train']} and {folders['heldout']}, "
                             f"or rebuild with --source LOG")
        found = "No log was given at build time; the split folders are empty."
        figures = "Build with `--source LOG` to get the figures of your log here."
        files = "None: no log was given."
    else:
        found, figures = _add_source(source, folders, root, summary)
        files = _files_table(summary.episodes, root)
    _write_card(root / CARD_FILE, "pr2-sample.md", summary, spec=spec_text.strip(), found=found,
                figures=figures, files=files, share=f"{100 * SOURCE_SPLIT:.0f}")


def _add_source(given: Source, folders: dict[str, Path], root: Path,
                summary: BuildSummary) -> tuple[str, str]:
    """Split ``source`` by time into ``train/`` and ``heldout/``; the card's text and figures."""
    source, span = given
    stem = source.name.split(".")[0] or "log"
    targets = {}
    for split in (TRAIN, HELDOUT):
        low, high = TimeSlice(split=SOURCE_SPLIT, part=split).window(*span)
        targets[split] = folders[split] / f"{stem}-{split}.mcap"
        copied = copy_log(source, targets[split], start_ns=low, end_ns=high, overwrite=True)
        if copied.damage and not summary.damaged:
            summary.damaged = copied.damage
            warnings.warn(DataWarning(f"{copied.damage}: the dataset holds what could be salvaged"), stacklevel=2)
    spec = load_spec(root / SPEC_FILE)
    counts = {split: _check_fits(source, path, spec, folders) for split, path in targets.items()}
    for split, path in targets.items():
        summary.episodes.append(EpisodeFile(str(path), split, f"your log, {split} part", None, None))
    summary.notes.append(f"split {source} by time: the first {100 * SOURCE_SPLIT:.0f} % into "
                         f"{targets[TRAIN]}, the rest into {targets[HELDOUT]}")
    found = (f"Built with `--source {source.name}`, split by time: the first "
             f"{100 * SOURCE_SPLIT:.0f} % of its time went to `train/{targets[TRAIN].name}` "
             f"({counts[TRAIN]}), the rest to `heldout/{targets[HELDOUT].name}` ({counts[HELDOUT]}).")
    return found, _figures().log_figures(targets[TRAIN], targets[HELDOUT], root / SPEC_FILE)


class Source(NamedTuple):
    """A ``--source`` log and the log times of its messages."""

    path: Path
    span: tuple[int, int]


def _source(source: Path) -> Source:
    """``source`` with the time span of its messages, or a one-line refusal."""
    if not source.exists():
        raise InputError(f"--source {source}: no such log (give an MCAP file, a rosbag2 folder, "
                         f"a .db3 or a .bag)")
    with open_log(source) as log:
        span = log.time_range()
    if span is None:
        raise InputError(f"--source {source}: the log has no messages")
    return Source(source, span)


def _check_fits(source: Path, path: Path, spec, folders: dict[str, Path]) -> str:
    """``"N steps and M events"`` of a split under the spec; refuse (and clean up) if it does not fit."""
    try:
        [(_, episode, report)] = list(read_episodes([path], spec, Vocabulary()))
    except SpecError as err:
        for folder in folders.values():
            for file in folder.iterdir():
                file.unlink()
        raise InputError(f"--source {source}: the pr2-sample spec does not fit it: {err}") from err
    return (f"{report.n_messages:,} messages read, {len(episode)} steps and {episode.n_events} "
            f"events under the spec")


DATASETS: dict[str, Dataset] = {
    "pointer-paper": Dataset(
        "pointer-paper",
        "the paper's rotary pointer, six conditions x 5 episodes of 10,000 trials",
        "MIT (simulated by slearn)", _build_pointer_paper),
    "pointer-arm": Dataset(
        "pointer-arm",
        "a pointer arm of 1, 2, 3 and 4 joints, 5 episodes of 10,000 trials each",
        "MIT (simulated by slearn)", _build_pointer_arm),
    "pr2-sample": Dataset(
        "pr2-sample",
        "spec and card for a real PR2 ROS 2 log (/joint_states); bring your own log",
        "spec and card MIT; logs keep their own license (the PR2 sample: BSD)",
        _build_pr2_sample),
}
