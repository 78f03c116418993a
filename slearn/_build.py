"""The install's one build step: slearn's kernels compiled ahead of time (``_aot``).

Named in ``pyproject.toml`` as the ``build_ext`` command. Any failure (no C compiler, a numba
without ``pycc``) is a warning, never a failed install: slearn then compiles its kernels at
first use, as it always could. ``SLEARN_AOT=0`` skips the step.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

from setuptools.command.build_ext import build_ext

# setuptools loads this file before slearn is importable: slearn.core._aot.EXTENSION, and the
# source tree that build imports slearn from
EXTENSION = "slearn.core._compiled"
ROOT = Path(__file__).resolve().parents[1]


class BuildKernels(build_ext):
    """``build_ext`` that compiles the extension ``slearn.core._compiled`` with numba."""

    def run(self) -> None:
        if os.environ.get("SLEARN_AOT", "1") == "0":
            self.extensions = [e for e in self.extensions if e.name != EXTENSION]  # type: ignore[has-type]
        super().run()

    def build_extension(self, ext) -> None:
        if ext.name != EXTENSION:
            return super().build_extension(ext)
        target = Path(self.get_ext_fullpath(ext.name))
        target.parent.mkdir(parents=True, exist_ok=True)
        sys.path.insert(0, str(ROOT))
        scratch = tempfile.mkdtemp(prefix="slearn-build-")  # the callees' numba cache: not the user's
        os.environ["SLEARN_CACHE_DIR"] = scratch
        try:
            from slearn.core._aot import build
            skipped = build(target, ROOT)
        except Exception as error:  # the install goes on: numba compiles at first use
            target.unlink(missing_ok=True)
            print(f"warning: slearn's kernels were not compiled ahead of time ({type(error).__name__}: "
                  f"{error}); numba compiles them at first use", file=sys.stderr)
            return
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
        if skipped:
            print(f"slearn: compiled at first use instead (their modules need more than numpy and numba "
                  f"to import): {', '.join(skipped)}", file=sys.stderr)
