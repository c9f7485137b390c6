"""An installed (not editable) cevm carries the project's configs/: logger profiles,
vehicles, cycles and fleet scenarios, found where the code looks for them."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_ships_every_config_file_where_the_code_looks(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(ROOT)],
                   check=True, capture_output=True, timeout=600)
    (wheel,) = tmp_path.glob("cevm-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "configs").rglob("*") if p.is_file())
    assert shipped, "configs/ is empty"
    missing = [p for p in shipped if f"cevm/{p}" not in names]
    assert not missing, f"not in the wheel: {missing}"
    # the code looks in cevm/configs next to its modules (cevm.configs_dir)
    assert "cevm/configs_dir.py" in names and "cevm/configs/loggers/srf.toml" in names


def test_installed_cevm_finds_the_checkouts_configs():
    """Editable or regular install: the configs the code finds are this checkout's,
    file for file and byte for byte (a regular install carries a copy)."""
    from cevm.configs_dir import shipped_configs_dir
    from cevm.ingest.profiles import builtin_profile_dirs, load_profiles

    found = shipped_configs_dir()

    def files(d: Path) -> dict[str, bytes]:
        return {p.relative_to(d).as_posix(): p.read_bytes() for p in d.rglob("*")
                if p.is_file() and "__pycache__" not in p.parts}

    assert files(found) == files(ROOT / "configs")
    assert builtin_profile_dirs() == [shipped_configs_dir() / "loggers"]
    assert {"srf", "portal", "twizy"} <= set(load_profiles(include_env=False))


def test_every_module_of_the_installed_package_imports():
    """Every module of cevm (and the sample-log generator) imports from the install the
    tests run against: a module a wheel leaves out, or one that imports what the
    project does not declare, fails here (CI runs the tests on a regular install)."""
    import importlib
    import pkgutil

    import cevm
    import cevm_samplegen

    names = []
    for pkg in (cevm, cevm_samplegen):
        names.append(pkg.__name__)
        names += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")
                  if not m.name.startswith("cevm.configs") and not m.name.endswith(".__main__")]
    assert "cevm.core.calibration.fitting" in names
    for name in names:
        importlib.import_module(name)
