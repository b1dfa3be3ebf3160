"""`samfdi fdi tune` as a user meets it: the folder it resumes (its chunk store: manifest,
damaged chunks, the user's own files), bad --out / --scheduler, and what metrics.md /
metrics.json / rates.png say. The Monte Carlo itself is replaced by hand-made seeded chunks
(tune.chunk_job monkeypatched), so each test takes well under a second or two."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chunkstore import CHUNK_DIR, MANIFEST, SUMS
from fdi import Thresholds, metrics, rates, tune
from fdi.montecarlo import LEAKS, TUNE, leak_flow_lpm, make_batch
from fdi.thresholds import SHIPPED_THRESHOLDS
from sam import UserError, load_plant
from samfdi.cli import build_parser, main

N_RUNS = 10  # 10 healthy runs, max(5, 10 // 5) = 5 runs per fault case: one chunk each


def _fake_chunk(plant, th, fault, size, n, seed, inputs="standard", reference=False, bound=False):
    """A chunk as chunk_job returns it, made by hand (seeded): healthy runs never alarm; fault
    runs alarm on the right hypothesis 100 ms after their onset and the bank names it there,
    except that in K_int 0.5 L/min the bank names K_extA in run 0 (a wrong isolation)."""
    rng = np.random.default_rng(seed)
    H = len(tune.HYP)
    k0 = np.round(tune.draw_onsets(n, seed) / TUNE.dt).astype(np.int64)
    first = np.full((n, H), -1, dtype=np.int64)
    iso_h = np.full(n, -1, dtype=np.int64)
    if fault is not None:
        right = ("offset+" if size > 0 else "offset-") if fault == "offset" else fault
        first[:, tune.HYP.index(right)] = k0 + 100
        iso_h[:] = tune.HYP.index(right)
        if (fault, size) == ("K_int", 0.5):
            iso_h[0] = tune.HYP.index("K_extA")
    res = {"first": first, "max": np.zeros((n, H, 3)), "m_L": rng.uniform(0, 800, n), "resets": np.zeros(n),
           "k_onset": k0, "iso_h": iso_h, "iso_k": np.where(iso_h >= 0, k0 + 150, -1),
           "conf_k": np.where(iso_h >= 0, k0 + 100, -1), "n_withdrawn": np.zeros(n, dtype=np.int64)}
    if bound:
        res["evidence"] = rng.uniform(0, 10, (n, 5))
    if fault in LEAKS:  # every run's leak passes 0.6 of its rated flow
        res["leak_flow_lpm"] = np.full(n, 0.6 * size)
    return res


@pytest.fixture
def calls(monkeypatch):
    """The (fault, size, n, seed, inputs) of every chunk the tune computes (with the fake Monte Carlo)."""
    made = []

    def fake(*args):
        made.append(args[2:7])
        return _fake_chunk(*args)

    monkeypatch.setattr(tune, "chunk_job", fake)
    return made


def _tune(out: Path, *extra: str) -> int:
    """The tune command in this process (one worker), where the fake Monte Carlo is patched in."""
    return main(["fdi", "tune", "--source", "sam", "--runs", str(N_RUNS), "--workers", "1", "--out", str(out), *extra])


def test_resume_refuses_a_folder_made_with_other_settings(tmp_path, calls, capsys):
    """A folder's manifest holds what its chunks were made with: the same settings resume it
    (nothing computed, same numbers), other --runs, thresholds or plant are refused in one
    line naming the folder and what differs, before anything is computed."""
    out = tmp_path / "t"
    assert _tune(out) == 0
    n_jobs = len(tune.jobs_of(N_RUNS))
    assert len(calls) == n_jobs == 1 + 1 + 17
    man = json.loads((out / MANIFEST).read_text())["fingerprint"]
    assert man["runs"] == N_RUNS and man["layout"] == tune.CHUNK_VERSION
    before = json.loads((out / "metrics.json").read_text())["rows"]
    capsys.readouterr()

    assert _tune(out) == 0  # resume: no --force needed, nothing recomputed
    assert len(calls) == n_jobs
    assert json.loads((out / "metrics.json").read_text())["rows"] == before
    assert f"nothing to compute: all {n_jobs} chunks were already in" in capsys.readouterr().out

    assert main(["fdi", "tune", "--source", "sam", "--runs", "40", "--workers", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert str(out) in err and f"--runs {N_RUNS} there, 40 now" in err and "another --out" in err
    assert len(err.splitlines()) == 1
    other = tmp_path / "other.toml"
    other.write_text(SHIPPED_THRESHOLDS.read_text().replace("drift = 1.0", "drift = 1.5"))
    assert _tune(out, "--thresholds", str(other)) == 2
    assert "other thresholds (--thresholds;" in capsys.readouterr().err
    assert len(calls) == n_jobs  # nothing computed by the refused runs

    plant = load_plant()
    with pytest.raises(UserError, match="another plant"):
        tune.run_tune(plant.replace(B_eff=plant.fluid.B_eff * 1.1), out, n_runs=N_RUNS, progress=False)
    # the --bound mode is tagged apart and shares the folder
    assert _tune(out, "--bound") == 0
    assert len(calls) == 2 * n_jobs


def test_folder_of_an_older_tune_is_refused_untouched(tmp_path, calls):
    """A tune folder written before the chunk store (tune.json, chunks without checksums) is
    refused in one line naming it, before anything is computed; so is a chunks/ folder without a
    manifest, whose origin is unknown. Nothing in either is deleted."""
    out = tmp_path / "t"
    (out / "chunks").mkdir(parents=True)
    (out / "tune.json").write_text(json.dumps({"layout": "x", "runs": N_RUNS}))
    np.savez(out / "chunks" / "healthy_1000_x.npz", first=np.full((N_RUNS, len(tune.HYP)), -1))
    with pytest.raises(UserError, match=rf"^{out}: a tune folder of an older samfdi .*another --out$"):
        tune.run_tune(load_plant(), out, n_runs=N_RUNS, progress=False)
    (out / "tune.json").unlink()
    with pytest.raises(UserError, match=f"{MANIFEST} is missing, so their origin is unknown"):
        tune.run_tune(load_plant(), out, n_runs=N_RUNS, progress=False)
    assert calls == [] and [p.name for p in (out / "chunks").iterdir()] == ["healthy_1000_x.npz"]


def test_damaged_chunk_is_reported_and_recomputed(tmp_path, calls):
    """A chunk cut short (as `truncate -s 500` does) is reported in one line and recomputed;
    the metrics equal those of the undamaged folder."""
    out = tmp_path / "t"
    tune.run_tune(load_plant(), out, n_runs=N_RUNS, progress=False)
    rows0 = json.loads((out / "metrics.json").read_text())["rows"]
    job = tune.jobs_of(N_RUNS)[3]
    path = out / CHUNK_DIR / f"{tune.chunk_key(job)}.npz"
    with open(path, "r+b") as f:
        f.truncate(500)
    n = len(calls)
    with pytest.warns(UserWarning, match=rf"{path.name}: damaged: .*; computing it again"):
        tune.run_tune(load_plant(), out, n_runs=N_RUNS, progress=False)
    assert calls[n:] == [job[1:]]
    assert json.loads((out / "metrics.json").read_text())["rows"] == rows0


def test_chunks_are_written_atomically(tmp_path, calls, monkeypatch):
    """A chunk whose write fails half way (disk full, kill) leaves no file under the chunk's
    name, nor a checksum for it, so the resume does not take a partial file for a finished chunk;
    the user gets one line saying why."""
    def broken(stream, array, **kw):
        stream.write(b"\x93NUMPY partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np.lib.format, "write_array", broken)
    out = tmp_path / "t"
    with pytest.raises(UserError, match="No space"):
        tune.run_tune(load_plant(), out, n_runs=N_RUNS, progress=False)
    assert [p.name for p in (out / CHUNK_DIR).iterdir()] == [SUMS] and (out / CHUNK_DIR / SUMS).read_text() == ""


@pytest.mark.parametrize("where", ["file", "under_file", "proc"])
def test_bad_out_is_one_line_before_any_computing(tmp_path, calls, capsys, where):
    """--out that is a file, lies under a file, or cannot be created: exit 2, one line."""
    (tmp_path / "some.csv").write_text("t,u\n")
    if where == "proc" and not Path("/proc").is_dir():
        pytest.skip("no /proc")
    out = {"file": tmp_path / "some.csv", "under_file": tmp_path / "some.csv" / "sub", "proc": Path("/proc/x")}[where]
    assert _tune(out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(out) in err and "--out" in err
    assert calls == [] and (tmp_path / "some.csv").read_text() == "t,u\n"


def test_unreachable_scheduler_is_one_line(tmp_path, calls, capsys):
    """A dask scheduler that does not answer: exit 2 with 'cannot reach the dask scheduler'."""
    dask = pytest.importorskip("dask")
    pytest.importorskip("dask.distributed")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # the default waits 30 s
        assert _tune(tmp_path / "t", "--scheduler", "tcp://127.0.0.1:1") == 2
    err = capsys.readouterr().err.strip()
    assert "cannot reach the dask scheduler at tcp://127.0.0.1:1: " in err and len(err.splitlines()) == 1
    assert calls == []


def test_users_files_are_not_overwritten_without_force(tmp_path, calls, capsys):
    """A folder that is no tune folder but holds a file the tune writes is refused (the file
    unchanged); --force writes there; the tune folder it then is resumes without --force."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "metrics.md").write_text("my notes\n")
    (out / "rates.png").write_bytes(b"my figure")
    assert _tune(out) == 2
    err = capsys.readouterr().err
    assert "already holds metrics.md, rates.png" in err and "--force" in err
    assert (out / "metrics.md").read_text() == "my notes\n" and (out / "rates.png").read_bytes() == b"my figure"
    assert calls == [] and not (out / CHUNK_DIR).exists()
    assert _tune(out, "--force") == 0
    assert (out / "metrics.md").read_text().startswith("# FDI tuning metrics")
    assert _tune(out) == 0


def _hand_made_chunks(bound: bool) -> tuple:
    """Hand-made chunks (one per job of N_RUNS runs): (jobs, tag, chunk key -> arrays)."""
    jobs, tag = tune.jobs_of(N_RUNS), tune.mode_tag(False, bound)
    return jobs, tag, {tune.chunk_key(j, tag): _fake_chunk(None, None, *j[1:], bound=bound) for j in jobs}


def test_metrics_json_is_valid_json_with_wrong_isolation(tmp_path):
    """metrics.json has no NaN (null where nothing was measured: a fault case never detected
    has no mean delay) and gives the wrong isolations: 1 of the 5 K_int 0.5 L/min runs, all
    detected within 1 s, was named K_extA -> 0.2; overall 1 of the 16 detected cases x 5 runs."""
    jobs, tag, chunks = _hand_made_chunks(False)
    d = chunks[tune.chunk_key(next(j for j in jobs if j[0] == "K_extB_0.1"), tag)]
    for key in ("first", "conf_k", "iso_h", "iso_k"):  # never alarmed: no delay to average
        d[key][:] = -1
    tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), Thresholds.shipped())
    text = (tmp_path / "metrics.json").read_text()
    m = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in metrics.json"))
    rows = {(r["fault"], r["size"]): r for r in m["rows"]}
    assert rows[("K_extB", 0.1)]["mean_delay_s"] is None and rows[("K_extB", 0.1)]["wrong_isolation"] is None
    assert rows[("K_int", 0.5)]["wrong_isolation"] == 0.2 and rows[("K_int", 0.5)]["isolated_within_1s"] == 0.8
    assert rows[("K_int", 1.0)]["wrong_isolation"] == 0.0
    assert (m["isolation_decisions_within_1s"], m["wrong_isolation_decisions"]) == (16 * 5, 1)
    assert m["wrong_isolation_rate"] == pytest.approx(1 / 80)


def test_withdrawn_alarms_are_not_false_alarms(tmp_path):
    """Healthy runs whose CUSUM alarmed (g/h above 1) count as false alarms only when the bank
    confirmed the alarm (conf_k >= 0): of 3 alarmed runs 1 stood -> false-alarm rate 1 / n, the
    trigger rate 3 / n; metrics.md gives both. A fault run whose only confirmed alarm is 1.5 s
    after the onset is not detected within 1 s, whatever its CUSUM did."""
    jobs, tag, chunks = _hand_made_chunks(False)
    healthy = [j for j in jobs if j[0] == "healthy"]
    d = chunks[tune.chunk_key(healthy[0], tag)]
    d["max"][:3, 0, 2] = 2.0  # three CUSUM alarms ...
    d["conf_k"][0] = 5000  # ... one of which the bank confirmed
    d = chunks[tune.chunk_key(next(j for j in jobs if j[0] == "K_extA_1"), tag)]
    d["conf_k"][0] = d["k_onset"][0] + 1500
    d = chunks[tune.chunk_key(next(j for j in jobs if j[0] == "healthy_long"), tag)]
    d["max"][:2, 1, 2] = 1.5  # the long cycles: two CUSUM alarms, both confirmed
    d["conf_k"][:2] = 9000
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), Thresholds.shipped())
    n, n_long = m["healthy_runs"], m["long_cycles"]["runs"]
    assert (n, n_long) == (N_RUNS, tune.long_cycle_runs(N_RUNS))
    assert m["false_alarm_rate"] == pytest.approx(1 / n) and m["trigger_rate"] == pytest.approx(3 / n)
    assert m["long_cycles"]["false_alarm_rate"] == m["long_cycles"]["trigger_rate"] == pytest.approx(2 / n_long)
    row = next(r for r in m["rows"] if (r["fault"], r["size"]) == ("K_extA", 1.0))
    assert row["detected_within_1s"] == pytest.approx(1 - 1 / row["runs"])
    md = (tmp_path / "metrics.md").read_text()
    assert f"that the bank confirmed per run): {1 / n:.3f}" in md and f"withdrawn): {3 / n:.3f}" in md
    long_line = next(line for line in md.splitlines() if line.startswith("Held-out healthy runs of the issue's 20-60 s"))
    assert f"{n_long} x 20 s" in long_line and f"per run): {2 / n_long:.3f}" in long_line
    assert "(the h were set for 0.1 of the nuisance study's healthy runs)" in md  # the shipped trigger level
    # counted and judged on their exact intervals (fdi.rates): 3 of 15 runs is shown above 1 %
    assert (m["false_alarms"], m["long_cycles"]["false_alarms"], m["all_healthy"]["false_alarms"]) == (1, 2, 3)
    assert m["all_healthy"]["runs"] == n + n_long and m["all_healthy"]["false_alarm_verdict"] == "not met"
    lo, hi = rates.interval(3, n + n_long)
    assert f"All {n + n_long} healthy runs: false-alarm rate {3 / (n + n_long):.3f} (3 of {n + n_long}; 95 % interval " \
           f"{lo:.4f}-{hi:.4f}; <= 0.01: not met)" in md
    k = row["isolated_runs"]
    assert k == round(row["isolated_within_1s"] * row["runs"]) and row["isolated_ci"] == list(rates.interval(k, row["runs"]))
    assert row["isolated_verdict"] == rates.verdict(k, row["runs"], TUNE.target_rate)


def test_isolation_by_the_flow_the_leak_passed(tmp_path):
    """Each leak run passes 0.6 of its rated flow (hand-made chunks): K_int 0.1 / 0.25 / 0.5 / 1
    L/min fall in the 0.05-0.1, 0.15-0.25, 0.25-0.5 and 0.5-1 L/min bins, 5 runs each, and the
    one wrong isolation (K_int 0.5 L/min) is missing from its bin; offsets have no flow."""
    jobs, tag, chunks = _hand_made_chunks(False)
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), Thresholds.shipped())
    assert m["flow_bins_lpm"] == TUNE.flow_bins_lpm and set(m["isolated_by_flow"]) == set(LEAKS)
    assert m["isolated_by_flow"]["K_int"] == [[0, 0], [5, 5], [0, 0], [5, 5], [4, 5], [5, 5], [0, 0]]
    row = next(r for r in m["rows"] if (r["fault"], r["size"]) == ("K_extB", 0.25))
    assert row["leak_flow_median_lpm"] == pytest.approx(0.15)
    assert all("isolated_by_flow" not in r for r in m["rows"] if r["fault"] == "offset")
    md = (tmp_path / "metrics.md").read_text()
    assert "| leak | < 0.05 L/min | 0.05-0.1 L/min | 0.1-0.15 L/min |" in md
    assert "| K_int | - | 5/5 | - | 5/5 | 4/5 | 5/5 | - |" in md


@pytest.mark.parametrize("fault", LEAKS)
def test_leak_flow_is_the_leak_law_at_the_runs_own_pressures(fault):
    """leak_flow_lpm of simulated runs (0.25 L/min at 10 MPa, stepping in at each run's onset): the
    rated flow times the mean sqrt(|dp| / 10 MPa) over the second after the onset, dp the true
    pressure difference the leak sees (tank at 0 Pa gauge), written out here; in the second
    before the onset the leak passes nothing."""
    n = 4
    runs = make_batch(load_plant(), n, 7, fault=fault, size=0.25, duration=4.0, onset=tune.draw_onsets(n, 7))
    k0 = runs.truth["k_onset"]
    p_A, p_B = runs.truth["p_A"], runs.truth["p_B"]
    dp = {"K_int": p_A - p_B, "K_extA": p_A, "K_extB": p_B}[fault]
    expect = [0.25 * np.mean(np.sqrt(np.abs(dp[b, k:k + 1000]) / 10e6)) for b, k in enumerate(k0)]
    np.testing.assert_allclose(leak_flow_lpm(runs, fault, k0, 1.0), expect, rtol=1e-12)
    assert (leak_flow_lpm(runs, fault, k0 - 1000, 1.0) == 0.0).all()


def test_metrics_md_tables_with_units_and_no_exclusive_column(tmp_path):
    """metrics.md: no 'exclusive' column with likelihood isolation (it equals 'isolated'), a
    'wrong isolation' column and overall line, the smallest sizes as tables in L/min and %
    (also the bound's)."""
    jobs, tag, chunks = _hand_made_chunks(True)
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), Thresholds.shipped())
    md = (tmp_path / "metrics.md").read_text()
    assert "exclusive" not in md and "{'" not in md
    header = next(line for line in md.splitlines() if line.startswith("| fault | size | runs"))
    i = header.strip("|").split(" | ").index("wrong isolation")
    k_int_05 = next(line for line in md.splitlines() if line.startswith("| K_int | +0.5 L/min | 5 |"))
    assert k_int_05.strip("|").split(" | ")[i].strip() == "0.20"
    assert "(fault runs detected within 1 s): 85, of which wrong (named another fault hypothesis): 1 = 0.012" in md
    # every size is isolated in all runs but K_int 0.5 L/min (80 %): K_int from 1 L/min on
    assert "| all loads | 1 L/min | 0.1 L/min | 0.1 L/min | 1 % | 1 % |" in md
    assert m["smallest_detected_and_isolated_95pct_within_1s"]["offset+"] == 0.01
    assert "| ours: detected and isolated within 1 s | 1 L/min | 0.1 L/min | 0.1 L/min | 1 % | 1 % |" in md
    assert "| bound: isolable |" in md
    assert "--reference" not in md  # a --bound tune calibrates nothing


def test_rates_figure_shows_each_rate_with_its_interval(tmp_path, saved_figures):
    """rates.png (was roc.png, 17 near-identical curves): one panel per fault with the detected and
    the detected-and-isolated share of runs against size, each point k / n with its exact
    interval as a bar (K_int 0.5 L/min: 4 of 5 isolated), and a panel of false alarms per healthy
    run with theirs against the stated level."""
    jobs, tag, chunks = _hand_made_chunks(False)
    d = chunks[tune.chunk_key(next(j for j in jobs if j[0] == "healthy"), tag)]
    d["max"][:1, 0, 2], d["conf_k"][0] = 2.0, 5000  # one false alarm of 10
    m = tune.summarise(tmp_path, tune.gather(chunks, jobs, tag), Thresholds.shipped())
    fig = saved_figures[-1]
    assert (tmp_path / "rates.png").stat().st_size > 10_000 and not (tmp_path / "roc.png").exists()
    panels = {ax.get_title(): ax for ax in fig.axes}
    assert set(panels) == {"internal leak, A to B (K_int)", "external leak out of A (K_extA)",
                           "external leak out of B (K_extB)", "valve spool offset, + side (offset+)",
                           "valve spool offset, - side (offset-)", "false alarms per healthy run"}
    detected, isolated = panels["internal leak, A to B (K_int)"].containers
    assert isolated.get_label() == "detected and isolated within 1 s"
    rows = [r for r in m["rows"] if r["fault"] == "K_int"]
    np.testing.assert_allclose(isolated.lines[0].get_ydata(), [100 * r["isolated_within_1s"] for r in rows])
    assert [r["isolated_within_1s"] for r in rows] == [1.0, 1.0, 0.8, 1.0]
    bars = np.array([seg[:, 1] for seg in isolated.lines[2][0].get_segments()])
    np.testing.assert_allclose(bars, 100 * np.array([rates.interval(k, 5) for k in (5, 5, 4, 5)]))
    (fa,) = panels["false alarms per healthy run"].containers[:1]
    lo, hi = m["false_alarm_ci"]
    assert fa.lines[0].get_ydata()[0] == pytest.approx(10.0) and m["false_alarms"] == 1
    np.testing.assert_allclose(fa.lines[2][0].get_segments()[0][:, 1], [100 * lo, 100 * hi])


def test_worker_pool_after_a_simulation_in_the_same_process(tmp_path):
    """A forked worker of a process that has run the simulator's OpenMP loop is killed by libgomp
    ("fork() called from a process already using GNU OpenMP"), so the tune's pool must not fork
    there: the chunk store's pool spawns its workers. After a simulation in this process, two
    workers compute real chunks into the store, identical to the same chunks computed here."""
    from chunkstore import Store

    plant, th = load_plant(), Thresholds.shipped()
    make_batch(plant, 2, 1, duration=0.1)  # the simulator's parallel loop runs in this process
    jobs = [("healthy", None, 0.0, 2, 1000, "standard"), ("K_extA_1", "K_extA", 1.0, 2, 510_000, "standard")]
    th4 = th.with_(run_length_s=4.0)
    with Store.open(tmp_path, {"test": "pool"}) as store:
        tune.compute_chunks(store, plant, th4, jobs, "t", workers=2)
        for job in jobs:
            got = store.load(tune.chunk_key(job, "t"))
            here = tune.chunk_job(plant, th4, *job[1:])
            assert set(got) == set(here) | {"compute_s"}  # and the seconds it took (tune.timed_chunk_job)
            for key in here:
                np.testing.assert_array_equal(got[key], here[key], err_msg=f"{job[0]} {key}")


def test_help_states_the_workers_and_runs_rules():
    """--workers is a process pool (dask only with --scheduler); --runs states the fault-run
    rule of jobs_of, checked against it."""
    sub = build_parser()._subparsers._group_actions[0].choices["fdi"]._subparsers._group_actions[0].choices["tune"]
    helps = {a.dest: a.help for a in sub._actions}
    assert "process pool" in helps["workers"] and "(dask)" not in helps["workers"]
    assert "max(5, N // 5) per fault type and size" in helps["runs"] and "max(5, N // 2) more" in helps["runs"]
    assert "force" in helps
    for n in (5, 10, 24, 25, 26, 230):
        per_case = sum(j[3] for j in tune.jobs_of(n) if j[0] == "K_int_0.25")
        assert per_case == max(5, n // 5) and sum(j[3] for j in tune.jobs_of(n) if j[0] == "healthy") == n
        assert sum(j[3] for j in tune.jobs_of(n) if j[0] == "healthy_long") == max(5, n // 2)


def test_smallest_size_needs_every_larger_size_and_runs():
    """A size is met only when it and every larger tested size reach 95 %; a load third with no
    runs of a size (rate NaN) is not a pass."""
    from fdi.metrics import smallest_met
    rows = [{"size": s, "r": r} for s, r in ((0.1, 1.0), (0.25, 0.96), (0.5, 0.97), (1.0, 0.99))]
    passes = lambda r: r["r"] >= 0.95  # noqa: E731  as the tune's rule for the point rate
    assert smallest_met(rows, passes) == 0.1
    rows[2]["r"] = 0.9  # 0.5 fails: 0.1 and 0.25 passing below it are lucky draws
    assert smallest_met(rows, passes) == 1.0
    rows[3]["r"] = float("nan")  # no 1 L/min runs in this third
    assert smallest_met(rows, passes) is None


def test_a_resumed_tune_states_what_all_its_runs_cost(tmp_path, calls, capsys):
    """Each chunk keeps the seconds it took; a tune resumed after losing three chunks says that
    its wall time covers only the part it computed, and gives the worker-seconds per 1000 runs
    of all runs from the chunks' own timings (chunks of an older samfdi, without one, are not
    counted)."""
    chunks = {"a": {"compute_s": np.float64(2.0)}, "b": {"compute_s": np.float64(3.0)}, "c": {}}
    tm = tune.timing(chunks, {"a": 10, "b": 5, "c": 5}, ["b"], 4.0, 2)
    assert (tm["runs_computed"], tm["runs"], tm["runs_timed"], tm["worker_s"]) == (5, 20, 15, 5.0)
    assert tm["s_per_1000_runs"] == 800.0 and tm["worker_s_per_1000_runs"] == pytest.approx(1000 / 3)
    assert tune.timing_text(tm) == ("5 runs in 4.0 s with 2 worker(s) (800 s per 1000 runs: this run's part only; "
                                    "2 of 3 chunks were resumed from the store); all 20 runs: 15 runs timed in their "
                                    "chunks: 5.0 worker-s (333 worker-s per 1000 runs)")

    out = tmp_path / "t"
    assert _tune(out) == 0
    lost = [tune.chunk_key(j) for j in tune.jobs_of(N_RUNS)[2:5]]
    for key in lost:
        (out / CHUNK_DIR / f"{key}.npz").unlink()
    capsys.readouterr()
    assert _tune(out) == 0
    said = capsys.readouterr().out.splitlines()[-2]
    tm = json.loads((out / "metrics.json").read_text())["timing"]
    n_lost = 3 * 5  # three fault cases of 5 runs
    assert tm["runs_computed"] == n_lost and tm["runs_timed"] == tm["runs"] == N_RUNS + 5 + 17 * 5
    assert said.startswith(f"{n_lost} runs in ") and "this run's part only; 16 of 19 chunks were resumed" in said
    assert said.endswith(f"all {tm['runs']} runs: {tm['runs']} runs timed in their chunks: {tm['worker_s']:.1f} "
                         f"worker-s ({tm['worker_s_per_1000_runs']:.0f} worker-s per 1000 runs)")
    assert tm["worker_s"] == pytest.approx(sum(float(np.load(p)["compute_s"]) for p in (out / CHUNK_DIR).glob("*.npz")))


def test_workers_default_to_every_core_as_gsa_run(tmp_path, monkeypatch):
    """`fdi tune` and `fdi thresholds` without --workers use every core, as `gsa run` does."""
    import os
    from fdi import cli

    seen = {}
    monkeypatch.setattr(cli, "run_tune", lambda *a, workers, **k: seen.setdefault("tune", workers) and 1 / 0)
    monkeypatch.setattr(cli, "compute_thresholds", lambda *a, workers, **k: seen.setdefault("thresholds", workers) and 1 / 0)
    for cmd in ("tune", "thresholds"):
        with pytest.raises(ZeroDivisionError):
            main(["fdi", cmd, "--out", str(tmp_path / cmd)])
    assert seen == {"tune": os.cpu_count(), "thresholds": os.cpu_count()}
    gsa = build_parser()._subparsers._group_actions[0].choices["gsa"]._subparsers._group_actions[0].choices["run"]
    assert "default: all" in {a.dest: a.help for a in gsa._actions}["workers"]
