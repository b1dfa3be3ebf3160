"""``samfdi mismatch RECORDING [--plant plant.toml] [--validate OTHER] --out DIR [--force]``."""

from __future__ import annotations

import argparse
from pathlib import Path

import sam
from sam.errors import output_folder
from sam.options import real

from .diagnose import diagnose
from .report import OUTPUT_FILES, console_lines


def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "mismatch",
        help="locate where simulation and a recording differ, name the missing physics, model it",
        description="Compare the plant model with a recording, calibrate what commissioning fixes (notch "
                    "flows, B_eff, offset, the plant file's [uncertain] load and geometry), locate the "
                    "mismatch, rank candidate effects (entrained air, friction, spool lap, flow saturation, "
                    "supply droop, bypass leakage, hose compliance, load inertia, transmitter lag/delay) against "
                    "the model's own error and write DIR/report.md, DIR/report.json, figures and, for a "
                    "look-alike, DIR/separate.toml (the test that would tell the two apart).",
    )
    p.add_argument("recording", type=Path, help="recording (.csv or .mat, see docs/recordings.md)")
    p.add_argument("--plant", type=Path, default=None, help="plant TOML (default: the shipped SAM)")
    p.add_argument("--validate", type=Path, default=None,
                   help="second recording of the same plant for held-out validation (default: every third segment)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--segment", type=real(above=0.0), default=1.0,
                   help="simulation segment length [s] (default 1; at least 0.3, at most a third of the recording)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--force", action="store_true", help="overwrite report.md, report.json and figures in --out")
    p.set_defaults(func=handler)


def handler(args: argparse.Namespace) -> int:
    out = output_folder(args.out, OUTPUT_FILES, args.force, create=False)  # before the work, not after it
    plant = sam.load_plant(args.plant)
    rec = sam.read_recording(args.recording).measured()
    val = sam.read_recording(args.validate).measured() if args.validate else None
    report = diagnose(rec, plant, out, validate=val, seg_s=args.segment, figures=not args.no_figures,
                      plant_path=args.plant)
    print("\n".join(console_lines(report)))
    print(f"report: {out / 'report.md'}  ({report.timings['total_s']:.1f} s)")
    return 0
