"""How long each synthetic dataset takes to build (the cards promise "seconds").

    python bench/bench_datasets.py

Prints, per dataset: build seconds, episodes, bytes written. Anchor: recording the same
number of pointer trials with ``slearn record pointer`` alone (the build's floor).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from slearn.datasets.registry import build_dataset, list_datasets


def main() -> None:
    print(f"{'dataset':<16} {'seconds':>8} {'episodes':>9} {'MB':>7}")
    for dataset in list_datasets():
        if dataset.name == "pr2-sample":  # needs --source: a copy of a real log
            continue
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            summary = build_dataset(dataset.name, Path(tmp) / dataset.name)
            seconds = time.perf_counter() - start
            size = sum(p.stat().st_size for p in Path(tmp).rglob("*") if p.is_file())
        print(f"{dataset.name:<16} {seconds:>8.1f} {len(summary.episodes):>9} {size / 1e6:>7.2f}")


if __name__ == "__main__":
    main()
