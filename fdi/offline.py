"""Offline replay of one recording (``samfdi fdi replay``): the stages end to end, the files and
the figure.

recording (checked: :mod:`fdi.recording`) -> filter (:func:`fdi.filter.run_filter`, calibrated
on a healthy reference recording if one is given: :mod:`fdi.calibration`) -> diagnosis
(:func:`fdi.diagnosis.diagnose`) -> estimates.csv, residuals.csv, diagnosis.json, replay.png.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sam import Plant, Recording, UserError
from sam.errors import output_folder
from sam.measurement import at_ceiling

from . import calibration
from .bank import DESIGN, BankDesign
from .conditions import held
from .config import FilterConfig, StopRules
from .diagnosis import Diagnosis, diagnose, shown_statistics
from .faults import PARAMS
from .figures import replay_figure
from .filter import FilterOutput, run_filter
from .recording import (
    at_thresholds_rate, check_duration, check_observable, detect_position_sensor, excitation_caveat, filter_input,
    recording_sensors,
)
from .states import STATE_NAMES, leak_lpm
from .statistics import residuals, statistics
from .thresholds import Thresholds

OUTPUT_FILES = ("estimates.csv", "residuals.csv", "diagnosis.json", "replay.png")


@dataclass(frozen=True)
class Replay:
    """A replayed recording: the filter's output, the residuals and statistics the detector ran
    (restarted after withdrawn alarms), the diagnosis."""

    output: FilterOutput  #: the filter's output over the recording (one run)
    residuals: dict  #: name -> (1, T)
    statistics: dict  #: test -> (1, T)
    diagnosis: Diagnosis  #: what diagnosis.json holds


def learn_reference(ref: Recording, plant: Plant, cfg: FilterConfig, *,
                    drop_out_of_range: bool = False) -> calibration.Calibration:
    """The machine constants (notch flows, bulk modulus) that ``cfg``'s calibration states learn
    on a healthy reference recording of the same machine (:mod:`fdi.calibration`)."""
    name = str(ref.source or "reference recording")
    inp, _ = filter_input(without_saturated(ref.measured())[0], plant, drop_out_of_range=drop_out_of_range)
    cal = calibration.learn(run_filter(inp, cfg), cfg)
    if not cal.factor:
        raise UserError(f"{name}: --reference: the filter of these thresholds calibrates none of "
                        f"{', '.join(calibration.MACHINE_STATES)}, so a reference has nothing to teach it")
    return cal


def reference_baseline(ref: Recording, plant: Plant, th: Thresholds, cfg: FilterConfig,
                       cal: calibration.Calibration | None = None, *, drop_out_of_range: bool = False) -> np.ndarray:
    """(1, 4) healthy baseline of the fault estimates from a reference recording of the same
    machine: the mean of each over the reference's second half (filtered with the calibration
    ``cal`` if the replay uses one), where its test is not held (the whole reference if its
    second half holds it)."""
    name = str(ref.source or "reference recording")
    inp, _ = filter_input(without_saturated(ref.measured())[0], plant, drop_out_of_range=drop_out_of_range)
    out = run_filter(*(calibration.apply(inp, cfg, cal) if cal is not None else (inp, cfg)))
    seen = ~held(out, th)[0]  # (4, T)
    second = np.arange(out.mean.shape[1]) >= out.mean.shape[1] // 2
    base = []
    for i, (param, j) in enumerate(PARAMS.items()):
        w = seen[i] & second if (seen[i] & second).any() else seen[i]
        if not w.any():
            raise UserError(f"{name}: --baseline: the pressures are pinned to supply and tank throughout, "
                            f"so {param} is never observable there; record a reference in motion")
        base.append(out.mean[0, w, j].mean())
    return np.array([base])


def prepare(rec: Recording, plant: Plant, thresholds: Thresholds | None = None, *, drop_out_of_range: bool = False,
            own_baseline: bool = True, plant_name: str = "plant", position_sensor: str | None = None,
            stops: StopRules = StopRules()) -> tuple:
    """A recording checked and made the filter's input, as :func:`replay` takes it: (the measured
    recording at the thresholds' rate, :class:`fdi.filter.FilterInput`, the thresholds (None: the
    shipped file of the position sensor), the position sensor, the input's health report). Every
    refusal is a UserError naming the recording."""
    sensor = position_sensor or detect_position_sensor(rec, plant)
    thresholds = Thresholds.shipped(sensor) if thresholds is None else thresholds
    rec, k = at_thresholds_rate(rec.measured(), thresholds)  # never the true_* columns
    rec, ceiling = without_saturated(rec)
    inp, report = filter_input(rec, plant, drop_out_of_range=drop_out_of_range, position_sensor=sensor, stops=stops)
    health = report.to_dict()
    if ceiling:
        health["at_range_ceiling_samples"] = ceiling
    if k > 1:
        health["decimated_by"] = k
    check_duration(rec, thresholds, own_baseline=own_baseline)
    check_observable(inp, plant, plant_name, str(rec.source or "the recording"))
    return rec, inp, thresholds, sensor, health


def without_saturated(rec: Recording) -> tuple[Recording, dict]:
    """``rec`` with the pressures' samples at a saturated transmitter's ceiling
    (:func:`sam.measurement.at_ceiling`) made missing, as the range's floor is: the filter predicts
    through them instead of fitting a cut-off pressure. A supply pressure read at a chamber's
    ceiling is cut too: its transmitter is of the same range, and a supply above the range reads
    as a constant, which no noise gives away. And {column: [samples, ceiling Pa]}."""
    signals, said = dict(rec.signals), {}
    for column in ("pA", "pB", "pS"):
        if column not in signals:
            continue
        top = at_ceiling(signals[column], rec.dt)
        if column == "pS":
            top |= np.isin(signals[column], [c for _, c in said.values()])
        if top.any():
            said[column] = [int(top.sum()), float(signals[column][top][0])]
            signals[column] = np.where(top, np.nan, signals[column])
    return (replace(rec, signals=signals) if said else rec), said


def own_noise(cfg: FilterConfig, inp) -> tuple[FilterConfig, str]:
    """``cfg`` with the recording's own sensor noise where it is larger
    (:func:`fdi.recording.recording_sensors`), and a note saying so ("" when unchanged)."""
    sensors = recording_sensors(cfg.sensors, inp)
    if sensors == cfg.sensors:
        return cfg, ""
    pairs = (("pressure noise", sensors.pressure_noise, cfg.sensors.pressure_noise, 1e-3, "kPa"),
             ("position noise", sensors.x_noise, cfg.sensors.x_noise, 1e6, "um"),
             ("encoder pulse", sensors.theta_pulse, cfg.sensors.theta_pulse, 180 / np.pi, "deg"))
    said = [f"{name} {new * k:.3g} {unit} (the filter's {old * k:.3g})" for name, new, old, k, unit in pairs
            if new != old]
    return cfg.with_(sensors=sensors), (
        f"the recording's sensors are noisier than the filter's: {', '.join(said)}; the filter assumed the "
        "recording's own, so faults are found later and the thresholds' false-alarm level is not the tuned one")


def replay(rec: Recording, plant: Plant, *, cfg: FilterConfig | None = None, thresholds: Thresholds | None = None,
           drop_out_of_range: bool = False, baseline: Recording | np.ndarray | None = None,
           reference: Recording | None = None, plant_name: str = "plant", position_sensor: str | None = None,
           design: BankDesign = DESIGN) -> Replay:
    """Filter one recording ``rec`` (its measured columns only) with ``cfg`` (default: the shipped
    filter) given the ``plant``, and diagnose it; ``drop_out_of_range``: drop samples outside the
    sensors' ranges instead of refusing the recording (:func:`fdi.recording.filter_input`).

    ``thresholds``: None, the shipped file of the recording's position sensor (``position_sensor``,
    or when None the one :func:`fdi.recording.detect_position_sensor` finds); a file derived for
    another sensor is used, with a warning in the diagnosis' note. ``reference``: a healthy
    recording of the same machine whose learnt notch flows and bulk modulus replace the plant
    file's. ``baseline``: a healthy recording whose estimates are the change tests' baseline
    (for a fault present from the start), or (1, 4) baseline values; default: the recording's own
    estimates over its baseline window. ``plant_name``: how messages name the plant; ``design``:
    the likelihood bank's (:class:`fdi.bank.BankDesign`)."""
    cfg = FilterConfig() if cfg is None else cfg
    rec, inp, thresholds, sensor, health = prepare(rec, plant, thresholds, drop_out_of_range=drop_out_of_range,
                                                   own_baseline=baseline is None, plant_name=plant_name,
                                                   position_sensor=position_sensor, stops=cfg.stops)
    # a healthy recording of the machine is held to what replay asks of any recording
    given = {"--reference": reference, "--baseline": baseline if isinstance(baseline, Recording) else None}
    given = {role: at_thresholds_rate(r, thresholds)[0] for role, r in given.items() if r is not None}
    for role, r in given.items():
        check_duration(r, thresholds, own_baseline=True, role=role)
    cal = None
    if "--reference" in given:
        cal = learn_reference(given["--reference"], plant, cfg, drop_out_of_range=drop_out_of_range)
        health["calibrated_from_reference"] = cal.to_json()
    if "--baseline" in given:
        baseline = reference_baseline(given["--baseline"], plant, thresholds, cfg, cal,
                                      drop_out_of_range=drop_out_of_range)
    if cal is not None:
        inp, cfg = calibration.apply(inp, cfg, cal)
    cfg, noise_note = own_noise(cfg, inp)
    out = run_filter(inp, cfg)
    out = replace(out, t=rec.t - rec.t[0])
    diag = diagnose(out, thresholds, 0, statistics(out, thresholds, baseline), baseline, design=design)
    health["position_sensor"] = sensor
    caveat = excitation_caveat(inp)
    if caveat:
        health["input_not_excited"] = caveat
    note = "; ".join(n for n in (diag.note, noise_note) if n)
    if noise_note:
        health["noise_warning"] = noise_note
    if thresholds.derived.position_sensor != sensor:
        warning = (f"the thresholds were derived for the {thresholds.derived.position_sensor} position sensor, but "
                   f"the recording's position reads as the {sensor} one: their false-alarm level does not hold "
                   f"(derive thresholds with `samfdi fdi thresholds --position-sensor {sensor}`)")
        health["position_sensor_warning"] = warning
        note = f"{note}; {warning}" if note else warning
    diag = replace(diag, filter_health={**diag.filter_health, **health}, note=note)
    return Replay(out, residuals(out, thresholds, baseline), shown_statistics(out, thresholds, diag, baseline), diag)


def replay_recording(rec: Recording, plant: Plant, out_dir, *, force: bool = False,
                     thresholds: Thresholds | None = None, drop_out_of_range: bool = False, figure: bool = True,
                     baseline=None, reference=None, plant_name: str = "plant",
                     position_sensor: str | None = None) -> Diagnosis:
    """Replay a recording ``rec`` given the ``plant`` (:func:`replay`, which documents
    ``thresholds``, ``drop_out_of_range``, ``baseline``, ``reference``, ``plant_name`` and
    ``position_sensor``) and write estimates.csv, residuals.csv, diagnosis.json and, with
    ``figure``, replay.png into ``out_dir`` (an existing file only with ``force``). Returns the
    diagnosis."""
    out_dir = output_folder(out_dir, OUTPUT_FILES, force, create=False)
    sensor = position_sensor or detect_position_sensor(rec, plant)
    thresholds = Thresholds.shipped(sensor) if thresholds is None else thresholds
    r = replay(rec, plant, thresholds=thresholds, drop_out_of_range=drop_out_of_range, baseline=baseline,
               reference=reference, plant_name=plant_name, position_sensor=sensor)
    output_folder(out_dir)
    t = r.output.t + rec.t[0]  # the samples filtered (every k-th of a faster recording)
    _write_estimates(out_dir / "estimates.csv", t, r.output)
    _write_residuals(out_dir / "residuals.csv", t, r.residuals, r.statistics, thresholds)
    (out_dir / "diagnosis.json").write_text(r.diagnosis.to_json() + "\n")
    if figure:
        replay_figure(out_dir / "replay.png", t, r, thresholds, truth=rec.truth, truth_t=rec.t)
    return r.diagnosis


def _write_estimates(path: Path, t, out: FilterOutput) -> None:
    cols = {"t": t}
    for name in ("K_int", "K_extA", "K_extB"):
        j = STATE_NAMES.index(name)
        m, s = out.mean[0, :, j], out.std[0, :, j]
        cols[name] = m
        cols[f"{name}_lo2s"] = m - 2 * s
        cols[f"{name}_hi2s"] = m + 2 * s
        cols[f"{name}_Lpm"] = leak_lpm(m)
        cols[f"{name}_Lpm_lo2s"] = leak_lpm(m - 2 * s)
        cols[f"{name}_Lpm_hi2s"] = leak_lpm(m + 2 * s)
    for name in ("offset", "F_d", "v", "p_A", "p_B", "x"):
        j = STATE_NAMES.index(name)
        m, s = out.mean[0, :, j], out.std[0, :, j]
        cols[name] = m
        cols[f"{name}_lo2s"] = m - 2 * s
        cols[f"{name}_hi2s"] = m + 2 * s
    write_csv(path, cols)


def _write_residuals(path: Path, t, res: dict, stats: dict, th: Thresholds) -> None:
    cols = {"t": t}
    for k, v in res.items():
        cols[k] = v[0]
    for h, g in stats.items():
        cols[f"cusum_{h}"] = g[0]
        cols[f"threshold_{h}"] = np.full(len(t), th.test.h[h])
    write_csv(path, cols)


def write_csv(path: Path, cols: dict) -> None:
    """Columns (name -> (T,) array) as CSV, each value as '%.17g' (reads back to the same
    float64; 'nan' where undefined): np.savetxt (the fastest writer: benchmarks/bench_fdi.py)."""
    names = list(cols)
    data = np.column_stack([np.asarray(cols[n], dtype=float) for n in names])
    np.savetxt(path, data, fmt="%.17g", delimiter=",", header=",".join(names), comments="")
