"""Vehicle TOML files and cycle CSV files: values, and errors that name file, line, key."""

import numpy as np
import pytest

from cevm.errors import InputError
from cevm.io import load_vehicle, load_vehicles, read_cycle_csv


def test_shipped_vehicles_hold_the_papers_values(root):
    bus = load_vehicle(root / "configs/vehicles/electric-bus-paper.toml")
    assert (bus.powertrain, bus.cda_m2, bus.cr, bus.mass_kg, bus.eta) == ("ev", 3.99, 0.0066, 9825.0, 0.78)
    assert bus.battery_j > 0
    hgv = load_vehicle(root / "configs/vehicles/diesel-hgv-paper.toml")
    assert (hgv.powertrain, hgv.cda_m2, hgv.cr, hgv.eta) == ("ice", 6.62, 0.0066, 0.45)
    assert (hgv.kerb_mass_kg, hgv.max_gross_kg) == (18000.0, 44000.0)
    assert 35e6 <= hgv.fuel_lhv_j_per_l <= 36.5e6
    assert hgv.ice_braking == "paper"
    assert hgv.with_payload(26000).mass_kg == 44000.0
    # the realistic files keep the paper's road loads
    for stem, paper in (("electric-bus", bus), ("diesel-hgv", hgv)):
        v = load_vehicle(root / f"configs/vehicles/{stem}.toml")
        assert (v.cda_m2, v.cr, v.kerb_mass_kg) == (paper.cda_m2, paper.cr, paper.kerb_mass_kg)
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


# ------------------------------------------------------- plausibility bounds, identity

GOOD_ICE = ('name = "t"\npowertrain = "ice"\nkerb_mass_kg = 15000\nmax_gross_kg = 40000\ncda_m2 = 6\ncr = 0.006\n'
            'eta = 0.38\nfuel_lhv_mj_per_l = 35.8\ntank_l = 400\n')


@pytest.mark.parametrize("key, value", [
    ("kerb_mass_kg", "1e20"), ("kerb_mass_kg", "5"), ("max_gross_kg", "1e7"), ("cda_m2", "0.001"),
    ("cda_m2", "600"), ("cr", "0.0001"), ("eta", "0.01"), ("fuel_lhv_mj_per_l", "358"), ("tank_l", "1e6"),
    ("idle_fuel_lph", "300"),
])
def test_implausible_values_are_refused_naming_file_and_key(tmp_path, key, value):
    p = tmp_path / "v.toml"
    lines = [ln for ln in GOOD_ICE.splitlines() if not ln.startswith(f"{key} =")]
    p.write_text("\n".join(lines) + f"\n{key} = {value}\n")
    with pytest.raises(InputError) as err:
        load_vehicle(p)
    msg = str(err.value)
    assert str(p) in msg and f"'{key}'" in msg and "plausible range" in msg


@pytest.mark.parametrize("key, value", [("battery_kwh", "1e6"), ("aux_power_kw", "5000"), ("mass_kg", "1e9")])
def test_implausible_ev_values_are_refused(tmp_path, key, value):
    p = tmp_path / "v.toml"
    lines = [ln for ln in GOOD_EV.splitlines() if not ln.startswith(f"{key} =")]
    p.write_text("\n".join(lines) + f"\n{key} = {value}\n")
    with pytest.raises(InputError, match=f"'{key}'.*plausible range"):
        load_vehicle(p)


def test_every_shipped_vehicle_is_within_the_bounds(root):
    assert len(load_vehicles([root / "configs/vehicles"])) >= 3


def test_vehicle_id_is_the_id_key_else_the_stem(tmp_path):
    a = tmp_path / "bus-a.toml"
    a.write_text(GOOD_EV)
    assert load_vehicle(a).id == "bus-a" and load_vehicle(a).label == "bus-a"
    b = tmp_path / "b.toml"
    b.write_text('id = "bus-calibrated-2024"\n' + GOOD_EV)
    assert load_vehicle(b).id == "bus-calibrated-2024"


def test_two_vehicles_with_one_id_are_refused(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "bus.toml").write_text(GOOD_EV)
    (tmp_path / "bus.toml").write_text(GOOD_EV.replace('"x"', '"other"'))
    with pytest.raises(InputError, match="vehicle id 'bus' is also the id of"):
        load_vehicles([tmp_path / "x" / "bus.toml", tmp_path / "bus.toml"])
    (tmp_path / "bus.toml").write_text('id = "bus-2"\n' + GOOD_EV)
    assert [v.id for v in load_vehicles([tmp_path / "x" / "bus.toml", tmp_path / "bus.toml"])] == ["bus", "bus-2"]


@pytest.mark.parametrize("value", ['"a\\rb"', '""', '" padded"', "12", '"' + "x" * 81 + '"'])
def test_bad_vehicle_ids_are_refused(tmp_path, value):
    p = tmp_path / "v.toml"
    p.write_text(f"id = {value}\n" + GOOD_EV)
    with pytest.raises(InputError, match="'id'"):
        load_vehicle(p)


def test_a_stem_with_a_control_character_is_escaped(tmp_path):
    p = tmp_path / "bus\rA.toml"
    p.write_text(GOOD_EV)
    assert load_vehicle(p).id == "bus\\rA"
