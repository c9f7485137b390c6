"""The README and the manual in docs/ stay true: every relative link and anchor resolves,
the command reference names every option of every command, the logger-profile example
loads, and the README's worked example runs as printed (exit 0 for every command, the
numbers it shows printed again)."""

from __future__ import annotations

import os
import re
import shlex
from collections import Counter
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from cevm.cli import app
from cevm.ingest.profiles import load_profile
from conftest import ROOT

PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are not links)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", text))


def slug(heading: str) -> str:
    """The anchor a heading gets, as GitHub and MyST (myst_heading_anchors) make it."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            s = slug(m.group(1))
            n = seen.get(s, 0)
            out.add(s if n == 0 else f"{s}-{n}")
            seen[s] = n + 1
    return out


def test_the_pages_exist():
    names = {p.relative_to(ROOT).as_posix() for p in PAGES}
    assert {"README.md", "CHANGELOG.md", "docs/index.md", "docs/reference/commands.md", "docs/model.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_and_anchor_resolves(page):
    bad = []
    for target in LINK.findall(prose(page.read_text(encoding="utf-8"))):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no file {dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading '#{anchor}' in {dest.relative_to(ROOT)}")
    assert not bad, "\n".join(bad)


def _commands(cmd, path=()):
    if hasattr(cmd, "list_commands"):
        if path:
            yield path, cmd
        for name in cmd.list_commands(None):
            yield from _commands(cmd.get_command(None, name), (*path, name))
    else:
        yield path, cmd


def test_the_command_reference_names_every_command_and_option():
    """A new option is documented in docs/reference/commands.md, or this fails."""
    ref = (ROOT / "docs" / "reference" / "commands.md").read_text(encoding="utf-8")
    missing = []
    for path, cmd in _commands(typer.main.get_command(app)):
        if f"cevm {' '.join(path)}" not in ref:
            missing.append(f"command 'cevm {' '.join(path)}'")
        opts = [o for p in cmd.params for o in (*getattr(p, "opts", []), *getattr(p, "secondary_opts", []))]
        missing.extend(f"cevm {' '.join(path)} {o}" for o in opts
                       if o.startswith("--") and o != "--help" and not re.search(rf"`[^`]*{re.escape(o)}\b", ref))
    assert not missing, "not in docs/reference/commands.md: " + ", ".join(missing)


def test_the_logger_profile_example_loads(tmp_path):
    guide = (ROOT / "docs" / "guide" / "logger-profile.md").read_text(encoding="utf-8")
    toml = re.search(r"```toml\n(.*?)```", guide, re.S).group(1)
    f = tmp_path / "acme-obd.toml"
    f.write_text(toml, encoding="utf-8")
    prof = load_profile(f)
    assert prof.name == "acme-obd" and prof.time.format == "unix_ms"
    fuel = next(c for c in prof.columns if c.canonical == "fuel_rate_lps")
    assert fuel.factor == pytest.approx(1e-3 / 0.835)  # g/s -> l/s through 0.835 kg/l


def readme_example() -> list[tuple[str, list[str]]]:
    """The commands of the README's worked example (the console block after its heading),
    each with the output lines printed under it."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Worked example", 1)[1]
    block = re.search(r"```console\n(.*?)```", section, re.S).group(1)
    lines, cmds = block.splitlines(), []
    i = 0
    while i < len(lines):
        line = lines[i]
        i += 1
        if not line.startswith("$ "):
            continue
        cmd = line[2:]
        while cmd.endswith("\\"):
            cmd = cmd[:-1] + lines[i].strip()
            i += 1
        out = []
        while i < len(lines) and not lines[i].startswith("$ "):
            out.append(lines[i])
            i += 1
        cmds.append((cmd.split("  #")[0].strip(), out))
    return cmds


#: A number as printed (signs, thousands separators, the "+-" of a range).
NUMBER = re.compile(r"(?:\+-|[+-])?\d[\d,]*(?:\.\d+)?")
#: A duration: it varies from run to run and machine to machine.
TIME = re.compile(r"(?:\+-|[+-])?\d[\d,]*(?:\.\d+)?\s*(?:us|ms|s)\b")


def printed_numbers(lines: list[str]) -> list[str]:
    """The numbers of printed output that do not vary between runs: every number, except
    durations (``1.47 s``, ``49.9 us``) and the lines the README elides (``  ... (``
    up to its closing parenthesis: prose about the output, not the output)."""
    kept, eliding = [], False
    for line in lines:
        if line.lstrip().startswith("... ("):
            eliding = True
        if not eliding:
            kept.append(TIME.sub(" ", line))
        if eliding and line.rstrip().endswith(")"):
            eliding = False
    return NUMBER.findall("\n".join(kept))


def test_printed_numbers_leave_out_times_and_elisions():
    lines = ["cevm ingest: 25 files, 1866.6 km in 1.47 s -> out/x.sqlite", "| mu(t_exe) | 49.9 us | 16.5 ms |",
             "| fuel | +-0.40 l | 21,410 kg | -0.06 % |", "  ... (the candidates: eta 0.416,", "      idle 3.4 l/h)",
             "after 7"]
    assert printed_numbers(lines) == ["25", "1866.6", "+-0.40", "21,410", "-0.06", "7"]


@pytest.mark.slow
def test_the_readme_worked_example_runs_as_printed(tmp_path, monkeypatch):
    """Every command of the README's example exits 0 and prints the numbers the README
    shows: the same fuel, errors, intervals and counts, whatever the terminal's width
    (a narrower one folds the tables' columns differently, so numbers are compared as a
    multiset, not line by line), times apart. The sample logs, the calibration and the
    prediction are deterministic (fixed seeds, no clock in them), so the numbers are
    compared as printed, to their last digit."""
    cmds = readme_example()
    assert cmds and cmds[0][0].startswith(". .venv/bin/activate")
    for name in ("configs", "sample_logs"):
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CEVM_STORE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    runner = CliRunner()
    for cmd, printed in cmds[1:]:
        argv = shlex.split(cmd)
        assert argv[0] == "cevm", cmd
        res = runner.invoke(app, argv[1:])
        assert res.exit_code == 0, f"{cmd}\n{res.output}"
        expected, got = Counter(printed_numbers(printed)), Counter(printed_numbers(res.output.splitlines()))
        missing = expected - got
        assert not missing, f"{cmd}: the README prints {sorted(missing.elements())}, not in\n{res.output}"
    assert os.path.exists("out/hgv-11.toml")


def library_example() -> str:
    """The Python block of docs/guide/library.md's five-line notebook."""
    guide = (ROOT / "docs" / "guide" / "library.md").read_text(encoding="utf-8")
    section = guide.split("## Calibrate a vehicle and predict a cycle, in five lines", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow
def test_the_library_guides_notebook_runs_and_prints_the_readmes_numbers(tmp_path, monkeypatch, capsys):
    """The guide's lines, run as written, after the README's ingest: they print the terms
    and the fuel with its 90 % half-width that the README's calibrate and predict print
    (7.06 and 15.48 l, +-0.34 and +-0.59 l: the same model through the command line)."""
    code = library_example()
    assert len([ln for ln in code.splitlines() if ln.strip() and not ln.startswith("import ")]) == 5
    for name in ("configs", "sample_logs"):
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    ingest = next(c for c, _ in readme_example() if c.startswith("cevm ingest"))
    assert CliRunner().invoke(app, shlex.split(ingest)[1:]).exit_code == 0
    exec(compile(code, "docs/guide/library.md", "exec"), {})
    printed = capsys.readouterr().out
    assert printed.startswith("('eta', 'idle', 'kin', 'heat', 'cool') ")
    readme = {c.split()[1]: printed_numbers(out) for c, out in readme_example()[1:]}
    mean, half = [float(x) for x in NUMBER.findall(printed)[:2]], [float(x) for x in NUMBER.findall(printed)[2:]]
    assert {f"{mean[0]:.2f}", f"{mean[1]:.2f}", f"+-{half[0]:.2f}", f"+-{half[1]:.2f}"} <= set(readme["predict"])
    assert printed.strip() in (ROOT / "docs" / "guide" / "library.md").read_text(encoding="utf-8")


#: Files that still name a tracker's issue, each with why (the house rule: reasons in
#: place, never a pointer to a tracker a reader of the code does not have).
TRACKER_REFERENCE_EXCEPTIONS: set[str] = set()


def test_no_file_points_at_a_tracker_issue():
    pattern = re.compile(r"\b" + "issue" + r" \d+", re.I)
    files = [ROOT / "README.md", *(p for d in ("src", "tests", "docs", "benchmarks") for p in (ROOT / d).rglob("*")
                                   if p.suffix in (".py", ".md", ".toml", ".rst") and "_build" not in p.parts
                                   and "generated" not in p.parts)]
    found = [f"{p.relative_to(ROOT)}:{i}" for p in files if p.relative_to(ROOT).as_posix()
             not in TRACKER_REFERENCE_EXCEPTIONS
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]
    assert found == [], "say the reason in place: " + ", ".join(found)
