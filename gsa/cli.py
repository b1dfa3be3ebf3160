"""``samfdi gsa run``: a Sobol' study from its TOML file to tables and figures."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import time
import warnings
from pathlib import Path

from chunkstore import CHUNK_DIR, MANIFEST, SUMS, FolderLock, StoreError
from gsa import ESTIMATORS, reconstruct_cli, resources, run, saltelli_design
from gsa.errors import GSAError
from gsa.report import report_files, write_report
from gsa.sam_model import SamModel
from gsa.studies import MIN_BOOTSTRAP, load_study
from sam.errors import UserError, output_folder
from sam.options import integer


def add_commands(sub: argparse._SubParsersAction) -> None:
    gsa = sub.add_parser("gsa", help="Sobol' global sensitivity analysis",
                         description="Sobol' global sensitivity analysis of a study file.")
    gsa_sub = gsa.add_subparsers(dest="gsa_command", metavar="SUBCOMMAND", required=True)
    p = gsa_sub.add_parser(
        "run", help="run a study (e.g. scenarios/gsa/paper_parameters.toml)",
        description="Run a Sobol' study and write indices.csv, ranking.csv, interactions.csv, "
                    "summary.md and figures into --out. Finished chunks are checkpointed: a killed "
                    "run continues with --resume.")
    p.add_argument("study", type=Path, help="study TOML file")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--n", type=integer(minimum=2), default=None,
                   help="base sample size N (overrides the study's; a power of two)")
    p.add_argument("--estimator", default=None,
                   help="saltelli2010-jansen (default), saltelli2002 (the paper's), janon, azzini")
    p.add_argument("--bootstrap", type=integer(minimum=MIN_BOOTSTRAP), default=None,
                   help=f"bootstrap resamples for the 95 %% intervals (>= {MIN_BOOTSTRAP}; default: the study's)")
    p.add_argument("--workers", type=integer(minimum=1), default=None, help="cores to use (default: all)")
    p.add_argument("--executor", choices=("auto", "inline", "processes", "dask"), default="auto",
                   help="auto: the SAM model runs in-process on --workers threads, others in processes")
    p.add_argument("--scheduler", default=None, help="dask.distributed scheduler ADDRESS (implies dask)")
    p.add_argument("--chunk-size", type=integer(minimum=1), default=None, help="runs per checkpointed chunk")
    p.add_argument("--precision", choices=("float32", "float64"), default="float32",
                   help="arithmetic of the bootstrap replicates (point estimates are always "
                        "float64); float32 moves the interval bounds by ~1e-7 and is ~1.5x faster")
    p.add_argument("--resume", action="store_true", help="continue a killed run in --out")
    p.add_argument("--force", action="store_true",
                   help="replace report files (summary.md, indices.csv, ...) in a folder that holds no run")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_command)
    reconstruct_cli.add_command(gsa_sub)


def run_command(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except (GSAError, StoreError) as exc:
        raise UserError(str(exc)) from None


def _run(args: argparse.Namespace) -> int:
    spec = load_study(args.study)
    N = args.n if args.n is not None else spec.N
    estimator = args.estimator or spec.estimator
    if estimator is not None and estimator not in ESTIMATORS:
        raise UserError(f"--estimator: unknown estimator {estimator!r}; expected one of {sorted(ESTIMATORS)}")
    workers = args.workers or os.cpu_count() or 1
    is_sam = isinstance(spec.study.model, SamModel)
    executor = _executor(args, is_sam)
    study = spec.study
    if is_sam:
        threads = workers if executor == "inline" else 1
        study = dataclasses.replace(study, model=dataclasses.replace(study.model, threads=threads))
    chunk = args.chunk_size or (16384 if is_sam else 65536)
    # a folder holding a run: its report files are that run's (the chunk store refuses it without --resume)
    out = output_folder(args.out, report_files(study.output_names, study.output_times),
                        force=args.force or (args.out / MANIFEST).exists(), create=False)
    problem = study.problem
    reusable = sum(p.stat().st_size for p in (out / CHUNK_DIR).glob("*.npz")) if args.resume else 0
    resources.check(N, problem.k, problem.n_factors, study.M, chunk, out, reusable_bytes=reusable)
    n_boot = args.bootstrap if args.bootstrap is not None else spec.n_bootstrap
    t0 = time.perf_counter()
    with FolderLock(out), _naming(study.name):
        design = saltelli_design(problem, N=N, seed=spec.seed)
        result = run(study, design, out, chunk_size=chunk, executor=executor,
                     workers=None if executor == "inline" else workers, scheduler=args.scheduler,
                     resume=args.resume, progress=not args.no_progress)
        kwargs = {"estimator": estimator} if estimator else {}
        sobol = result.analyze(n_boot=n_boot, ci=spec.ci, seed=spec.seed, precision=args.precision, **kwargs)
        runtime = time.perf_counter() - t0
        paths = write_report(sobol, spec, out, runtime)
    print(f"{study.name}: {design.n_runs} runs, {study.M} outputs, estimator {sobol.estimator}, "
          f"{runtime:.1f} s ({result.chunks_computed} chunks computed, {result.chunks_reused} reused)")
    for path in paths:
        print(f"  wrote {path}")
    print(f"  checksums of the chunks: {out / CHUNK_DIR / SUMS}")
    return 0


@contextlib.contextmanager
def _naming(study: str):
    """Every warning shown while a study runs starts with its name: a command that runs several
    studies (the demo) must say which one an 'indices are NaN' belongs to."""
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        show = warnings.showwarning

        def named(message, category, filename, lineno, file=None, line=None):
            show(f"study '{study}': {message}", category, filename, lineno, file, line)

        warnings.showwarning = named
        yield


def _executor(args: argparse.Namespace, is_sam: bool) -> str:
    if args.scheduler:
        return "dask"
    if args.executor != "auto":
        return args.executor
    if args.workers == 1:
        return "inline"
    return "inline" if is_sam else "processes"
