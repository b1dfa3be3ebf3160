"""Offline replay of a recording: filter, residuals, alarms, diagnosis, files, figure.

Only ``rec.measured()`` is ever used: the ``true_*`` columns are dropped before
anything else looks at the recording.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from sam import P, Plant, Recording, UserError, simulate_batch
from sam.errors import output_folder
from sam.geometry import joint_angle, piston_position
from sam.measurement import ENCODER_RESOLUTION_RAD

from . import calibration
from .detect import (
    HYPOTHESES, MIN_TESTED_S, PARAMS, Diagnosis, Thresholds, detector_statistics, diagnose, held, residuals, statistics,
)
from .config import FilterConfig
from .filter import FilterInput, FilterOutput, model_substeps, run_filter
from .states import K_PER_LPM, POS_THETA, POS_X, STATE_NAMES, leak_lpm

SENSOR_RANGE_PA = (0.0, 25e6)  #: pressure sensors of the SAM
RANGE_MARGIN_PA = 0.5e6  #: noise around the range ends that is still accepted
#: Hz: the coarsest sampling replay accepts. The model is stepped every <= 1 ms whatever the
#: rate (fdi.ukf.model_substeps), and thresholds derived for the rate (``samfdi fdi thresholds
#: --sample-rate``) keep the false alarms at their level, but detection fades with the rate:
#: measured, 0.5 L/min leaks and 2 % offsets found within 1 s in 74 / 49 / 26 / 1 of 75 runs at
#: 1000 / 500 / 200 / 100 Hz (docs/fdi.md, "Sampling rate"); below 100 Hz nothing is left
MIN_SAMPLE_RATE_HZ = 100.0
#: relative: a recording's step against its thresholds' (the format allows 1 % of jitter)
DT_TOLERANCE = 0.01
#: m: how far a position reading may stray outside the plant's stroke (sensor zero and noise);
#: further out the recording and the plant file describe different machines
POSITION_MARGIN_M = 0.005
OUTPUT_FILES = ("estimates.csv", "residuals.csv", "diagnosis.json", "replay.png")
FIGURE_CLIP = 5.0  #: the replay figure shows statistic / threshold up to this


#: a recording's x counts as computed from the SAM's encoder when its samples, turned back into
#: joint angles with the plant's geometry, sit on a grid of encoder pulses: locally, within
#: windows of ENCODER_GRID_WINDOW pulses of theta, so that a plant geometry a little off the
#: logger's (which stretches the grid along the stroke) or x rounded to 10 um keeps it. The
#: measure is the mean resultant length of the samples' phases on the grid, sum over windows of
#: |sum exp(2 pi i theta / pulse)| / n: 1 on a grid, about 1 / sqrt(samples per window) for a
#: continuous reading. Measured on five shipped scenarios: the encoder's x 1.00 (1 um of white
#: noise 0.98, rounded to 10 um 0.87-0.89, read with the plant's L_1 1 mm off 0.91-0.96, 5 mm off
#: 0.20-0.50); the true x with 10 um of white noise 0.04-0.21, noise-free 0.06-0.32 (long rests)
ENCODER_GRID_WINDOW = 50
ENCODER_GRID_COHERENCE = 0.6


def detect_position_sensor(rec: Recording, plant: Plant) -> str:
    """The position sensor of a recording (fdi.detect.SHIPPED_BY_SENSOR): "encoder" when the filter
    reads theta or an x computed from the encoder's theta (on its grid,
    :data:`ENCODER_GRID_COHERENCE`), "linear" for any other x. Why it matters: the thresholds
    depend on it (Thresholds.position_sensor), and so does the filter on an end stop
    (fdi.ukf.FilterConfig.stop_learners). An x that never moves reads as the encoder."""
    if "x" not in rec.signals:
        return "encoder"
    return "encoder" if encoder_grid_coherence(rec.signals["x"], plant) >= ENCODER_GRID_COHERENCE else "linear"


def encoder_grid_coherence(x: np.ndarray, plant: Plant) -> float:
    """How closely positions x (T,) [m] sit on the encoder's grid, 0-1 (:data:`ENCODER_GRID_COHERENCE`);
    0 when no sample maps to a joint angle."""
    p = plant.vector()
    x = np.asarray(x, dtype=float)
    theta = joint_angle(x[np.isfinite(x)], p[P.L_1], p[P.L_2], p[P.L_3])
    phase = theta[np.isfinite(theta)] / ENCODER_RESOLUTION_RAD  # in pulses
    if not len(phase):
        return 0.0
    _, window = np.unique(np.floor(phase / ENCODER_GRID_WINDOW), return_inverse=True)
    z = np.exp(2j * np.pi * phase)
    resultant = np.bincount(window, z.real) + 1j * np.bincount(window, z.imag)
    return float(np.abs(resultant).sum() / len(phase))


def filter_input(rec: Recording, plant: Plant, *, drop_out_of_range: bool = False,
                 position_sensor: str | None = None) -> tuple[FilterInput, dict]:
    """Check a (measured-only) recording and turn it into the filter's input. ``position_sensor``:
    where its x came from (:func:`detect_position_sensor` when None)."""
    name = str(rec.source) if rec.source else "recording"
    if rec.n < 10:
        raise UserError(f"{name}: only {rec.n} samples; the filter needs at least 10")
    dt = rec.dt
    info = {"samples": rec.n, "dt_s": dt, "position": "x" if "x" in rec.signals else "theta",
            "supply_pressure_measured": "pS" in rec.signals, "out_of_range_samples": 0,
            "ignored_optional_columns": sorted(set(rec.signals) & {"v", "xs"})}
    sig = {k: np.array(v, dtype=float) for k, v in rec.signals.items()}
    for ch in ("pA", "pB", "pS"):
        if ch in sig:
            a = sig[ch]
            bad = np.isfinite(a) & ((a < SENSOR_RANGE_PA[0] - RANGE_MARGIN_PA) | (a > SENSOR_RANGE_PA[1] + RANGE_MARGIN_PA))
            _drop(name, rec.t, ch, a, bad, "Pa", "the sensor range 0-25 MPa", drop_out_of_range, info)
    column = "x" if "x" in sig else "theta"
    bad, stroke = _outside_stroke(column, sig[column], plant)
    _drop(name, rec.t, column, sig[column], bad, "m" if column == "x" else "rad", stroke, drop_out_of_range, info,
          hint="check the sensor's zero and sign, or the plant file; ")
    for ch in ("pA", "pB", column):
        if not np.isfinite(sig[ch]).any():  # --drop-out-of-range left nothing of it
            raise UserError(f"{name}: '{ch}': every sample is outside its valid range; nothing is left to filter")
    if "pS" in sig and not np.isfinite(sig["pS"]).any():  # the plant's supply pressure, as without the column
        del sig["pS"]
        info["supply_pressure_measured"] = False
    u = sig["u"]
    if np.isnan(u).any():  # the input drives the model: hold the last value through a gap
        idx = np.where(np.isfinite(u), np.arange(len(u)), 0)
        np.maximum.accumulate(idx, out=idx)
        u = u[idx]
        u[~np.isfinite(u)] = 0.0
        info["u_gaps_held"] = int(np.isnan(sig["u"]).sum())
    pos, kind = sig[column], POS_X if column == "x" else POS_THETA
    sensor = "encoder" if column == "theta" else position_sensor or detect_position_sensor(rec, plant)
    params = plant.vector()[None, :]
    inp = FilterInput(dt=dt, u=u[None, :], pA=sig["pA"][None, :], pB=sig["pB"][None, :], pos=pos[None, :],
                      pos_kind=kind, params=params, pS=sig["pS"][None, :] if "pS" in sig else None,
                      position_sensor=sensor)
    return inp, info


def _drop(name: str, t, column: str, a: np.ndarray, bad: np.ndarray, unit: str, valid: str,
          drop: bool, info: dict, hint: str = "") -> None:
    """Samples ``bad`` of column ``a`` lie outside ``valid``: refuse the recording (UserError)
    or, with ``drop`` (--drop-out-of-range), make them missing samples (NaN, in place) and count
    them in ``info``."""
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    if not drop:
        raise UserError(f"{name}: '{column}': {int(bad.sum())} sample(s) outside {valid} (first at data row "
                        f"{i + 1}, t = {t[i]:.6g} s: {a[i]:.6g} {unit}); {hint}use --drop-out-of-range to treat "
                        "them as missing samples")
    a[bad] = np.nan
    info["out_of_range_samples"] += int(bad.sum())


def _outside_stroke(column: str, pos: np.ndarray, plant: Plant) -> tuple[np.ndarray, str]:
    """(bad (T,), description): samples of the position column ("x" [m] or "theta" [rad]) whose
    piston position lies outside the plant's stroke [0, x_end] by more than POSITION_MARGIN_M
    (theta outside (0, pi) has no position). Outside it the filter would hold the piston on an
    end stop at every sample and report a confident, meaningless diagnosis."""
    p = plant.vector()
    L = p[P.L_1], p[P.L_2], p[P.L_3]
    x_joint = piston_position(p[P.theta_max], *L)
    x_end = min(p[P.x_max], x_joint)
    if column == "x":
        x = pos
    else:
        x = np.where((pos > 0.0) & (pos < np.pi), piston_position(np.clip(pos, 0.0, np.pi), *L), np.nan)
    bad = np.isfinite(pos) & ~((x >= -POSITION_MARGIN_M) & (x <= x_end + POSITION_MARGIN_M))
    ends = ("" if column == "x" else
            f"theta {joint_angle(0.0, *L):.4g}-{joint_angle(x_end, *L):.4g} rad, i.e. ") + f"x 0-{x_end:.4g} m"
    limit = (f"theta_max {p[P.theta_max]:g} rad limits x_max {p[P.x_max]:g} m" if x_joint < p[P.x_max]
             else f"x_max {p[P.x_max]:g} m")
    return bad, f"the plant's stroke ({ends}, +-{POSITION_MARGIN_M * 1e3:g} mm; {limit})"


def check_observable(inp: FilterInput, plant: Plant, name: str = "plant", recording: str = "the recording") -> None:
    """Refuse a plant under which a fault parameter cannot change the measurements.

    Simulates the recording's input for up to 2 s with each fault set to a clear
    size (1 L/min at 10 MPa, 2 % offset) and checks that the pressures move by more
    than the sensor noise.
    """
    T = min(inp.u.shape[1], int(2.0 / inp.dt) + 1)
    p0 = plant.vector()
    rows = [p0.copy()]
    sizes = {"K_int": K_PER_LPM, "K_extA": K_PER_LPM, "K_extB": K_PER_LPM, "offset": 0.02}
    for f, v in sizes.items():
        p = p0.copy()
        p[P[f]] = v
        rows.append(p)
    params = np.array(rows)
    from sam import initial_state
    x0 = initial_state(params, x=0.05)
    n_sub = model_substeps(inp.dt)  # the model steps the filter takes: a coarse recording's input held
    res = simulate_batch(params, np.repeat(inp.u[0, :T - 1], n_sub), inp.dt / n_sub, x0=x0,
                         record_every=n_sub, channels=("p_A", "p_B", "x"))
    ok = [np.isfinite(res[c]).all() for c in ("p_A", "p_B", "x")]
    if not all(ok):
        raise UserError(f"{name}: the model diverges under this plant and the input of {recording}; "
                        "check the plant parameters (lengths and diameters in m, volumes, B_eff, valve flows)")
    for i, f in enumerate(sizes, start=1):
        effect = max(np.max(np.abs(res["p_A"][i] - res["p_A"][0])), np.max(np.abs(res["p_B"][i] - res["p_B"][0])))
        if not effect > 20e3:
            raise UserError(
                f"{name}: parameter '{f}' is unobservable with this plant: a fault of "
                f"{'2 %' if f == 'offset' else '1 L/min at 10 MPa'} changes the chamber pressures by "
                f"only {effect:.3g} Pa (< the 20 kPa sensor noise) under the input of {recording}; "
                "check p_S, B_eff, V_0A, V_0B and the valve flows")


def learn_reference(ref: Recording, plant: Plant, cfg: FilterConfig, *,
                    drop_out_of_range: bool = False) -> calibration.Calibration:
    """The machine constants (notch flows, bulk modulus) that ``cfg``'s calibration states
    learn on a healthy reference recording of the same machine (:mod:`fdi.calibration`)."""
    name = str(ref.source or "reference recording")
    inp, _ = filter_input(ref.measured(), plant, drop_out_of_range=drop_out_of_range)
    cal = calibration.learn(run_filter(inp, cfg), cfg)
    if not cal.factor:
        raise UserError(f"{name}: --reference: the filter of these thresholds calibrates none of "
                        f"{', '.join(calibration.MACHINE_STATES)}, so a reference has nothing to teach it")
    return cal


def reference_baseline(ref: Recording, plant: Plant, th: Thresholds, cfg: FilterConfig,
                       cal: calibration.Calibration | None = None, *,
                       drop_out_of_range: bool = False) -> np.ndarray:
    """(1, 4) healthy baseline of the fault estimates from a reference recording of the same
    machine: the mean of each estimate over the second half of the reference, filtered with the
    calibration ``cal`` if the replay uses one, over the samples at which pinned pressures do not
    hide it (:func:`fdi.detect.held`; the whole reference if its second half hides it)."""
    name = str(ref.source or "reference recording")
    inp, _ = filter_input(ref.measured(), plant, drop_out_of_range=drop_out_of_range)
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


def replay(rec: Recording, plant: Plant, *, cfg: FilterConfig | None = None,
           thresholds: Thresholds | None = None, drop_out_of_range: bool = False,
           baseline: Recording | np.ndarray | None = None, reference: Recording | None = None,
           plant_name: str = "plant", position_sensor: str | None = None):
    """Filter one recording and diagnose it. Returns (output, residuals, stats, diagnosis, info).

    ``thresholds``: None, the shipped file of the recording's position sensor: ``position_sensor``
    (fdi.detect.SHIPPED_BY_SENSOR), or when None the one :func:`detect_position_sensor` finds; a
    file derived for another sensor is used, with a warning in the diagnosis' note.

    ``reference``: a healthy recording of the same machine whose learnt notch flows and bulk
    modulus replace the plant file's (:func:`learn_reference`); the change test keeps its own
    baseline. ``baseline``: a healthy recording whose estimates are the baseline instead
    (:func:`reference_baseline`; for faults present from the start), or (1, 4) baseline
    values; default: the recording's own estimates over the baseline window of the thresholds.
    ``plant_name``: how messages name the plant (its file)."""
    sensor = position_sensor or detect_position_sensor(rec, plant)
    thresholds = Thresholds.shipped(sensor) if thresholds is None else thresholds
    cfg = FilterConfig() if cfg is None else cfg
    rec, k = at_thresholds_rate(rec.measured(), thresholds)  # never the true_* columns
    inp, info = filter_input(rec, plant, drop_out_of_range=drop_out_of_range, position_sensor=sensor)
    if k > 1:
        info["decimated_by"] = k
    _check_duration(rec, thresholds, own_baseline=baseline is None)
    check_observable(inp, plant, plant_name, str(rec.source or "the recording"))
    cal = None
    if reference is not None:
        cal = learn_reference(at_thresholds_rate(reference, thresholds)[0], plant, cfg,
                              drop_out_of_range=drop_out_of_range)
        info["calibrated_from_reference"] = cal.to_json()
    if isinstance(baseline, Recording):
        baseline = reference_baseline(at_thresholds_rate(baseline, thresholds)[0], plant, thresholds, cfg, cal,
                                      drop_out_of_range=drop_out_of_range)
    if cal is not None:
        inp, cfg = calibration.apply(inp, cfg, cal)
    out = run_filter(inp, cfg)
    out = replace(out, t=rec.t - rec.t[0])
    stats = statistics(out, thresholds, baseline)
    diag = diagnose(out, thresholds, 0, stats, baseline)
    stats = detector_statistics(out, thresholds, diag, baseline)  # restarted after withdrawn alarms
    info["position_sensor"] = sensor
    if thresholds.position_sensor != sensor:
        warning = (f"the thresholds were derived for the {thresholds.position_sensor} position sensor, but the "
                   f"recording's position reads as the {sensor} one: their false-alarm level does not hold (derive "
                   f"thresholds with `samfdi fdi thresholds --position-sensor {sensor}`)")
        info["position_sensor_warning"] = warning
        diag.note = f"{diag.note}; {warning}" if diag.note else warning
    diag.filter_health.update(info)
    if info["out_of_range_samples"]:
        diag.filter_health["out_of_range_samples"] = info["out_of_range_samples"]
    res = residuals(out, thresholds, baseline)
    return out, res, stats, diag, info


def at_thresholds_rate(rec: Recording, th: Thresholds) -> tuple[Recording, int]:
    """The recording at the rate its thresholds were derived for (sigma and h depend on it:
    measured, the 1 kHz thresholds raise 12 % false alarms at 500 Hz), and the decimation k:
    as it is (k = 1) within DT_TOLERANCE of that rate, every k-th sample when it is a whole k
    times faster; otherwise a UserError that names what to do."""
    if not (rec.dt <= (1.0 + DT_TOLERANCE) / MIN_SAMPLE_RATE_HZ):
        raise UserError(f"{rec.source or 'recording'}: 't': sampled every {rec.dt * 1e3:.3g} ms ({1 / rec.dt:.4g} Hz); "
                        f"the filter needs {MIN_SAMPLE_RATE_HZ:g} Hz or faster to follow the chamber pressures")
    ratio = th.sample_dt_s / rec.dt
    k = max(1, round(ratio))
    if abs(ratio / k - 1.0) <= DT_TOLERANCE:
        if k == 1:
            return rec, 1
        return Recording(rec.t[::k], {c: v[::k] for c, v in rec.signals.items()}, {}, rec.metadata, rec.source), k
    rate, ms = 1.0 / rec.dt, rec.dt * 1e3
    supported = 1000.0 / max(1, round(ms))  # the studies sample every whole ms
    if rate < 1000.0 and abs(supported / rate - 1.0) <= DT_TOLERANCE and supported >= MIN_SAMPLE_RATE_HZ:
        todo = (f"derive thresholds for it with `samfdi fdi thresholds --sample-rate {supported:.5g} --out DIR` "
                "and pass --thresholds DIR/thresholds.toml")
    else:
        todo = "resample it to 1000 Hz, or to 1000 / k Hz (k = 2 ... 10) and derive thresholds for that rate"
    raise UserError(f"{rec.source or 'recording'}: 't': sampled at {rate:.4g} Hz, but the thresholds were derived "
                    f"for {1 / th.sample_dt_s:.4g} Hz ({th.source}); {todo}")


def _check_duration(rec: Recording, th: Thresholds, own_baseline: bool) -> None:
    """Refuse a recording too short to test: "healthy" would only mean "not looked at"."""
    needed = th.warmup_s + (th.baseline_s if own_baseline else 0.0) + MIN_TESTED_S
    duration = float(rec.t[-1] - rec.t[0])
    if duration < needed:
        parts = f"{th.warmup_s:g} s filter warm-up" + (f", {th.baseline_s:g} s healthy baseline" if own_baseline else "")
        raise UserError(f"{rec.source or 'recording'}: 't': only {duration:.3g} s long; a diagnosis needs at least "
                        f"{needed:g} s ({parts} and {MIN_TESTED_S:g} s to test)")


def replay_recording(rec: Recording, plant: Plant, out_dir, *, force: bool = False,
                     thresholds: Thresholds | None = None, drop_out_of_range: bool = False,
                     figure: bool = True, baseline=None, reference=None, plant_name: str = "plant",
                     position_sensor: str | None = None) -> Diagnosis:
    """Replay and write estimates.csv, residuals.csv, diagnosis.json and replay.png into out_dir."""
    out_dir = output_folder(out_dir, OUTPUT_FILES, force, create=False)
    sensor = position_sensor or detect_position_sensor(rec, plant)
    thresholds = Thresholds.shipped(sensor) if thresholds is None else thresholds
    out, res, stats, diag, info = replay(rec, plant, thresholds=thresholds, drop_out_of_range=drop_out_of_range,
                                         baseline=baseline, reference=reference, plant_name=plant_name,
                                         position_sensor=sensor)
    output_folder(out_dir)
    t = out.t + rec.t[0]  # the samples filtered (every k-th of a faster recording)
    _write_estimates(out_dir / "estimates.csv", t, out)
    _write_residuals(out_dir / "residuals.csv", t, res, stats, thresholds)
    (out_dir / "diagnosis.json").write_text(diag.to_json() + "\n")
    if figure:
        _figure(out_dir / "replay.png", t, out, res, stats, thresholds, diag)
    return diag


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
    _write_csv(path, cols)


def _write_residuals(path: Path, t, res, stats, th: Thresholds) -> None:
    cols = {"t": t}
    for k, v in res.items():
        cols[k] = v[0]
    for h, g in stats.items():
        cols[f"cusum_{h}"] = g[0]
        cols[f"threshold_{h}"] = np.full(len(t), th.h[h])
    _write_csv(path, cols)


def _write_csv(path: Path, cols: dict) -> None:
    """Columns (name -> (T,) array) as CSV, each value as '%.17g' (reads back to the same
    float64; 'nan' where undefined). np.savetxt formats a row per call: about 1 us per value,
    the main cost of a long replay's output besides the filter (docs/benchmarks.md)."""
    names = list(cols)
    data = np.column_stack([np.asarray(cols[n], dtype=float) for n in names])
    np.savetxt(path, data, fmt="%.17g", delimiter=",", header=",".join(names), comments="")


def _alarm_lines(diag) -> list:
    """(time [s], axvline style) of the alarms to mark: with the likelihood bank the alarm that
    stood (red) and the withdrawn ones (grey, dashed); otherwise every hypothesis' first alarm."""
    lik = diag.likelihood
    if "withdrawn_alarms_s" not in lik:
        return [(ta, {"color": "r", "lw": 0.8}) for ta in diag.alarms.values()]
    lines = [(ta, {"color": "0.5", "lw": 0.8, "ls": "--"}) for ta in lik["withdrawn_alarms_s"]]
    if lik.get("alarm_s") is not None and lik.get("confirmed_s") is not None:
        lines.append((lik["alarm_s"], {"color": "r", "lw": 0.8}))
    return lines


def _figure(path: Path, t, out, res, stats, th, diag) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    ax = axes[0]
    for name, c in zip(("K_int", "K_extA", "K_extB"), ("C0", "C1", "C2")):
        j = STATE_NAMES.index(name)
        m, s = leak_lpm(out.mean[0, :, j]), leak_lpm(out.std[0, :, j])
        ax.plot(t, m, c, label=name)
        ax.fill_between(t, m - 2 * s, m + 2 * s, color=c, alpha=0.2)
    ax.set_ylabel("leak [L/min at 10 MPa]")
    ax.legend(loc="upper left")
    ax2 = axes[1]
    j = STATE_NAMES.index("offset")
    m, s = 100 * out.mean[0, :, j], 100 * out.std[0, :, j]
    ax2.plot(t, m, "C3", label="offset")
    ax2.fill_between(t, m - 2 * s, m + 2 * s, color="C3", alpha=0.2)
    ax2.set_ylabel("offset [% travel]")
    ax2.legend(loc="upper left")
    ax3 = axes[2]
    for i, (h, g) in enumerate(stats.items()):
        ax3.plot(t, g[0] / th.h[h], f"C{i}", label=f"CUSUM {h} / h" if h in HYPOTHESES else f"{h} jump / h")
    ax3.axhline(1.0, color="k", ls="--", label="threshold")
    # a real fault drives g/h to hundreds or thousands: clip, so that the threshold stays readable
    top = max((float(np.nanmax(g[0] / th.h[h])) for h, g in stats.items()), default=1.0)
    ax3.set_ylim(0.0, min(max(2.0, 1.1 * top), FIGURE_CLIP))
    if top > FIGURE_CLIP:
        ax3.text(0.99, 0.97, f"clipped at {FIGURE_CLIP:g} (max {top:.3g})", transform=ax3.transAxes,
                 ha="right", va="top", fontsize=8)
    if "pinned" in res and res["pinned"][0].any():  # stalled / end stop: some tests held
        ax3.fill_between(t, 0, 1, where=res["pinned"][0] > 0, transform=ax3.get_xaxis_transform(),
                         color="0.85", label="pinned at supply / tank (tests held)")
    if "long_stroke" in res and res["long_stroke"][0].any():  # K_int / offset tests count only large excursions
        ax3.fill_between(t, 0, 1, where=res["long_stroke"][0] > 0, transform=ax3.get_xaxis_transform(),
                         color="C9", alpha=0.12, label=f"long stroke (K_int, offset: drift {th.long_stroke_drift:g} sigma)")
    ax3.set_ylabel("statistic / threshold")
    ax3.set_xlabel("t [s]")
    ax3.legend(loc="upper left", fontsize=8)
    for ta, style in _alarm_lines(diag):
        for a in axes:
            a.axvline(ta, **style)
    if diag.likelihood.get("withdrawn_alarms_s"):
        ax3.plot([], [], color="0.5", lw=0.8, ls="--", label="withdrawn alarm (the bank saw no fault; tests restarted)")
        ax3.legend(loc="upper left", fontsize=8)
    title = f"diagnosis: {diag.status} {', '.join(diag.isolated)}"
    if diag.isolation_time_s is not None:  # the likelihood bank's decision
        for a in axes:
            a.axvline(diag.isolation_time_s, color="k", lw=1.2, ls=":")
        title += f" (isolated by likelihood at {diag.isolation_time_s:.2f} s, dotted)"
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
