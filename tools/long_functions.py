"""List the functions of the package longer than the house style's ~60 lines, longest first.

Run: .venv/bin/python tools/long_functions.py [--limit 60]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lads"


def long_functions(limit: int) -> list[tuple[int, str, str]]:
    """(lines, module path, function name) of every function over `limit` lines."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                if length > limit:
                    found.append((length, str(path.relative_to(PACKAGE.parent)), node.name))
    return sorted(found, reverse=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=60)
    rows = long_functions(parser.parse_args().limit)
    sys.stdout.write("".join(f"{n:4d}  {path}  {name}\n" for n, path, name in rows))
    sys.stdout.write(f"{len(rows)} functions\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
