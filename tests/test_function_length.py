"""No function in daddpg_jax/ or mjx_envs/ is longer than MAX_LINES lines (a nested function
counts as part of the function that encloses it; decorators and docstrings count)."""

import ast

import pytest

from tests.package_sources import PACKAGES, sources

MAX_LINES = 100


def outermost_functions(tree: ast.AST):
    """Functions and methods not inside another function."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node
        else:
            yield from outermost_functions(node)


def long_functions(package: str, max_lines: int = MAX_LINES) -> list[str]:
    out = []
    for path, rel, src in sources(package):
        for fn in outermost_functions(ast.parse(src, path)):
            first = min([fn.lineno] + [d.lineno for d in fn.decorator_list])
            n = fn.end_lineno - first + 1
            if n > max_lines:
                out.append(f"{rel}:{first} {fn.name}: {n} lines")
    return out


def test_outermost_functions_counts_nested_in_the_enclosing_one():
    tree = ast.parse("def f():\n    def g():\n        pass\n    return g\n"
                     "class C:\n    def m(self):\n        pass\n")
    assert [f.name for f in outermost_functions(tree)] == ["f", "m"]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_function_longer_than_max_lines(package):
    too_long = long_functions(package)
    assert not too_long, (f"functions longer than {MAX_LINES} lines (split them):\n"
                          + "\n".join(too_long))
