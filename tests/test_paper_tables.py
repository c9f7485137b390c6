"""The paper's published tables 1 and 2, pinned (the habit of pvlib's tests: a published
figure, a stated tolerance, and why that tolerance).

What of the tables can be reproduced here, and how closely:

- the figures themselves, as cevm prints them beside its own (``cevm calibrate``'s
  "paper" column, ``benchmarks/bench_tables.py``): copied from the paper's text, so
  compared to the digit it prints (tolerance zero: a transcription either is right or
  is not);
- the vehicles the tables were computed for (section 5: CdA, Cr, masses, eta): the
  shipped ``configs/vehicles`` files say they are the paper's, so they equal the text;
- the CE model's error on the diesel HGV (table 2: mu 1.3 %, sigma 3.7 %), reproduced
  with the benchmark's protocol against our detailed model on the public cycles
  (``../shared/cycles``; skipped without them). The paper's measurements are not
  public, so this is the same model against another reference; the tolerances below
  say how far that can move the figure.

Not asserted, and why: the bus (table 1, sigma 4.0 %) is not reproduced by our detailed
bus, whose regeneration power cap no CE term represents (benchmarks/TABLES.md: the best
CE variant scatters by 7.4 %, 3.95 % with the cap removed); the computation times
(t_exe) depend on the machine (speed lives in benchmarks/, never in tests); the
detailed ("baseline") models' errors are against the paper's measurements, ours is the
reference itself.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from conftest import ROOT, SHARED
from test_tables import bt  # noqa: F401 (the fixture: benchmarks/bench_tables.py as a module)

SEED = SHARED / "seed" / "000_ea7ad05432725787.txt"


def _paper_table(number: int) -> dict[str, tuple[float, float]]:
    """Table ``number`` of the paper's text: item -> (CE model, baseline model), errors in
    %, times in s (``1.9×10^{-2} s``)."""
    if not SEED.exists():
        pytest.skip(f"the paper's text is not in the shared folder ({SEED})")
    text = SEED.read_text(encoding="utf-8")
    block = text.split(f"Table {number}. Error", 1)[1].split("\n\n", 2)[1]

    def value(cell: str) -> float:
        cell = cell.strip().replace("−", "-")
        m = re.fullmatch(r"([-+]?[\d.]+)(?:×10\^\{(-?\d+)\})?\s*(%|s)", cell)
        assert m, cell
        return float(m.group(1)) * 10.0 ** int(m.group(2) or 0)

    rows = {}
    for line in block.splitlines()[1:]:
        item, ce, base = line.split("\t")
        rows[item.strip("$").replace("\\", "")] = (value(ce), value(base))
    return rows


def test_the_papers_tables_read():
    t1, t2 = _paper_table(1), _paper_table(2)
    assert t1 == {"mu(e)": (0.4, -0.5), "sigma(e)": (4.0, 3.9), "mu(t_{exe})": (pytest.approx(0.019), 2.85),
                  "sigma(t_{exe})": (pytest.approx(0.0026), pytest.approx(0.04))}
    assert set(t2) == set(t1)


@pytest.mark.parametrize(("kind", "table", "is_ev"), [("bus", 1, True), ("truck", 2, False)])
def test_the_figures_cevm_prints_as_the_papers_are_the_papers(bt, kind, table, is_ev):
    """Transcriptions: equal to the digits printed (rel 1e-12 only for 1.9×10^-2 as a float)."""
    from cevm.cli.calibrate import PAPER_CE

    paper = _paper_table(table)
    name, mu, sd, tmu, tsd = PAPER_CE[(is_ev, kind)]  # by powertrain and class
    assert f"table {table}" in name
    assert (mu, sd) == (paper["mu(e)"][0], paper["sigma(e)"][0])
    assert (tmu, tsd) == pytest.approx((paper["mu(t_{exe})"][0], paper["sigma(t_{exe})"][0]), rel=1e-12)
    p = bt.PAPER[kind]
    assert (p["ce_mean"], p["ce_std"], p["det_mean"], p["det_std"]) == (
        *paper["mu(e)"][:1], *paper["sigma(e)"][:1], paper["mu(e)"][1], paper["sigma(e)"][1])
    assert (p["ce_t"], p["ce_t_std"], p["det_t"], p["det_t_std"]) == pytest.approx(
        (paper["mu(t_{exe})"][0], paper["sigma(t_{exe})"][0], paper["mu(t_{exe})"][1], paper["sigma(t_{exe})"][1]),
        rel=1e-12)


def test_the_papers_vehicles():
    """Section 5.1 (bus) and 5.2 (HGV): CdA, Cr, masses and the paper's eta, as printed."""
    from cevm.io import load_vehicle

    bus = load_vehicle(ROOT / "configs" / "vehicles" / "electric-bus.toml")
    assert (bus.cda_m2, bus.cr, bus.eta) == (3.99, 0.0066, 0.78)
    assert bus.mass_kg == 9000.0 + 11 * 75.0  # 9,000 kg kerb + 11 passengers x 75 kg
    hgv = load_vehicle(ROOT / "configs" / "vehicles" / "diesel-hgv-paper.toml")
    assert (hgv.cda_m2, hgv.cr, hgv.eta) == (6.62, 0.0066, 0.45)
    assert hgv.kerb_mass_kg == 18000.0  # gross weight 18,000-44,000 kg


@pytest.mark.slow
def test_table_2_ce_error_reproduced_on_public_cycles(bt):
    """Table 2's CE model (mu 1.3 %, sigma 3.7 %) against our detailed HGV on the public
    truck cycles, with the benchmark's protocol (benchmarks/TABLES.md): eta and idle fuel
    calibrated, braking energy not credited (the paper's eq. 24 credit is the erratum's
    subject: it scatters by 39 % on these cycles).

    Tolerances:
    - in-sample sigma(e) = 3.7 % +- 0.6 point: the standard error of a standard deviation
      estimated from n trips is sigma / sqrt(2 (n - 1)), 0.6 point at 3.7 % from 21;
    - |mu(e)| and the held-out median sigma(e) within the paper's own claim (abstract:
      "standard deviation less than 5 % and its mean less than 2 %"), not its +1.3 %: a
      mean error is the reference's bias, and our reference is not the paper's trucks.
    """
    from cevm.io import load_vehicle

    cycles_dir = SHARED / "cycles"
    if not (cycles_dir / "advisor").is_dir() or not (cycles_dir / "vecto-carculator").is_dir():
        pytest.skip(f"the public cycles are not in the shared folder ({cycles_dir})")
    hgv = load_vehicle(bt.TRUCK_TOML)
    variant = next(v for v in bt.ICE_VARIANTS if v.params == ("eta", "idle_fuel_lps") and v.ice_braking == "no-credit")
    res = bt.run_table("truck", hgv, bt.load_cycles("truck", cycles_dir), bt.TRUCK_PAYLOADS_KG, ablation=False,
                       timing=False, variants=[variant])
    r = res.results[("base", variant.key)]
    mu_in, sd_in = r.in_sample
    paper_mu, paper_sd = _paper_table(2)["mu(e)"][0], _paper_table(2)["sigma(e)"][0]
    assert sd_in == pytest.approx(paper_sd, abs=paper_sd / math.sqrt(2 * (res.n_trips - 1)))
    assert abs(mu_in) < 2.0 and abs(paper_mu) < 2.0
    held_out_sd = r.summary("std")[0]
    assert np.isfinite(held_out_sd) and held_out_sd < 5.0
