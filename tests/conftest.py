import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def shared_cycles() -> Path:
    p = SHARED / "cycles" / "advisor"
    if not p.is_dir():
        pytest.skip("../shared/cycles is not beside this checkout")
    return p
