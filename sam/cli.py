"""``samfdi simulate``: turn a scenario TOML into a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from .errors import UserError, output_file
from .plotting import figure_suffixes, plot_recordings
from .recording import write_recording
from .scenario import load_scenario, run_scenario


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a scenario TOML into a recording (CSV or .mat)",
        description="Simulate a scenario (plant, input, load, faults, sensors, seed) and write a "
                    "recording in the shared format, with ground truth in true_* columns.",
    )
    p.add_argument("scenario", type=Path, help="scenario TOML file, e.g. scenarios/paper_step.toml")
    p.add_argument("--out", type=Path, required=True, help="output recording, .csv or .mat")
    p.add_argument("--plot", type=Path, help="also save a figure of u, x, v, p_A and p_B (.png, .pdf, .svg, ...)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=simulate_command)


def simulate_command(args: argparse.Namespace) -> int:
    out = check_outputs(args)
    scenario = load_scenario(args.scenario)
    write_outputs(args, out, scenario, run_scenario(scenario))
    return 0


def check_outputs(args: argparse.Namespace) -> Path:
    """The recording's path, its and the figure's checked before the work is done (suffix, no
    overwrite without --force, not the scenario file itself)."""
    out = output_file(args.out, args.force, suffixes=(".csv", ".mat"))
    if out.resolve() == args.scenario.resolve():
        raise UserError(f"{out}: --out would overwrite the scenario file")
    if args.plot is not None:  # checked before the work, not after the recording is written
        output_file(args.plot, args.force, suffixes=figure_suffixes(), option="--plot")
    return out


def write_outputs(args: argparse.Namespace, out: Path, scenario, rec) -> None:
    """Write the recording (and the figure) a simulate command asked for, and say what was written."""
    write_recording(out, rec, overwrite=args.force)
    print(f"wrote {out} ({rec.n} samples, {rec.t[-1]:.3g} s)")
    if "warning" in rec.metadata:
        print(f"warning: {rec.metadata['warning']}")
    if args.plot is not None:
        plot_recordings({scenario.name: rec}, args.plot, scenario.description)
        print(f"wrote {args.plot}")
