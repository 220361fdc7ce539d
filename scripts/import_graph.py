"""The project's import graph: which package leans on which, cycles, and library modules that import CLI modules.

    python -m scripts.import_graph            # the summary and every offending import
    python -m scripts.import_graph --edges    # also every project-internal import (module -> module)
    python -m scripts.import_graph --check    # exit 1 if any arrow aat_deploy -> training, cycle or library -> CLI

Reads the source with `ast` (nothing is imported). Every `import` counts, at module level or inside a function
(a lazy import is still a dependency; it is marked `lazy`). `from pkg import name` counts as an import of the
submodule `pkg.name` when that is a module of the project, else of `pkg`. The rules checked:

- **ground floor**: `aat_deploy` (the torch-free runtime) never imports `training` (the torch side);
- **no cycles**: no strongly connected set of modules (Tarjan), counting lazy imports;
- **CLI at the top**: no module outside a `cli` package imports one inside it.

It also lists **folders that import each other** (a folder is a package directory; modules directly in it belong to
it, a subfolder is its own folder): `aat_deploy/lens` -> `aat_deploy/optics` -> `aat_deploy/lens` is a cycle of
rooms even when no module cycle exists. Each pair is shown with the imports of its lighter direction (the ones to
move). These are reported, not checked (`--check` ignores them: the tree still has some, issue 36);
tests/deploy/test_ground_floor.py keeps their list from growing.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("aat_deploy", "training")


@dataclass(frozen=True)
class Edge:
    src: str   # importing module
    dst: str   # imported project module
    line: int
    lazy: bool  # inside a function or class body (not at module level)


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the project's packages, by dotted name."""
    mods = {}
    for pkg in PACKAGES:
        for p in sorted((root / pkg).rglob("*.py")):
            mods[module_name(p, root)] = p
    return mods


def _resolve(node: ast.ImportFrom, importer: str, is_pkg: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = importer.split(".")
    base = base if is_pkg else base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(path: Path, name: str, mods: dict[str, Path]) -> list[Edge]:
    """The project-internal imports of one module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out: list[Edge] = []

    def target(dotted: str) -> str | None:
        while dotted and dotted not in mods:  # `import a.b.c` where c is a name, not a module
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    def visit(node: ast.AST, lazy: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for a in child.names:
                    if a.name.split(".")[0] in PACKAGES and (t := target(a.name)):
                        out.append(Edge(name, t, child.lineno, lazy))
            elif isinstance(child, ast.ImportFrom):
                base = _resolve(child, name, is_pkg)
                if base.split(".")[0] not in PACKAGES:
                    continue
                for a in child.names:
                    sub = f"{base}.{a.name}"
                    t = sub if sub in mods else target(base)
                    if t:
                        out.append(Edge(name, t, child.lineno, lazy))
            visit(child, inner)

    visit(tree, False)
    return out


def all_edges(root: Path = ROOT) -> tuple[dict[str, Path], list[Edge]]:
    mods = project_modules(root)
    edges = [e for name, p in mods.items() for e in imports_of(p, name, mods) if e.dst != name]
    return mods, list(dict.fromkeys(edges))  # `from m import a, b` is one import of m


def cycles(mods: dict[str, Path], edges: list[Edge]) -> list[list[str]]:
    """Strongly connected sets of more than one module (Tarjan, iterative)."""
    graph: dict[str, set[str]] = defaultdict(set)
    for e in edges:
        graph[e.src].add(e.dst)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    sccs: list[list[str]] = []
    counter = 0
    for start in sorted(mods):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    sccs.append(sorted(comp))
    return sorted(sccs)


def folder_of(module: str, mods: dict[str, Path]) -> str:
    """The package directory a module lives in, as a dotted name (a package's `__init__` is in its own folder)."""
    p = mods[module]
    return module if p.name == "__init__.py" else module.rpartition(".")[0]


def folder_pairs(mods: dict[str, Path], edges: list[Edge]) -> list[tuple[str, str, list[Edge], list[Edge]]]:
    """Folders that import each other: (a, b, imports a -> b, imports b -> a), a < b, sorted."""
    between: dict[tuple[str, str], list[Edge]] = defaultdict(list)
    for e in edges:
        a, b = folder_of(e.src, mods), folder_of(e.dst, mods)
        if a != b:
            between[(a, b)].append(e)
    return [(a, b, es, between[(b, a)]) for (a, b), es in sorted(between.items()) if a < b and (b, a) in between]


def is_cli(module: str) -> bool:
    return ".cli." in f".{module}." and not module.endswith(".cli")


def report(root: Path = ROOT) -> dict:
    """The findings as plain data (tests read this)."""
    mods, edges = all_edges(root)
    return {
        "modules": len(mods),
        "edges": edges,
        "deploy_to_training": [e for e in edges if e.src.startswith("aat_deploy") and e.dst.startswith("training")],
        "training_to_deploy": [e for e in edges if e.src.startswith("training") and e.dst.startswith("aat_deploy")],
        "cycles": cycles(mods, edges),
        "folder_pairs": folder_pairs(mods, edges),
        "library_to_cli": [e for e in edges if is_cli(e.dst) and not is_cli(e.src)],
    }


def _rel(module: str, mods: dict[str, Path]) -> str:
    return str(mods[module].relative_to(ROOT)) if module in mods else module


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edges", action="store_true", help="also list every project-internal import")
    ap.add_argument("--check", action="store_true", help="exit 1 on any arrow aat_deploy -> training, cycle or "
                                                         "library -> CLI import")
    args = ap.parse_args(argv)
    mods = project_modules()
    r = report()
    d2t = r["deploy_to_training"]
    files = sorted({e.src for e in d2t})
    print(f"modules: {r['modules']}, internal imports: {len(r['edges'])}")
    print(f"aat_deploy -> training: {len(d2t)} imports in {len(files)} files "
          f"(training -> aat_deploy: {len(r['training_to_deploy'])})")
    for e in sorted(d2t, key=lambda e: (e.src, e.line)):
        print(f"  {_rel(e.src, mods)}:{e.line} -> {e.dst}{'  (lazy)' if e.lazy else ''}")
    print(f"cycles: {len(r['cycles'])}")
    for c in r["cycles"]:
        print("  " + " <-> ".join(c))
    print(f"folders that import each other: {len(r['folder_pairs'])}")
    for a, b, ab, ba in r["folder_pairs"]:
        (x, y, few) = (a, b, ab) if len(ab) <= len(ba) else (b, a, ba)
        print(f"  {a} <-> {b}  ({len(ab)} imports one way, {len(ba)} the other; the {len(few)} {x} -> {y}:)")
        for e in sorted(few, key=lambda e: (e.src, e.line)):
            print(f"    {_rel(e.src, mods)}:{e.line} -> {e.dst}{'  (lazy)' if e.lazy else ''}")
    print(f"library -> CLI imports: {len(r['library_to_cli'])}")
    for e in r["library_to_cli"]:
        print(f"  {_rel(e.src, mods)}:{e.line} -> {e.dst}{'  (lazy)' if e.lazy else ''}")
    if args.edges:
        print("edges:")
        for e in sorted(r["edges"], key=lambda e: (e.src, e.line)):
            print(f"  {e.src} -> {e.dst}{'  (lazy)' if e.lazy else ''}")
    bad = d2t or r["cycles"] or r["library_to_cli"]
    return 1 if (args.check and bad) else 0


if __name__ == "__main__":
    sys.exit(main())
