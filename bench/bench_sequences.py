"""Next-item prediction on sequence data, in the protocol of the CPT+ and SuBSeq papers.

The protocol is IPredict's (the CPT+ authors' evaluation code, github.com/tedgueniche/IPredict,
``Evaluator`` and the per-dataset ``Profile`` classes), which the SuBSeq paper reuses:

- A dataset is read in file order; consecutive repeats are dropped where IPredict drops
  them (MSNBC, FIFA, SIGN); sequences shorter than ``min_size`` items are left out, and the
  first ``max_count`` kept (5000; SIGN 1000). The sequences are shuffled (``--seed``) and
  split into ``--folds`` folds (14, as in IPredict's experiments): each fold in turn is the
  test set, the others train the model, in the shuffled order (as IPredict does).
- A test sequence's last ``consequent`` items are the consequent; the ``window`` items
  before them are the prefix the model sees. The model predicts one item; it is a hit when
  that item is one of the consequent's ("one of the next items"). Accuracy is hits over all
  test sequences (abstentions are misses: IPredict's "Overall").
- Profiles (window, consequent, min_size): BMS and FIFA (5, 1, 6), MSNBC and BIBLE_CHAR
  (5, 2, 7), SIGN (7, 3, 10); the synthetic sources and the text use (5, 1, 6) and (5, 2, 7).

Models, trained on whole training sequences, then frozen:

- ``AKOM5``: all-k-order Markov, k <= 5 (:mod:`peers`, as IPredict's ``MarkovAllKPredictor``).
- ``AKOM*``: the best of AKOM(1..5) on the test folds, its order in brackets (chosen
  after the fact, so an optimistic reference, not a peer).
- ``PPM-C5``: PPM with escape method C and exclusion, orders 5..0 (:mod:`peers`).
- ``slearn``: :func:`slearn_adapter.slearn_sequence_predictions` (one sequence = one
  episode, no actions).
- ``ceiling``: for the synthetic sources, the Bayes-optimal hit rate given the prefix (the
  source is known).

Data: synthetic sources generated here (``markov2``: order 2 over 30 symbols, ``markov3``:
order 3 over 20, ``periodic``: a period-7 pattern over 20 symbols with 10 % of items
replaced at random); ``licenses``: the text of ``/usr/share/common-licenses`` (or
``--text FILE``) as characters, one line = one sequence, read at run time; and, with
``--data DIR``, the public datasets in SPMF format (``MSNBC.txt``, ``BMS.txt``,
``FIFA.txt``, ``SIGN.txt``; items separated by ``-1``, a sequence ended by ``-2``) or
IPredict's own files (``msnbc.seq``, ``BMS.dat``, ``FIFA.dat``, ``sign_language.txt``), and
a plain text for BIBLE_CHAR and BIBLE_WORD (``Bible.txt`` or ``kjv.txt``, one verse per
line). The published accuracies (CPT+ / SuBSeq, in %) are printed next to them. IPredict's
other datasets are read too when present: ``koran.txt`` and ``leviathan.txt`` as words
(KORAN_WORD, LEVIATHAN_WORD), ``snake.dat`` (SNAKE, proteins) and the Canadarm robot arm's
``Canadarm1_actions.txt`` and ``Canadarm2_states.txt`` (SPMF). Where slearn is below a peer,
a line after the table says so.

Run: ``python bench/bench_sequences.py [--data DIR] [--folds 14] [--datasets a,b] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from peers import CountModel
from slearn_adapter import slearn_sequence_predictions

LICENSES = Path("/usr/share/common-licenses")
PUBLISHED = {"MSNBC": (59, 64), "BMS": (38, 33), "FIFA": (34, 29), "SIGN": (34, 23),
             "BIBLE_CHAR": (80, 88)}
MODELS = ("AKOM5", "PPM-C5", "slearn")
AKOM_ORDERS = range(1, 6)


@dataclass(frozen=True)
class Profile:
    """IPredict's evaluation parameters of one dataset."""

    window: int = 5
    consequent: int = 1
    min_size: int = 6
    max_count: int = 5000


@dataclass
class Dataset:
    """Sequences of dense item ids, the profile to evaluate them with, and, for a known
    source, ``ceiling(prefix, consequent) -> probability of the best guess being a hit``."""

    name: str
    sequences: list[list[int]]
    profile: Profile
    ceiling: Callable[[list[int], list[int]], float] | None = None


# --- reading -----------------------------------------------------------------------------

def _dense(sequences: list[list]) -> list[list[int]]:
    ids: dict = {}
    return [[ids.setdefault(item, len(ids)) for item in s] for s in sequences]


def _no_repeats(sequence: list) -> list:
    return [x for i, x in enumerate(sequence) if i == 0 or x != sequence[i - 1]]


def _select(sequences, profile: Profile, drop_repeats: bool) -> list[list[int]]:
    kept = []
    for sequence in sequences:
        if drop_repeats:
            sequence = _no_repeats(sequence)
        if len(sequence) >= profile.min_size:
            kept.append(sequence)
            if len(kept) == profile.max_count:
                break
    return _dense(kept)


def read_spmf(path: Path):
    """Sequences of an SPMF file (itemsets flattened in order)."""
    with open(path, encoding="utf-8", errors="replace") as lines:
        current: list[str] = []
        for line in lines:
            if line[:1] in "#%@" or not line.strip():
                continue
            for token in line.split():
                if token == "-2":
                    yield current
                    current = []
                elif token != "-1":
                    current.append(token)


def _read_lines_of_items(path: Path):
    """One sequence per line of integers (IPredict's FIFA and MSNBC files); other lines skipped."""
    with open(path, encoding="utf-8", errors="replace") as lines:
        for line in lines:
            items = line.split()
            if items and all(item.lstrip("-").isdigit() for item in items):
                yield items


def _read_bms(path: Path):
    """IPredict's BMS.dat: ``sequence-id item`` per line."""
    current, last = [], None
    with open(path) as lines:
        for line in lines:
            sid, item = line.split()[:2]
            if sid != last and current:
                yield current
                current = []
            last = sid
            current.append(item)
    if current:
        yield current


def _read_sign(path: Path):
    """IPredict's sign_language.txt: ``utterance item item ...`` lines; -11/-12 are not items."""
    current, last = [], None
    with open(path) as lines:
        for line in lines:
            tokens = line.split()
            if not tokens or line.startswith("#"):
                continue
            if tokens[0] != last and current:
                yield current
                current = []
            last = tokens[0]
            current += [t for t in tokens[1:] if t not in ("-11", "-12")]
    if current:
        yield current


def _read_text_lines(path: Path):
    with open(path, encoding="utf-8", errors="replace") as lines:
        for line in lines:
            yield list(line.rstrip("\n"))


def _read_words(path: Path):
    """A text as sentences of words (IPredict's word datasets): only letters, ``.``, ``?``,
    ``:`` and spaces are kept, words are split at spaces, and a word holding ``.``, ``?`` or
    ``:`` ends its sentence (its last character cut); a sentence goes on across lines.
    Unlike IPredict, empty words (two spaces) are not items."""
    current: list[str] = []
    with open(path, encoding="utf-8", errors="replace") as lines:
        for line in lines:
            for word in "".join(c for c in line if c.isalpha() or c in ".?: ").split(" "):
                ends = any(c in ".?:" for c in word)
                word = word[:-1] if ends else word
                if word:
                    current.append(word)
                if ends:
                    yield current
                    current = []


def _read_snake(path: Path):
    """IPredict's snake.dat: one protein per line, letters as items, lines of 50 or more."""
    with open(path) as lines:
        for line in lines:
            line = line.rstrip("\n")
            if len(line) >= 50:
                yield list(line)


PUBLIC = {  # name: (profile, drop consecutive repeats, [(file name, reader), ...])
    "MSNBC": (Profile(5, 2, 7), True, [("MSNBC.txt", read_spmf), ("msnbc.seq", _read_lines_of_items),
                                         ("msnbc990928.seq", _read_lines_of_items)]),
    "BMS": (Profile(5, 1, 6), False, [("BMS.txt", read_spmf), ("BMS.dat", _read_bms)]),
    "FIFA": (Profile(5, 1, 6), True, [("FIFA.txt", read_spmf), ("FIFA.dat", _read_lines_of_items)]),
    "SIGN": (Profile(7, 3, 10, 1000), True, [("SIGN.txt", read_spmf),
                                              ("sign_language.txt", _read_sign)]),
    "BIBLE_CHAR": (Profile(5, 2, 7), False, [("Bible.txt", _read_text_lines),
                                             ("kjv.txt", _read_text_lines)]),
    # IPredict's other datasets: a verse-per-line text as words, two more texts, a protein
    # set and the Canadarm robot arm's actions and states (SPMF); profiles as IPredict's
    # (its DefaultProfile where it has none)
    "BIBLE_WORD": (Profile(3, 1, 4), False, [("Bible.txt", _read_words), ("kjv.txt", _read_words)]),
    "KORAN_WORD": (Profile(), False, [("koran.txt", _read_words)]),
    "LEVIATHAN_WORD": (Profile(), False, [("leviathan.txt", _read_words)]),
    "SNAKE": (Profile(5, 2, 7), False, [("snake.dat", _read_snake)]),
    "CANADARM1": (Profile(), False, [("Canadarm1_actions.txt", read_spmf)]),
    "CANADARM2": (Profile(), False, [("Canadarm2_states.txt", read_spmf)]),
}


def public_datasets(folder: Path) -> tuple[list[Dataset], list[str]]:
    """The public datasets found in ``folder``, and notes on the ones missing."""
    found, notes = [], []
    for name, (profile, repeats, candidates) in PUBLIC.items():
        path, reader = next(((folder / f, r) for f, r in candidates if (folder / f).is_file()),
                            (None, None))
        if path is None:
            notes.append(f"{name}: none of {', '.join(f for f, _ in candidates)} in {folder}")
            continue
        sequences = _select(reader(path), profile, repeats)
        if not sequences:
            notes.append(f"{name}: {path} holds no sequence of {profile.min_size} items or more"
                         " (an empty or partial download?): left out")
            continue
        found.append(Dataset(f"{name}", sequences, profile))
    return found, notes


def text_dataset(paths: list[Path], name: str) -> Dataset | None:
    """Lines of text files as sequences of characters (BIBLE_CHAR's profile)."""
    profile = Profile(5, 2, 7)
    lines = (line for path in paths for line in _read_text_lines(path))
    sequences = _select(lines, profile, False)
    return Dataset(name, sequences, profile) if sequences else None


def license_files() -> list[Path]:
    """The distinct regular files of /usr/share/common-licenses (symlinks resolved)."""
    if not LICENSES.is_dir():
        return []
    return sorted({p.resolve() for p in LICENSES.iterdir() if p.resolve().is_file()})


# --- synthetic sources -------------------------------------------------------------------

def markov_source(order: int, symbols: int, seed: int, count: int = 5000) -> Dataset:
    """Sequences of 10-40 items from a random order-``order`` Markov source (each context's
    next-item distribution drawn from Dirichlet(0.2)), with its exact ceiling."""
    rng = np.random.default_rng(seed)
    table = rng.dirichlet(np.full(symbols, 0.2), size=symbols ** order)
    cumulative = np.cumsum(table, axis=1)

    def context(items):
        return int(np.ravel_multi_index(items[-order:], (symbols,) * order))

    sequences = []
    for _ in range(count):
        items = rng.integers(0, symbols, order).tolist()
        for _ in range(int(rng.integers(10, 41)) - order):
            items.append(int(np.searchsorted(cumulative[context(items)], rng.random())))
        sequences.append(items)

    def ceiling(prefix, consequent):
        return float(table[context(prefix)].max())

    return Dataset(f"markov{order}", sequences, Profile(), ceiling)


def periodic_source(seed: int, period: int = 7, symbols: int = 20, noise: float = 0.1,
                    count: int = 5000) -> Dataset:
    """A fixed pattern of ``period`` items from a random phase, each item replaced by a
    uniform one with probability ``noise``; the ceiling filters the phase from the prefix."""
    rng = np.random.default_rng(seed)
    pattern = rng.integers(0, symbols, period)
    sequences = []
    for _ in range(count):
        n = int(rng.integers(10, 41))
        items = pattern[(int(rng.integers(period)) + np.arange(n)) % period]
        noisy = rng.random(n) < noise
        items[noisy] = rng.integers(0, symbols, noisy.sum())
        sequences.append(items.tolist())
    emit = np.full((period, symbols), noise / symbols)
    emit[np.arange(period), pattern] += 1 - noise

    def ceiling(prefix, consequent):
        phase = np.ones(period)
        for t, item in enumerate(prefix):
            phase *= emit[(np.arange(period) + t) % period, item]
        after = (np.arange(period) + len(prefix)) % period
        return float(((phase / phase.sum()) @ emit[after]).max())

    return Dataset("periodic", sequences, Profile(), ceiling)


# --- evaluation --------------------------------------------------------------------------

def split(n: int, folds: int, seed: int) -> list[np.ndarray]:
    """IPredict's k-fold split of the shuffled sequences: equal folds, the last one takes
    what is left over."""
    order = np.random.default_rng(seed).permutation(n)
    size = n // folds
    return [order[i * size:(i + 1) * size if i < folds - 1 else n] for i in range(folds)]


def _query(sequence: list[int], profile: Profile) -> tuple[list[int], list[int]]:
    cut = len(sequence) - profile.consequent
    return sequence[max(cut - profile.window, 0):cut], sequence[cut:]


def peer_predictions(train: list[list[int]], prefixes: list[list[int]],
                     order: int = 5) -> dict[str, np.ndarray]:
    """AKOM(1..order) and PPM-C(order) trained on ``train``, then asked after each prefix."""
    model = CountModel(order)
    for sequence in train:
        model.learn(np.asarray(sequence, np.int32), _no_actions(len(sequence)))
    out = {name: np.full(len(prefixes), -1) for name in [f"AKOM{k}" for k in AKOM_ORDERS]
           + ["PPM-C5"]}
    for i, prefix in enumerate(prefixes):
        obs = np.asarray(prefix + [0], np.int32)  # the last item is the one asked for
        found = model.run(obs, _no_actions(len(obs)), learn=False, ppm="C", ppm_order=order)
        for k in AKOM_ORDERS:
            out[f"AKOM{k}"][i] = found.akom(k)[-1]
        out["PPM-C5"][i] = found.ppm[-1]
    return out


def _no_actions(n: int) -> np.ndarray:
    act = np.zeros(n, np.int32)  # one token for "no action"
    act[:1] = -1
    return act


def evaluate(dataset: Dataset, folds: int, seed: int) -> dict:
    """Accuracy of every model (and the ceiling, when known) over the folds, in percent."""
    names = list(MODELS) + [f"AKOM{k}" for k in AKOM_ORDERS if k != 5]
    hits = {m: 0 for m in names}
    ceiling, tested = 0.0, 0
    sequences = dataset.sequences
    shuffled = np.concatenate(split(len(sequences), folds, seed))
    for test in split(len(sequences), folds, seed):
        in_test = np.zeros(len(sequences), bool)
        in_test[test] = True
        train = [sequences[j] for j in shuffled if not in_test[j]]  # IPredict's order: shuffled
        queries = [_query(sequences[i], dataset.profile) for i in test]
        prefixes = [q[0] for q in queries]
        guesses = peer_predictions(train, prefixes)
        guesses["slearn"] = slearn_sequence_predictions(train, prefixes)
        for model in names:
            hits[model] += sum(int(g) in q[1] for g, q in zip(guesses[model], queries))
        if dataset.ceiling is not None:
            ceiling += sum(dataset.ceiling(*q) for q in queries)
        tested += len(queries)
    out = {m: 100.0 * hits[m] / tested for m in names}
    best = max(AKOM_ORDERS, key=lambda k: out[f"AKOM{k}"])
    out["AKOM*"], out["AKOM* order"] = out[f"AKOM{best}"], best
    out["ceiling"] = 100.0 * ceiling / tested if dataset.ceiling is not None else None
    return out


def describe(dataset: Dataset) -> dict:
    """Size figures of a dataset."""
    items = sum(len(s) for s in dataset.sequences)
    return {"sequences": len(dataset.sequences), "items": items,
            "alphabet": len({x for s in dataset.sequences for x in s}),
            "mean_length": items / max(len(dataset.sequences), 1),
            "window": dataset.profile.window, "consequent": dataset.profile.consequent}


def datasets(args: argparse.Namespace) -> tuple[list[Dataset], list[str]]:
    """The synthetic sources, the text and the public datasets asked for."""
    found = [markov_source(2, 30, 1), markov_source(3, 20, 2), periodic_source(3)]
    notes = []
    texts = [Path(args.text)] if args.text else license_files()
    text = text_dataset(texts, "text" if args.text else "licenses") if texts else None
    if text is None:
        notes.append("licenses: no text found in /usr/share/common-licenses (use --text FILE)")
    else:
        found.append(text)
    if args.data:
        public, missing = public_datasets(Path(args.data))
        found += public
        notes += missing
    if args.datasets:
        wanted = set(args.datasets.split(","))
        found = [d for d in found if d.name in wanted]
    return found, notes


def render(rows: list[dict], folds: int, notes: list[str]) -> str:
    """One row per dataset."""
    head = (f"{'dataset':<15}{'seqs':>6}{'items':>9}{'alph':>6}{'len':>6}{'w/c':>5}  "
            + "".join(f"{m:>8}" for m in MODELS) + f"{'AKOM*':>10}{'ceiling':>9}{'CPT+':>6}"
            f"{'SuBSeq':>7}")
    lines = [f"next-item accuracy, {folds}-fold cross-validation, % of test sequences", head,
             "-" * len(head)]
    for r in rows:
        published = PUBLISHED.get(r["name"])
        ceiling = f"{r['ceiling']:9.1f}" if r["ceiling"] is not None else f"{'-':>9}"
        paper = f"{published[0]:6d}{published[1]:7d}" if published else f"{'-':>6}{'-':>7}"
        lines.append(f"{r['name']:<15}{r['sequences']:>6}{r['items']:>9}{r['alphabet']:>6}"
                     f"{r['mean_length']:6.1f}{r['window']:>3}/{r['consequent']}  "
                     + "".join(f"{r[m]:8.1f}" for m in MODELS)
                     + f"{r['AKOM*']:6.1f} ({r['AKOM* order']})" + ceiling + paper)
    below = [f"slearn below {m} on {r['name']}: {r['slearn']:.2f} against {r[m]:.2f} "
             f"({fewer} of {r['sequences']:,} test sequences)"
             for r in rows for m in MODELS[:-1]
             if (fewer := round((r[m] - r["slearn"]) * r["sequences"] / 100)) > 0]
    return "\n".join(lines + below + notes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", help="folder with the public datasets (see the docstring)")
    parser.add_argument("--text", help="a text file to use instead of the licenses")
    parser.add_argument("--folds", type=int, default=14)
    parser.add_argument("--seed", type=int, default=0, help="seed of the shuffle")
    parser.add_argument("--datasets", help="comma-separated dataset names (default: all)")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    if args.folds < 2:
        parser.error("--folds must be at least 2")
    chosen, notes = datasets(args)
    rows = []
    for dataset in chosen:
        started = time.perf_counter()
        rows.append({"name": dataset.name, **describe(dataset),
                     **evaluate(dataset, args.folds, args.seed),
                     "published_cpt_plus_subseq": PUBLISHED.get(dataset.name)})
        print(f"{dataset.name}: {time.perf_counter() - started:.1f} s", file=sys.stderr)
    for note in notes:
        print(note, file=sys.stderr)
    if args.json:
        print(json.dumps({"folds": args.folds, "seed": args.seed, "datasets": rows,
                          "notes": notes}))
    else:
        print(render(rows, args.folds, []))


if __name__ == "__main__":
    main()
