"""The task and benchmark names have one home, ``floaff_zoo.names``; every other module's name is that object."""

from __future__ import annotations

import ast
import typing
from pathlib import Path

from floaff_zoo import contract, demo, names
from floaff_zoo.data import floaff_kitchen
from floaff_zoo.sim import fileformat, kitchen, presets

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "floaff_zoo"


def test_old_names_are_the_one_definition():
    for tasks in (contract.TASKS, kitchen.TASKS, presets.ALL_TASKS, demo.ALL_TASKS):
        assert tasks is names.TASKS
    for benchmarks in (presets.ALL_BENCHMARKS, fileformat.BENCHMARKS, floaff_kitchen.BENCHMARKS):
        assert benchmarks is names.BENCHMARKS


def test_order_is_the_canonical_one():
    # generation seeds, the validation draw and the tables follow this order: changing it changes the data
    assert names.TASKS == ("PnPCounterToCab", "OpenSingleDoor", "CloseDrawer", "CloseDoubleDoor")
    assert names.BENCHMARKS == ("styles", "layouts")


def test_benchmark_literal_is_the_names():
    # a type annotation must spell its Literal out (jsonargparse's choices); it may not drift from the one home
    hint = typing.get_type_hints(floaff_kitchen.FloAffKitchenDataModule.__init__)["benchmark"]
    assert typing.get_args(hint) == names.BENCHMARKS


def _literal_slices(tree: ast.AST) -> set[int]:
    """ids of the tuples inside ``Literal[...]`` (annotations, which must spell the values out)."""
    return {
        id(node.slice)
        for node in ast.walk(tree)
        if isinstance(node, ast.Subscript) and getattr(node.value, "id", getattr(node.value, "attr", "")) == "Literal"
    }


def test_no_module_writes_the_names_again():
    """No tuple, list or set literal of the package or its scripts spells out all the tasks or both benchmarks,
    except names.py (and a ``Literal[...]`` annotation, checked above)."""
    again = []
    for path in sorted([*SRC.rglob("*.py"), *(ROOT / "scripts").glob("*.py"), *(ROOT / "benchmarks").glob("*.py")]):
        if path.name == "names.py" and path.parent == SRC:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        literals = _literal_slices(tree)
        for node in ast.walk(tree):
            if id(node) in literals:
                continue
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)) and all(isinstance(e, ast.Constant) for e in node.elts):
                values = {e.value for e in node.elts}
                if values >= set(names.TASKS) or values == set(names.BENCHMARKS):
                    again.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not again, f"task/benchmark names written again (import floaff_zoo.names): {again}"
