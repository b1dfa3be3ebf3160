"""Bad input to every command: one line naming the file or option and what is wrong, exit 2,
no traceback, nothing overwritten, and no work done before the refusal."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import one_line_error, read_only_folder, samfdi
from samfdi.cli import main

ROOT = Path(__file__).resolve().parents[1]
GSA = ROOT / "scenarios" / "gsa"
ISHIGAMI = str(GSA / "ishigami.toml")


def refused(capsys, *args) -> str:
    """Run ``samfdi ARGS`` in this process; the one error line of its refusal."""
    assert main([*args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("samfdi: error: "), err
    return err[0]


# -- numeric options: one typed helper, every command ------------------------------------------


@pytest.mark.parametrize("option, value, rule", [
    ("--bootstrap", "0", "an integer >= 40"),  # wrote [nan, nan] intervals
    ("--workers", "0", "an integer >= 1"),
    ("--chunk-size", "0", "an integer >= 1"),  # silently became 65536
    ("--n", "1", "an integer >= 2"),
    ("--n", "1e3", "an integer >= 2"),
    ("--workers", "two", "an integer >= 1"),
])
def test_gsa_run_numeric_options_are_checked_before_any_work(tmp_path, capsys, option, value, rule):
    line = refused(capsys, "gsa", "run", ISHIGAMI, "--out", str(tmp_path / "o"), option, value)
    assert f"argument {option}: expected {rule}, got '{value}'" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf"])
def test_mismatch_segment_must_be_a_positive_length(tmp_path, capsys, value):
    """--segment 0 or -1 changed the verdict while the report still spoke of 1 s segments."""
    line = refused(capsys, "mismatch", str(tmp_path / "none.csv"), "--out", str(tmp_path / "o"),
                   "--segment", value)
    assert f"argument --segment: expected a finite number > 0, got '{value}'" in line


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith("samfdi ")


# -- output paths: one checked helper ---------------------------------------------------------


def test_gsa_run_out_is_checked_before_any_work(tmp_path, capsys):
    (tmp_path / "file").write_text("mine")
    assert "file: --out: is a file, not a folder" in refused(
        capsys, "gsa", "run", ISHIGAMI, "--out", str(tmp_path / "file"))
    assert (tmp_path / "file").read_text() == "mine"
    assert "/proc/x: --out: cannot create it in /proc" in refused(capsys, "gsa", "run", ISHIGAMI, "--out", "/proc/x")


def test_gsa_run_never_overwrites_a_summary_without_force(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "summary.md").write_text("my notes")
    line = refused(capsys, "gsa", "run", ISHIGAMI, "--out", str(out), "--n", "64", "--no-progress")
    assert "already holds summary.md; use --force" in line
    assert (out / "summary.md").read_text() == "my notes" and not (out / "chunks").exists()
    assert main(["gsa", "run", ISHIGAMI, "--out", str(out), "--n", "64", "--bootstrap", "40",
                 "--no-progress", "--force"]) == 0
    assert (out / "summary.md").read_text().startswith("# Sobol'")


def test_read_only_folders_are_refused_before_any_work():
    with read_only_folder() as folder:
        line = one_line_error(samfdi("gsa", "run", ISHIGAMI, "--out", str(folder)))
        assert f"{folder}: --out: the folder is not writable" in line
        line = one_line_error(samfdi("demo", "--out", str(folder / "demo")))
        assert f"{folder}/demo: --out: cannot create it in {folder}" in line
        line = one_line_error(samfdi("demo", cwd=folder))
        assert "the current folder is not writable" in line and "--out" in line


def test_a_study_too_large_for_memory_says_what_fits(tmp_path, capsys):
    t0 = time.perf_counter()
    line = refused(capsys, "gsa", "run", ISHIGAMI, "--out", str(tmp_path / "o"), "--n", "100000000")
    assert "N = 100000000: the study needs about" in line and "GiB of memory" in line
    assert "N = " in line.split("available; ")[1] and "fits" in line
    fits = int(line.split("available; N = ")[1].split()[0])
    assert fits & (fits - 1) == 0 and 2**10 <= fits < 100_000_000
    assert not (tmp_path / "o").exists()
    assert time.perf_counter() - t0 < 60  # refused up front, not after allocating


# -- files given to the wrong command ---------------------------------------------------------


def test_a_scenario_given_to_gsa_run_is_named_as_such(tmp_path, capsys):
    line = refused(capsys, "gsa", "run", str(ROOT / "scenarios" / "paper_step.toml"), "--out", str(tmp_path / "o"))
    assert "paper_step.toml: this is a scenario file" in line and "not a GSA study file" in line
    line = refused(capsys, "simulate", ISHIGAMI, "--out", str(tmp_path / "r.csv"))
    assert "ishigami.toml: this is a GSA study file" in line and "samfdi gsa run" in line


def test_warnings_of_a_study_name_the_study(tmp_path, capsys):
    """The demo runs two studies: an 'indices are NaN' warning must say which one it belongs to."""
    text = (GSA / "paper_leakage.toml").read_text().replace('outputs = ["p_A", "p_B", "v"]', 'outputs = ["x_s"]')
    path = tmp_path / "leak.toml"
    path.write_text(text)
    assert main(["gsa", "run", str(path), "--out", str(tmp_path / "o"), "--n", "64", "--bootstrap", "40",
                 "--no-progress"]) == 0
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "do not vary" in ln]
    assert warnings and all(ln.startswith("samfdi: warning: study 'paper_leakage': ") for ln in warnings)
    assert np.isnan(float(next(r for r in (tmp_path / "o" / "indices.csv").read_text().splitlines()[1:]
                               if r.startswith("x_s,")).split(",")[3]))


# -- sizes and values no specific check foresaw ------------------------------------------------


def test_a_run_too_large_for_memory_is_one_line(tmp_path, capsys):
    scenario = tmp_path / "huge.toml"
    scenario.write_text('duration_s = 1e9\n[input]\nkind = "step"\namplitude_V = 2.5\n')
    line = refused(capsys, "simulate", str(scenario), "--out", str(tmp_path / "r.csv"))
    assert "not enough memory" in line and "smaller run" in line


@pytest.mark.parametrize("study, edit, words", [
    ("ishigami.toml", ("b = 0.1 }", 'b = "0.1" }'), ["'model_options.b'", "a number"]),
    ("sobol_g.toml", ("a = [", 'a = ["x", '), ["'model_options.a'", "a_i >= 0"]),
    ("sobol_g.toml", ("seed = ", 'ci = "student"\nseed = '), ["'ci'", "'student'"]),
    ("paper_leakage.toml", ('outputs = ["p_A", "p_B", "v"]', 'outputs = "p_A"'), ["'simulation.outputs'", "list"]),
    ("paper_leakage.toml", ("bounds = [0.0, 5.27e-9]", "bounds = [0.0, nan]"), ["'parameters.K_int.bounds'", "finite"]),
    ("paper_leakage.toml", ("n_bootstrap = 1000", "n_bootstrap = 0"), ["'n_bootstrap'", ">= 40"]),
])
def test_study_values_are_checked_when_the_file_is_read(tmp_path, capsys, study, edit, words):
    text = (GSA / study).read_text()
    assert edit[0] in text, edit
    path = tmp_path / study
    path.write_text(text.replace(edit[0], edit[1], 1))
    line = refused(capsys, "gsa", "run", str(path), "--out", str(tmp_path / "o"))
    for word in words:
        assert word in line
    assert not (tmp_path / "o").exists()
