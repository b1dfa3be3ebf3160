"""``samfdi gsa reconstruct``: score candidate reconstructions of a machine against its paper."""

from __future__ import annotations

import argparse
import dataclasses
import warnings
from pathlib import Path

from gsa.errors import GSAError
from gsa.reconstruct import run_reconstruction
from gsa.reconstruct_report import REPORT_FILES, write_reconstruction_report
from gsa.reconstruct_spec import load_reconstruction, select_candidates
from sam.errors import UserError, output_folder


def add_command(gsa_sub: argparse._SubParsersAction) -> None:
    p = gsa_sub.add_parser(
        "reconstruct", help="score candidate reconstructions against the paper (scenarios/gsa/reconstruct.toml)",
        description="Run the paper's Sobol' studies on every candidate model of a reconstruction study, score "
                    "each against every published result (with bootstrap intervals) and say which candidate "
                    "the evidence supports. Writes reconstruct.md, reconstruct.json and reconstruct.png into "
                    "--out; finished candidates are saved there, so a killed run continues with --resume.")
    p.add_argument("study", type=Path, help="reconstruction study TOML file")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--n", type=int, default=None, help="base sample size N per study (overrides the file's)")
    p.add_argument("--bootstrap", type=int, default=None, help="bootstrap replicates (overrides the file's)")
    p.add_argument("--candidates", default=None,
                   help="comma-separated names: score only these candidates (the first is the reference)")
    p.add_argument("--workers", type=int, default=None, help="cores to simulate on (default: all)")
    p.add_argument("--resume", action="store_true", help="reuse the candidates a killed run in --out finished")
    p.add_argument("--force", action="store_true", help="recompute everything and overwrite --out's results")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=reconstruct_command)


def reconstruct_command(args: argparse.Namespace) -> int:
    try:
        return _reconstruct(args)
    except GSAError as exc:
        raise UserError(str(exc)) from None


def _reconstruct(args: argparse.Namespace) -> int:
    for flag, value, lo in (("--n", args.n, 2), ("--bootstrap", args.bootstrap, 10), ("--workers", args.workers, 1)):
        if value is not None and value < lo:
            raise UserError(f"{flag}: must be >= {lo}, got {value}")
    done = [*REPORT_FILES, "candidates"]
    out = output_folder(args.out, () if args.resume else tuple(done), force=args.force, create=False)
    spec = load_reconstruction(args.study)
    spec = dataclasses.replace(spec, N=args.n or spec.N, n_bootstrap=args.bootstrap or spec.n_bootstrap)
    if args.candidates is not None:
        spec = select_candidates(spec, [n.strip() for n in args.candidates.split(",") if n.strip()])
    out = output_folder(out, create=True)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        result = run_reconstruction(spec, out, resume=args.resume and not args.force,
                                    progress=not args.no_progress, threads=args.workers)
    paths = write_reconstruction_report(result, out)
    print(f"{spec.name}: {len(spec.candidates)} candidates at N = {spec.N}, {result.runtime_s:.0f} s "
          f"({result.computed} computed, {result.reused} reused)")
    print(result.verdict.statement().replace("**", ""))
    for path in paths:
        print(f"  wrote {path}")
    return 0
