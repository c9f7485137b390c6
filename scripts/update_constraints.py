#!/usr/bin/env python3
"""Write constraints.txt: the versions CI installs (``pip install -c constraints.txt ".[test,lint]"``).

The goldens expect bit-identical output, so CI must not pick up a new numpy, pandas or
SciPy by itself: a release that moves the last digit would fail tests for no fault of
the change under test. Run this on purpose, in a venv where the project's tests and
linters pass with what is installed there:

    .venv/bin/python scripts/update_constraints.py            # writes constraints.txt
    .venv/bin/python scripts/update_constraints.py --check    # exit 1 when it would change

It pins every distribution that installing the project with the given extras (default
``test,lint``) pulls in: the closure of ``[project] dependencies`` and the extras'
requirements (with their markers evaluated here), each at the version installed in the
running interpreter's environment. Nothing else of that environment is listed (a dev
venv also holds pre-commit and its dependencies, which CI does not install).
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
HEADER = """\
# Pinned versions of everything `pip install ".[{extras}]"` installs, as resolved in a venv
# where the tests and linters pass. .ci/run installs with it (pip install -c constraints.txt),
# so the goldens meet the versions they were written with. Update on purpose, with
# scripts/update_constraints.py (docs/development.md).
"""


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def pinned(extras: list[str]) -> list[str]:
    """``name==version`` of every installed distribution the project with ``extras`` needs."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    optional = project.get("optional-dependencies", {})
    todo = [Requirement(r) for r in project["dependencies"]]
    pending = list(extras)
    while pending:
        for r in optional[pending.pop()]:
            req = Requirement(r)
            if _norm(req.name) == _norm(project["name"]):  # an extra naming others: cevm[test,lint]
                pending += sorted(req.extras)
            else:
                todo.append(req)
    seen: dict[str, str] = {}
    missing = []
    while todo:
        req = todo.pop()
        if _norm(req.name) in seen:
            continue
        try:
            dist = metadata.distribution(req.name)
        except metadata.PackageNotFoundError:
            missing.append(str(req))
            continue
        seen[_norm(req.name)] = f"{dist.metadata['Name']}=={dist.version}"
        for spec in dist.requires or []:
            sub = Requirement(spec)
            if sub.marker is None or any(sub.marker.evaluate({"extra": e}) for e in (req.extras or {""})):
                todo.append(sub)
    if missing:
        sys.exit(f"update_constraints: not installed here: {', '.join(sorted(missing))} "
                 f"(pip install -e '.[{','.join(extras)}]' first)")
    return [seen[n] for n in sorted(seen)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--extras", default="test,lint", help="comma-separated extras (default test,lint)")
    ap.add_argument("--check", action="store_true", help="exit 1 if constraints.txt would change")
    ap.add_argument("--out", type=Path, default=ROOT / "constraints.txt")
    a = ap.parse_args()
    extras = [e for e in a.extras.split(",") if e]
    text = HEADER.format(extras=",".join(extras)) + "".join(f"{p}\n" for p in pinned(extras))
    if a.check:
        same = a.out.exists() and a.out.read_text(encoding="utf-8") == text
        print(f"{a.out.name}: {'up to date' if same else 'would change'}")
        return 0 if same else 1
    a.out.write_text(text, encoding="utf-8")
    print(f"wrote {a.out} ({text.count(chr(10)) - HEADER.count(chr(10))} pins)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
