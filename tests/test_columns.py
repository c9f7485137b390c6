"""One column specification for predict and feasibility output (cevm.cli.columns,
cevm.cli.prediction_columns): every format derives from it, and a column added to it
appears in each format, for the rows of its powertrains, without another edit."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from cevm.cli.columnar import csv_text, json_objects
from cevm.cli.columns import Column, ColumnSpec
from cevm.cli.output import OutputFormat, write_rows
from cevm.cli.prediction_columns import FEASIBILITY, PREDICT, BlockRows, feasibility_row
from cevm.core.cycle import DriveCycle
from cevm.core.feasibility import feasibility
from cevm.core.sweep import PredictionSet, Source, predict_source
from cevm.io import load_vehicles

ROOT = Path(__file__).resolve().parents[1]
#: The keys every JSON object of the first `cevm predict` started with, in this order.
FIRST_CONTRACT = ["cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh"]


@pytest.fixture(scope="module")
def block():
    vehicles = load_vehicles([ROOT / "configs/vehicles/electric-bus.toml", ROOT / "configs/vehicles/diesel-hgv.toml"])
    t = np.arange(0.0, 301.0)
    v = 12.0 * np.sin(np.pi * t / 300.0) ** 2
    cycle = DriveCycle(t, v, 20.0 * np.sin(t / 50.0), name="hill")
    pset = PredictionSet.build(vehicles, payload_kg=[0.0, 2000.0, 4000.0])
    return predict_source(Source.from_cycle(cycle), pset, ranges=True)


def _csv_rows(spec: ColumnSpec, cols: dict) -> list[dict[str, str]]:
    text = ",".join(spec.names) + "\n" + csv_text(cols, spec)
    return list(csv.DictReader(io.StringIO(text)))


def test_every_column_says_what_it_means_and_how_it_is_got():
    for spec in (PREDICT, FEASIBILITY):
        for c in spec.columns:
            assert c.meaning.strip() and c.value is not None, c.name
        assert len(set(spec.names)) == len(spec.names)
    lines = PREDICT.reference()
    assert len(lines) == 2 + len(PREDICT.columns) and "| `soc_min_pct` | number | EV |" in "\n".join(lines)


def test_a_column_is_refused_with_a_kind_a_layout_or_powertrains_it_cannot_have():
    with pytest.raises(ValueError, match="kind"):
        Column("x", "x", kind="float")
    with pytest.raises(ValueError, match="layout"):
        Column("x", "x", layout="centre")
    with pytest.raises(ValueError, match="powertrains"):
        Column("x", "x", ("diesel",))
    with pytest.raises(ValueError, match="twice"):
        ColumnSpec((Column("x", "x"), Column("x", "y")))
    with pytest.raises(ValueError, match="json_lead"):
        ColumnSpec((Column("x", "x"),), json_lead=("y",))


def test_predict_json_objects_keep_the_first_contract_and_have_only_their_powertrains_columns(block):
    cols = PREDICT.values(BlockRows(block))
    objs = [json.loads(s) for s in json_objects(cols, PREDICT, block.pset.is_ev)]
    assert len(objs) == block.n == 6
    for obj, ev in zip(objs, block.pset.is_ev, strict=True):
        keys = list(obj)
        assert keys[:7] == FIRST_CONTRACT
        if ev:
            assert keys[7:9] == ["energy_kwh", "energy_kwh_per_km"]
            assert "fuel_l" not in obj and "tank_ok" not in obj and "soc_min_pct" in obj
        else:
            assert keys[7:10] == ["fuel_l", "fuel_l_per_100km", "ice_braking"]
            assert "energy_kwh" not in obj and "soc_min_pct" not in obj and "tank_ok" in obj
    ev_obj = objs[0]
    assert ev_obj["energy_kwh"] == pytest.approx(block.energy_j[0] / 3.6e6, rel=1e-15)
    assert ev_obj["mass_kg"] == 9000.0 and ev_obj["payload_kg"] == 0.0


def test_predict_csv_has_every_column_with_empty_cells_where_a_row_has_none(block):
    rows = _csv_rows(PREDICT, PREDICT.values(BlockRows(block)))
    assert [r["powertrain"] for r in rows] == ["ev"] * 3 + ["ice"] * 3
    assert all(r["fuel_l"] == "" and r["energy_kwh"] != "" for r in rows[:3])
    assert all(r["energy_kwh"] == "" and r["fuel_l"] != "" for r in rows[3:])
    assert {r["over_max_gross"] for r in rows} <= {"true", "false"}
    assert rows[1]["mass_kg"] == "11000"  # 3 decimals, trailing zeros dropped
    assert float(rows[0]["energy_kwh"]) == pytest.approx(block.energy_j[0] / 3.6e6, abs=5e-7)


def test_a_column_added_to_the_spec_appears_in_csv_json_and_tables_for_its_rows_only(block):
    """One edit: the Column entry. Here a column of EV rows, the battery energy in MJ with
    two CSV decimals, and one of both powertrains, a flag."""
    extra = (Column("energy_mj", "battery energy [MJ]", ("ev",), header="MJ", digits=1, decimals=2,
                    value=lambda r: r.block.energy_j / 1e6),
             Column("heavy", "above 12 t", kind="bool", value=lambda r: (r.pset.mass_kg > 12000).astype(float)))
    spec = ColumnSpec(PREDICT.columns + extra, PREDICT.json_lead)
    cols = spec.values(BlockRows(block))
    rows = _csv_rows(spec, cols)
    assert list(rows[0])[-2:] == ["energy_mj", "heavy"]
    assert rows[0]["energy_mj"] == f"{block.energy_j[0] / 1e6:.2f}".rstrip("0").rstrip(".")
    assert rows[4]["energy_mj"] == ""  # an ICE row
    assert [r["heavy"] for r in rows] == ["false", "false", "true", "true", "true", "true"]
    objs = [json.loads(s) for s in json_objects(cols, spec, block.pset.is_ev)]
    assert list(objs[0])[-2:] == ["energy_mj", "heavy"] and objs[0]["energy_mj"] == block.energy_j[0] / 1e6
    assert "energy_mj" not in objs[3] and list(objs[3])[-1] == "heavy"
    out = io.StringIO()
    table_rows = [{"cycle": "hill", "energy_mj": float(x)} for x in block.energy_j[:3] / 1e6]
    write_rows(table_rows, OutputFormat.table, columns=spec.table(["cycle", "energy_mj"]), stream=out)
    text = out.getvalue()
    assert "MJ" in text and f"{block.energy_j[0] / 1e6:,.1f}" in text


def test_feasibility_rows_have_their_powertrains_columns_in_the_specs_order(block):
    res = feasibility(block.source, block.pset.vehicles, payload_kg=1000.0)
    rows = [feasibility_row(res, i, None, "--payload-kg") for i in range(2)]
    ev_row, ice_row = rows
    assert list(ev_row) == list(FEASIBILITY.json_keys("ev")) and list(ice_row) == list(FEASIBILITY.json_keys("ice"))
    assert "soc_min_pct" in ev_row and "fuel_l" not in ev_row and "tank_l" in ice_row and "energy_kwh" not in ice_row
    assert ev_row["payload_kg"] == 1000.0 and ev_row["mass_source"] == "--payload-kg"
    assert ice_row["ice_braking"] == block.pset.vehicles[1].ice_braking
    assert ev_row["soc_min_pct"] == pytest.approx(float(res.soc_min_pct[0]), rel=1e-15)
