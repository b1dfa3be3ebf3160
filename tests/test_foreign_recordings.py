"""Recordings written by other labs' loggers, spreadsheets, R, pandas and MATLAB, within the
shared format (docs/recordings.md): what they commonly write is read, with the right numbers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.io

from sam.recording import RecordingError, RecordingWarning, read_recording

N = 6
T = np.arange(N) * 0.002
COLUMNS = {"t": T, "u": np.linspace(-1, 1, N), "pA": np.linspace(1e6, 2e6, N), "pB": np.full(N, 3e5),
           "theta": np.linspace(0.8, 0.9, N)}


def lines(columns=COLUMNS, fmt="{!r}") -> list[str]:
    return [",".join(columns)] + [",".join(fmt.format(float(v[i])) for v in columns.values()) for i in range(N)]


def read(path, text: str):
    path.write_text(text, encoding="utf-8", newline="")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = read_recording(path)
    return rec, [str(w.message) for w in caught if issubclass(w.category, RecordingWarning)]


def test_pandas_row_index_column_without_a_name_is_ignored_with_a_warning(tmp_path):
    # df.to_csv() writes the index as a first column whose header field is empty
    text = "\n".join(("," if k == 0 else f"{k - 1},") + ln for k, ln in enumerate(lines())) + "\n"
    rec, said = read(tmp_path / "pandas.csv", text)
    assert np.array_equal(rec.signals["pA"], COLUMNS["pA"])
    assert np.array_equal(rec.t, T)
    assert said == [f"{tmp_path / 'pandas.csv'}: ignoring column(s) 1 of 6: no name in the header (line 1)"]


def test_a_comma_ending_every_line_is_an_unnamed_column_ignored(tmp_path):
    rec, said = read(tmp_path / "logger.csv", "\r\n".join(ln + "," for ln in lines()) + "\r\n")
    assert np.array_equal(rec.signals["theta"], COLUMNS["theta"])
    assert "column(s) 6 of 6: no name" in said[0]


def test_R_write_csv_NA_and_quoted_names_and_row_names_are_read(tmp_path):
    # write.csv(df): quoted names, a quoted row-name column with an empty name, NA for missing
    body = [",".join(f'"{n}"' for n in ["", *COLUMNS])]
    for i in range(N):
        values = ["NA" if (name == "pA" and i == 2) else repr(float(v[i])) for name, v in COLUMNS.items()]
        body.append(",".join([f'"{i + 1}"', *values]))
    rec, _ = read(tmp_path / "r.csv", "\n".join(body) + "\n")
    expected = COLUMNS["pA"].copy()
    expected[2] = np.nan
    assert np.array_equal(rec.signals["pA"], expected, equal_nan=True)


@pytest.mark.parametrize("marker", ["NA", "n/a", "#N/A"])
def test_spreadsheet_missing_markers_are_missing_samples(tmp_path, marker):
    text = lines()
    fields = text[3].split(",")
    fields[2] = marker  # pA of data row 3
    text[3] = ",".join(fields)
    rec, _ = read(tmp_path / "gaps.csv", "\n".join(text) + "\n")
    assert np.isnan(rec.signals["pA"][2]) and np.isfinite(rec.signals["pA"]).sum() == N - 1


def test_a_units_row_under_the_header_is_refused_naming_it(tmp_path):
    text = lines()
    text.insert(1, "s,V,Pa,Pa,rad")
    with pytest.raises(RecordingError) as err:
        read(tmp_path / "units.csv", "\n".join(text) + "\n")
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'units.csv'}: 't' (data row 1, line 2): non-numeric value 's'; ")
    assert "a row of units or names under the header?" in message and "\n" not in message


def test_text_in_a_later_row_gets_no_units_hint(tmp_path):
    text = lines()
    text[4] = text[4].replace(repr(float(COLUMNS["u"][3])), "err", 1)
    with pytest.raises(RecordingError, match=r"'u' \(data row 4, line 5\): non-numeric value 'err'$"):
        read(tmp_path / "text.csv", "\n".join(text) + "\n")


def test_a_header_of_only_commas_is_refused_in_one_line(tmp_path):
    with pytest.raises(RecordingError, match=r"header \(line 1\) has no column names$"):
        read(tmp_path / "blank.csv", ",,,,\n" + "\n".join(lines()[1:]) + "\n")


def test_two_unnamed_columns_are_not_duplicates(tmp_path):
    text = [ln + ",," for ln in lines()]
    rec, said = read(tmp_path / "two.csv", "\n".join(text) + "\n")
    assert "column(s) 6, 7 of 7" in said[0] and rec.n == N


# ------------------------------------------------ forms read before, kept (the other labs' files)


def test_bom_crlf_metadata_float32_time_and_blank_tail(tmp_path):
    t32 = np.cumsum(np.full(N, np.float32(0.002), dtype=np.float32)).astype(float) + 1234.5
    cols = {**COLUMNS, "t": t32, "pressure_setpoint": np.ones(N)}
    text = "\r\n".join(["# plant: sam", "# operator: J. K.", *lines(cols, "{:.8g}")]) + "\r\n\r\n \r\n"
    path = tmp_path / "lab.csv"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    with pytest.warns(RecordingWarning, match="'pressure_setpoint'"):
        rec = read_recording(path)
    assert rec.metadata == {"plant": "sam", "operator": "J. K."}
    assert rec.dt == pytest.approx(0.002, rel=1e-5) and rec.t[0] == pytest.approx(1234.502)


@pytest.mark.parametrize("oned_as", ["row", "column"])
def test_mat_row_or_column_vectors_ints_float32_and_a_char_matrix_description(tmp_path, oned_as):
    variables = {**COLUMNS, "pB": COLUMNS["pB"].astype(np.int32), "u": COLUMNS["u"].astype(np.float32),
                 "description": np.array(["rig B, run 7", "healthy     "])}
    scipy.io.savemat(tmp_path / "lab.mat", variables, oned_as=oned_as, do_compression=oned_as == "row")
    rec = read_recording(tmp_path / "lab.mat")
    assert rec.metadata == {"description": "rig B, run 7\nhealthy"}
    assert rec.signals["pB"].dtype == np.float64 and np.array_equal(rec.signals["pB"], COLUMNS["pB"])
    assert np.array_equal(rec.signals["u"], COLUMNS["u"].astype(np.float32).astype(float))


# ------------------------------------------------ pressures at a transmitter's ceiling


def test_at_ceiling_marks_runs_flat_at_the_top_of_a_noisy_signal_only():
    from sam.measurement import at_ceiling

    rng = np.random.default_rng(3)
    p = 6e6 + 2e6 * np.sin(np.linspace(0, 6, 4000)) + rng.normal(0, 15e3, 4000)
    assert not at_ceiling(p, 1e-3).any()  # noise never repeats its top reading
    clipped = np.minimum(p, 7.5e6)
    marked, cut = at_ceiling(clipped, 1e-3), p >= 7.5e6
    assert not (marked & ~cut).any() and marked.sum() >= 0.98 * cut.sum()  # flickers at the edge are short runs
    smooth = np.minimum(6e6 + 2e6 * np.sin(np.linspace(0, 6, 4000)), 7.5e6)
    assert not at_ceiling(smooth, 1e-3).any()  # no noise: a simulation's own flat top, not a transmitter
    short = p.copy()
    short[100:104] = short.max() + 1.0  # 4 equal readings: a top, not a saturated run
    assert not at_ceiling(short, 1e-3).any()


def test_mat_description_as_a_cell_array_of_lines_is_read(tmp_path):
    scipy.io.savemat(tmp_path / "cell.mat", {**COLUMNS, "description": np.array(["rig B", "run 7"], dtype=object)})
    assert read_recording(tmp_path / "cell.mat").metadata == {"description": "rig B\nrun 7"}


def test_mat_run_kept_in_one_struct_is_refused_saying_how_to_save_it(tmp_path):
    scipy.io.savemat(tmp_path / "struct.mat", {"run7": COLUMNS})
    with pytest.raises(RecordingError) as err:
        read_recording(tmp_path / "struct.mat")
    assert str(err.value) == (f"{tmp_path / 'struct.mat'}: 'run7': a struct with fields t, u, pA, pB, theta; the format "
                              "wants one variable per column: in MATLAB, save(file, '-struct', 'run7') saves them so")


def _clipped_healthy_run():
    """5 s of the model under a sine input with 20 kPa transmitter noise, read through transmitters
    whose top is where 80 % of pA's samples lie: pA cut there and the supply pressure (above the
    top) a constant; and how many samples of pA the cut flattened."""
    from fdi.synth import input_signal, simulate_runs
    from sam import Recording, load_plant

    t = np.arange(5001) * 1e-3
    u = input_signal("sine", t, amplitude=3.0, frequency=0.25)
    r = simulate_runs(load_plant().vector()[None], u, 1e-3, seed=9)
    pA = r.inp.pA[0].copy()
    top = float(np.quantile(pA, 0.8))
    pA = np.minimum(pA, top)
    pS = np.minimum(load_plant().supply.p_S + np.random.default_rng(9).normal(0, 20e3, len(t)), top)
    signals = {"u": u, "pA": pA, "pB": r.inp.pB[0], "theta": r.inp.pos[0], "pS": pS}
    return Recording(t, signals), int((pA == top).sum()), top


def test_replay_predicts_through_a_saturated_transmitter_and_says_so(tmp_path):
    import fdi
    from sam import load_plant

    rec, flat, top = _clipped_healthy_run()
    d = fdi.replay_recording(rec, load_plant(), tmp_path / "sat", figure=False)
    assert d.status == "healthy", (d.status, d.alarms, d.note)
    n, ceiling = d.filter_health["at_range_ceiling_samples"]["pA"]
    assert ceiling == top and 0.95 * flat <= n <= flat  # all but flickers at the edges of the cut
    assert d.filter_health["at_range_ceiling_samples"]["pS"] == [rec.n, top]


def test_mismatch_does_not_score_a_saturated_transmitter(tmp_path):
    from discrepancy.data import missing_note, prepare
    from sam import load_plant

    rec, flat, top = _clipped_healthy_run()
    data = prepare(rec, load_plant())
    cut = rec.signals["pA"] == top
    missing = ~data.valid["pA"]
    assert not (missing & ~cut).any() and missing.sum() >= 0.95 * flat  # all but flickers at the cut's edges
    assert not (data.scored["pA"] & missing).any()
    assert f"sample(s) of 'pA' flat at {top / 1e6:.4g} MPa, a transmitter at the top of its range" in missing_note(data)


def test_replay_of_a_recording_on_the_loggers_clock_says_where_its_times_start(tmp_path, capsys):
    from dataclasses import replace

    from sam import write_recording
    from samfdi.cli import main

    rec, _, _ = _clipped_healthy_run()
    rec = replace(rec, t=rec.t + 1234.5)
    path = write_recording(tmp_path / "clock.csv", rec)
    assert main(["fdi", "replay", str(path), "--out", str(tmp_path / "out")]) == 0
    said = capsys.readouterr().out.splitlines()
    assert "times above are seconds from the recording's start, t = 1234.5 s in the file (estimates.csv and " \
           "residuals.csv keep the file's t)" in said
    assert float((tmp_path / "out" / "estimates.csv").read_text().splitlines()[1].split(",")[0]) == 1234.5


def test_mismatch_says_when_it_filled_in_the_input(tmp_path):
    from dataclasses import replace

    from discrepancy.data import missing_note, prepare
    from sam import load_plant

    rec, _, _ = _clipped_healthy_run()
    u = rec.signals["u"].copy()
    u[:200] = np.nan  # a logger that starts the valve channel late
    note = missing_note(prepare(replace(rec, signals={**rec.signals, "u": u}), load_plant()))
    assert note.startswith("recording: missing (NaN) samples, 200 in the input 'u'; ")
