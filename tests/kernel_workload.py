"""The commands whose kernels the install compiles ahead of time (``slearn/core/_aot.py``).

Runs slearn's main paths on small inputs (the demo, recording, learning with either scoring,
merging, frozen and online replay, a multi-joint arm, the Python API, control) and collects
the signatures every kernel was called with from Python. ``--write`` stores them as the
manifest the build reads; without it, prints them.

Run: ``python tests/kernel_workload.py --write`` after changing a kernel's arguments
(``tests/test_compiled_kernels.py`` fails until the manifest covers the workload). It runs
without the compiled extension, on an empty kernel cache of its own.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tempfile
from pathlib import Path


def _cli(*args: str) -> None:
    from slearn.cli import main
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            main(list(args), standalone_mode=False)
        except SystemExit as stop:
            if stop.code not in (0, None):
                raise RuntimeError(f"slearn {' '.join(args)} exited {stop.code}") from None


def run(folder: Path) -> None:
    """Every path of the workload, writing under ``folder``."""
    _cli("demo", "--out", str(folder / "demo"), "--seeds", "1", "--trials", "1000", "--quiet")
    for condition in ("delay", "error"):
        _cli("record", "pointer", "--condition", condition, "--trials", "1000", "-o", str(folder / f"{condition}.mcap"))
    delay, error = str(folder / "delay.mcap"), str(folder / "error.mcap")
    _cli("learn", delay, "-o", str(folder / "delay.parquet"))
    _cli("learn", error, "-o", str(folder / "error.parquet"))
    _cli("learn", delay, "--scoring", "literal", "-o", str(folder / "literal.parquet"))
    _cli("merge", str(folder / "delay.parquet"), str(folder / "error.parquet"), "-o", str(folder / "merged.parquet"))
    for library in ("merged", "literal"):
        _cli("replay", str(folder / f"{library}.parquet"), error, "--json")
        _cli("replay", str(folder / f"{library}.parquet"), error, "--online", "--json")
    _cli("info", str(folder / "merged.parquet"))

    from slearn.recorders.arm import ArmConfig, record_arm
    record_arm(ArmConfig(joints=3, trials=1000, seed=0, sensors="all"), folder / "arm.mcap")
    channels = [f"/arm/joint{j}/{field}:{field}:{role}" for j in (1, 2, 3)
                for field, role in (("command", "action"), ("position", "observation"))]
    _cli("learn", str(folder / "arm.mcap"), *(x for c in channels for x in ("--channel", c)),
         "-o", str(folder / "arm.parquet"))
    _cli("replay", str(folder / "arm.parquet"), str(folder / "arm.mcap"), "--json")

    from slearn import SequenceModel
    model = SequenceModel()
    for line in ["the cat sat", "the cat ran", "the cat sat", "a cat ran"] * 3:
        model.learn(line)
    model.predict("the ca")
    model.rank("the cat ", k=2)
    model.predict_many(["the c", "a c", "xyz"])
    model.save(folder / "text.parquet")
    SequenceModel.load(folder / "text.parquet").predict("the c")
    steps = SequenceModel()
    steps.learn_steps([({"cmd": "R"}, {"pos": 1}), ({"cmd": "R"}, {"pos": 2}), ({"cmd": "L"}, {"pos": 1})])
    steps.predict_step([({}, {"pos": 1})], {"cmd": "R"})

    _cli("control", "--condition", "simple", "--goals", "3", "--trials", "2000", "--json")


def signatures() -> dict[str, list]:
    """The workload's signatures (in a fresh temporary folder)."""
    from slearn.core import _aot
    with tempfile.TemporaryDirectory() as tmp, _aot.PythonCalls() as calls:
        run(Path(tmp))
    return calls.signatures()


def main() -> None:
    with tempfile.TemporaryDirectory() as cache:
        os.environ.update(SLEARN_AOT="0", SLEARN_CACHE_DIR=cache)
        found = signatures()
    lines = ",\n".join(f"  {json.dumps(name)}: [\n" + ",\n".join(f"   {json.dumps(sig)}" for sig in sigs) + "\n  ]"
                       for name, sigs in found.items())
    text = f'{{\n "about": "written by tests/kernel_workload.py --write",\n "signatures": {{\n{lines}\n }}\n}}'
    if "--write" in sys.argv:
        from slearn.core import _aot
        _aot.MANIFEST.write_text(text + "\n")
        print(f"{_aot.MANIFEST}: {sum(map(len, found.values()))} signatures of {len(found)} functions")
    else:
        print(text)


if __name__ == "__main__":
    main()
