"""The chunk store: atomic checksummed chunks, manifest, lock, workers that die with their parent."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import scipy.linalg  # noqa: F401  (a worker unpickling blas_threads loads scipy's own BLAS)
from threadpoolctl import threadpool_info

from chunkstore import LockedError, Store, StoreError, StoreWarning, compute, process_pool

REPO = Path(__file__).resolve().parents[1]
FP = {"job": "squares", "n": 4}


def squares(i: int, n: int) -> dict:
    """Module level, so that worker processes can unpickle it."""
    return {"y": np.arange(i * n, (i + 1) * n, dtype=float) ** 2, "i": np.array(i)}


TASKS = {f"part_{i:02d}": (i, 4) for i in range(6)}


def collect(chunks) -> dict:
    return {c.key: c for c in chunks}


def test_a_run_saves_checksummed_chunks_and_resumes_them(tmp_path):
    with Store.open(tmp_path, FP) as store:
        first = collect(compute(store, squares, TASKS))
    assert not any(c.reused for c in first.values())
    np.testing.assert_array_equal(first["part_05"].arrays["y"], np.arange(20, 24) ** 2)
    # the checksums are the standard tool's format
    check = subprocess.run(["sha256sum", "--check", "SHA256SUMS"], cwd=tmp_path / "chunks",
                           capture_output=True, text=True)
    assert check.returncode == 0 and check.stdout.count(": OK") == 6
    with Store.open(tmp_path, FP, resume=True) as store:
        again = collect(compute(store, squares, TASKS))
    assert all(c.reused for c in again.values())
    for key in TASKS:
        np.testing.assert_array_equal(again[key].arrays["y"], first[key].arrays["y"])


@pytest.mark.parametrize("damage, words", [
    (lambda p: p.write_bytes(np.random.default_rng(1).bytes(p.stat().st_size)), "do not hash to the sha256"),
    (lambda p: p.write_bytes(b""), "its 0 bytes do not hash"),
    (lambda p: p.write_bytes(p.read_bytes()[:-7]), "do not hash to the sha256"),
])
def test_a_damaged_chunk_is_named_and_computed_again(tmp_path, damage, words):
    with Store.open(tmp_path, FP) as store:
        collect(compute(store, squares, TASKS))
    damage(tmp_path / "chunks" / "part_03.npz")
    with Store.open(tmp_path, FP, resume=True) as store:
        with pytest.warns(StoreWarning, match=rf"part_03.npz: damaged: .*{words}.*changed or truncated on "
                                              rf"disk.*computing it again"):
            chunks = collect(compute(store, squares, TASKS))
    assert not chunks["part_03"].reused and sum(c.reused for c in chunks.values()) == 5
    np.testing.assert_array_equal(chunks["part_03"].arrays["y"], np.arange(12, 16) ** 2)


def test_a_chunk_without_a_recorded_checksum_is_computed_again(tmp_path):
    """Killed between the rename and the checksum line: the chunk is not counted as finished."""
    with Store.open(tmp_path, FP) as store:
        collect(compute(store, squares, TASKS))
    sums = tmp_path / "chunks" / "SHA256SUMS"
    sums.write_text("".join(line + "\n" for line in sums.read_text().splitlines() if "part_02" not in line)
                    + "0123abc torn li")
    with Store.open(tmp_path, FP, resume=True) as store:
        chunks = collect(compute(store, squares, TASKS))
    assert [k for k, c in chunks.items() if not c.reused] == ["part_02"]


def test_the_folder_refuses_another_run_a_fresh_start_and_stray_chunks(tmp_path):
    with Store.open(tmp_path / "a", FP) as store:
        collect(compute(store, squares, TASKS))
    with pytest.raises(StoreError, match=r"already holds a run \(6 finished chunks\).*Nothing was deleted"):
        Store.open(tmp_path / "a", FP)
    with pytest.raises(StoreError, match=r"holds a different run.*n is 4 there, 5 here"):
        Store.open(tmp_path / "a", {**FP, "n": 5}, resume=True)
    (tmp_path / "b" / "chunks").mkdir(parents=True)
    (tmp_path / "b" / "chunks" / "x.npz").write_bytes(b"PK")
    with pytest.raises(StoreError, match="manifest.json is missing"):
        Store.open(tmp_path / "b", FP, resume=True)
    (tmp_path / "file").write_text("")
    with pytest.raises(StoreError, match="exists and is not a folder"):
        Store.open(tmp_path / "file", FP)
    with pytest.raises(StoreError, match="cannot create the folder"):
        Store.open("/proc/chunkstore-test", FP)
    with Store.open(tmp_path / "c", FP) as store:
        with pytest.raises(StoreError, match="chunk key '../x'"):
            collect(compute(store, squares, {"../x": (0, 1)}))
        with pytest.raises(StoreError, match="workers must be an integer >= 1, got 0"):
            collect(compute(store, squares, TASKS, executor="processes", workers=0))


def test_a_second_process_is_locked_out_until_the_first_ends(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, time
            from chunkstore import Store
            with Store.open({str(tmp_path)!r}, {FP!r}):
                print("locked", flush=True)
                time.sleep(60)
        """)], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(LockedError, match=rf"another run is writing into this folder \(pid {holder.pid} "):
            Store.open(tmp_path, FP, resume=True)
    finally:
        holder.send_signal(signal.SIGKILL)  # the OS drops the lock: nothing stale is left
        holder.wait()
    with Store.open(tmp_path, FP, resume=True):
        with Store.open(tmp_path, FP, resume=True):  # re-entrant in one process
            pass


def test_an_error_keeps_the_finished_chunks_and_says_how_to_resume(tmp_path):
    def failing(i, n):
        if i == 3:
            raise RuntimeError("boom")
        return squares(i, n)

    with Store.open(tmp_path, FP) as store:
        with pytest.raises(RuntimeError, match="boom") as err:
            collect(compute(store, failing, TASKS))
    assert any("raised in chunk part_03" in n for n in err.value.__notes__)
    assert any("running again with resume" in n for n in err.value.__notes__)
    with Store.open(tmp_path, FP, resume=True) as store:
        assert store.keys() == ["part_00", "part_01", "part_02"]


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"  # a zombie has died
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pool_workers_die_with_their_parent_after_kill_9(tmp_path):
    """kill -9 of a run leaves no worker process behind (the issue: two of ~280 MB each)."""
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent("""
        import os, sys, time
        from chunkstore import Store, compute

        def work(i):
            open(os.path.join(sys.argv[1], f"worker_{os.getpid()}"), "w").close()
            time.sleep(60)
            return {"i": i}

        if __name__ == "__main__":
            with Store.open(os.path.join(sys.argv[1], "run"), {"job": "sleep"}) as store:
                for _ in compute(store, work, {f"c{i}": (i,) for i in range(4)}, executor="processes", workers=2):
                    pass
    """))
    parent = subprocess.Popen([sys.executable, str(script), str(tmp_path)], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.glob("worker_*"))) < 2:
            assert parent.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        workers = [int(p.name.split("_")[1]) for p in tmp_path.glob("worker_*")]
        assert all(_alive(pid) for pid in workers)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 10
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(pid) for pid in workers), "a worker outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()
        for p in tmp_path.glob("worker_*"):
            pid = int(p.name.split("_")[1])
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


def blas_threads(_: int) -> int:
    """Module level, so that worker processes can unpickle it: the most BLAS/OpenMP threads any
    library loaded in this worker would start (numpy's and scipy's OpenBLAS are two)."""
    return max((pool["num_threads"] for pool in threadpool_info()), default=1)


def test_pool_workers_share_the_cores_blas_threads():
    """Each of W workers may start at most cores // W BLAS threads (at least one): a
    worker's threads spinning against the other workers cost the tune 25 % of its time."""
    workers = 2
    with process_pool(workers) as pool:
        seen = list(pool.map(blas_threads, range(workers)))
    assert seen == [max(1, (os.cpu_count() or 1) // workers)] * workers
