"""``samfdi simulate ... --engine rig``: the rig simulator behind the simulate command.

``sam.cli`` registers ``samfdi simulate`` (sam's model); this module adds ``--engine`` to it,
so that one command runs a scenario on either: ``sam`` (the default) or ``rig``.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from sam.cli import check_outputs, simulate_command as simulate_on_sam, write_outputs
from sam.errors import UserError
from sam.plant import read_toml

from .population import FORMATS, FORMS, LARGER_CASES, TARGET_CASES, cases, write_population
from .scenario import load_rig_scenario
from .simulate import record

ENGINES = ("sam", "rig")


def add_commands(sub: argparse._SubParsersAction) -> None:
    simulate = sub.choices["simulate"]  # registered by sam.cli
    simulate.add_argument(
        "--engine", default="sam", metavar="ENGINE",
        help="sam: the model's step (default); rig: the rig simulator (rig/, docs/rig.md): closed-loop "
             "[control], contact end stops, transmitters and encoder, the [rig.*] effects")
    simulate.set_defaults(func=simulate_command)

    r = sub.add_parser("rig", help="the rig simulator's own commands (population)")
    rsub = r.add_subparsers(dest="rig_command", metavar="SUBCOMMAND", required=True)
    p = rsub.add_parser("population", help="write a population of labelled rig recordings (true_* columns) "
                        "for `samfdi fdi evaluate`; resumable")
    p.add_argument("--out", required=True, help="output folder, one recording per run (files already there are kept)")
    p.add_argument("--healthy", type=int, default=100, help="healthy runs, each of 20-60 s (default 100)")
    p.add_argument("--per-case", type=int, default=20,
                   help="runs per fault case (default 20): K_int, K_extA, K_extB at 0.25 L/min and the offset at "
                        "+-1 %%, each stepping in at a random onset")
    p.add_argument("--larger", action="store_true", help="also the next sizes up (0.5 L/min, +-2 %%), as many runs each")
    p.add_argument("--form", default="development", choices=sorted(FORMS),
                   help="how runs are drawn (rig/population.py): development (default); held-out, other input, "
                        "loop and machine forms that a detector is never tuned on; other-sensors, the held-out "
                        "form through 5-60 kPa transmitters, 12/16-bit ADCs and 0.007-0.036 deg encoders")
    p.add_argument("--seed", type=int, default=1, help="the population's seed (each run's draws from (seed, run))")
    p.add_argument("--plant", help="plant TOML the runs are drawn around (default: the shipped SAM)")
    p.add_argument("--format", default="mat", choices=FORMATS, help="file format (default mat: compressed)")
    p.set_defaults(func=population_command)


def simulate_command(args: argparse.Namespace) -> int:
    if args.engine not in ENGINES:
        raise UserError(f"--engine: expected one of {list(ENGINES)}, got {args.engine!r}")
    if args.engine == "sam":
        if "rig" in read_toml(args.scenario):
            warnings.warn(f"{args.scenario}: the [rig.*] tables are read by --engine rig only; ignored")
        return simulate_on_sam(args)
    out = check_outputs(args)
    scenario, settings = load_rig_scenario(args.scenario)
    write_outputs(args, out, scenario, record(scenario, settings))
    return 0


def population_command(args: argparse.Namespace) -> int:
    for name in ("healthy", "per_case"):
        if getattr(args, name) < 0:
            raise UserError(f"--{name.replace('_', '-')}: must be >= 0, got {getattr(args, name)}")
    if args.seed < 0:
        raise UserError(f"--seed: must be >= 0, got {args.seed}")
    runs = cases(args.healthy, args.per_case, TARGET_CASES + (LARGER_CASES if args.larger else ()))
    if not runs:
        raise UserError("--healthy and --per-case are both 0: nothing to write")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a folder")
    paths = write_population(out, args.plant, FORMS[args.form], args.seed, runs, args.format)
    print(f"wrote {len(paths)} recordings into {out}/ ({args.form} form, seed {args.seed})")
    return 0
