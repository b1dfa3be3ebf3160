"""`samfdi fdi` as a new user meets it: bad input in one line naming the file, the field and the
problem (exit 2, no traceback, before any work); a headline that says first when a recording
cannot support a diagnosis; help that points at files the clone has."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import one_line_error, read_only_folder, samfdi
from fdi import Thresholds, replay
from sam import Recording, UserError, load_plant, write_recording
from samfdi.cli import build_parser, main
from fdi.synth import input_signal, simulate_runs

DT = 1e-3
REPO = Path(__file__).resolve().parents[1]


def _recording(T: int = 3001, seed: int = 5) -> Recording:
    """A healthy, seeded recording: 3 s of a 3 V, 0.25 Hz sine at the nominal plant, theta from the encoder."""
    p = load_plant().vector()
    t = np.arange(T) * DT
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    r = simulate_runs(p[None], u, DT, seed=seed)
    return Recording(t, {"u": u, "pA": r.inp.pA[0], "pB": r.inp.pB[0], "theta": r.inp.pos[0]}, {}, {})


@pytest.fixture(scope="module")
def healthy_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "healthy.csv"
    write_recording(path, _recording())
    return path


def _error(capsys, args: list) -> str:
    """The one error line of a refused `samfdi fdi ...` (exit 2), checked to be one line."""
    assert main(args) == 2
    captured = capsys.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    return lines[0]


def test_help_points_at_the_recording_format_in_the_project(capsys):
    """Every fdi subcommand's help cites the recording format where a clone has it
    (docs/recordings.md), never ../shared/recording-format.md."""
    fdi = build_parser()._subparsers._group_actions[0].choices["fdi"]
    commands = fdi._subparsers._group_actions[0].choices
    texts = {name: p.format_help() for name, p in commands.items()}
    assert all("recording-format" not in t and "../shared" not in t for t in texts.values())
    assert "docs/recordings.md" in " ".join(texts["replay"].split()) and (REPO / "docs" / "recordings.md").is_file()


@pytest.mark.parametrize("role", ["--reference", "--baseline"])
def test_a_healthy_recording_too_short_to_replay_is_refused(healthy_csv, tmp_path, capsys, role):
    """A 0.5 s recording given as --reference or --baseline is refused as replay refuses it to
    diagnose: one line naming the file, the option and 't', exit 2, nothing written."""
    short = tmp_path / "short.csv"
    rec = _recording()
    write_recording(short, Recording(rec.t[:501], {k: v[:501] for k, v in rec.signals.items()}, {}, {}))
    line = _error(capsys, ["fdi", "replay", str(healthy_csv), role, str(short), "--out", str(tmp_path / "o")])
    assert f"short.csv: {role}: 't': only 0.5 s long; a diagnosis needs at least 2 s" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("column", ["u", "pA", "theta"])
def test_a_column_that_is_mostly_missing_is_refused(tmp_path, capsys, column):
    """A column measured for only its first 0.2 s of 3 s (the rest NaN) cannot support the 2 s a
    diagnosis needs: one line naming the file, the column and how much of it is there (before,
    the missing samples were predicted through and the run called healthy or faulty)."""
    rec = _recording()
    rec.signals[column][200:] = np.nan
    path = tmp_path / "gappy.csv"
    write_recording(path, rec)
    line = _error(capsys, ["fdi", "replay", str(path), "--out", str(tmp_path / "o")])
    assert f"gappy.csv: '{column}': only 200 of 3001 samples (0.2 s) are numbers, the rest missing (NaN)" in line


def test_scattered_missing_samples_are_still_predicted_through(tmp_path):
    """Every other pressure sample missing leaves 1.5 s of the 3 s: refused; every tenth missing
    leaves 2.7 s: replayed, with the gaps counted."""
    plant, rec = load_plant(), _recording()
    rec.signals["pB"][::2] = np.nan
    with pytest.raises(UserError, match=r"'pB': only 1500 of 3001 samples \(1.5 s\)"):
        replay(rec, plant)
    rec = _recording()
    rec.signals["pB"][::10] = np.nan
    r = replay(rec, plant)
    assert r.diagnosis.filter_health["nan_samples"] == 301 and r.diagnosis.status == "healthy"


@pytest.mark.parametrize("given, problem", [
    ("missing.toml", "--thresholds: file does not exist"),
    ("folder", "--thresholds: is a folder"),
    ("healthy.csv", "--thresholds: expected a .toml file"),
    ("list.json", "--thresholds: not a thresholds file from `samfdi fdi thresholds`"),
    ("binary.toml", "--thresholds: not a text file"),
])
def test_a_thresholds_file_that_is_not_one_is_named(healthy_csv, tmp_path, capsys, given, problem):
    (tmp_path / "folder").mkdir()
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "binary.toml").write_bytes(b"\xff\xfe\x00\x81")
    path = healthy_csv if given == "healthy.csv" else tmp_path / given
    for cmd in (["replay", str(healthy_csv)], ["tune", "--runs", "5"]):
        line = _error(capsys, ["fdi", *cmd, "--thresholds", str(path), "--out", str(tmp_path / "o")])
        assert line.startswith(f"samfdi: error: {path}: {problem}"), line


def test_constant_input_leads_the_headline_with_the_caveat(tmp_path, capsys):
    """The recording's motion with its valve input replaced by a constant 1 V (the logger saved
    the set-point): the first line says there is no diagnosis and why, and only the second gives
    the detector's reading. diagnosis.json keeps the detector's status; a recording whose input
    varies gets the reading alone."""
    rec = _recording()
    path = tmp_path / "const.csv"
    rec.signals["u"] = np.full(rec.n, 1.0)
    write_recording(path, rec)
    assert main(["fdi", "replay", str(path), "--out", str(tmp_path / "c")]) == 0
    first, second = capsys.readouterr().out.splitlines()[:2]
    d = json.loads((tmp_path / "c" / "diagnosis.json").read_text())
    assert first.startswith("no diagnosis (the recording cannot support one): the valve input u is constant (1 V")
    assert second.startswith(f"the detector's reading, not a diagnosis: {d['status']}")
    assert "constant" in d["filter_health"]["input_not_excited"]
    plain = replay(_recording(), load_plant()).diagnosis
    assert plain.caveats() == [] and plain.headline() == "healthy"


def test_read_only_and_existing_output_folders(healthy_csv, tmp_path):
    """A read-only --out, and a folder that already holds the command's files (without --force),
    are refused in one line before any work, for every fdi command that writes."""
    (tmp_path / "done").mkdir()
    for name in ("diagnosis.json", "signatures.md", "thresholds.md", "metrics.md"):
        (tmp_path / "done" / name).write_text("mine")
    commands = {"replay": ["replay", str(healthy_csv)], "signatures": ["signatures"],
                "thresholds": ["thresholds"], "tune": ["tune", "--runs", "5"]}
    with read_only_folder() as ro:
        for cmd in commands.values():
            line = one_line_error(samfdi("fdi", *cmd, "--out", str(ro / "sub")))
            assert str(ro / "sub") in line and "--out" in line and "Permission denied" in line
            line = one_line_error(samfdi("fdi", *cmd, "--out", str(tmp_path / "done")))
            assert "already holds" in line and "--force" in line
    assert all((tmp_path / "done" / n).read_text() == "mine" for n in ("diagnosis.json", "signatures.md"))


def test_replay_figure_draws_the_true_size_and_explains_itself(tmp_path, saved_figures):
    """replay.png of a recording with true_* columns (a 1 L/min leak out of A from 2 s) draws the
    true size as read from them, in L/min at 10 MPa, over the estimate; its legends say what the
    shading, the dashed alarm level and the vertical lines are, and name the tests in words (no
    "notch_flow jump / h"), in type readable at the size the figure is shown."""
    from fdi import K_PER_LPM, replay_recording
    from fdi.synth import profile

    rec = _recording()
    t = rec.t
    true = profile("step", K_PER_LPM, t, t0=2.0)
    faulty = simulate_runs(load_plant().vector()[None], rec.signals["u"], DT, faults={"K_extA": true[None]}, seed=5)
    rec = Recording(t, {**rec.signals, "pA": faulty.inp.pA[0], "pB": faulty.inp.pB[0], "theta": faulty.inp.pos[0]},
                    {"true_K_extA": true}, {})
    d = replay_recording(rec, load_plant(), tmp_path / "r")
    fig, = saved_figures
    leaks = fig.axes[0]
    dashed = [ln for ln in leaks.get_lines() if ln.get_linestyle() == "--"]
    assert len(dashed) == 1
    np.testing.assert_array_equal(dashed[0].get_xdata(), t)
    assert dashed[0].get_ydata().max() == pytest.approx(1.0) and dashed[0].get_ydata()[t < 2.0].max() == 0.0
    texts = [tx for leg in [*fig.legends, *(ax.get_legend() for ax in fig.axes)] if leg for tx in leg.get_texts()]
    words = " | ".join(tx.get_text() for tx in texts)
    for phrase in ("+-2 sigma", "the true size", "alarm level: a test alarms where it crosses 1",
                   "external leak out of A (K_extA)", "valve-flow jump trigger", "the alarm that stood"):
        assert phrase in words, words
    assert "/ h" not in words and "notch_flow" not in words and "CUSUM" not in words
    assert min(tx.get_fontsize() for tx in texts) >= 10
    assert d.isolated == ["K_extA"] and fig._suptitle.get_text().startswith("fault: K_extA")
