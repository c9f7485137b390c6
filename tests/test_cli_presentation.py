"""The command line reads right: help texts keep their bracketed words, flags show no
metavar, exit codes as docs/reference/commands.md says, one message per mistake across commands, fleet
days by name or 1-based number, tables that do not break ids, text that cannot forge
output (control characters escaped in tables, CSV and error lines)."""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np
import pytest
import typer.main
from typer.testing import CliRunner

from cevm.cli import app
from cevm.cli.output import OutputFormat, write_rows
from cevm.text import printable

runner = CliRunner()


def _commands():
    """(path, click command) of every command and subcommand of the app."""
    root = typer.main.get_command(app)
    out = []

    def walk(cmd, path):
        out.append((path, cmd))
        if getattr(cmd, "commands", None):
            for name, sub in cmd.commands.items():
                walk(sub, path + [name])

    walk(root, [])
    return out


COMMANDS = _commands()


def _bracketed(text: str) -> set[str]:
    return set(re.findall(r"\[[^\]\s]+\]", text or ""))


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p) or "cevm")
def test_help_keeps_its_bracketed_words_and_shows_no_bool_metavar(path):
    cmd = {tuple(p): c for p, c in COMMANDS}[tuple(path)]
    words = _bracketed(cmd.help)
    for param in cmd.params:
        words |= _bracketed(getattr(param, "help", None))
    res = runner.invoke(app, [*path, "--help"])
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    missing = {w for w in words if w not in flat}
    assert not missing, f"{' '.join(path)} --help lost {missing}"
    assert "<bool>" not in res.output


def test_the_help_texts_the_issue_named():
    sim = " ".join(runner.invoke(app, ["simulate", "--help"]).output.split())
    assert "[detailed] table" in sim and "Gross mass [kg]" in sim
    pred = " ".join(runner.invoke(app, ["predict", "--help"]).output.split())
    assert "pip install 'cevm[dask]'" in pred


def test_ingest_of_nothing_is_bad_usage_and_creates_no_store(tmp_path):
    store = tmp_path / "s.sqlite"
    res = runner.invoke(app, ["ingest", str(tmp_path / "no" / "such"), "--store", str(store)])
    assert res.exit_code == 2
    assert "no such file" in res.output
    assert not store.exists() and not list(tmp_path.iterdir())


@pytest.fixture()
def paths(root):
    return {"hgv": str(root / "configs/vehicles/diesel-hgv.toml"),
            "bus": str(root / "configs/vehicles/electric-bus.toml"),
            "urban": str(root / "configs/cycles/urban-bus.csv")}


def _error_line(res) -> str:
    lines = [x for x in res.output.splitlines() if x.startswith("cevm: error:")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    return lines[0]


def test_a_negative_payload_gets_one_message_from_every_command(paths):
    got = {
        "predict": _error_line(runner.invoke(app, ["predict", "-v", paths["hgv"], "-c", paths["urban"], "-p", "-100"])),
        "feasibility": _error_line(runner.invoke(app, ["feasibility", "-v", paths["hgv"], "-c", paths["urban"],
                                                       "-p", "-100"])),
        "simulate": _error_line(runner.invoke(app,
                                              ["simulate", "-v", paths["hgv"], "-c", paths["urban"], "-p", "-100"])),
    }
    assert len(set(got.values())) == 1, got
    assert "payload -100 kg is negative" in got["predict"]


def test_a_gross_mass_below_the_kerb_mass_gets_one_message_from_every_command(paths):
    got = {
        "predict": _error_line(runner.invoke(app, ["predict", "-v", paths["hgv"], "-c", paths["urban"], "-m", "100"])),
        "feasibility": _error_line(runner.invoke(app, ["feasibility", "-v", paths["hgv"], "-c", paths["urban"],
                                                       "-m", "100"])),
        "simulate": _error_line(runner.invoke(app,
                                              ["simulate", "-v", paths["hgv"], "-c", paths["urban"], "-m", "100"])),
    }
    assert len(set(got.values())) == 1, got
    assert "gross mass 100 kg is below the kerb mass 18,000 kg" in got["predict"]


def test_a_state_of_charge_out_of_range_gets_one_message_from_every_command(paths):
    got = {cmd: _error_line(runner.invoke(app, [cmd, "-v", paths["bus"], "-c", paths["urban"], "--soc-start", "120"]))
           for cmd in ("predict", "feasibility", "simulate")}
    assert len(set(got.values())) == 1, got
    assert "--soc-start" in got["predict"] and "(0, 100]" in got["predict"]


def test_over_max_gross_stays_a_flag(paths):
    res = runner.invoke(app, ["predict", "-v", paths["hgv"], "-c", paths["urban"], "-m", "50000", "-f", "json"])
    assert res.exit_code == 0
    assert json.loads(res.stdout)[0]["over_max_gross"] is True


def test_simulate_refuses_a_file_without_a_detailed_table(root, paths):
    res = runner.invoke(app,
                        ["simulate", "-v", str(root / "configs/vehicles/renault-twizy.toml"), "-c", paths["urban"]])
    line = _error_line(res)
    assert "no [detailed] table" in line and "renault-twizy.toml" in line


@pytest.mark.slow
def test_fleet_days_by_name_or_1_based_number(root):
    scenario = str(root / "configs/fleet/paper-case-study.toml")

    def plan_days(day):
        res = runner.invoke(app, ["fleet", "plan", scenario, "--day", day, "-f", "json"])
        assert res.exit_code == 0, res.output
        return [s["day"] for s in json.loads(res.stdout)["summary"]]

    assert plan_days("3") == ["day 3"]
    assert plan_days("1") == ["day 1"]
    assert plan_days("day 2") == ["day 2"]
    for bad, words in (("0", "numbered from 1"), ("4", "has 3 days"), ("monday", "unknown day")):
        line = _error_line(runner.invoke(app, ["fleet", "plan", scenario, "--day", bad]))
        assert words in line and "1 = 'day 1'" in line


# ----------------------------------------------------------------- tables and text


def test_table_never_breaks_an_id():
    tid = "HGV-11:2019-05-14T06:12:33Z:0001-with-a-long-suffix"
    rows = [{"trip_id": tid, "vehicle_id": "HGV-11", "status": "ok " * 30, "km": 1.0, "s": 2.0, "x": 3.0}]
    buf = io.StringIO()
    write_rows(rows, OutputFormat.table, stream=buf)
    assert tid in buf.getvalue()


HOSTILE = "EV\r01\nfake: line\x1b[31m\u202e[bold]x"


def test_control_characters_are_escaped_in_tables_and_csv_and_exact_in_json():
    rows = [{"vehicle_id": HOSTILE, "note": 'a "quoted", text', "km": 1.5}]
    buf = io.StringIO()
    write_rows(rows, OutputFormat.csv, stream=buf)
    text = buf.getvalue()
    assert text.count("\n") == 2 and "\r" not in text and "\x1b" not in text  # one line per record
    got = list(csv.DictReader(io.StringIO(text)))
    assert got[0]["vehicle_id"] == printable(HOSTILE) and got[0]["note"] == 'a "quoted", text'
    buf = io.StringIO()
    write_rows(rows, OutputFormat.table, stream=buf)
    table = buf.getvalue()
    assert "\r" not in table and "\x1b" not in table and "\u202e" not in table
    assert "[bold]x" in table  # no console markup either
    buf = io.StringIO()
    write_rows(rows, OutputFormat.json, stream=buf)
    assert json.loads(buf.getvalue())[0]["vehicle_id"] == HOSTILE


def test_printable_escapes_and_is_idempotent():
    assert printable("a\rb\nc\td\x00e\x85f\u2028g\u202eh") == "a\\rb\\nc\\td\\x00e\\x85f\\u2028g\\u202eh"
    assert printable(printable(HOSTILE)) == printable(HOSTILE)
    assert printable("Zürich 東京 ok") == "Zürich 東京 ok"


def test_a_file_name_with_a_newline_cannot_forge_an_error_line(tmp_path):
    bad = tmp_path / "a\ncevm: error: forged.toml"
    res = runner.invoke(app, ["predict", "-v", str(bad), "-c", str(bad)])
    assert res.exit_code == 2
    assert len([x for x in res.output.splitlines() if x.startswith("cevm: error:")]) == 1
    assert "\\n" in res.output


def test_predict_fast_csv_writer_quotes_and_escapes(tmp_path, root):
    cyc = tmp_path / "a,b\r\"c.csv"
    cyc.write_text((root / "configs/cycles/urban-bus.csv").read_text())
    res = runner.invoke(app, ["predict", "-v", str(root / "configs/vehicles/electric-bus.toml"), "-c", str(cyc),
                              "-f", "csv"])
    assert res.exit_code == 0, res.output
    assert "\r" not in res.stdout and res.stdout.count("\n") == 2
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    assert rows[0]["cycle"] == printable('a,b\r"c')


def test_a_leg_repeated_past_the_limit_is_refused_at_once(root, tmp_path):
    text = (root / "configs/fleet/paper-case-study.toml").read_text()
    text = text.replace("../cycles/", str(root / "configs/cycles") + "/").replace("../vehicles/",
                                                                                  str(root / "configs/vehicles") + "/")
    p = tmp_path / "s.toml"
    p.write_text(text.replace("repeat = 3", "repeat = 100000000"))
    line = _error_line(runner.invoke(app, ["fleet", "plan", str(p)]))  # before: never returned
    assert "repeat must be an integer from 1 to 1,000, got 100000000" in line


def test_csv_writes_booleans_as_predicts_fast_path_and_json_do():
    # predict's fast CSV path writes "true"/"false"; every other CSV output must agree,
    # numpy booleans included (a column read back by one parser for every command).
    rows = [{"ok": True, "flag": np.bool_(False), "n": 1}]
    buf = io.StringIO()
    write_rows(rows, OutputFormat.csv, stream=buf)
    got = list(csv.DictReader(io.StringIO(buf.getvalue())))
    assert got == [{"ok": "true", "flag": "false", "n": "1"}]


def test_every_ice_answer_says_its_braking_mode(root):
    # the vehicle files state their modes (diesel-hgv.toml: no-credit, diesel-hgv-paper.toml
    # and the paper's fleet case: paper); an override must show as the mode used
    veh, cyc = root / "configs/vehicles", str(root / "configs/cycles/urban-bus.csv")
    res = runner.invoke(app, ["predict", "-v", str(veh / "diesel-hgv.toml"), "-v", str(veh / "electric-bus.toml"),
                              "-c", cyc])
    assert res.exit_code == 0, res.output
    legend = [x for x in res.stdout.splitlines() if x.startswith("vehicles: ")]
    # (the shipped files state no heating or A/C: they take their class's, and the legend says so)
    taken = " with heat+cool from its class's priors"
    assert len(legend) == 1 and f"diesel-hgv = Scania P320 diesel HGV{taken} (ICE, braking energy not credited)" \
        in legend[0]
    assert f"electric-bus = Optare Metrocity EV{taken}" in legend[0] and "priors (ICE" not in legend[0].split(";")[1]
    res = runner.invoke(app, ["feasibility", "-v", str(veh / "diesel-hgv.toml"), "-c", cyc, "--ice-braking", "paper"])
    assert res.exit_code == 0, res.output
    assert f"diesel-hgv = Scania P320 diesel HGV{taken} (ICE, braking energy credited (eq. 24))" in res.stdout
    res = runner.invoke(app, ["feasibility", "-v", str(veh / "diesel-hgv.toml"), "-c", cyc, "--ice-braking", "paper",
                              "-f", "json"])
    assert [r["ice_braking"] for r in json.loads(res.stdout)] == ["paper"]
    scenario = str(root / "configs/fleet/paper-case-study.toml")
    res = runner.invoke(app, ["fleet", "plan", scenario])
    assert res.exit_code == 0, res.output
    assert "vehicles: HGV1, HGV2, HGV3 = diesel-hgv-paper: " in res.stdout and "braking energy credited" in res.stdout
    res = runner.invoke(app, ["fleet", "plan", scenario, "-f", "json"])
    got = {v["id"]: (v["vehicle_key"], v["ice_braking"]) for v in json.loads(res.stdout)["vehicles"]}
    assert got == {f"HGV{i}": ("diesel-hgv-paper", "paper") for i in (1, 2, 3)}


def test_simulate_says_the_auxiliary_power_it_assumed(root, tmp_path):
    # electric-bus.toml's [detailed] table: aux_base_power_kw 4.0, hvac_power_kw 0.0; with
    # hvac_power_kw 12 the battery feeds 16 kW besides the motor
    bus = root / "configs/vehicles/electric-bus.toml"
    cyc = str(root / "configs/cycles/urban-bus.csv")
    res = runner.invoke(app, ["simulate", "-v", str(bus), "-c", cyc, "-f", "json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)[0]["aux_power_kw"] == pytest.approx(4.0)
    winter = tmp_path / "bus-winter.toml"
    text = bus.read_text()
    assert "hvac_power_kw = 0.0" in text
    winter.write_text(text.replace("hvac_power_kw = 0.0", "hvac_power_kw = 12.0"))
    res = runner.invoke(app, ["simulate", "-v", str(winter), "-c", cyc, "-f", "json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)[0]["aux_power_kw"] == pytest.approx(16.0)


def test_fleet_plan_warns_outside_what_a_calibration_saw(root, tmp_path):
    # a calibration on 12 light, cold trips: the paper's case loads HGV1 to 43,000 kg on
    # its first leg, at the vehicle's default 20 degC (the scenario gives no temperature)
    veh = tmp_path / "hgv-cal.toml"
    veh.write_text((root / "configs/vehicles/diesel-hgv-paper.toml").read_text()
                   + '\n[calibration]\nterms = ["eta"]\nn_trips = 12\nmass_kg = [18000, 25000]\nambient_c = [0, 5]\n')
    text = (root / "configs/fleet/paper-case-study.toml").read_text()
    cycles = (root / "configs/cycles").as_posix()
    sc = tmp_path / "case.toml"
    sc.write_text(text.replace('"../vehicles/diesel-hgv-paper.toml"', f'"{veh.as_posix()}"')
                  .replace('"../cycles/', f'"{cycles}/'))
    res = runner.invoke(app, ["fleet", "plan", str(sc), "-f", "json"])
    assert res.exit_code == 0, res.output
    warnings = json.loads(res.stdout)["warnings"]
    hgv1 = [w for w in warnings if w.startswith("HGV1: ")]
    assert any("calibrated on 12 trips at 18,000 to 25,000 kg; asked at" in w and "43,000 kg" in w for w in hgv1)
    assert any("calibrated on 12 trips at 0.0 to 5.0 degC; asked at 20.0 degC" in w for w in hgv1)
    assert "cevm: warning: HGV1: " in res.stderr
    res = runner.invoke(app, ["fleet", "plan", str(root / "configs/fleet/paper-case-study.toml"), "-f", "json"])
    assert json.loads(res.stdout)["warnings"] == [] and "warning" not in res.stderr  # not calibrated: nothing to say


def test_a_temperature_the_model_cannot_use_is_said(root, tmp_path):
    # electric-bus-paper.toml states no heating, A/C or warm-up (zeros: the paper's model;
    # a file that leaves them out takes its class's prior instead): a winter question would
    # get the same number as a summer one; a bus with a heating term takes it without a word
    bus, cyc = str(root / "configs/vehicles/electric-bus-paper.toml"), str(root / "configs/cycles/urban-bus.csv")
    heated = tmp_path / "heated.toml"
    heated.write_text('name = "heated bus"\npowertrain = "ev"\nkerb_mass_kg = 9000\npayload_kg = 1000\n'
                      'cda_m2 = 4.0\ncr = 0.007\neta = 0.8\nbattery_kwh = 300\naux_power_kw = 3\n'
                      'aux_heating_kw_per_k = 0.25\n')
    for cmd in (["predict"], ["feasibility"]):
        res = runner.invoke(app, [*cmd, "-v", bus, "-v", str(heated), "-c", cyc, "--ambient-c", "-10"])
        assert res.exit_code == 0, res.output
        said = [x for x in res.stderr.splitlines() if "changes nothing" in x]
        assert len(said) == 1 and said[0].startswith("cevm: warning: electric-bus-paper: ")
        assert "--ambient-c -10" in said[0]
        res = runner.invoke(app, [*cmd, "-v", bus, "-c", cyc])
        assert "changes nothing" not in res.stderr  # nothing asked, nothing to say
    res = runner.invoke(app, ["fleet", "plan", str(root / "configs/fleet/paper-case-study.toml"), "--ambient-c", "30"])
    assert res.exit_code == 0, res.output
    assert "cevm: warning: diesel-hgv-paper: no term of its model depends on the ambient temperature" in res.stderr


def test_a_cycle_without_elevation_says_it_is_taken_flat(root, tmp_path):
    flat = tmp_path / "flat.csv"
    flat.write_text("time_s,speed_kmh\n" + "".join(f"{i},{min(i, 30)}\n" for i in range(60)))
    bus, hilly = str(root / "configs/vehicles/electric-bus.toml"), str(root / "configs/cycles/urban-bus.csv")
    for cmd in ("predict", "feasibility", "simulate"):
        res = runner.invoke(app, [cmd, "-v", bus, "-c", str(flat)])
        assert res.exit_code == 0, res.output
        assert "flat" in res.stderr and "a flat road assumed" in res.stderr
        res = runner.invoke(app, [cmd, "-v", bus, "-c", hilly])  # urban-bus.csv has elevation_m
        assert "flat road" not in res.stderr


def test_a_stored_trip_without_elevation_says_it_is_taken_flat(root, tmp_path):
    # the portal export has no altitude column: without --dsm its trips are stored flat
    db = tmp_path / "s.sqlite"
    log = root / "sample_logs/portal/portal_export_2019-10-25_2019-10-28.csv"
    assert runner.invoke(app, ["ingest", str(log), "--store", str(db), "-q"]).exit_code == 0
    res = runner.invoke(app, ["predict", "-v", str(root / "configs/vehicles/diesel-hgv.toml"), "--vehicle-id",
                              "KX19 LMR", "--store", str(db)])
    assert res.exit_code == 0, res.output
    assert "stored trip(s) had neither DSM nor GPS elevation at ingest" in res.stderr
