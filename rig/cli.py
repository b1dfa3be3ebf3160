"""``samfdi simulate ... --engine rig``: the rig simulator behind the simulate command.

``sam.cli`` registers ``samfdi simulate`` (sam's model); this module adds ``--engine`` to it,
so that one command runs a scenario on either: ``sam`` (the default) or ``rig``.
"""

from __future__ import annotations

import argparse
import warnings

from sam.cli import check_outputs, simulate_command as simulate_on_sam, write_outputs
from sam.errors import UserError
from sam.plant import read_toml

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
