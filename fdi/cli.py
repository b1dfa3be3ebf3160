"""``samfdi fdi replay | signatures | thresholds | tune | evaluate``."""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

from rig.population import tune_recordings
from sam import load_plant, read_recording
from sam.errors import UserError, output_folder
from sam.options import integer

from .evaluate import evaluate_folder
from .offline import replay_recording
from .recording import CHECKS
from .signatures import signature_table, write_signatures
from .study import OUTPUT_FILES, StudyDesign, compute_thresholds, write_thresholds
from .thresholds import SHIPPED_BY_SENSOR, Thresholds, describe
from .tune import run_tune, timing_text

SENSORS = tuple(SHIPPED_BY_SENSOR)


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("fdi", help="fault detection and isolation with the augmented-state UKF")
    sub = p.add_subparsers(dest="fdi_command", metavar="SUBCOMMAND", required=True)

    r = sub.add_parser("replay", help="filter a recording and diagnose it")
    r.add_argument("recording", help="recording file (.csv or .mat; the format: docs/recordings.md)")
    r.add_argument("--plant", help="plant TOML (default: the shipped SAM)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--thresholds", help="thresholds.toml from `samfdi fdi thresholds` (default: the shipped one of "
                   "the position sensor)")
    r.add_argument("--position-sensor", choices=SENSORS,
                   help="the position sensor of the recording: encoder (theta, or x computed from the encoder's "
                        "theta) or linear (x from a linear transducer); default: found from the recording (x on the "
                        "encoder's grid of pulses: encoder). Chooses the shipped thresholds of that sensor")
    r.add_argument("--reference", help="healthy recording of the same machine: the notch flows and bulk modulus "
                   "learnt there replace the plant file's (recommended; the change test keeps this recording's "
                   "own baseline)")
    r.add_argument("--baseline", help="healthy recording of the same machine: its estimates are the baseline the "
                   "change test compares against, for a fault present from the start (default: this recording's own "
                   "estimates over its first unpinned second; costs false alarms when the loads differ, docs/fdi.md)")
    r.add_argument("--force", action="store_true", help="overwrite existing output files")
    r.add_argument("--drop-out-of-range", action="store_true",
                   help="treat pressure samples outside 0-25 MPa and position samples outside the plant's "
                   "stroke as missing instead of refusing the file")
    r.set_defaults(func=_replay)

    s = sub.add_parser("signatures", help="fault signature tables (CSV, Markdown, heat map)")
    s.add_argument("--plant", help="plant TOML (default: the shipped SAM)")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--force", action="store_true", help="overwrite existing output files")
    s.set_defaults(func=_signatures)

    g = sub.add_parser("thresholds", help="thresholds from the leakage and nuisance Sobol' studies (prints them)")
    g.add_argument("--plant", help="plant TOML (default: the shipped SAM)")
    g.add_argument("--n-leak", type=int, default=16, help="base sample size of the leakage GSA (a power of 2 keeps the Sobol' "
                   "sequence balanced; other sizes work)")
    g.add_argument("--n-nuisance", type=int, default=128,
                   help="base sample size of the nuisance GSA (a power of 2 recommended; its 2N distinct "
                   "experiments set h)")
    g.add_argument("--workers", type=integer(minimum=1), default=None,
                   help="local worker processes (default: every core, as `gsa run`)")
    g.add_argument("--sample-rate", type=float, default=1000.0,
                   help="Hz: the sampling rate of the recordings the thresholds are for (default 1000; "
                   "1000 / rate must be a whole number, at least 100 Hz); replay refuses a recording "
                   "sampled at another rate than its thresholds'")
    g.add_argument("--trigger-level", type=float, default=None,
                   help="rate of CUSUM alarms per healthy run the h are set for (default 0.1; between the "
                        "false-alarm level 0.01 and 1): each alarm is a trigger that the likelihood bank confirms "
                        "or withdraws, which keeps the false alarms at 0.01 per run")
    g.add_argument("--position-sensor", default="encoder", choices=SENSORS,
                   help="the position sensor of the recordings the thresholds are for: encoder (default; the "
                        "joint angle theta from the quantised encoder, or x computed from it) or linear (x from a "
                        "linear transducer, 10 um white noise); replay picks the shipped file of the sensor it "
                        "finds and warns when a given file was derived for another")
    g.add_argument("--out", required=True, help="output folder: thresholds.toml, thresholds.md, thresholds_gsa.json")
    g.add_argument("--force", action="store_true", help="overwrite existing output files")
    g.set_defaults(func=_thresholds)

    t = sub.add_parser("tune", help="Monte Carlo detection metrics on held-out runs (resumable)")
    t.add_argument("--thresholds", help="thresholds.toml (default: the shipped one)")
    t.add_argument("--plant", help="plant TOML (default: the shipped SAM)")
    t.add_argument("--runs", type=int, default=100, help="healthy runs N (default 100), each as long as the thresholds' "
                   "run_length_s (20 s for the shipped ones), and max(5, N // 2) more of 20-60 s extend/retract "
                   "cycles; fault runs of 4 s: max(5, N // 5) per fault type and size. Every rate comes with its exact "
                   "95 %% interval; a case can show >= 95 %% only from 72 runs (N >= 360); N = 1000 (200 per case) tells "
                   "a case at 90 %% or at 99 %% apart from 95 %%")
    t.add_argument("--source", default="rig", choices=("rig", "sam"),
                   help="what records the runs: rig (default; the rig simulator, rig/population.py's development "
                        "form: closed and open loops, 20-60 s healthy runs, the machine drawn off its plant file, "
                        "data the filter's model did not make) or sam (the model's own batched simulator: about 5x "
                        "cheaper per tune, in-model, for comparison). With rig, --runs N gives N + max(5, N // 2) healthy "
                        "runs of 20-60 s and the fault runs below with their onsets at 4-8 s")
    t.add_argument("--workers", type=integer(minimum=1), default=None,
                   help="local worker processes (a process pool; default: every core, as `gsa run`; "
                        "--scheduler runs on a dask cluster instead)")
    t.add_argument("--scheduler", help="dask scheduler address, e.g. tcp://host:8786")
    t.add_argument("--reference", action="store_true",
                   help="calibrate every Monte Carlo machine on a healthy reference recording of its own first "
                   "(as `fdi replay --reference` does)")
    t.add_argument("--bound", action="store_true",
                   help="also measure what the data carry: the likelihood evidence of each fault at its TRUE "
                   "onset (fdi/bound.py), to tell misses no detector could avoid from misses of ours; "
                   "about three times the work of the tune")
    t.add_argument("--out", required=True, help="output folder (re-run the same command to resume; a folder made "
                   "with other --runs, --thresholds or --plant is refused)")
    t.add_argument("--force", action="store_true",
                   help="overwrite metrics.md, metrics.json, thresholds_used.json, rates.png in a folder that is not "
                   "a tune folder")
    t.set_defaults(func=_tune)

    e = sub.add_parser("evaluate", help="score the detector on a folder of labelled recordings (true_* columns; "
                       "resumable)")
    e.add_argument("folder", help="folder of recordings (.csv, .mat) with true_* columns, e.g. from "
                   "`samfdi rig population`")
    e.add_argument("--out", required=True, help="output folder: evaluation.md, evaluation.json, evaluation.png and "
                   "the chunk store (re-run to resume; recordings added later are scored then)")
    e.add_argument("--plant", help="plant TOML (default: the shipped SAM)")
    e.add_argument("--thresholds", help="thresholds.toml (default: the shipped one of each recording's position sensor)")
    e.add_argument("--workers", type=integer(minimum=1), default=None,
                   help="local worker processes (default: every core, as `gsa run`)")
    e.add_argument("--bound", action="store_true", help="also what the data carry at each fault's TRUE onset "
                   "(fdi/bound.py), to tell misses no detector could avoid from ours; about twice the work")
    e.add_argument("--force", action="store_true", help="overwrite evaluation.* in a folder that is not an "
                   "evaluation folder")
    e.set_defaults(func=_evaluate)


def _plant(args):
    return load_plant(args.plant)


def _workers(args) -> int:
    """--workers, or every core (as `gsa run`)."""
    return args.workers or os.cpu_count() or 1


def _load_thresholds(path):
    if not path:
        return None  # the shipped file of the recording's position sensor (replay) or of the encoder
    if not Path(path).is_file():
        raise UserError(f"{path}: --thresholds: {'is a folder' if Path(path).is_dir() else 'file does not exist'}; "
                        "give the thresholds.toml that `samfdi fdi thresholds` wrote")
    if Path(path).suffix not in (".toml", ".json"):
        raise UserError(f"{path}: --thresholds: expected a .toml file (the thresholds.toml that "
                        "`samfdi fdi thresholds` wrote, or a thresholds_used.json)")
    try:
        return Thresholds.load(path)
    except UnicodeDecodeError:
        raise UserError(f"{path}: --thresholds: not a text file; give the thresholds.toml that "
                        "`samfdi fdi thresholds` wrote") from None
    except (OSError, ValueError, TypeError, AttributeError) as exc:
        raise UserError(f"{path}: --thresholds: not a thresholds file from `samfdi fdi thresholds` "
                        f"({' '.join(str(exc).split())})") from None


def _thresholds(args) -> int:
    k = 1000.0 / args.sample_rate if math.isfinite(args.sample_rate) and args.sample_rate > 0 else float("inf")
    tol, min_rate = CHECKS.rate_tolerance, CHECKS.min_sample_rate_Hz
    # within 1 % of a whole number of ms, as replay matches a recording's rate: 333.3 Hz is 3 ms
    if not (math.isfinite(k) and abs(k / max(1, round(k)) - 1.0) <= tol and 1 <= round(k) <= 1000 / min_rate):
        raise UserError(f"--sample-rate: {args.sample_rate:g} Hz; the studies simulate at 1 kHz and can sample "
                        f"every 1, 2, ..., {int(1000 / min_rate)} ms: 1000, 500, 333.33, 250, 200, ..., {min_rate:g} Hz")
    for name, n in (("--n-leak", args.n_leak), ("--n-nuisance", args.n_nuisance)):
        if n < 4:
            raise UserError(f"{name}: need at least 4, got {n}")
    default = StudyDesign()
    trigger = default.trigger_level if args.trigger_level is None else args.trigger_level
    if not (math.isfinite(trigger) and default.false_alarm_level <= trigger <= 1.0):
        raise UserError(f"--trigger-level: {args.trigger_level:g} is not a rate per run between the false-alarm "
                        f"level {default.false_alarm_level:g} and 1")
    plant = _plant(args)
    out = output_folder(args.out, OUTPUT_FILES, args.force)
    design = StudyDesign(n_leak=args.n_leak, n_nuisance=args.n_nuisance, trigger_level=trigger,
                         sample_dt_s=round(k) * 1e-3, position_sensor=args.position_sensor)
    th, report = compute_thresholds(plant, design, workers=_workers(args), progress=True)
    print(describe(th))
    for p in write_thresholds(th, report, out):
        print(f"wrote {p}")
    return 0


def _replay(args) -> int:
    plant = _plant(args)
    rec = read_recording(args.recording)
    th = _load_thresholds(args.thresholds)
    base = read_recording(args.baseline) if args.baseline else None
    ref = read_recording(args.reference) if args.reference else None
    diag = replay_recording(rec, plant, args.out, force=args.force, thresholds=th,
                            drop_out_of_range=args.drop_out_of_range, baseline=base, reference=ref,
                            plant_name=args.plant or "the shipped plant (scenarios/plants/sam.toml)",
                            position_sensor=args.position_sensor)
    print(diag.headline())  # first: what a person reads first
    if th is None and diag.thresholds["position_sensor"] != "encoder":
        print(f"position sensor: {diag.thresholds['position_sensor']} "
              f"({'as given' if args.position_sensor else 'x is not on the encoder grid'}): the shipped "
              f"thresholds for it ({diag.thresholds['source']})")
    cal = diag.filter_health.get("calibrated_from_reference")
    if cal:
        print("calibrated from the reference: " + ", ".join(
            f"{k} x{v['factor']:.4f} (+-{100 * v['relative_sd']:.2f} %)" for k, v in cal.items()))
    if diag.filter_health.get("decimated_by"):
        print(f"kept 1 sample in {diag.filter_health['decimated_by']}: the thresholds are for "
              f"{1 / diag.filter_health['dt_s']:.4g} Hz")
    for column, (n, top) in diag.filter_health.get("at_range_ceiling_samples", {}).items():
        print(f"{column}: {n} sample(s) sit flat at {top / 1e6:.4g} MPa, a transmitter at the top of its range: "
              "treated as missing")
    if diag.filter_health.get("nan_samples"):
        print(f"predicted through {diag.filter_health['nan_samples']} sample(s) with missing measurements")
    if diag.filter_health.get("u_gaps_held"):
        print(f"held the input u through {diag.filter_health['u_gaps_held']} missing sample(s)")
    if diag.note:
        print(f"note: {diag.note}")
    if rec.t[0] != 0:  # the file's clock: a user looks for an alarm's time in it
        print(f"times above are seconds from the recording's start, t = {rec.t[0]:.10g} s in the file "
              "(estimates.csv and residuals.csv keep the file's t)")
    print(f"wrote {Path(args.out)}/estimates.csv, residuals.csv, diagnosis.json, replay.png")
    return 0


def _signatures(args) -> int:
    plant = _plant(args)
    out = output_folder(args.out, ("signatures.csv", "signatures.md", "signatures.png"), args.force)
    rows = signature_table(plant)
    for p in write_signatures(rows, out):
        print(f"wrote {p}")
    return 0


def _tune(args) -> int:
    if args.runs < 5:
        raise UserError(f"--runs: need at least 5 runs, got {args.runs}")
    recorder = functools.partial(tune_recordings, args.plant, "development") if args.source == "rig" else None
    m = run_tune(_plant(args), Path(args.out), n_runs=args.runs, workers=_workers(args), scheduler=args.scheduler,
                 thresholds=_load_thresholds(args.thresholds), reference=args.reference,
                 bound=args.bound, force=args.force, recorder=recorder, source=args.source)
    print(Path(args.out, "metrics.md").read_text())
    print(timing_text(m["timing"]))
    print(f"wrote {args.out}/metrics.md, metrics.json, thresholds_used.json, rates.png")
    return 0


def _evaluate(args) -> int:
    evaluate_folder(Path(args.folder), Path(args.out), _plant(args), _load_thresholds(args.thresholds),
                    workers=_workers(args), force=args.force, bound=args.bound)
    print(Path(args.out, "evaluation.md").read_text())
    print(f"wrote {args.out}/evaluation.md, evaluation.json, evaluation.png")
    return 0
