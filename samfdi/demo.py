"""``samfdi demo``: the main job on embedded defaults, written to a folder it names.

1. Simulate the paper's step (healthy) and the same run with a 0.5 L/min
   external leak from chamber A, and plot them together.
2. Sobol' sensitivity analysis of both paper studies (Tables 1 and 5) at a
   reduced sample size.
3. A faulty rig recording (the rig simulator, rig/: a +1 % valve offset from t = 7 s
   under closed-loop position control) replayed blind through the augmented-state UKF,
   with its diagnosis.
4. A recording from the rig simulator (rig/) in which the model's missing physics (hose
   compliance) and a load other than the plant file's are concealed, diagnosed blind:
   the load recalibrated, the hoses located, named, modelled, fit before and after.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import time
from pathlib import Path

import discrepancy
import fdi
import rig
from gsa.cli import run_command
from gsa.report import NEGLIGIBLE_ST, tied_ranking
from sam.errors import UserError, output_folder
from sam.plant import default_plant_path, load_plant
from sam.plotting import plot_recordings
from sam.recording import write_recording
from sam.scenario import run_scenario, scenario_from_table

DEMO_LEAK_LPM = 0.5  #: L/min at 10 MPa, the demo's external leak
DEMO_GSA_N = 512  #: base sample size of the demo's sensitivity studies (the paper's is 10000)
DEMO_GSA_BOOTSTRAP = 200
DEMO_MISMATCH_SCENARIO = "mismatch_demo_hoses.toml"  #: the rig scenario of the demo's mismatch stage


def demo_scenario(faults: dict | None = None, duration_s: float = 4.0) -> dict:
    """The paper's step (Section 4) as a scenario table, optionally with fault profiles."""
    return {
        "description": "paper step, 25 % opening, 494 kg",
        "duration_s": duration_s, "dt_s": 1e-3, "seed": 1,
        "input": {"kind": "step", "amplitude_V": 2.5, "t0_s": 0.0},
        "load": {"m_L_kg": 494.0},
        "faults": faults or {},
    }


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on embedded defaults",
                       description="Simulate a healthy and a leaking run and compare them "
                                   "(and, where installed, run the later stages).")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: a new folder samfdi-demo[-N] here)")
    p.set_defaults(func=demo_command)


def new_folder(requested: Path | None) -> Path:
    """The output folder: the requested one if new or empty, else a fresh samfdi-demo[-N] here;
    checked (and created) before any work."""
    if requested is not None:
        if requested.is_dir() and any(requested.iterdir()):
            raise UserError(f"{requested}: folder exists and is not empty; choose another --out")
        return output_folder(requested)
    for n in range(1, 1000):
        folder = Path("samfdi-demo" if n == 1 else f"samfdi-demo-{n}")
        if not folder.exists():
            try:
                return output_folder(folder)
            except UserError:
                raise UserError(f"{Path.cwd()}: the current folder is not writable, so the demo cannot make "
                                f"its folder here; pass --out DIR with a folder you can write") from None
    raise UserError("too many samfdi-demo folders here; pass --out")


def demo_command(args: argparse.Namespace) -> int:
    out = new_folder(args.out)
    print(f"samfdi demo: writing to {out}/")
    t0 = time.perf_counter()
    healthy = run_scenario(scenario_from_table(demo_scenario(), out / "healthy.toml"))
    leak = {"K_extA": {"kind": "step", "value": DEMO_LEAK_LPM, "unit": "L/min", "t0_s": 1.0}}
    leaking = run_scenario(scenario_from_table(demo_scenario(leak), out / "leak.toml"))
    write_recording(out / "healthy.csv", healthy)
    write_recording(out / "extA_leak.csv", leaking)
    plot_recordings({"healthy": healthy, f"K_extA: {DEMO_LEAK_LPM} L/min from 1 s": leaking},
                    out / "healthy_vs_leak.png", "Paper step: healthy vs external leak A")
    dpA = (leaking.truth["true_pA"] - healthy.truth["true_pA"])[-1]
    dv = (leaking.truth["true_v"] - healthy.truth["true_v"])[-1]
    print(f"  1. simulation: healthy and {DEMO_LEAK_LPM} L/min external leak A "
          f"({time.perf_counter() - t0:.1f} s); at 4 s the leak changes p_A by {dpA / 1e3:+.0f} kPa "
          f"and v by {dv * 1e3:+.2f} mm/s -> healthy.csv, extA_leak.csv, healthy_vs_leak.png")
    _demo_gsa(out)
    _demo_fdi(out)
    _demo_mismatch(out)
    print(f"done: {out}/")
    return 0


def _demo_gsa(out: Path) -> None:
    """Stage 2: both paper studies at reduced N, through the same command a user runs."""
    studies = default_plant_path().parents[1] / "gsa"
    for name in ("paper_parameters", "paper_leakage"):
        t0 = time.perf_counter()
        args = argparse.Namespace(
            study=studies / f"{name}.toml", out=out / f"gsa_{name}", n=DEMO_GSA_N, estimator=None,
            bootstrap=DEMO_GSA_BOOTSTRAP, workers=None, executor="auto", scheduler=None,
            chunk_size=None, precision="float32", resume=False, force=False, no_progress=True)
        with contextlib.redirect_stdout(io.StringIO()):
            run_command(args)
        ranking = _steady_ranking(out / f"gsa_{name}" / "ranking.csv")
        print(f"  2. sensitivity ({name}, N = {DEMO_GSA_N}, {time.perf_counter() - t0:.1f} s): "
              + "; ".join(f"{o}: {r}" for o, r in ranking.items())
              + f" -> gsa_{name}/summary.md")


def _demo_fdi(out: Path) -> None:
    """Stage 3: record a faulty run on the rig simulator (written apart from the model: its own
    equations, a closed position loop, transmitters and encoder) and replay it blind through the UKF."""
    t0 = time.perf_counter()
    scenario = default_plant_path().parents[1] / "rig" / "offset_plus1pct_closed_loop.toml"
    rec = rig.record(*rig.load_rig_scenario(scenario))
    write_recording(out / "rig_offset_plus1pct.csv", rec)
    diagnosis = fdi.replay_recording(rec.measured(), load_plant(), out / "fdi_replay")
    print(f"  3. fault replay of a rig recording, {scenario.name} (true: offset +1 % from 7 s, closed loop), "
          f"{time.perf_counter() - t0:.1f} s: {_describe(diagnosis)} -> fdi_replay/diagnosis.json")


def _demo_mismatch(out: Path) -> None:
    """Stage 4: a rig recording with concealed hose compliance and a load other than the plant
    file's, diagnosed blind against the nominal plant."""
    t0 = time.perf_counter()
    scenario = default_plant_path().parents[1] / "rig" / DEMO_MISMATCH_SCENARIO
    rec = rig.record(*rig.load_rig_scenario(scenario))
    write_recording(out / "mismatch_recording.csv", rec)
    report = discrepancy.diagnose(rec.measured(), load_plant(), out / "mismatch")
    print(f"  4. mismatch diagnosis of a rig recording ({scenario.name}: hoses of 0.3 L, 350 kg; "
          f"{time.perf_counter() - t0:.1f} s): {report.headline} -> mismatch/report.md")


def _describe(diagnosis) -> str:
    """One line of a fdi.Diagnosis: its headline (caveats first, as replay prints it) and when the
    fault was isolated."""
    line = diagnosis.headline().replace("\n", " | ")
    if diagnosis.isolation_time_s is not None:
        line += f", isolated at t = {diagnosis.isolation_time_s:.2f} s"
    return line


def _steady_ranking(path: Path) -> dict[str, str]:
    """Steady-state ranking by total index per output, from a ranking.csv, stated only as far as
    the 95 % intervals separate it; factors negligible even at their upper bound are left out."""
    groups: dict[str, dict[int, list[str]]] = {}
    with open(path) as f:
        for row in csv.DictReader(f):
            if row["by"] == "ST" and row["output"].endswith("_steady") and float(row["hi"]) >= NEGLIGIBLE_ST:
                output = row["output"][: -len("_steady")]
                groups.setdefault(output, {}).setdefault(int(row["group"]), []).append(row["parameter"])
    return {output: tied_ranking([g[k] for k in sorted(g)]) for output, g in groups.items()}
