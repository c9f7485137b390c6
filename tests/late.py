"""Run a ``cevm`` command whose process lingers after it has finished, for tests that
stop it then with a real signal (tests/test_faults_campaign.py), kept out of cevm.

``python tests/late.py MARKER CEVM-ARGS...`` runs ``cevm CEVM-ARGS`` through the entry
point (:func:`cevm.__main__.main`), with an exit hook that, once the command has returned
and its exit begins, creates the file MARKER and waits for 5 s (short sleeps, in which
Python runs signal handlers): the moment "after the summary" made long enough to hit.
"""

from __future__ import annotations

import atexit
import sys
import time
from pathlib import Path


def _linger(marker: Path) -> None:
    marker.touch()
    t_end = time.monotonic() + 5.0
    while time.monotonic() < t_end:
        time.sleep(0.02)


if __name__ == "__main__":
    marker, *args = sys.argv[1:]
    atexit.register(_linger, Path(marker))
    sys.argv = ["cevm", *args]
    from cevm.__main__ import main

    main()
