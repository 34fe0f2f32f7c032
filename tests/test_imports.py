"""Imports go at the top of modules; an import inside a function or class (deliberately lazy:
a JAX-free path, an optional extra, an import cycle) says why in a comment on its line or on
one of the COMMENT_LINES lines above it. One comment may cover a group of consecutive imports.
Module-level imports (``if TYPE_CHECKING:`` blocks, ``try: ... except ImportError:`` at module
level) need none. Parsed with ``ast``, so docstrings and example code do not count. ~1 s."""

import ast
import io
import re
import tokenize

import pytest

from tests.package_sources import PACKAGES, sources

COMMENT_LINES = 3
_IMPORTS = (ast.Import, ast.ImportFrom)
_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)
# linter and type-checker directives say nothing about why an import is lazy
_DIRECTIVE = re.compile(r"noqa(:\s*[A-Z]+[0-9]+(\s*,\s*[A-Z]+[0-9]+)*)?|type:\s*ignore(\[[^]]*\])?"
                        r"|pragma:\s*no\s*cover", re.IGNORECASE)


def comment_lines(source: str) -> set[int]:
    """Line numbers (1-based) that carry a real comment (tokenize: not a '#' inside a string),
    linter directives (``# noqa: ...``, ``# type: ignore``) not counted."""
    out = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            text = _DIRECTIVE.sub("", tok.string.lstrip("#")).strip(" #:()")
            if text:
                out.add(tok.start[0])
    return out


def nested_import_groups(tree: ast.AST, in_scope: bool = False):
    """Groups (lists) of consecutive import statements inside a function or class body."""
    for field in ("body", "orelse", "finalbody", "handlers"):
        stmts = getattr(tree, field, None)
        if not isinstance(stmts, list):
            continue
        group = []
        for node in stmts:
            if isinstance(node, _IMPORTS) and in_scope:
                group.append(node)
                continue
            if group:
                yield group
                group = []
            yield from nested_import_groups(node, in_scope or isinstance(node, _SCOPES))
        if group:
            yield group
    if isinstance(tree, ast.Match):
        for case in tree.cases:
            yield from nested_import_groups(case, in_scope)


def uncommented_imports(source: str, path: str = "<string>") -> list[int]:
    """Line numbers of nested imports whose group has no comment on any of its lines or on the
    COMMENT_LINES lines above its first import."""
    tree = ast.parse(source, path)
    comments = comment_lines(source)
    bad = []
    for group in nested_import_groups(tree):
        first = group[0].lineno
        lines = set(range(max(1, first - COMMENT_LINES), first))
        for node in group:
            lines.update(range(node.lineno, node.end_lineno + 1))
        if not lines & comments:
            bad.extend(node.lineno for node in group)
    return bad


def test_finds_only_nested_uncommented_imports():
    lines = ['"""Example:', "    from x import y", '"""',
             "import os", "from typing import TYPE_CHECKING",
             "if TYPE_CHECKING:", "    import numpy",
             "try:", "    import onnx", "except ImportError:", "    onnx = None",
             "def f():", "    import json", "    return json",                 # 13: no reason
             "def g():", "    # lazy: a reason", "    import csv", "    import json", "",
             "    from a import b", "    return csv",                        # one group
             "class C:", "    def m(self):", "        import json  # noqa: F401",  # 24
             "    x = 1", "    y = 2", "    z = 3",
             "def h():", "    import io  # optional extra",
             "    x = 1", "    y = 2", "    z = '# not a comment'", "    import re"]  # 33
    assert uncommented_imports("\n".join(lines) + "\n") == [13, 24, 33]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_lazy_import_says_why(package):
    bad = []
    for path, rel, src in sources(package):
        bad += [f"{rel}:{n}" for n in uncommented_imports(src, path)]
    assert not bad, ("imports inside functions or classes without a comment saying why they "
                     "are lazy (move them to the top, or add e.g. '# lazy: keeps --help "
                     "JAX-free'):\n" + "\n".join(bad))
