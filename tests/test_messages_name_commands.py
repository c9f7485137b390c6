"""Every message, help text and note that names a cevm command in quotes (``'cevm trips
set-mass'``, ```cevm predict```) names one the command line has: replay once told users
that ``'cevm trips list'`` shows the stored vehicles, a command that never existed. The
names are taken from the source's string literals (f-strings' text parts included) and
checked against the typer app itself."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import typer.main

from cevm.cli import app

SRC = Path(__file__).resolve().parents[1] / "src" / "cevm"
#: A quoted command: a quote or backtick, "cevm", then its words (lower case, hyphens).
QUOTED = re.compile(r"['`]cevm ((?:[a-z][a-z0-9-]*)(?: [a-z][a-z0-9-]*)*)")


def _strings(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            yield node.lineno, node.value


def _named() -> list[tuple[str, int, str]]:
    out = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        rel = str(path.relative_to(SRC))
        out.extend((rel, line, m.group(1)) for line, text in _strings(tree) for m in QUOTED.finditer(text))
    return out


def test_every_quoted_command_exists():
    root = typer.main.get_command(app)
    named = _named()
    assert len(named) > 20  # the pattern finds the messages (e.g. 'cevm trips set-mass', `cevm store check`)
    bad = []
    for where, line, words in named:
        parts = words.split()
        cmd = root.commands.get(parts[0])  # type: ignore[attr-defined]
        if cmd is None:
            bad.append(f"{where}:{line}: 'cevm {words}': no command {parts[0]!r}")
            continue
        subs = getattr(cmd, "commands", None)
        if subs is not None and len(parts) > 1 and parts[1] not in subs:
            bad.append(f"{where}:{line}: 'cevm {words}': {parts[0]} has no subcommand {parts[1]!r} "
                       f"(it has {', '.join(sorted(subs))})")
    assert not bad, "\n".join(bad)
