"""Both paper studies end to end in float64 and in float32 (the kernel's single-precision option),
side by side in one run: their times, and how far the indices move.

For each study, the same design is run twice, ``[simulation] precision`` float64 then float32,
and analysed with the same bootstrap (1000 resamples, as `samfdi gsa run`); printed: the seconds
of each (simulation with its chunk files, analysis), the largest change of S1 and ST over every
output, over the outputs at the paper's instants and at the steady state, against the indices'
own 95 % bootstrap half-width there, and whether any ranking by ST changes at those instants.

Usage::

    python benchmarks/bench_kernel_gsa.py [--n 10000]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from gsa import run, saltelli_design
from gsa.studies import load_study

ROOT = Path(__file__).resolve().parents[1]
STUDIES = [ROOT / "scenarios" / "gsa" / "paper_parameters.toml", ROOT / "scenarios" / "gsa" / "paper_leakage.toml"]
CHUNK = 16384


def one(spec, design, precision: str, out: Path):
    model = dataclasses.replace(spec.study.model, precision=precision)
    study = dataclasses.replace(spec.study, model=model)
    t0 = time.perf_counter()
    res = run(study, design, out / f"{spec.study.name}_{precision}", chunk_size=CHUNK, progress=False)
    t1 = time.perf_counter()
    sobol = res.analyze(n_boot=1000, seed=spec.seed, precision="float32")
    return sobol, t1 - t0, time.perf_counter() - t1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    total = {"float64": 0.0, "float32": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for path in STUDIES:
            spec = load_study(path)
            design = saltelli_design(spec.study.problem, N=args.n, seed=spec.seed)
            res = {p: one(spec, design, p, Path(tmp)) for p in ("float64", "float32")}
            a, b = res["float64"][0], res["float32"][0]
            names = np.array(a.output_names)
            times = np.asarray(a.output_times)
            paper = np.zeros(len(names), bool)
            for t in spec.instants_s:
                paper |= np.isclose(times, t)
            paper |= np.char.endswith(names.astype(str), "_steady")
            ok = ~a.constant & ~b.constant
            print(f"{spec.study.name}: {design.n_runs} runs, N = {args.n}")
            for p, (_, sim, ana) in res.items():
                total[p] += sim + ana
                print(f"  {p}: simulate {sim:6.1f} s, analyse {ana:5.1f} s")
            for idx in ("S1", "ST"):
                d = np.abs(getattr(a, idx) - getattr(b, idx))[:, ok]
                half = 0.5 * (getattr(a, f"{idx}_hi") - getattr(a, f"{idx}_lo"))[:, ok]
                sel = paper[ok]
                print(f"  {idx}: largest change {np.nanmax(d):.2e} over all {ok.sum()} outputs "
                      f"(median {np.nanmedian(d):.1e}); {np.nanmax(d[:, sel]):.2e} at the paper's instants and steady "
                      f"states, where the 95 % half-width is {np.nanmedian(half[:, sel]):.1e} (median); "
                      f"largest change / half-width {np.nanmax(d / np.maximum(half, 1e-12)):.2f}")
            ra, rb = a.ranking("ST")[:, ok][:, paper[ok]], b.ranking("ST")[:, ok][:, paper[ok]]
            print(f"  rankings by ST at the paper's instants and steady states: "
                  f"{int(np.sum(np.any(ra != rb, axis=0)))} of {ra.shape[1]} outputs change")
    print(f"both studies end to end: float64 {total['float64']:.1f} s, float32 {total['float32']:.1f} s")


if __name__ == "__main__":
    main()
