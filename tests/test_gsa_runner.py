"""The runner: chunked, resumable, executor-independent evaluation of a study."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from chunkstore import StoreWarning
from gsa import GSAError, Study, analyze, run, saltelli_design
from gsa import testfunctions as tf
from gsa.runner import chunk_key
from gsa.studies import load_study

REPO = Path(__file__).resolve().parents[1]
N = 2**9  # 2560 runs for Ishigami


def ishigami_pair(X):
    """Two outputs, module-level so that it pickles for the process executor."""
    y = tf.ishigami(X)
    return np.c_[y, y**2 + X[:, 2:3]]


@pytest.fixture(scope="module")
def study():
    return Study("ishigami-pair", tf.ishigami_problem(), ishigami_pair, ("y", "y2"))


@pytest.fixture(scope="module")
def design(study):
    return saltelli_design(study.problem, N, seed=42)


@pytest.fixture(scope="module")
def reference(study, design, tmp_path_factory):
    """Uninterrupted inline run with one big chunk."""
    out = tmp_path_factory.mktemp("reference")
    return run(study, design, out, chunk_size=design.n_runs, progress=False)


def indices(result):
    return result.analyze(n_boot=200, seed=3)


def assert_same_indices(a, b):
    for name in ("S1", "S1_lo", "S1_hi", "ST", "ST_lo", "ST_hi"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


class FailAfter:
    """Model that raises on its (n+1)-th call: a crash in the middle of a study."""

    def __init__(self, n):
        self.n, self.calls = n, 0

    def __call__(self, X):
        self.calls += 1
        if self.calls > self.n:
            raise RuntimeError("simulated crash")
        return ishigami_pair(X)


class Counting:
    def __init__(self):
        self.calls = 0

    def __call__(self, X):
        self.calls += 1
        return ishigami_pair(X)


def test_reference_values(reference, design):
    np.testing.assert_array_equal(reference.Y, ishigami_pair(design.X))
    assert reference.chunks_computed == 1 and reference.chunks_reused == 0
    assert not reference.nonfinite


def test_chunked_inline_equals_reference(study, design, reference, tmp_path):
    result = run(study, design, tmp_path, chunk_size=300, progress=False)
    np.testing.assert_array_equal(result.Y, reference.Y)
    assert_same_indices(indices(result), indices(reference))
    files = sorted(p.name for p in (tmp_path / "chunks").glob("*.npz"))
    assert files == [chunk_key(i) + ".npz" for i in range(9)]  # ceil(2560 / 300)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    fp = manifest["fingerprint"]
    assert (fp["study"], fp["N"], fp["seed"], fp["chunk_size"]) == ("ishigami-pair", N, 42, 300)
    assert manifest["layout"]["run_order"] == ["A", "B", "AB_1", "AB_2", "AB_3"]
    assert np.load(tmp_path / "chunks" / f"{chunk_key(8)}.npz")["Y"].shape == (2560 - 8 * 300, 2)


def test_crash_then_resume_equals_uninterrupted(study, design, reference, tmp_path):
    crashing = Study(study.name, study.problem, FailAfter(4), study.output_names)
    with pytest.raises(RuntimeError, match="simulated crash") as err:
        run(crashing, design, tmp_path, chunk_size=256, progress=False)
    assert any("resume" in note for note in err.value.__notes__)
    assert len(list((tmp_path / "chunks").glob("chunk_*.npz"))) == 4

    counting = Counting()
    resumed = run(
        Study(study.name, study.problem, counting, study.output_names),
        design, tmp_path, chunk_size=256, resume=True, progress=False,
    )
    assert counting.calls == 10 - 4  # finished chunks were not recomputed
    assert (resumed.chunks_reused, resumed.chunks_computed) == (4, 6)
    np.testing.assert_array_equal(resumed.Y, reference.Y)
    assert_same_indices(indices(resumed), indices(reference))

    again = run(study, design, tmp_path, chunk_size=256, resume=True, progress=False)
    assert again.chunks_computed == 0
    np.testing.assert_array_equal(again.Y, reference.Y)


def test_two_process_workers_equal_reference(study, design, reference, tmp_path):
    result = run(
        study, design, tmp_path, chunk_size=200, executor="processes", workers=2, progress=False
    )
    np.testing.assert_array_equal(result.Y, reference.Y)
    assert_same_indices(indices(result), indices(reference))


def _slow_study_script(folder: Path) -> Path:
    """A script running a slow 20-chunk study into the folder given as its argument."""
    script = folder / "slow_study.py"
    script.write_text(
        textwrap.dedent(
            """
            import sys, time
            from gsa import Study, run, saltelli_design
            from gsa import testfunctions as tf

            def slow_ishigami(X):
                time.sleep(0.15)
                return tf.ishigami(X)

            problem = tf.ishigami_problem()
            design = saltelli_design(problem, 256, seed=7)
            run(Study("slow", problem, slow_ishigami, ("y",)), design, sys.argv[1],
                chunk_size=64, progress=False)
            """
        )
    )
    return script


def test_sigkill_then_resume_equals_uninterrupted(tmp_path):
    """A run killed with SIGKILL mid-way leaves only complete chunks; resume finishes it."""
    script = _slow_study_script(tmp_path)
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, str(script), str(out)], env=env)
    try:
        deadline = time.monotonic() + 60
        while len(list((out / "chunks").glob("chunk_*.npz"))) < 3:
            assert proc.poll() is None, "the study finished or died before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    finished = len(list((out / "chunks").glob("chunk_*.npz")))
    assert 3 <= finished < 20

    problem = tf.ishigami_problem()
    design = saltelli_design(problem, 256, seed=7)
    result = run(Study("slow", problem, tf.ishigami, ("y",)), design, out,
                 chunk_size=64, resume=True, progress=False)
    assert result.chunks_reused == finished and result.chunks_computed == 20 - finished
    np.testing.assert_array_equal(result.Y, tf.ishigami(design.X))
    assert not list((out / "chunks").glob(".chunk_*"))  # no half-written leftovers
    assert subprocess.run(["sha256sum", "--check", "--quiet", "SHA256SUMS"], cwd=out / "chunks").returncode == 0


def test_damaged_or_empty_chunks_are_named_and_computed_again(study, design, reference, tmp_path):
    """A zero-length chunk used to raise EOFError; random bytes were blamed on the model (NaN/inf)."""
    run(study, design, tmp_path, chunk_size=512, progress=False)
    (tmp_path / "chunks" / f"{chunk_key(1)}.npz").write_bytes(b"")
    damaged = tmp_path / "chunks" / f"{chunk_key(3)}.npz"
    damaged.write_bytes(np.random.default_rng(0).bytes(damaged.stat().st_size))
    with pytest.warns(StoreWarning) as caught:
        result = run(study, design, tmp_path, chunk_size=512, resume=True, progress=False)
    messages = sorted(str(w.message) for w in caught)
    assert len(messages) == 2
    assert "chunk_00001.npz: damaged: its 0 bytes do not hash" in messages[0]
    assert "chunk_00003.npz: damaged:" in messages[1] and "computing it again" in messages[1]
    assert (result.chunks_reused, result.chunks_computed) == (3, 2)
    np.testing.assert_array_equal(result.Y, reference.Y)


def test_a_second_run_into_a_folder_in_use_is_refused(tmp_path):
    """Two concurrent runs into one folder sometimes both ran."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(_slow_study_script(tmp_path)), str(out)],
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 60
        while not list((out / "chunks").glob("chunk_*.npz")):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.02)
        problem = tf.ishigami_problem()
        with pytest.raises(GSAError, match=rf"another run is writing into this folder \(pid {proc.pid} "):
            run(Study("slow", problem, tf.ishigami, ("y",)), saltelli_design(problem, 256, seed=7), out,
                chunk_size=64, resume=True, progress=False)
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.slow
def test_dask_local_cluster_equals_reference(study, design, reference, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        result = run(
            study, design, tmp_path, chunk_size=500, executor="dask",
            scheduler=cluster.scheduler_address, progress=False,
        )
    np.testing.assert_array_equal(result.Y, reference.Y)
    assert_same_indices(indices(result), indices(reference))


# -- refusals ---------------------------------------------------------------------------


def test_resume_refuses_another_seed_study_or_chunking(study, design, tmp_path):
    run(study, design, tmp_path, chunk_size=512, progress=False)
    other_seed = saltelli_design(study.problem, N, seed=43)
    with pytest.raises(GSAError, match=r"different run.*seed is 42 there, 43 here"):
        run(study, other_seed, tmp_path, chunk_size=512, resume=True, progress=False)
    renamed = Study("other-study", study.problem, study.model, study.output_names)
    with pytest.raises(GSAError, match=r"study is 'ishigami-pair' there, 'other-study' here"):
        run(renamed, design, tmp_path, chunk_size=512, resume=True, progress=False)
    with pytest.raises(GSAError, match=r"chunk_size is 512 there, 256 here"):
        run(study, design, tmp_path, chunk_size=256, resume=True, progress=False)
    bigger = saltelli_design(study.problem, 2 * N, seed=42)
    with pytest.raises(GSAError, match=r"N is 512 there, 1024 here"):
        run(study, bigger, tmp_path, chunk_size=512, resume=True, progress=False)


def test_fresh_run_refuses_a_folder_with_chunks_and_deletes_nothing(study, design, tmp_path):
    run(study, design, tmp_path, chunk_size=512, progress=False)
    before = sorted((tmp_path / "chunks").iterdir())
    with pytest.raises(GSAError, match=r"already holds a run \(5 finished chunks\).*resume"):
        run(study, design, tmp_path, chunk_size=512, progress=False)
    assert sorted((tmp_path / "chunks").iterdir()) == before


def nan_when_x1_high(X):
    Y = ishigami_pair(X)
    Y[X[:, 0] > 3.1, 1] = np.nan
    return Y


def test_nonfinite_model_output_is_reported_with_rows(study, design, tmp_path):
    bad = Study("nan-study", study.problem, nan_when_x1_high, study.output_names)
    expected = np.flatnonzero(design.X[:, 0] > 3.1)
    assert len(expected) > 0
    with pytest.raises(GSAError, match=rf"NaN/inf in {len(expected)} of 2560 runs") as err:
        run(bad, design, tmp_path / "a", chunk_size=512, progress=False)
    message = str(err.value)
    assert "outputs affected: 1: 'y2'" in message
    first = expected[0]
    block, m = design.locate(first)
    assert f"run {first} ({block}, sample {m}): x1={design.X[first, 0]:.6g}" in message
    listed = json.loads((tmp_path / "a" / "nonfinite.json").read_text())
    assert [r["run"] for r in listed["runs"]] == expected.tolist()

    result = run(bad, design, tmp_path / "b", chunk_size=512, progress=False, nonfinite="report")
    report = result.nonfinite
    assert report.count == len(expected)
    np.testing.assert_array_equal(report.runs, expected)
    np.testing.assert_array_equal(report.X, design.X[expected])
    assert report.outputs.tolist() == [1]
    with pytest.raises(GSAError, match="NaN/inf"):  # the analysis refuses them too
        result.analyze(n_boot=0)


def test_model_contract_violations(study, design, tmp_path):
    wrong = Study("wrong", study.problem, tf.ishigami, ("y", "y2"))  # returns 1 column
    with pytest.raises(GSAError, match=r"returned shape \(512, 1\) for chunk 0.*expected \(512, 2\)"):
        run(wrong, design, tmp_path / "a", chunk_size=512, progress=False)
    lam = Study("lambda", study.problem, lambda X: ishigami_pair(X), study.output_names)
    with pytest.raises(GSAError, match="picklable model.*module-level function"):
        run(lam, design, tmp_path / "b", executor="processes", progress=False)
    with pytest.raises(GSAError, match="needs a scheduler address"):
        run(study, design, tmp_path / "c", executor="dask", progress=False)
    with pytest.raises(GSAError, match="unknown executor 'threads'"):
        run(study, design, tmp_path / "d", executor="threads", progress=False)


def test_partial_model_in_processes_and_analysis_shortcut(tmp_path):
    problem = tf.sobol_g_problem(3)
    model = functools.partial(tf.sobol_g, a=(0.0, 1.0, 9.0))
    design = saltelli_design(problem, 2**8, seed=1)
    result = run(Study("g", problem, model, ("g",)), design, tmp_path,
                 chunk_size=128, executor="processes", workers=2, progress=False)
    np.testing.assert_array_equal(result.Y, model(design.X))
    direct = analyze(problem, design, model(design.X), n_boot=50, seed=1, output_names=["g"])
    assert_same_indices(result.analyze(n_boot=50, seed=1), direct)


def ishigami_single(X):
    """A single-precision model (module level: picklable): float32 outputs."""
    return ishigami_pair(X).astype(np.float32)


def test_single_precision_chunks_are_stored_as_float32_and_read_back_exactly(design, tmp_path):
    """A float32 model's chunks hold float32 (half the bytes of float64); Y is float64 with the
    same values, from a fresh run and from a resumed one."""
    single = Study("ishigami-single", design.problem, ishigami_single, ("y", "y2"))
    want = ishigami_single(design.X).astype(np.float64)
    fresh = run(single, design, tmp_path, chunk_size=1000, progress=False)
    assert fresh.Y.dtype == np.float64
    np.testing.assert_array_equal(fresh.Y, want)
    with np.load(tmp_path / "chunks" / f"{chunk_key(0)}.npz") as z:
        assert z["Y"].dtype == np.float32 and z["Y"].shape == (1000, 2)
    resumed = run(single, design, tmp_path, chunk_size=1000, resume=True, progress=False)
    assert resumed.chunks_computed == 0
    np.testing.assert_array_equal(resumed.Y, want)


def test_resume_refuses_a_model_described_otherwise(study, design, tmp_path):
    """A model that describes itself (the SAM model: plant, input, step, precision) is part of the
    run's identity: the same study name with the model edited is refused, not mixed."""

    class Described:
        def __init__(self, precision):
            self.precision = precision

        def __call__(self, X):
            return study.model(X)

        def fingerprint(self):
            return f"model-{self.precision}"

    first = Study(study.name, study.problem, Described("float64"), study.output_names)
    run(first, design, tmp_path, chunk_size=512, progress=False)
    edited = Study(study.name, study.problem, Described("float32"), study.output_names)
    with pytest.raises(GSAError, match=r"model is 'model-float64' there, 'model-float32' here"):
        run(edited, design, tmp_path, chunk_size=512, resume=True, progress=False)


def test_sam_model_fingerprint_follows_what_the_outputs_depend_on():
    """The SAM model's fingerprint changes with the precision and the step, not with threads."""
    model = load_study(Path(__file__).resolve().parents[1] / "scenarios" / "gsa" / "paper_leakage.toml").study.model
    assert model.fingerprint() == replace(model, threads=1).fingerprint()
    assert model.fingerprint() != replace(model, precision="float32" if model.precision == "float64"
                                           else "float64").fingerprint()
    assert model.fingerprint() != replace(model, dt=model.dt / 2).fingerprint()
