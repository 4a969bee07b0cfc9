"""No import circles: every module imports on its own, and the import graph (lazy imports included) is acyclic.

Two checks:

* static: every ``import``/``from ... import`` of ``floaff_zoo`` in every module, at any depth (inside
  functions, methods, ``if TYPE_CHECKING:``), plus ``importlib.import_module("<literal>")``, forms a
  graph; importing ``a.b.c`` also runs the packages ``a`` and ``a.b`` (except the importer's own
  parents, which are already running). The graph must have no cycle, neither between modules nor
  between subpackages; a failure lists the cycle.
* dynamic: each module is imported alone in a fresh ``floaff_zoo`` state. A helper interpreter
  imports the third-party libraries once and forks one child per module, so every child starts with
  no ``floaff_zoo`` module loaded (a fresh interpreter per module, without paying torch's import
  70 times). ``floaff_zoo.sim`` is also imported in a plain fresh interpreter to check that it
  pulls in neither torch nor Lightning.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "floaff_zoo"


def _module_files() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package (packages by their __init__)."""
    out = {}
    for path in sorted((SRC / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _module_files()


def _resolve(name: str) -> str | None:
    """The longest module of the package that ``name`` starts with (``a.b.Cls`` -> ``a.b``)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _is_package(module: str) -> bool:
    return MODULES[module].name == "__init__.py"


def _imported_names(module: str, tree: ast.AST) -> set[str]:
    """Every floaff_zoo module ``module`` imports anywhere in its code (as written, then resolved)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the importer's package
                base = module.split(".") if _is_package(module) else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:  # `from pkg import submodule` imports the submodule
                sub = f"{target}.{alias.name}"
                names.add(sub if sub in MODULES else target)
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            names.add(node.args[0].value)
    return {n for n in names if n == PACKAGE or n.startswith(PACKAGE + ".")}


def import_graph() -> dict[str, set[str]]:
    """module -> the floaff_zoo modules importing it executes (explicit imports + the packages they run)."""
    graph: dict[str, set[str]] = {}
    for module, path in MODULES.items():
        own_parents = {module.rsplit(".", i)[0] for i in range(1, module.count(".") + 1)}
        edges: set[str] = set()
        for name in _imported_names(module, ast.parse(path.read_text(encoding="utf-8"), str(path))):
            target = _resolve(name)
            if target is None:
                continue
            edges.add(target)
            parts = target.split(".")
            edges.update(p for p in (".".join(parts[:i]) for i in range(1, len(parts))) if p not in own_parents)
        edges.discard(module)
        graph[module] = edges
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as [a, b, ..., a], or None (iterative DFS, deterministic order)."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    for start in sorted(graph):
        if state.get(start):
            continue
        path, stack = [start], [iter(sorted(graph[start]))]
        state[start] = 1
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                state[path.pop()] = 2
                stack.pop()
            elif state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            elif not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                stack.append(iter(sorted(graph.get(nxt, ()))))
    return None


def test_cycle_finder_reports_the_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]


def test_import_graph_sees_lazy_imports():
    graph = import_graph()
    # a function-level import counts as much as a top-level one, and importing a submodule runs its package
    assert "floaff_zoo.sim.kitchen" in graph["floaff_zoo.callbacks.rollout"]
    assert "floaff_zoo.sim" in graph["floaff_zoo.callbacks.rollout"]


def test_import_graph_has_no_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle (lazy imports included): " + " -> ".join(cycle)


def test_subpackages_depend_one_way():
    """Collapsed to ``floaff_zoo.<part>`` (sim, data, nn, models, hub, callbacks, report, cli, ...), still acyclic."""
    parts: dict[str, set[str]] = {}
    for module, edges in import_graph().items():
        src = ".".join(module.split(".")[:2])
        parts.setdefault(src, set()).update(
            dst for dst in (".".join(e.split(".")[:2]) for e in edges) if dst not in (src, PACKAGE)
        )
    cycle = find_cycle(parts)
    assert cycle is None, "subpackage circle: " + " -> ".join(cycle)


def test_sim_imports_neither_torch_nor_lightning():
    sim = sorted(m for m in MODULES if m.startswith(f"{PACKAGE}.sim"))
    code = (
        "import importlib, sys\n"
        f"for m in {sim!r}:\n"
        "    importlib.import_module(m)\n"
        "print(sorted(k for k in ('torch', 'lightning', 'pytorch_lightning', 'torchmetrics') if k in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", "floaff_zoo.sim imported " + out.stdout


#: imported once by the helper before it forks (no floaff_zoo module among them)
_PRELOAD = (
    "numpy",
    "scipy",
    "torch",
    "lightning",
    "torchmetrics",
    "jsonargparse",
    "yaml",
    "mujoco",
    "matplotlib",
    "safetensors",
)

_FORK_EACH = r"""
import importlib, json, os, sys, traceback
for lib in PRELOAD:
    try:
        importlib.import_module(lib)
    except ImportError:
        pass
assert not any(m == "floaff_zoo" or m.startswith("floaff_zoo.") for m in sys.modules)
results = {}
for name in MODULES:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: import one module from a state without any floaff_zoo module
        os.close(r)
        try:
            importlib.import_module(name)
            msg = b""
        except BaseException:
            msg = traceback.format_exc().encode()
        os.write(w, msg[-20000:])
        os._exit(1 if msg else 0)
    os.close(w)
    chunks = []
    while chunk := os.read(r, 65536):
        chunks.append(chunk)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        results[name] = b"".join(chunks).decode(errors="replace") or f"exit status {status}"
print("RESULT " + json.dumps(results))
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_every_module_imports_alone():
    code = f"PRELOAD = {_PRELOAD!r}\nMODULES = {sorted(MODULES)!r}\n{_FORK_EACH}"
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    assert out.returncode == 0 and lines, out.stderr[-3000:]
    failed = json.loads(lines[-1][len("RESULT ") :])
    assert not failed, "modules that fail to import alone:\n" + "\n".join(f"== {k}\n{v}" for k, v in failed.items())
