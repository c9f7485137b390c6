"""Vehicle TOML files and cycle CSV files: values, and errors that name file, line, key."""

import numpy as np
import pytest

from cevm.errors import InputError
from cevm.io import load_vehicle, load_vehicles, read_cycle_csv


def test_shipped_vehicles_hold_the_papers_values(root):
    bus = load_vehicle(root / "configs/vehicles/electric-bus.toml")
    assert (bus.powertrain, bus.cda_m2, bus.cr, bus.mass_kg, bus.eta) == ("ev", 3.99, 0.0066, 9825.0, 0.78)
    assert bus.battery_j > 0
    hgv = load_vehicle(root / "configs/vehicles/diesel-hgv.toml")
    assert (hgv.powertrain, hgv.cda_m2, hgv.cr, hgv.eta) == ("ice", 6.62, 0.0066, 0.45)
    assert (hgv.kerb_mass_kg, hgv.max_gross_kg) == (18000.0, 44000.0)
    assert 35e6 <= hgv.fuel_lhv_j_per_l <= 36.5e6
    assert hgv.ice_braking == "paper"
    assert hgv.with_payload(26000).mass_kg == 44000.0
    names = {v.name for v in load_vehicles([root / "configs/vehicles"])}
    assert {"Optare Metrocity EV", "Scania P320 diesel HGV", "Renault Twizy 80"} <= names


GOOD_EV = 'name = "x"\npowertrain = "ev"\nmass_kg = 1000\ncda_m2 = 1\ncr = 0.01\neta = 0.8\nbattery_kwh = 10\n'


@pytest.mark.parametrize(
    "text, key",
    [
        (GOOD_EV.replace("cda_m2 = 1\n", ""), "cda_m2"),
        (GOOD_EV.replace("battery_kwh = 10\n", ""), "battery_kwh"),
        (GOOD_EV.replace('powertrain = "ev"', 'powertrain = "steam"'), "powertrain"),
        (GOOD_EV.replace("eta = 0.8", "eta = 1.4"), "eta"),
        (GOOD_EV.replace("eta = 0.8", 'eta = "high"'), "eta"),
        (GOOD_EV.replace("cr = 0.01", "crr = 0.01"), "crr"),
        (GOOD_EV + "fuel_lhv_mj_per_l = 36\n", "fuel_lhv_mj_per_l"),
        (GOOD_EV.replace("mass_kg = 1000\n", ""), "mass_kg"),
        (GOOD_EV.replace('name = "x"\n', ""), "name"),
    ],
)
def test_bad_vehicle_key_is_named(tmp_path, text, key):
    p = tmp_path / "v.toml"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        load_vehicle(p)
    msg = str(err.value)
    assert str(p) in msg and f"'{key}'" in msg


def test_typo_suggests_the_key(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text(GOOD_EV.replace("cr = 0.01", "crr = 0.01"))
    with pytest.raises(InputError, match="did you mean 'cr'"):
        load_vehicle(p)


def test_invalid_toml_names_the_line(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text(GOOD_EV + "oops =\n")
    with pytest.raises(InputError) as err:
        load_vehicle(p)
    assert err.value.line == 8


def test_cycle_csv_kmh_and_elevation(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("time_s,speed_kmh,elevation_m,other\n0,0,10,a\n1,36,11,b\n2,72,12,c\n")
    c = read_cycle_csv(p)
    np.testing.assert_allclose(c.speed_mps, [0, 10, 20])
    np.testing.assert_allclose(c.elevation_m, [10, 11, 12])
    assert c.name == "c"


def test_cycle_csv_mps_without_elevation_is_flat(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("speed_mps,time_s\n1.5,0\n2.5,0.5\n")
    c = read_cycle_csv(p)
    assert c.elevation_m is None
    np.testing.assert_allclose(c.time_s, [0, 0.5])


@pytest.mark.parametrize(
    "body, line, column, words",
    [
        ("time_s,speed\n0,1\n1,2\n", 1, "speed", "speed unit is not in the column name"),
        ("speed_kmh\n0\n1\n", 1, None, "no time column found"),
        ("time_s,speed_kmh\n0,1\n1,abc\n2,3\n", 3, "speed_kmh", "not a number: 'abc'"),
        ("time_s,speed_kmh\n0,1\n1,\n2,3\n", 3, "speed_kmh", "empty cell"),
        ("time_s,speed_kmh\n0,1\n1,nan\n2,3\n", 3, "speed_kmh", "not a number: 'nan'"),
        ("time_s,speed_kmh\n0,1\n1,inf\n2,3\n", 3, "speed_kmh", "not a finite number"),
        ("time_s,speed_kmh\n0,1\n2,2\n2,3\n", 4, "time_s", "does not increase"),
        ("time_s,speed_kmh\n0,1\n3,2\n1,3\n", 4, "time_s", "does not increase"),
        ("time_s,speed_kmh\n0,1\n1,-2\n", 3, "speed_kmh", "negative speed"),
        ("time_s,speed_kmh,elevation_m\n0,1,3\n1,2,x\n", 3, "elevation_m", "not a number: 'x'"),
        ("time_s,speed_kmh\n0,1\n\n2,x\n", 4, "speed_kmh", "not a number: 'x'"),  # blank lines are no rows
        ("time_s,speed_kmh\n0,1\n\n0,3\n", 4, "time_s", "does not increase"),
        ("time_s,speed_kmh\n0,1\n1\n", 3, "speed_kmh", "only 1 field,"),
        ("time_s,speed_kmh\n0,1\n1,\n", 3, "speed_kmh", "empty cell"),
        ("", 1, None, "empty file"),
        ("time_s,speed_kmh\n0,1\n", 3, None, "at least 2 samples"),
    ],
)
def test_bad_cycle_csv_names_line_and_column(tmp_path, body, line, column, words):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(InputError) as err:
        read_cycle_csv(p)
    e = err.value
    assert (e.line, e.column) == (line, column)
    assert words in str(e) and str(p) in str(e)


def test_binary_and_missing_cycle_files(tmp_path):
    p = tmp_path / "junk.csv"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    with pytest.raises(InputError, match="binary"):
        read_cycle_csv(p)
    with pytest.raises(InputError, match="not found"):
        read_cycle_csv(tmp_path / "nope.csv")
    p2 = tmp_path / "latin.csv"
    p2.write_bytes("time_s,speed_kmh\n0,1\n1,2\xe9\n".encode("latin-1"))
    with pytest.raises(InputError, match="not UTF-8"):
        read_cycle_csv(p2)
