"""Loading the repository's scripts (``scripts/``) and benchmarks (``benchmarks/``) as modules in tests.

Kept free of torch and of the package so that the subprocess drivers of some tests can import it too without
changing what their child interpreter has imported.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_file(path: Path) -> ModuleType:
    """A fresh module of the file ``path``, named by its stem and left out of ``sys.modules`` (each call runs the
    file again), executed with its folder on ``sys.path`` (for imports of its neighbours: ``bench_models``,
    ``sr_json``, ...)."""
    folder = str(path.parent)
    sys.path.insert(0, folder)
    try:
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(folder)


def load_script(name: str) -> ModuleType:
    """The module of ``scripts/<name>.py``."""
    return load_file(ROOT / "scripts" / f"{name}.py")


def load_benchmark(name: str) -> ModuleType:
    """The module of ``benchmarks/<name>.py``."""
    return load_file(ROOT / "benchmarks" / f"{name}.py")
