"""What ``cevm ingest`` says of its ``--dsm``: the share of the ingested logs' distance
the DSM covers, overall and per file, and one warning when it covers few of them (the
rest of the road takes its elevation from GPS altitude or a flat road, in silence
before)."""

from __future__ import annotations

from pathlib import Path

from cevm.cli.common import warn
from cevm.text import printable

#: Below this share of the logs' distance [%] on the DSM, ingest says so (overall, and
#: names each file below :data:`DSM_FILE_FEW_PCT`): their road elevation comes from GPS
#: altitude or a flat road instead, which calibration and the power checks treat
#: differently (cevm.core.limits.ELEVATION_SD_M).
DSM_FEW_PCT = 90.0
DSM_FILE_FEW_PCT = 50.0


def dsm_coverage(st, report) -> tuple[float | None, list[tuple[str, float]]]:
    """The share [%] of the distance of the trips of the files this run ingested that
    lies on the DSM (each trip's dsm_coverage_pct weighted by its distance; None without
    such trips), and each file's share, in the run's order."""
    import numpy as np

    ingested = [str(Path(f.path).resolve()) for f in report.files if f.status == "ingested"]  # as stored
    if not ingested:
        return None, []
    rows = st.list_trips()
    rows = rows[rows["source_file"].map(lambda p: str(Path(p).resolve())).isin(ingested)]
    d = rows["distance_m"].to_numpy(dtype=np.float64)
    c = np.nan_to_num(rows["dsm_coverage_pct"].to_numpy(dtype=np.float64))
    if not d.sum() > 0:
        return None, []
    per = []
    for path in ingested:
        sel = (rows["source_file"].map(lambda p: str(Path(p).resolve())) == path).to_numpy()
        if d[sel].sum() > 0:
            per.append((path, float(np.dot(c[sel], d[sel]) / d[sel].sum())))
    return float(np.dot(c, d) / d.sum()), per


def warn_dsm_coverage(coverage: tuple[float | None, list[tuple[str, float]]], dsm: str) -> None:
    """One warning when --dsm covers few of the logs ingested (module constants), with
    the share covered overall and of each file below half."""
    overall, per = coverage
    few = [(p, c) for p, c in per if c < DSM_FILE_FEW_PCT]
    if overall is None or (overall >= DSM_FEW_PCT and not few):
        return
    named = ", ".join(f"{printable(Path(p).name)} {c:.0f} %" for p, c in few[:5]) + (" ..." if len(few) > 5 else "")
    what = "none" if overall == 0 else f"{overall:.0f} %"
    warn(f"--dsm {printable(str(dsm))} covers {what} of the distance of the {len(per)} log(s) ingested"
         + (f"; under half of {len(few)}: {named}" if few else "")
         + ": their road elevation is from GPS altitude or a flat road (columns dsm_coverage_pct and "
         "elevation_source of 'cevm trips'; a DSM of another area or CRS covers nothing)")
