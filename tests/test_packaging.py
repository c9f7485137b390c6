"""An installed (not editable) cevm carries the project's configs/: logger profiles,
vehicles, cycles and fleet scenarios, found where the code looks for them."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


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


def test_checkout_finds_its_configs():
    from cevm.configs_dir import shipped_configs_dir
    from cevm.ingest.profiles import builtin_profile_dirs, load_profiles

    assert shipped_configs_dir().resolve() == (ROOT / "configs").resolve()
    assert builtin_profile_dirs() == [shipped_configs_dir() / "loggers"]
    assert {"srf", "portal", "twizy"} <= set(load_profiles(include_env=False))
