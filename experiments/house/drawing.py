"""The drawing of the house: the import graph of daddpg_jax and mjx_envs collapsed to their
layers (subpackages), as a Mermaid graph, with the figures that say how the house holds:
import loops (strongly connected components of the module graph), package lines, the largest
module and the longest function.

    python -m experiments.house.drawing [--root DIR] [--json OUT]

``--root`` reads another checkout (e.g. a ``git worktree`` of an earlier revision). The module
graph is the one tests/test_import_graph.py checks (every import, also inside functions)."""

from __future__ import annotations

import argparse
import ast
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, ROOT)

from tests.test_import_graph import import_graph, strongly_connected  # noqa: E402

PACKAGES = ("daddpg_jax", "mjx_envs")
LAYERS = ("daddpg_jax.cli", "daddpg_jax.analysis", "daddpg_jax.running", "daddpg_jax.algo",
          "daddpg_jax.tools", "daddpg_jax.deploy.camera", "daddpg_jax.deploy", "daddpg_jax",
          "mjx_envs.tasks", "mjx_envs.physics", "mjx_envs")
"""the layers, most specific first (a module belongs to the first that prefixes it)"""


def read(root: str):
    """[(path relative to root, source)] of every .py file of the packages under root."""
    out = []
    for package in PACKAGES:
        for dirpath, dirnames, names in os.walk(os.path.join(root, package)):
            dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
            for name in sorted(n for n in names if n.endswith(".py")):
                path = os.path.join(dirpath, name)
                with open(path, encoding="utf-8") as f:
                    out.append((os.path.relpath(path, root), f.read()))
    return out


def layer(module: str) -> str:
    return next(lay for lay in LAYERS if module == lay or module.startswith(lay + "."))


def longest_function(files) -> tuple[int, str]:
    best = (0, "")
    for rel, src in files:
        for node in ast.walk(ast.parse(src, rel)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                best = max(best, (n, f"{rel}:{node.name}"))
    return best


def figures(root: str) -> dict:
    files = read(root)
    graph = import_graph(files)
    loops = [sorted(c) for c in strongly_connected(graph) if len(c) > 1]
    edges = sorted({(layer(a), layer(b)) for a, targets in graph.items() for b in targets
                    if layer(a) != layer(b)})
    sizes = sorted(((src.count("\n"), rel) for rel, src in files), reverse=True)
    return dict(modules=len(files), lines=sum(n for n, _ in sizes), loops=loops,
                largest_module=list(sizes[0]), longest_function=list(longest_function(files)),
                layer_edges=edges, floors=floors(graph) if not loops else None)


def floors(graph) -> list[list[str]]:
    """The modules by floor: floor 0 imports nothing of the packages, floor k imports only
    modules below it (the longest import chain under it). Defined only without loops, and
    every import then points downwards: a drawing with no circle."""
    depth: dict[str, int] = {}

    def down(m, seen=()):
        if m not in depth:
            depth[m] = 1 + max((down(t, (*seen, m)) for t in graph[m]), default=-1)
        return depth[m]

    for m in graph:
        down(m)
    out = [[] for _ in range(max(depth.values()) + 1)]
    for m, d in sorted(depth.items()):
        out[d].append(m)
    return out


def mermaid(edges) -> str:
    ids = {lay: lay.replace(".", "_") for lay in LAYERS}
    lines = ["graph TD"] + [f"  {ids[a]}[{a}] --> {ids[b]}[{b}]" for a, b in edges]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default=ROOT)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    out = figures(args.root)
    print(mermaid(out["layer_edges"]))
    print(f"\nmodules {out['modules']}, lines {out['lines']}, import loops {len(out['loops'])}, "
          f"largest module {out['largest_module']}, longest function "
          f"{out['longest_function']}")
    for loop in out["loops"]:
        print("loop:", " <-> ".join(loop))
    for k, mods in enumerate(out["floors"] or ()):
        print(f"floor {k}: {', '.join(mods)}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
