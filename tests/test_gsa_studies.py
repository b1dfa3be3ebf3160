"""Study files and `samfdi gsa run`: analytic validation end to end, the paper's
SAM studies at reduced size, and bad input."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

import sam
from gsa import ZeroVarianceWarning, analyze, saltelli_design
from gsa.studies import load_study
from gsa.testfunctions import ishigami_indices, sobol_g_indices
from sam.errors import UserError
from samfdi.cli import main

ROOT = Path(__file__).resolve().parents[1]
GSA = ROOT / "scenarios" / "gsa"


def read_indices(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("study, exact", [
    ("ishigami.toml", ishigami_indices(7.0, 0.1)),
    ("sobol_g.toml", sobol_g_indices([0, 1, 4.5, 9, 99, 99])),
])
def test_analytic_studies_recover_exact_indices_through_the_cli(tmp_path, study, exact):
    out = tmp_path / "out"
    assert main(["gsa", "run", str(GSA / study), "--out", str(out), "--no-progress"]) == 0
    rows = read_indices(out / "indices.csv")
    S1_exact, ST_exact = exact
    for row, s1, st in zip(rows, S1_exact, ST_exact):
        assert row["time_s"] == ""
        for name, value in (("S1", s1), ("ST", st)):
            est, lo, hi = (float(row[c]) for c in (name, f"{name}_lo", f"{name}_hi"))
            assert abs(est - value) <= 0.02
            assert lo <= value <= hi
    assert "Largest absolute error" in (out / "summary.md").read_text()


@pytest.fixture(scope="module")
def paper_parameters_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pp")
    assert main(["gsa", "run", str(GSA / "paper_parameters.toml"), "--out", str(out), "--n", "1024",
                 "--bootstrap", "200", "--no-progress"]) == 0
    return out


def steady(out: Path, by: str = "S1") -> dict[str, dict[str, float]]:
    table: dict[str, dict[str, float]] = {}
    for row in read_indices(out / "indices.csv"):
        if row["output"].endswith("_steady"):
            table.setdefault(row["output"][: -len("_steady")], {})[row["parameter"]] = float(row[by])
    return table


def test_paper_parameters_study_reproduces_section_4_1(paper_parameters_run):
    """Table 2 / Section 4.1 at N = 1024: the valve's nominal flows and pressure drops carry
    the steady-state variance, offset matters for velocity only, B_eff and b are negligible;
    interactions are a few percent (Table 3)."""
    S1, ST = steady(paper_parameters_run, "S1"), steady(paper_parameters_run, "ST")
    valve = {"Q_N_PA", "dp_N_PA", "Q_N_BT", "dp_N_BT"}
    for out in ("p_A", "p_B"):
        top4 = set(sorted(S1[out], key=S1[out].get, reverse=True)[:4])
        assert top4 == valve
    v_rank = sorted(S1["v"], key=S1["v"].get, reverse=True)
    assert v_rank[:3] == ["dp_N_PA", "Q_N_PA", "offset"]  # Table 2, velocity column
    for out in ("p_A", "p_B", "v"):
        assert ST[out]["B_eff"] < 0.01 and ST[out]["b"] < 0.01
        assert 0.0 < 1 - sum(S1[out].values()) < 0.15


def test_paper_parameters_outputs_and_figures(paper_parameters_run):
    rows = read_indices(paper_parameters_run / "indices.csv")
    times = sorted({float(r["time_s"]) for r in rows if r["time_s"]})
    assert times[0] == pytest.approx(0.01) and times[-1] == pytest.approx(4.0) and len(times) == 400
    summary = (paper_parameters_run / "summary.md").read_text()
    for table in ("Tables 2 and 6", "Table 3", "Tables 4 and 8", "Table 7"):
        assert table in summary
    # the conclusion a hydraulics engineer acts on: what to calibrate, what can stay nominal
    assert "## What the study shows" in summary and "**What to do with it.**" in summary
    assert "B_eff and b can stay at their nominal values" in summary
    assert "B_eff matters only during the transient" in summary
    groups = {(r["output"], r["parameter"]): int(r["group"]) for r in read_indices(paper_parameters_run / "ranking.csv")
              if r["by"] == "ST" and r["output"] == "v_steady"}
    assert groups[("v_steady", "dp_N_PA")] < groups[("v_steady", "B_eff")]
    for fig in ("steady_state_indices.png", "indices_over_time_p_A.png"):
        assert (paper_parameters_run / fig).stat().st_size > 20_000
    # B_eff matters in the transient and fades by 0.5-1 s (Section 4.1 / Table 4). Later the
    # ~5 % of runs in stick-slip (low K_PA, slow motion near v_s) give it weight again at
    # single instants: the phase of their limit cycle depends on B_eff (docs/paper-reproduction.md).
    st_beff = {float(r["time_s"]): float(r["ST"]) for r in rows
               if r["output"] == "p_A" and r["parameter"] == "B_eff" and r["time_s"]}
    assert max(v for t, v in st_beff.items() if t <= 0.3) > 0.02
    assert max(v for t, v in st_beff.items() if 0.5 <= t <= 1.0) < 0.03


def test_resume_reuses_chunks_and_refuses_a_different_seed(tmp_path, capsys):
    study = GSA / "ishigami.toml"
    out = tmp_path / "run"
    args = ["gsa", "run", str(study), "--out", str(out), "--n", "512", "--chunk-size", "512",
            "--no-progress", "--bootstrap", "50"]
    assert main(args) == 0
    first = (out / "indices.csv").read_text()
    assert main(args) == 2  # not without --resume
    assert "--resume" in capsys.readouterr().err
    assert main(args + ["--resume"]) == 0
    assert "0 chunks computed" in capsys.readouterr().out
    assert (out / "indices.csv").read_text() == first
    other = tmp_path / "other.toml"
    other.write_text(study.read_text().replace("seed = 1", "seed = 2"))
    assert main(["gsa", "run", str(other), "--out", str(out), "--n", "512", "--chunk-size", "512",
                 "--no-progress", "--resume"]) == 2
    assert "refus" in capsys.readouterr().err


@pytest.mark.parametrize("edit, words", [
    (("bounds = [0.0, 1.0]", "bounds = [1.0, 0.0]", 1), ["x1", "bounds", "below"]),
    (("bounds = [0.0, 1.0]", "bounds = [0.5, 0.5]", 1), ["x1", "bounds"]),
    (("[parameters.x1]", "[parameters.x1]\ndistribution = \"weibull\"", 1), ["x1", "weibull"]),
    (("N = 8192", "N = 1", 1), ["'N'", ">= 2"]),
    (("n_bootstrap = 1000", "n_bootstrapp = 1000", 1), ["n_bootstrapp", "did you mean 'n_bootstrap'"]),
])
def test_bad_study_files_are_named(tmp_path, edit, words):
    text = (GSA / "sobol_g.toml").read_text().replace(*edit)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError) as err:
        load_study(path)
    assert "bad.toml" in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_unknown_sam_parameter_is_named(tmp_path):
    text = (GSA / "paper_leakage.toml").read_text().replace("[parameters.K_int]", "[parameters.K_internal]")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError, match="K_internal.*not a parameter"):
        load_study(path)


@pytest.mark.parametrize("edit, words", [
    (("dt_s = 0.001", "dt_s = 0.05\nevery_s = 0.1"), ["'simulation.dt_s'", "unstable", "largest stable step"]),
    (("dt_s = 0.001", 'dt_s = "1 ms"'), ["'simulation.dt_s'", "positive number of seconds"]),
    (("steady_from_s = 3.0", "steady_from_s = 9.0"), ["'simulation.steady_from_s'", "before the end"]),
    (("m_L_kg = 494.0", 'm_L_kg = "494"'), ["'simulation.load.m_L_kg'", "number of kg"]),
    (("dt_s = 0.001", 'dt_s = 0.001\nprecision = "float16"'), ["'simulation.precision'", "float32", "float16"]),
])
def test_bad_sam_study_settings_are_named(tmp_path, edit, words):
    text = (GSA / "paper_leakage.toml").read_text().replace("every_s = 0.01\n", "")
    assert edit[0] in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(*edit))
    with pytest.raises(UserError) as err:
        load_study(path)
    for word in words:
        assert word in str(err.value)


def test_single_precision_reaches_the_model_and_follows_double(tmp_path):
    """``[simulation] precision = "float32"`` runs the model's step in single precision: the
    leakage study's outputs for 64 of its runs follow float64's to 1e-3 of the supply pressure."""
    text = (GSA / "paper_leakage.toml").read_text().replace("dt_s = 0.001", 'dt_s = 0.001\nprecision = "float32"')
    path = tmp_path / "f32.toml"
    path.write_text(text)
    single = load_study(path).study.model
    double = load_study(GSA / "paper_leakage.toml").study.model
    assert (single.precision, double.precision) == ("float32", "float64")
    X = np.random.default_rng(0).uniform(0.0, 5.27e-9, (64, 3))
    Y32, Y64 = single(X), double(X)
    assert 0.0 < np.max(np.abs(Y32 - Y64)[:, :Y64.shape[1] // 3]) < 1e-3 * 1e7  # p_A [Pa], p_S = 10 MPa


#: how far any S1 or ST of the leakage study at N = 512 may move when its model steps in float32
#: (measured 3.2e-6 at worst over its 1201 varying outputs; at N = 10000 see docs/benchmarks.md)
FLOAT32_INDEX_TOLERANCE = 2e-5


def test_single_precision_moves_the_leakage_indices_by_less_than_the_stated_tolerance():
    """The float32 option, judged where it matters, on the indices: the leakage study's S1 and ST
    (N = 512, every output) from float32 and from float64 runs of the same design."""
    spec = load_study(GSA / "paper_leakage.toml")
    design = saltelli_design(spec.study.problem, N=512, seed=spec.seed)
    got = {}
    for precision in ("float64", "float32"):
        model = dataclasses.replace(spec.study.model, precision=precision)
        with pytest.warns(ZeroVarianceWarning):  # v at the first instants: the piston has not moved yet
            got[precision] = analyze(spec.study.problem, design, model(design.X), n_boot=0)
    a, b = got["float64"], got["float32"]
    ok = ~a.constant & ~b.constant
    assert ok.sum() > 1100
    for name in ("S1", "ST"):
        move = np.abs(getattr(a, name) - getattr(b, name))[:, ok]
        assert 0.0 < move.max() < FLOAT32_INDEX_TOLERANCE, (name, move.max())


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_sam_model_outputs_are_the_recorded_states_then_their_steady_means(precision):
    """The SAM model's output layout: per signal its state at every recorded instant, as
    sam.simulate_batch records it (bit for bit), then the mean of those from steady_from on
    (float64 to 1e-15; float32 outputs rounded to float32)."""
    spec = load_study(GSA / "paper_parameters.toml")
    model = dataclasses.replace(spec.study.model, precision=precision)
    X = np.random.default_rng(5).uniform(*np.array(spec.study.problem.bounds).T, (40, 7))
    Y = model(X)
    params = np.tile(model.base, (len(X), 1))
    params[:, list(model.columns)] = X * model.scales
    res = sam.simulate_batch(params, model.u, model.dt, record_at=model.record_at, channels=model.signals,
                             precision=precision)
    n_rec = len(model.record_at)
    steady = model.record_at >= model.steady_from
    assert Y.dtype == np.dtype(precision) and Y.shape == (40, 3 * (n_rec + 1))
    for i, s in enumerate(model.signals):
        block = Y[:, i * (n_rec + 1) : (i + 1) * (n_rec + 1)]
        np.testing.assert_array_equal(block[:, :n_rec], res[s])
        want = res[s][:, steady].astype(np.float64).mean(axis=1)  # the model sums in float64
        if precision == "float64":
            np.testing.assert_allclose(block[:, n_rec], want, rtol=1e-15)
        else:
            np.testing.assert_array_equal(block[:, n_rec], want.astype(np.float32))


def test_zero_variance_output_is_nan_with_warning_others_compute(tmp_path, capsys):
    """The leakage study's p_A at t = 0.01 s barely moves; a truly constant output (the spool
    position) is NaN with a warning while the other outputs still compute."""
    text = (GSA / "paper_leakage.toml").read_text().replace('outputs = ["p_A", "p_B", "v"]',
                                                            'outputs = ["x_s", "p_A"]')
    path = tmp_path / "leak.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["gsa", "run", str(path), "--out", str(out), "--n", "256", "--bootstrap", "40",
                 "--no-progress"]) == 0
    assert "x_s" in capsys.readouterr().err
    rows = read_indices(out / "indices.csv")
    xs = [float(r["S1"]) for r in rows if r["output"] == "x_s"]
    pa = [float(r["S1"]) for r in rows if r["output"] == "p_A_steady"]
    assert all(math.isnan(v) for v in xs)
    assert all(np.isfinite(pa)) and sum(pa) > 0.8


def test_cli_rejects_bad_n_and_estimator(tmp_path, capsys):
    assert main(["gsa", "run", str(GSA / "ishigami.toml"), "--out", str(tmp_path / "a"), "--n", "1"]) == 2
    assert "--n" in capsys.readouterr().err
    assert main(["gsa", "run", str(GSA / "ishigami.toml"), "--out", str(tmp_path / "b"), "--estimator", "magic"]) == 2
    assert "magic" in capsys.readouterr().err
