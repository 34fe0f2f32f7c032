"""Per-module coverage of the package by one test tier: `make coverage` (the default tier).

Reads coverage.py's JSON report and prints one line per module of `daddpg_jax` and `mjx_envs`
(statements, executed, percent). Exits 1, naming them, if a module has executable statements
and none ran: every module must be exercised by the tier that developers run on each change.

    python -m coverage run -m pytest -q && python -m coverage json -o cov.json
    python tests/module_coverage.py cov.json
"""

from __future__ import annotations

import json
import sys


def module_rows(report: dict) -> list[tuple[str, int, int]]:
    """(module path, statements, executed statements) of every measured file, sorted."""
    rows = []
    for path, f in report["files"].items():
        s = f["summary"]
        rows.append((path, int(s["num_statements"]), int(s["covered_lines"])))
    return sorted(rows)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python tests/module_coverage.py COVERAGE.json", file=sys.stderr)
        return 2
    with open(argv[0]) as f:
        rows = module_rows(json.load(f))
    missed = [p for p, n, c in rows if n > 0 and c == 0]
    width = max(len(p) for p, _, _ in rows)
    for p, n, c in rows:
        pct = 100.0 * c / n if n else 100.0
        print(f"{p:<{width}}  {n:5d} statements  {c:5d} run  {pct:5.1f} %")
    total_n, total_c = sum(n for _, n, _ in rows), sum(c for _, _, c in rows)
    print(f"{len(rows)} modules, {total_c}/{total_n} statements run "
          f"({100.0 * total_c / max(total_n, 1):.1f} %)")
    if missed:
        print("modules no test of this tier runs: " + ", ".join(missed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
