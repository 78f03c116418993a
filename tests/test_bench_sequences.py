"""bench/bench_sequences.py: readers, the IPredict split and query, and a small evaluation."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_sequences as bench  # noqa: E402


def test_spmf_and_ipredict_files_are_read_as_ipredict_reads_them(tmp_path):
    (tmp_path / "FIFA.txt").write_text("# comment\n1 -1 2 -1 2 -1 3 -1 4 -1 5 -1 6 -1 -2\n"
                                       "7 -1 8 -1 -2\n")
    (tmp_path / "BMS.dat").write_text("".join(f"{s} {i}\n" for s in (1, 2) for i in range(10 * s)))
    (tmp_path / "sign_language.txt").write_text(
        "#header\n" + "".join(f"{u} {2 * i} -11 {2 * i + 1}\n" for u in (1, 2) for i in range(6)))
    (tmp_path / "kjv.txt").write_text("In the beginning\nshort\nAnd the earth\n")
    found, notes = bench.public_datasets(tmp_path)
    by_name = {d.name: d for d in found}
    assert sorted(by_name) == ["BIBLE_CHAR", "BMS", "FIFA", "SIGN"]
    assert by_name["FIFA"].sequences == [[0, 1, 2, 3, 4, 5]]  # repeat dropped, short one left out
    assert [len(s) for s in by_name["BMS"].sequences] == [10, 20]
    assert [len(s) for s in by_name["SIGN"].sequences] == [12, 12]  # -11 is not an item
    assert len(by_name["BIBLE_CHAR"].sequences) == 2 and by_name["BIBLE_CHAR"].profile.consequent == 2
    assert [n.split(":")[0] for n in notes] == ["MSNBC", "BIBLE_WORD", "KORAN_WORD", "LEVIATHAN_WORD",
                                                "SNAKE", "CANADARM1", "CANADARM2"]
    assert "left out" in notes[1] and "none of" in notes[0]  # no sentence ends in this kjv.txt


def test_texts_are_read_as_sentences_of_words_and_proteins_as_letters(tmp_path):
    (tmp_path / "kjv.txt").write_text("In the beginning God created; the heaven\n"
                                      "and the earth. And the  earth was: without form?\n"
                                      "Verse 3 [x] a b c d.\n")
    (tmp_path / "snake.dat").write_text("A" * 49 + "\n" + "MK" * 25 + "\n")
    (tmp_path / "Canadarm1_actions.txt").write_text("1 -1 2 -1 3 -1 4 -1 5 -1 6 -1 -2\n")
    found, _ = bench.public_datasets(tmp_path)
    by_name = {d.name: d for d in found}
    words = by_name["BIBLE_WORD"]
    # a sentence goes on across lines and ends at . ? or :; digits, brackets and ; dropped
    assert [len(s) for s in words.sequences] == [10, 4, 6]  # "without form" is short
    assert words.profile == bench.Profile(3, 1, 4)
    assert list(bench._read_words(tmp_path / "kjv.txt"))[1] == ["And", "the", "earth", "was"]
    assert list(bench._read_words(tmp_path / "kjv.txt"))[3] == ["Verse", "x", "a", "b", "c", "d"]
    assert [len(s) for s in by_name["SNAKE"].sequences] == [50]  # lines of 50 letters or more
    assert by_name["CANADARM1"].sequences == [[0, 1, 2, 3, 4, 5]]


def test_an_empty_or_short_public_file_is_left_out_with_a_note(tmp_path):
    (tmp_path / "msnbc.seq").write_text("")  # a download that failed
    (tmp_path / "BMS.dat").write_text("1 1\n1 2\n")  # one sequence, shorter than min_size
    found, notes = bench.public_datasets(tmp_path)
    assert found == []
    left_out = [n for n in notes if "left out" in n]
    assert [n.split(":")[0] for n in left_out] == ["MSNBC", "BMS"]
    assert "msnbc.seq" in left_out[0] and "BMS.dat" in left_out[1]


def test_split_and_query_follow_ipredict():
    folds = bench.split(31, 14, seed=0)
    assert [len(f) for f in folds] == [2] * 13 + [5]
    assert sorted(np.concatenate(folds).tolist()) == list(range(31))
    prefix, consequent = bench._query(list(range(20)), bench.Profile(7, 3, 10))
    assert prefix == list(range(10, 17)) and consequent == [17, 18, 19]


def test_a_deterministic_source_is_predicted_perfectly():
    rng = np.random.default_rng(0)
    sequences = []
    for _ in range(300):  # order 2: next = (a + 2b) mod 7
        s = rng.integers(0, 7, 2).tolist()
        while len(s) < 12:
            s.append((s[-2] + 2 * s[-1]) % 7)
        sequences.append(s)
    result = bench.evaluate(bench.Dataset("det", sequences, bench.Profile()), folds=3, seed=0)
    assert result["AKOM5"] == 100.0 and result["PPM-C5"] == 100.0
    assert 0 <= result["slearn"] <= 100 and result["ceiling"] is None


def test_synthetic_sources_and_their_ceilings():
    markov = bench.markov_source(2, 10, seed=1, count=300)
    periodic = bench.periodic_source(seed=2, count=300)
    for dataset, low, high in ((markov, 0.3, 0.9), (periodic, 0.85, 0.92)):
        assert len(dataset.sequences) == 300
        assert all(10 <= len(s) <= 40 for s in dataset.sequences)
        ceilings = [dataset.ceiling(*bench._query(s, dataset.profile)) for s in dataset.sequences]
        assert 0 < min(ceilings) and max(ceilings) <= 1
        assert low < np.mean(ceilings) < high  # periodic: 90 % + 10 % / 20 at most


def test_the_table_says_where_slearn_is_below_a_peer_in_test_sequences():
    row = {"name": "CANADARM2", "sequences": 170, "items": 8461, "alphabet": 1446,
           "mean_length": 49.8, "window": 5, "consequent": 1, "AKOM5": 100 * 109 / 170,
           "PPM-C5": 100 * 111 / 170, "slearn": 100 * 109 / 170, "AKOM*": 100 * 109 / 170,
           "AKOM* order": 5, "ceiling": None}
    text = bench.render([row], 14, [])
    assert text.splitlines()[-1] == ("slearn below PPM-C5 on CANADARM2: 64.12 against 65.29 "
                                     "(2 of 170 test sequences)")
    assert "below AKOM5" not in text
    assert "below" not in bench.render([dict(row, slearn=row["PPM-C5"])], 14, [])
