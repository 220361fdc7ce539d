"""Checks on the project's own source that no test of behaviour would catch: a condition that can never be false.

`any(Path(d).glob(...) for d in dirs)` is always true: each element is a generator object, which is truthy even
when it yields nothing. A skip guarded by it never skips (issue 37: the Vulkan screenshot test failed on a machine
without a driver instead of skipping). The same holds for `if p.glob(...)`, `bool(p.iterdir())`, `not map(...)`.
"""

from __future__ import annotations

import ast

from conftest import ROOT

LAZY = {"glob", "rglob", "iterdir", "finditer", "scandir", "walk"}  # calls that return an iterator, never a bool
LAZY_BUILTINS = {"map", "filter", "zip", "reversed", "iter"}
FOLDERS = ("aat_deploy", "training", "tests", "benchmarks", "scripts")


def _lazy(node: ast.AST) -> bool:
    """True for an expression that is an iterator object (truthy whatever it yields)."""
    if isinstance(node, ast.GeneratorExp):
        return True
    if isinstance(node, ast.Call):
        f = node.func
        return (isinstance(f, ast.Attribute) and f.attr in LAZY) or (isinstance(f, ast.Name) and f.id in LAZY_BUILTINS)
    return False


def always_true_conditions(source: str) -> list[int]:
    """Line numbers where an iterator object is used as a truth value."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        tested: list[ast.AST] = []
        if isinstance(node, (ast.If, ast.While, ast.IfExp, ast.Assert)):
            tested.append(node.test)
        elif isinstance(node, ast.BoolOp):
            tested.extend(node.values)
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            tested.append(node.operand)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.args:
            if node.func.id == "bool":
                tested.append(node.args[0])
            elif node.func.id in ("any", "all") and isinstance(node.args[0], ast.GeneratorExp):
                tested.append(node.args[0].elt)  # each element is a truth value
        elif isinstance(node, ast.comprehension):
            tested.extend(node.ifs)
        bad += [t.lineno for t in tested if _lazy(t)]
    return sorted(set(bad))


def test_the_detector_finds_the_pattern_and_spares_correct_code():
    wrong = ("from pathlib import Path\n"
             "ok = any(Path(d).glob('*.json') for d in ['a'])\n"
             "if Path('.').iterdir():\n    pass\n"
             "b = bool(map(str, []))\n"
             "c = [x for x in 'ab' if (y for y in x)]\n")
    assert always_true_conditions(wrong) == [2, 3, 5, 6]
    right = ("from pathlib import Path\n"
             "ok = any(next(Path(d).glob('*.json'), None) is not None for d in ['a'])\n"
             "if any(Path('.').iterdir()):\n    pass\n"
             "b = bool(list(map(str, [])))\n"
             "n = sum(1 for _ in Path('.').glob('*'))\n")
    assert always_true_conditions(right) == []


def test_no_iterator_is_used_as_a_truth_value_in_the_project():
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            found += [f"{path.relative_to(ROOT)}:{line}" for line in always_true_conditions(path.read_text())]
    assert found == [], "an iterator object is always truthy (wrap it: any(...), next(..., None), list(...)): " \
                        + ", ".join(found)


def test_test_files_have_unique_names():
    """tests/ has no __init__.py, so pytest imports each test file by its bare name: two files of one name in
    different folders make the whole collection fail ("import file mismatch") on a clean checkout."""
    seen: dict[str, list[str]] = {}
    for p in (ROOT / "tests").rglob("test_*.py"):
        seen.setdefault(p.name, []).append(str(p.relative_to(ROOT)))
    assert {n: ps for n, ps in seen.items() if len(ps) > 1} == {}
