"""Figures of the code's shape, for the layout's before and after.

    python scripts/code_figures.py [--top 20] [--json]

Over the Python of the product (every package with an ``__init__.py`` at the
top of the tree, tests left out): files per folder, the longest functions
(lines of code, the docstring left out), the share of lines that are
docstrings, docstrings of 20 lines or more, imports of another module's
``_private`` names, and the circles of the import graph (modules that import
each other, directly or round a loop; imports inside functions count too),
the imports between modules and the layers they make (the longest chain of
imports), and imports from one stage package into another.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def packages() -> list[Path]:
    """The top-level packages of the product (``tests`` left out)."""
    return sorted(p.parent for p in ROOT.glob("*/__init__.py") if p.parent.name != "tests")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def docstring_lines(tree: ast.Module) -> tuple[int, int]:
    """Lines taken by the docstrings of a module, its classes and functions,
    and how many of those docstrings have 20 lines or more."""
    total = long = 0
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
                if isinstance(body[0].value.value, str):
                    total += body[0].end_lineno - body[0].lineno + 1
                    long += body[0].end_lineno - body[0].lineno + 1 >= 20
    return total, long


def function_sizes(tree: ast.Module, module: str) -> list[tuple[int, str, int]]:
    """(lines of code, qualified name, docstring lines) of every function.

    Lines of code: from the ``def`` line to the function's last line, less its
    docstring (blank and comment lines count; nested functions count in their
    parent and on their own).
    """
    out = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                doc = 0
                body = child.body
                if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
                    doc = body[0].end_lineno - body[0].lineno + 1
                out.append((child.end_lineno - child.lineno + 1 - doc, f"{module}.{prefix}{child.name}", doc))
                visit(child, f"{prefix}{child.name}.")

    visit(tree, "")
    return out


def imports(tree: ast.Module, module: str, is_package: bool) -> list[tuple[str, list[str]]]:
    """(imported module, names) of every import of this product's packages."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = module.split(".")
                parts = parts[: len(parts) - node.level + (1 if is_package else 0)]
                base = ".".join(parts + ([base] if base else []))
            out.append((base, [a.name for a in node.names]))
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found = []
    sys.setrecursionlimit(10_000)

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return found


def layers(graph: dict[str, set[str]], circles: list[list[str]]) -> int:
    """Floors of the import graph: the longest chain of imports, a circle counted as one module."""
    group = {m: i for i, comp in enumerate(circles) for m in comp}
    node = {m: group.get(m, m) for m in graph}
    edges: dict = {}
    for a, targets in graph.items():
        edges.setdefault(node[a], set()).update(node[b] for b in targets if node[b] != node[a])
    depth: dict = {}

    def floor(v) -> int:
        if v not in depth:
            depth[v] = 0
            depth[v] = 1 + max((floor(w) for w in edges.get(v, ())), default=0)
        return depth[v]

    return max((floor(v) for v in edges), default=0)


def cross_stage(graph: dict[str, set[str]]) -> list[str]:
    """Imports from one stage package into another, and of a driver by an algorithm module."""
    out = []
    for a, targets in graph.items():
        for b in targets:
            pa, pb = a.split("."), b.split(".")
            if pa[0] == pb[0] == "stages" and len(pa) > 2 and len(pb) > 2:
                if pa[1] != pb[1]:
                    out.append(f"{a} -> {b}")
                elif pb[2] == "stage" and pa[2] != "stage":
                    out.append(f"{a} -> {b} (an algorithm imports its driver)")
    return sorted(out)


def measure() -> dict:
    files = [p for pkg in packages() for p in sorted(pkg.rglob("*.py"))]
    modules = {module_name(p): p for p in files}
    all_lines = doc_lines = 0
    sizes: list[tuple[int, str, int]] = []
    graph: dict[str, set[str]] = {}
    private: list[str] = []
    per_folder = Counter(p.parent.relative_to(ROOT).as_posix() for p in files)
    long_docs = 0
    for name, path in modules.items():
        text = path.read_text(encoding="utf-8")
        tree = ast.parse(text)
        all_lines += len(text.splitlines())
        doc, long = docstring_lines(tree)
        doc_lines += doc
        long_docs += long
        sizes += function_sizes(tree, name)
        graph[name] = set()
        for target, names in imports(tree, name, path.name == "__init__.py"):
            # "from a.b import c" may import the module a.b.c
            for cand in [f"{target}.{n}" for n in names] + [target]:
                if cand in modules and cand != name:
                    graph[name].add(cand)
                    break
            if target in modules and target != name:
                private += [f"{name} <- {target}.{n}" for n in names if n.startswith("_") and not n.startswith("__")]
    sizes.sort(reverse=True)
    return {
        "python_files": len(files),
        "python_lines": all_lines,
        "docstring_lines": doc_lines,
        "docstring_share": round(doc_lines / all_lines, 4),
        "docstrings_20_lines_or_more": long_docs,
        "files_per_folder": dict(sorted(per_folder.items(), key=lambda kv: -kv[1])),
        "functions_over_120": sum(1 for s in sizes if s[0] > 120),
        "functions_over_80": sum(1 for s in sizes if s[0] > 80),
        "functions_over_60": sum(1 for s in sizes if s[0] > 60),
        "longest_functions": [[n, s] for s, n, _ in sizes],
        "private_imports": private,
        "import_circles": cycles(graph),
        "import_arrows": sum(len(v) for v in graph.values()),
        "import_layers": layers(graph, cycles(graph)),
        "cross_stage_imports": cross_stage(graph),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--top", type=int, default=20, help="how many of the longest functions to list")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    fig = measure()
    fig["longest_functions"] = fig["longest_functions"][: args.top]
    if args.json:
        print(json.dumps(fig, indent=1))
        return 0
    print(f"{fig['python_files']} files, {fig['python_lines']} lines of Python")
    print(f"docstrings: {fig['docstring_lines']} lines ({100 * fig['docstring_share']:.1f} %), ", end="")
    print(f"{fig['docstrings_20_lines_or_more']} of them 20 lines or longer")
    print("files per folder: " + ", ".join(f"{k} {v}" for k, v in fig["files_per_folder"].items()))
    print(
        f"functions over 120 lines of code: {fig['functions_over_120']}, over 80: {fig['functions_over_80']}, "
        f"over 60: {fig['functions_over_60']}"
    )
    for name, size in fig["longest_functions"]:
        print(f"  {size:4d}  {name}")
    print(f"imports of another module's _private names: {len(fig['private_imports'])}")
    for row in fig["private_imports"]:
        print(f"  {row}")
    print(f"imports between modules: {fig['import_arrows']}, in {fig['import_layers']} layers")
    print(f"imports across stage packages (or of a driver by its algorithms): {len(fig['cross_stage_imports'])}")
    for row in fig["cross_stage_imports"]:
        print(f"  {row}")
    print(f"import circles: {len(fig['import_circles'])}")
    for comp in fig["import_circles"]:
        print("  " + " <-> ".join(comp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
