"""The README's commands and paths stay alive: every repository path it names exists, every
``python experiments/...`` script it runs exists, every ``daddpg-*`` command it uses is a
console script of pyproject.toml, and its Python example compiles and imports only names that
exist. Cost: ~0.5 s (the example's imports; nothing is trained)."""

from __future__ import annotations

import ast
import importlib
import os
import re
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()


def test_every_path_the_readme_names_exists():
    links = re.findall(r"\]\(((?:docs|daddpg_jax|mjx_envs|experiments|tests|assets)/[^)#\s]+)",
                       README)
    code = re.findall(r"(?<![\w/.<-])((?:docs|daddpg_jax|mjx_envs|experiments|assets|tests)"
                      r"/[\w./-]+\.(?:py|md|toml|png|sh|json|xml))", README)
    missing = sorted({p for p in links + code if not os.path.exists(os.path.join(ROOT, p))})
    assert not missing, missing
    assert len(set(links + code)) >= 10


def test_every_command_the_readme_runs_exists():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        scripts = set(tomllib.load(f)["project"]["scripts"])
    used = set(re.findall(r"(?<![\w-])(daddpg-[a-z-]+)(?= |\b)", README)) - {"daddpg-jax"}
    assert used and used <= scripts, used - scripts
    for script in re.findall(r"python (experiments/[\w/]+\.py)", README):
        assert os.path.exists(os.path.join(ROOT, script)), script
    for target in re.findall(r"^make ([\w-]+)", README, re.M):
        assert re.search(rf"^{target}:", open(os.path.join(ROOT, "Makefile")).read(), re.M), \
            target


def test_the_python_example_compiles_and_its_imports_exist():
    (example,) = [b for b in re.findall(r"```python\n(.*?)```", README, re.S)
                  if "NumpyPolicy" in b and "train(" in b]
    tree = ast.parse(example)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = importlib.import_module(node.module)
            for alias in node.names:
                assert hasattr(module, alias.name), (node.module, alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                importlib.import_module(alias.name)
