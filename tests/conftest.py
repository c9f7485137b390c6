import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
# The project's shared folder (public cycles, real logs), beside the checkout; a checkout
# elsewhere (a git worktree, say) names it with CEVM_TEST_SHARED. Tests that need it skip
# without it; each has a stand-in in tests/data that runs on a clean clone.
SHARED = Path(os.environ.get("CEVM_TEST_SHARED") or ROOT.parent / "shared")
sys.path.insert(0, str(Path(__file__).parent))


def shared_or_skip(*parts: str) -> Path:
    """``SHARED / parts``, or skip the test when it is not there."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"{'/'.join(parts)} not found in the shared folder ({SHARED}; set CEVM_TEST_SHARED for another)")
    return p


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def shared_cycles() -> Path:
    """The public ADVISOR cycles (../shared/cycles/advisor)."""
    return shared_or_skip("cycles", "advisor")


@pytest.fixture(params=["vendored", "public"])
def twizy_logs(request) -> tuple[Path, int]:
    """A folder of real Twizy logs and how many files it holds: the four of tests/data/twizy
    (gzip-compressed), and the dataset's 17 when ../shared/real-logs/twizy is there."""
    if request.param == "public":
        return shared_or_skip("real-logs", "twizy"), 17
    return DATA / "twizy", 4


@pytest.fixture(scope="session", autouse=True)
def _no_users_store(tmp_path_factory):
    """Every test runs as on a fresh account: the user's own store (``$CEVM_STORE``, or
    the one under ``~/.local/share``) is never opened nor written by a test that leaves
    out ``--store``, and parallel workers (``pytest -n``) never share one."""
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("CEVM_STORE", raising=False)
        mp.setenv("XDG_DATA_HOME", str(tmp_path_factory.mktemp("xdg-data")))
        yield
