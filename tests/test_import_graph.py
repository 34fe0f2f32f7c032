"""No import loop in the packages: the import graph of daddpg_jax and mjx_envs, built with
``ast`` over their sources, has no strongly connected component of more than one module.

Every import counts: at module level, inside functions and classes, under ``if TYPE_CHECKING:``
and ``try:``, and ``importlib.import_module("a.literal.name")``. ``from pkg import name`` is an
edge to the submodule ``pkg.name`` when there is one, else to ``pkg``; ``import a.b.c`` and
``from a.b.c import x`` to the longest prefix that is a module of the packages. The package
``__init__`` modules that Python runs first on the way to a submodule are no edges (they run
before it either way). Imports from outside the two packages are ignored. ~0.7 s."""

from __future__ import annotations

import ast

from tests.package_sources import PACKAGES, sources


def module_name(rel: str) -> tuple[str, bool]:
    """(dotted module name, whether it is a package ``__init__``) of a path relative to the
    repository, e.g. ``mjx_envs/tasks/push.py`` -> (``mjx_envs.tasks.push``, False)."""
    parts = rel[:-len(".py")].replace("\\", "/").split("/")
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), True
    return ".".join(parts), False


def _known(name: str, modules) -> str | None:
    """The longest prefix of `name` that is one of `modules` (None: none is)."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def _literal_import_module(node: ast.Call) -> str | None:
    func = node.func
    called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if (called == "import_module" and node.args and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)):
        return node.args[0].value
    return None


def imported_modules(tree: ast.AST, module: str, is_package: bool, modules) -> set[str]:
    """The modules of `modules` that the parsed source of `module` imports, anywhere in it."""
    package = module if is_package else module.rpartition(".")[0]
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([node.module] if node.module else []))
            names += [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                      for a in node.names]
        elif isinstance(node, ast.Call):
            literal = _literal_import_module(node)
            if literal:
                names.append(literal)
    return {m for m in (_known(n, modules) for n in names) if m is not None and m != module}


def import_graph(files) -> dict[str, set[str]]:
    """{module: the modules it imports} of `files`: (path relative to the repository, source)."""
    parsed = {}
    for rel, src in files:
        name, is_package = module_name(rel)
        parsed[name] = (ast.parse(src, rel), is_package)
    return {name: imported_modules(tree, name, is_package, parsed)
            for name, (tree, is_package) in parsed.items()}


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of `graph` (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, edges = work[-1]
            w = next(edges, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.add(w)
                    if w == v:
                        break
                out.append(component)
    return out


def test_the_graph_counts_every_kind_of_import():
    files = [
        ("p/__init__.py", "from p import a\n"),
        ("p/a.py", "import os\nfrom p.sub import c\n"),
        ("p/b.py", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p import a\n"),
        ("p/sub/__init__.py", ""),
        ("p/sub/c.py", "def f():\n    from .. import b\n    from ..a import x\n"),
        ("p/d.py", "import importlib\nimportlib.import_module('p.sub.c')\nimport p.sub\n"),
        ("p/e.py", "from p import sub, not_a_module\n"),
    ]
    graph = import_graph(files)
    assert graph == {"p": {"p.a"}, "p.a": {"p.sub.c"}, "p.b": {"p.a"}, "p.sub": set(),
                     "p.sub.c": {"p.b", "p.a"}, "p.d": {"p.sub.c", "p.sub"},
                     "p.e": {"p.sub", "p"}}
    components = sorted(sorted(c) for c in strongly_connected(graph) if len(c) > 1)
    assert components == [["p.a", "p.b", "p.sub.c"]]


def test_no_import_loop_in_the_packages():
    files = [(rel, src) for package in PACKAGES for _, rel, src in sources(package)]
    graph = import_graph(files)
    assert "mjx_envs.settings" in graph and "daddpg_jax.running.runner" in graph
    loops = [c for c in strongly_connected(graph) if len(c) > 1]
    assert not loops, "import loops (modules that import each other, directly or not):\n" + \
        "\n".join(" <-> ".join(sorted(c)) for c in loops)
