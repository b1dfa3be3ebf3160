"""`samfdi simulate ... --engine rig`, the shipped rig scenarios, and bad input: one line that
names the file and the field, exit 2, nothing written."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rig
import sam
from sam.errors import UserError
from sam.hydraulics import leak_lpm
from samfdi.cli import main

ROOT = Path(__file__).resolve().parents[1]
RIG_SCENARIOS = sorted((ROOT / "scenarios" / "rig").glob("*.toml"))
CLOSED = ROOT / "scenarios" / "rig" / "healthy_closed_loop_steps.toml"

BASE = '''description = "a test"
duration_s = 1.0
seed = 3
[load]
m_L_kg = 494.0
[initial]
x_m = 0.05
'''
CONTROL = '''[control]
kp_V_per_m = 300.0
[control.setpoint]
kind = "steps"
points = [[0.0, 0.05], [0.2, 0.10]]
'''
INPUT = '[input]\nkind = "step"\namplitude_V = 2.5\n'


@pytest.mark.parametrize("path", RIG_SCENARIOS, ids=[p.stem for p in RIG_SCENARIOS])
def test_every_rig_scenario_runs_and_does_what_its_name_says(path):
    """Each shipped rig scenario runs as written and gives a recording in the shared format: finite
    signals, no pS column unless asked for; its fault at its size in the true_* columns (healthy
    ones none); under closed-loop control the logged position (what the loop sees) settles within
    3 mm RMS of the setpoint 4 s after it last moved (behind one that moves, within 6 cm: a P loop
    lags by the setpoint's speed over its gain, some 4 cm at 0.1 m/s)."""
    sc, settings = rig.load_rig_scenario(path)
    rec = rig.record(sc, settings)
    assert sc.description
    assert {"t", "u", "pA", "pB", "theta", "x"} - {"t", *rec.signals} == set()
    assert all(np.all(np.isfinite(v)) for v in rec.signals.values())
    assert ("pS" in rec.signals) == settings.sensors.measure_pS
    leak = re.match(r"(int|extA|extB)_(\d+p\d+)lpm", path.stem)
    if leak:
        column = {"int": "true_K_int", "extA": "true_K_extA", "extB": "true_K_extB"}[leak[1]]
        assert leak_lpm(rec.truth[column].max()) == pytest.approx(float(leak[2].replace("p", ".")), rel=1e-3)
    if path.stem.startswith("offset_plus1pct"):
        assert rec.truth["true_offset"].max() == pytest.approx(0.01)
    if path.stem.startswith(("healthy", "concealed", "geometry")):
        assert all(np.all(rec.truth[c] == 0) for c in ("true_K_int", "true_K_extA", "true_K_extB", "true_offset"))
    if sc.control is not None:  # the logged position (what the loop sees) settles on the setpoint
        x_ref, error = rec.truth["true_x_ref"], rec.signals["x"] - rec.truth["true_x_ref"]
        settled = np.array([np.ptp(x_ref[max(i - 4000, 0):i + 1]) == 0 for i in range(len(x_ref))]) & (rec.t > 4.0)
        assert np.sqrt(np.mean(error[settled] ** 2)) < 3e-3 if settled.any() else np.sqrt(np.mean(error**2)) < 0.06


def test_cli_engine_rig_writes_the_shared_format(tmp_path, capsys):
    out = tmp_path / "rig.csv"
    assert main(["simulate", str(CLOSED), "--engine", "rig", "--out", str(out)]) == 0
    rec = sam.read_recording(out)
    assert rec.metadata["generator"] == "samfdi simulate --engine rig" and "closed loop" in rec.metadata["control"]
    assert rec.n == 20001 and "true_x_ref" in rec.truth and "pS" not in rec.signals
    assert np.all(np.abs(rec.signals["u"]) <= 10.0)


def test_engine_sam_refuses_a_closed_loop_and_warns_of_rig_tables(tmp_path, capsys):
    """sam's simulator has no controller: a closed-loop scenario is refused in one line; an open-loop
    one with [rig.*] tables runs, with a warning that they are the rig's."""
    assert main(["simulate", str(CLOSED), "--out", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert "'control'" in err and "--engine rig" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s.csv").exists()
    path = ROOT / "scenarios" / "rig" / "concealed_valve_and_supply.toml"
    assert main(["simulate", str(path), "--engine", "sam", "--out", str(tmp_path / "s.csv")]) == 0
    assert "[rig.*] tables are read by --engine rig only" in capsys.readouterr().err


BAD = [
    (BASE + CONTROL.replace("kp_V_per_m = 300.0\n", ""), ["control.kp_V_per_m", "missing"]),
    (BASE + CONTROL.replace("kp_V_per_m", "kp_V_per_mm"), ["control.kp_V_per_mm", "unknown key", "kp_V_per_m"]),
    (BASE + CONTROL.replace("300.0", "nan"), ["control.kp_V_per_m", "finite"]),
    (BASE + CONTROL.replace("[[0.0, 0.05], [0.2, 0.10]]", "[[0.0, 0.05], [0.2, 0.90]]"), ["control.setpoint", "stroke"]),
    (BASE + CONTROL.replace('kind = "steps"', 'kind = "stairs"'), ["control.setpoint.kind", "stairs"]),
    (BASE + CONTROL + INPUT, ["'input'", "not both"]),
    (BASE + CONTROL.replace("[control]\n", "[control]\nrate_Hz = 1500.0\n"), ["control.rate_Hz", "whole multiple"]),
    (BASE + INPUT + "[rig.effects]\nair_contnt = 0.01\n", ["rig.effects.air_contnt", "unknown key", "air_content"]),
    (BASE + INPUT + "[rig.effects]\nlap_PA = nan\n", ["rig.effects.lap_PA", "number"]),
    (BASE + INPUT + "[rig.effects]\npump_flow_m3_s = -1.0\n", ["rig.effects.pump_flow_m3_s", "must be in"]),
    (BASE + INPUT + "[rig.sensor]\nlag_s = 0.01\n", ["rig.sensor", "unknown table", "sensors"]),
    (BASE + INPUT + "[rig.sensors]\nmeasure_pS = 1\n", ["rig.sensors.measure_pS", "true or false"]),
    (BASE + INPUT + "[rig.numerics]\nstep_s = 3e-4\n", ["rig.numerics.step_s", "divide"]),
]


@pytest.mark.parametrize("text, words", BAD, ids=[w[0] for _, w in BAD])
def test_bad_rig_scenarios_are_one_line_naming_the_field(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError) as err:
        sc, settings = rig.load_rig_scenario(path)
        rig.record(sc, settings)
    message = str(err.value)
    assert "\n" not in message and "bad.toml" in message
    for word in words:
        assert word in message


def test_cli_bad_input_and_unknown_engine_are_one_line_without_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + CONTROL.replace("kp_V_per_m = 300.0\n", ""))
    for args, words in (([str(bad), "--engine", "rig"], ["bad.toml", "control.kp_V_per_m"]),
                        ([str(CLOSED), "--engine", "matlab"], ["--engine", "matlab", "rig"])):
        done = subprocess.run([sys.executable, "-m", "samfdi", "simulate", *args, "--out", str(tmp_path / "x.csv")],
                              capture_output=True, text=True, cwd=ROOT)
        assert done.returncode == 2 and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
        assert all(w in done.stderr for w in words)
        assert not (tmp_path / "x.csv").exists()
