"""Replay speed: the batched UKF (one sam.step_blocks call per sample for all sigma
points) against a plain filterpy loop calling the model once per sigma point.

    PYTHONPATH=. python benchmarks/bench_fdi.py

It ends with a 3-minute recording: its CSV read and the replay's CSV output, against what a
user would otherwise write (np.genfromtxt, csv.writer) and a field-by-field reader, then the
whole `samfdi fdi replay` path (read, filter, diagnosis, files, figure).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from sam import load_plant  # noqa: E402
from fdi import POS_THETA, FilterConfig, Thresholds, diagnose, replay, replay_recording, run_filter  # noqa: E402
from fdi.filter import initial_mean  # noqa: E402
from fdi.montecarlo import make_batch  # noqa: E402
from fdi.offline import write_csv  # noqa: E402
from fdi.statistics import statistics  # noqa: E402
from fdi.synth import input_signal, lpm, profile, simulate_runs  # noqa: E402
from fdi.tune import chunk_job, jobs_of  # noqa: E402


def main() -> None:
    plant = load_plant()
    dt, T = 1e-3, 4001
    t = np.arange(T) * dt
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    runs = simulate_runs(plant.vector()[None], u, dt, faults={"K_extA": profile("step", lpm(1), t, 2.0)})
    run_filter(runs.inp)  # compile / load the cache
    best = min(_timed(lambda: run_filter(runs.inp)) for _ in range(3))
    print(f"batched UKF, 4 s at 1 kHz: {best:.3f} s  -> {4.0 / best:.0f}x real time")

    from test_fdi_ukf import _filterpy_reference
    cfg = FilterConfig()
    z0 = initial_mean(runs.inp, cfg)
    P0 = np.diag((cfg.noise_vectors()[1] / cfg.state_scale()) ** 2)[None].copy()
    n_ref = 400  # the plain loop is slow: time 0.4 s and scale
    from dataclasses import replace
    short = replace(runs.inp, u=runs.inp.u[:, :n_ref], pA=runs.inp.pA[:, :n_ref], pB=runs.inp.pB[:, :n_ref],
                    pos=runs.inp.pos[:, :n_ref])
    ref = _timed(lambda: _filterpy_reference(short, cfg, z0, P0)) * (T / n_ref)
    print(f"filterpy loop (model once per sigma point), 4 s at 1 kHz: {ref:.2f} s  -> {4.0 / ref:.1f}x real time")
    print(f"speed-up: {ref / best:.0f}x")

    mc = make_batch(plant, 100, 1)
    run_filter(mc.inp)
    tb = _timed(lambda: run_filter(mc.inp))
    print(f"batched over 100 recordings of 4 s (one core): {tb:.2f} s = {tb / 100 * 1e3:.0f} ms per run "
          f"-> 1000 runs ~ {tb * 10:.0f} s on one core")

    _bench_isolation(plant, runs)
    _bench_long_recording(plant)


def _bench_isolation(plant, runs) -> None:
    """Replay with the likelihood isolation (filter, CUSUM, reference and bank over the record)
    and the tune's work per run (the bank decides within 1 s of the alarm) on alarmed runs."""
    th = Thresholds.shipped()

    def replay_once():
        out = run_filter(runs.inp)
        return diagnose(out, th, 0, statistics(out, th))

    replay_once()
    br = min(_timed(replay_once) for _ in range(3))
    d = replay_once()
    print(f"filter + diagnosis with likelihood isolation ({d.status}: {d.isolated}), 4 s at 1 kHz: {br:.3f} s "
          f"-> {4.0 / br:.0f}x real time")
    # what `samfdi fdi replay` runs (input checks, observability check, filter, residuals, every
    # stage of the diagnosis), without writing files: the "one replay" figure
    from sam import Recording
    t = np.arange(runs.inp.u.shape[1]) * runs.inp.dt
    rec = Recording(t, {"u": runs.inp.u[0], "pA": runs.inp.pA[0], "pB": runs.inp.pB[0], "theta": runs.inp.pos[0]},
                    source="bench")
    replay(rec, plant)
    times = [_timed(lambda: replay(rec, plant)) for _ in range(7)]
    print(f"fdi.replay (every check and stage, no files), 4 s at 1 kHz: median {np.median(times):.3f} s, "
          f"best {min(times):.3f} s -> {4.0 / np.median(times):.0f}x real time (median)")
    jobs = jobs_of(230)  # the tune of docs/fdi.md: 230 healthy + 46 runs per fault case
    n_h = sum(j[3] for j in jobs if j[1] is None)
    n_f = sum(j[3] for j in jobs if j[1] is not None)
    chunk_job(plant, th, "K_extA", 0.5, 4, 2)  # compile / load the cache
    th_ = _timed(lambda: chunk_job(plant, th, None, 0.0, 50, 1000))
    tf_ = _timed(lambda: chunk_job(plant, th, "K_int", 0.25, 50, 500_000))
    per_1000 = (n_h * th_ + n_f * tf_) / 50 / (n_h + n_f) * 1000
    th4 = th.with_(run_length_s=4.0)  # the measure: every run 4 s long
    t4_ = _timed(lambda: chunk_job(plant, th4, None, 0.0, 50, 1000))
    per_1000_4s = (n_h * t4_ + n_f * tf_) / 50 / (n_h + n_f) * 1000
    print(f"tune work per run (simulation, filter, CUSUM, isolation; one core): healthy {th.derived.run_length_s:g} s "
          f"{th_ / 50 * 1e3:.0f} ms, healthy 4 s {t4_ / 50 * 1e3:.0f} ms, faulty 4 s {tf_ / 50 * 1e3:.0f} ms -> "
          f"1000 runs of the tune's mix ~ {per_1000:.0f} s on one core, ~ {per_1000 / 2:.0f} s on 2 cores; "
          f"1000 runs of 4 s ~ {per_1000_4s / 2:.0f} s on 2 cores if every faulty run were as slow as these "
          f"(each alarms and runs the bank; the tune's own mix end to end: benchmarks/bench_tune.py)")


def _bench_long_recording(plant, duration_s: float = 180.0) -> None:
    """A 3-minute 1 kHz recording: where a long replay's time goes besides the filter."""
    import csv
    import math
    import tempfile

    from sam import Recording, read_recording, write_recording
    from sam import recording_csv as csv_reader

    t = np.arange(int(round(duration_s * 1e3)) + 1) * 1e-3
    u = input_signal("sine", t, amplitude=3.0, frequency=1.0 / 40.0)
    runs = simulate_runs(plant.vector()[None], u, 1e-3)
    pos = "theta" if runs.inp.pos_kind == POS_THETA else "x"
    sig = {"u": runs.inp.u[0], "pA": runs.inp.pA[0], "pB": runs.inp.pB[0], pos: runs.inp.pos[0]}
    with tempfile.TemporaryDirectory() as tmp:
        path = write_recording(Path(tmp) / "long.csv", Recording(t, sig, source="bench"))
        ours = _median(lambda: read_recording(path))
        fast_table = csv_reader._fast_table
        csv_reader._fast_table = lambda lines, n: None  # the field-by-field reader alone
        careful = _median(lambda: read_recording(path), 1)
        csv_reader._fast_table = fast_table
        gen = _median(lambda: np.genfromtxt(path, delimiter=",", names=True), 1)
        print(f"read a {duration_s:g} s CSV recording ({len(t)} rows): ours {ours:.2f} s, np.genfromtxt {gen:.2f} s "
              f"({gen / ours:.1f}x), field by field {careful:.2f} s ({careful / ours:.1f}x)")
        table = {f"c{j}": np.random.default_rng(j).normal(size=len(t)) for j in range(57)}  # a replay's 57 columns
        out = Path(tmp) / "out.csv"
        ours = _median(lambda: write_csv(out, table), 1)
        data = np.column_stack(list(table.values()))
        tuned = _median(lambda: _write_per_row(out, table), 1)

        def by_csv_writer():  # the standard library's writer
            with out.open("w", newline="") as f:
                w = csv.writer(f)
                w.writerow(list(table))
                for row in data:
                    w.writerow([repr(float(x)) if math.isfinite(x) else "nan" for x in row])

        old = _median(by_csv_writer, 1)
        print(f"write a replay's CSV output ({data.size / 1e6:.1f} M values): ours (np.savetxt '%.17g') {ours:.1f} s, "
              f"repr joined per row {tuned:.1f} s ({tuned / ours:.1f}x), csv.writer of repr "
              f"{old:.1f} s ({old / ours:.1f}x)")
        rec = read_recording(path)
        t0 = time.perf_counter()
        diag = replay_recording(rec, plant, Path(tmp) / "replay")
        whole = time.perf_counter() - t0
        n_withdrawn = len(diag.likelihood.get("withdrawn_alarms_s", []))
        print(f"samfdi fdi replay of the {duration_s:g} s recording (filter, diagnosis, files, figure; read not "
              f"included): {whole:.1f} s -> {duration_s / whole:.1f}x real time ({diag.status}; the bank judged "
              f"{n_withdrawn} withdrawn alarms, the tests restarted after each)")


def _write_per_row(path: Path, cols: dict) -> None:
    """The hand-written alternative to np.savetxt that was measured: repr joined per row."""
    data = np.column_stack(list(cols.values())).tolist()
    with path.open("w") as f:
        f.write(",".join(cols) + "\n")
        f.write("\n".join(",".join(map(repr, row)) for row in data) + "\n")


def _median(f, repeats: int = 3) -> float:
    return float(np.median([_timed(f) for _ in range(repeats)]))


def _timed(f) -> float:
    t0 = time.perf_counter()
    f()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
