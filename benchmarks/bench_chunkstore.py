"""Benchmark: the checkpoint of one SAM chunk through the chunk store, against a plain atomic np.save.

One chunk of `samfdi gsa run` on a SAM study is 16384 runs x 1203 outputs in float64 (158 MB).
Side by side, interleaved, 7 times, medians: the baseline a user would write (np.save to a
temporary file, os.replace; np.load) against chunkstore's Store.save (npz, sha256 recorded in
SHA256SUMS) and Store.load (sha256 checked, then read).

Usage::

    python benchmarks/bench_chunkstore.py
"""

import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from chunkstore import Store  # noqa: E402

Y = np.random.default_rng(0).standard_normal((16384, 1203))
base = Path(tempfile.mkdtemp())
t = {"old save": [], "new save": [], "old load": [], "new load": []}  # old: the baseline; new: chunkstore
for rep in range(7):
    p, tmp = base / f"old_{rep}.npy", base / f".old_{rep}.tmp"
    t0 = time.perf_counter()
    with open(tmp, "wb") as f:
        np.save(f, Y, allow_pickle=False)
    os.replace(tmp, p)
    t["old save"].append(time.perf_counter() - t0)
    with Store.open(base / f"new_{rep}", {"rep": rep}) as store:
        t0 = time.perf_counter()
        store.save("chunk_00000", {"Y": Y})
        t["new save"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        a = np.load(p)
        t["old load"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        b = store.load("chunk_00000")["Y"]
        t["new load"].append(time.perf_counter() - t0)
    assert np.array_equal(a, b)
    p.unlink()
shutil.rmtree(base)
for k, v in t.items():
    print(f"{k}: median {statistics.median(v):.3f} s (min {min(v):.3f}, max {max(v):.3f})")
print("load average", open("/proc/loadavg").read().split()[0])
