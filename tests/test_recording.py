"""Recording format: round trips, third-party files, and refusal of bad files."""

from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sam.errors import UserError
from sam.recording import (
    Recording,
    RecordingError,
    RecordingWarning,
    read_recording,
    write_recording,
)

N = 8
DT = 0.002


def sample_recording() -> Recording:
    """A small but complete recording: gaps, truth, awkward floats, multi-line metadata."""
    t = np.arange(N) * DT
    u = np.array([0.0, 1.5, -2.25, np.nan, 9.99, -10.0, 0.1, 1 / 3])
    pA = np.array([1.2e5, 1.3e5, np.nan, np.nan, 2.0e7, 1.1e5, 1.0e5, 0.0])
    pB = np.linspace(2e5, 3e5, N)
    x = np.array([0.0, 0.01, 0.02, 0.03, np.nan, 0.05, 0.06, 0.0700000001])
    pS = np.full(N, 2.1e7)
    truth = {"true_K_int": np.linspace(0, 1e-12, N), "true_mL": np.full(N, 494.0)}
    metadata = {"plant": "sam", "description": "extension, 494 kg load\nsecond line"}
    return Recording(t, {"u": u, "pA": pA, "pB": pB, "x": x, "pS": pS}, truth, metadata)


def assert_bits_equal(a: np.ndarray, b: np.ndarray) -> None:
    """Same NaN positions and, elsewhere, the same float64 bits (so -0.0 != 0.0)."""
    assert a.dtype == np.float64 and b.dtype == np.float64
    assert a.shape == b.shape
    assert np.array_equal(np.isnan(a), np.isnan(b))
    keep = ~np.isnan(a)
    assert np.array_equal(a[keep].view(np.uint64), b[keep].view(np.uint64))


def assert_same_recording(a: Recording, b: Recording) -> None:
    assert_bits_equal(a.t, b.t)
    assert a.signals.keys() == b.signals.keys()
    assert a.truth.keys() == b.truth.keys()
    for name in a.signals:
        assert_bits_equal(a.signals[name], b.signals[name])
    for name in a.truth:
        assert_bits_equal(a.truth[name], b.truth[name])
    assert a.metadata == b.metadata


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", [".csv", ".mat"])
def test_round_trip_is_bit_exact(tmp_path, suffix):
    rec = sample_recording()
    path = write_recording(tmp_path / f"run{suffix}", rec)
    back = read_recording(path)
    assert_same_recording(rec, back)
    assert back.source == path
    assert back.dt == pytest.approx(DT)
    assert back.n == N


def test_csv_writer_layout(tmp_path):
    rec = sample_recording()
    # signals given in a scrambled order must come out in SIGNALS order, truth sorted
    scrambled = Recording(rec.t, dict(reversed(rec.signals.items())), dict(reversed(rec.truth.items())), rec.metadata)
    text = write_recording(tmp_path / "run.csv", scrambled).read_text(encoding="utf-8").splitlines()
    assert text[:3] == ["# plant: sam", "# description: extension, 494 kg load", "# description: second line"]
    assert text[3] == "t,u,pA,pB,x,pS,true_K_int,true_mL"
    assert text[7].split(",")[1] == ""  # NaN gap in u is an empty field
    assert text[4].split(",")[0] == "0.0"


def test_mat_file_holds_one_vector_per_column(tmp_path):
    path = write_recording(tmp_path / "run.mat", sample_recording())
    data = scipy.io.loadmat(path)
    for name in ("t", "u", "pA", "pB", "x", "pS", "true_K_int", "true_mL"):
        assert data[name].size == N
    assert "plant: sam" in str(data["description"][0])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    values=arrays(np.float64, N, elements=st.floats(allow_nan=False, allow_infinity=False)),
    u=arrays(np.float64, N, elements=st.floats(-10, 10)),
    p=arrays(np.float64, N, elements=st.floats(-1e9, 1e9)),
    x=arrays(np.float64, N, elements=st.floats(-5, 5)),
)
def test_any_finite_floats_round_trip_through_csv(tmp_path, values, u, p, x):
    p[0] = 1e5  # keep the pressure plausible in Pa; every other sample is arbitrary
    rec = Recording(np.arange(N) * 0.01, {"u": u, "pA": p, "pB": p, "x": x}, {"true_any": values})
    back = read_recording(write_recording(tmp_path / "prop.csv", rec, overwrite=True))
    assert_same_recording(rec, back)


# ---------------------------------------------------------------- other people's files


FIELD_TEXTS = (repr, "{:.6e}".format, " {!r} ".format, "{:g}".format, lambda v: "NaN", lambda v: " nan")


@given(st.lists(st.tuples(st.floats(allow_nan=False, allow_infinity=False), st.integers(0, len(FIELD_TEXTS) - 1)),
                min_size=3, max_size=60))
def test_the_fast_csv_reader_reads_what_the_careful_one_does(fields):
    """numpy's C reader of plain numeric files (sam.recording_csv._fast_table) gives the same float64
    bits as the field-by-field reader, for every way a logger writes a number or a NaN."""
    from sam.recording_csv import _fast_table, _number

    n_cols = 3
    fields = fields[: len(fields) // n_cols * n_cols]
    texts = [FIELD_TEXTS[k](v) for v, k in fields]
    lines = [",".join(texts[i:i + n_cols]) for i in range(0, len(texts), n_cols)]
    fast = _fast_table(lines, n_cols)
    careful = np.array([_number(t) for t in texts]).reshape(-1, n_cols)
    assert fast is not None
    assert np.array_equal(fast, careful, equal_nan=True)


@pytest.mark.parametrize("row", ["0.1, ,2", "0.1,2,", "0.1,x,2", '0.1,"2",3', "0.1,2", "0.1,2,3,4", "0.1,1_0,2"])
def test_a_csv_the_fast_reader_cannot_read_exactly_goes_to_the_careful_one(row):
    """An empty field (a NaN gap), text, quotes or a row of the wrong width: the fast reader
    declines, and the careful reader reads it or names the problem."""
    from sam.recording_csv import _fast_table

    assert _fast_table(["0.0,1,2", row], 3) is None

LOGGER_CSV = (
    "# logger: HBM QuantumX\n"
    "# description: boom lift, 494 kg\n"
    "#   free comment without a colon\n"
    "t, u, pA, pB, theta, oil_temp\n"
    "0.000, 0.5, 1.0e5, 2e5, 0.728, 41.2\n"
    "0.010, 0.6, , 2e5, 0.730, 41.2\n"
    "0.020, 0.7, NaN, 2e5, 0.732, 41.3\n"
    "0.030, 0.8, 1.3e5, nan, 0.734, 41.3\n"
    "\n"
    "   \n"
)


def test_third_party_csv(tmp_path):
    path = tmp_path / "logger.csv"
    # Windows line ends and a byte-order mark, as spreadsheet programs save UTF-8
    path.write_bytes(LOGGER_CSV.replace("\n", "\r\n").encode("utf-8-sig"))
    with pytest.warns(RecordingWarning, match="oil_temp") as caught:
        rec = read_recording(path)
    assert len(caught) == 1
    assert rec.metadata == {"logger": "HBM QuantumX", "description": "boom lift, 494 kg"}
    assert set(rec.signals) == {"u", "pA", "pB", "theta"}
    assert rec.truth == {}
    assert rec.has("theta") and not rec.has("x") and not rec.has("oil_temp")
    assert rec.t.tolist() == [0.0, 0.01, 0.02, 0.03]
    assert rec.signals["theta"].tolist() == [0.728, 0.730, 0.732, 0.734]
    assert np.isnan(rec.signals["pA"][1:3]).all() and rec.signals["pA"][3] == 1.3e5
    assert np.isnan(rec.signals["pB"][3])
    assert all(v.dtype == np.float64 for v in rec.signals.values())


def test_third_party_mat(tmp_path):
    path = tmp_path / "matlab.mat"
    scipy.io.savemat(
        path,
        {
            "t": np.arange(4.0)[None, :] * 0.01,  # row vector
            "u": np.zeros((4, 1)),  # column vector
            "pA": np.full(4, 1e5),
            "pB": np.full(4, 2e5, dtype=np.float32),
            "x": np.arange(4, dtype=np.int16),
            "description": "bench 3, morning run",
            "operator": "anna",
        },
    )
    with pytest.warns(RecordingWarning, match="operator"):
        rec = read_recording(path)
    assert rec.metadata == {"description": "bench 3, morning run"}
    assert rec.t.shape == (4,) and rec.signals["x"].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert all(v.dtype == np.float64 for v in rec.signals.values())


# ---------------------------------------------------------------- bad files

GOOD = {
    "t": ["0", "0.01", "0.02", "0.03", "0.04", "0.05"],
    "u": ["0", "1", "2", "3", "4", "5"],
    "pA": ["1e5"] * 6,
    "pB": ["2e5"] * 6,
    "x": ["0", "0.1", "0.2", "0.3", "0.4", "0.5"],
}


def csv_text(columns: dict[str, list[str]], preamble: str = "") -> str:
    rows = zip(*columns.values())
    return preamble + ",".join(columns) + "\n" + "".join(",".join(r) + "\n" for r in rows)


def changed(column: str, row: int, value: str) -> dict[str, list[str]]:
    """GOOD with data row `row` (1-based) of `column` replaced."""
    columns = {k: list(v) for k, v in GOOD.items()}
    columns[column][row - 1] = value
    return columns


def without(*names: str) -> dict[str, list[str]]:
    return {k: v for k, v in GOOD.items() if k not in names}


def scaled(column: str, factor: float) -> dict[str, list[str]]:
    return {**GOOD, column: [repr(float(v) * factor) for v in GOOD[column]]}


# (case id, file text, words the message must contain). The preamble line shifts
# CSV line numbers, so 'line N' = data row + 2 checks that rows are counted right.
CSV_CASES = [
    ("missing-u", csv_text(without("u")), ["'u'", "missing required column"]),
    ("missing-pB", csv_text(without("pB")), ["'pB'", "missing required column"]),
    ("case-typo", csv_text({**without("pA"), "PA": GOOD["pA"]}), ["'pA'", "'PA'", "case-sensitive"]),
    ("no-position", csv_text(without("x")), ["'x'", "'theta'", "position"]),
    ("non-numeric", csv_text(changed("pB", 3, "abc"), "# a: b\n"), ["'pB'", "data row 3", "line 5", "'abc'"]),
    ("decimal-comma", csv_text(changed("u", 2, '"1,5"')), ["'u'", "data row 2", "'1,5'"]),
    ("inf", csv_text(changed("x", 4, "inf")), ["'x'", "data row 4", "infinite"]),
    ("t-backwards", csv_text(changed("t", 4, "0.015"), "# a: b\n"), ["'t'", "data row 4", "line 6", "not strictly increasing"]),
    ("t-repeated", csv_text(changed("t", 2, "0")), ["'t'", "data row 2", "not strictly increasing"]),
    ("t-jitter", csv_text(changed("t", 5, "0.0415")), ["'t'", "data row 5", "non-uniform sampling"]),
    ("t-gap", csv_text({k: v[:3] + v[4:] for k, v in GOOD.items()}), ["'t'", "data row 4", "non-uniform"]),
    ("t-nan", csv_text(changed("t", 3, "")), ["'t'", "data row 3", "NaN"]),
    ("all-nan", csv_text({**GOOD, "pB": ["nan"] * 6}), ["'pB'", "every sample is missing"]),
    ("all-nan-truth", csv_text({**GOOD, "true_v": [""] * 6}), ["'true_v'", "every sample is missing"]),
    ("bar", csv_text(scaled("pA", 1e-5)), ["'pA'", "looks like bar or MPa, expected Pa"]),
    ("MPa-pS", csv_text({**GOOD, "pS": ["21"] * 6}), ["'pS'", "looks like bar or MPa, expected Pa"]),
    ("degrees", csv_text({**without("x"), "theta": ["41.7"] * 6}), ["'theta'", "degrees"]),
    ("mm", csv_text(scaled("x", 1000)), ["'x'", "looks like mm"]),
    ("percent-xs", csv_text({**GOOD, "xs": ["50"] * 6}), ["'xs'", "percent"]),
    ("u-range", csv_text(changed("u", 6, "11")), ["'u'", "data row 6", "out of range"]),
    ("duplicate", csv_text({**GOOD, "x ": GOOD["x"]}), ["'x'", "duplicate"]),
    ("no-header", "0,1,1e5,2e5,0\n0.01,1,1e5,2e5,0\n", ["header row missing", "line 1"]),
    ("only-metadata", "# plant: sam\n\n", ["no header"]),
    ("no-rows", "t,u,pA,pB,x\n\n", ["no data rows"]),
    ("one-row", csv_text({k: v[:1] for k, v in GOOD.items()}), ["'t'", "at least 2"]),
    ("short-row", csv_text(GOOD) + "0.06,1,1e5\n", ["data row 7", "line 8", "'pB'"]),
    ("blank-inside", csv_text(GOOD).replace("\n0.03", "\n\n0.03"), ["data row 4", "blank line"]),
    # a European spreadsheet's CSV: "missing column 't'" never named the delimiter
    ("semicolons", csv_text(GOOD).replace(",", ";"), ["header (line 1) is one column", "separated by semicolons (';')",
                                                      "',' as the separator"]),
    ("tabs", csv_text(GOOD).replace(",", "\t"), ["separated by tabs", "'.' as the decimal mark"]),
]


@pytest.mark.parametrize("text, words", [c[1:] for c in CSV_CASES], ids=[c[0] for c in CSV_CASES])
def test_bad_csv_is_refused_with_a_precise_message(tmp_path, text, words):
    path = tmp_path / "bad_run.csv"
    path.write_text(text, encoding="utf-8")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        with pytest.raises(RecordingError) as err:
            read_recording(path)
    message = str(err.value)
    assert "bad_run.csv" in message
    for word in words:
        assert word in message
    assert "\n" not in message  # one message, one line


def mat_variables(**changes) -> dict[str, object]:
    variables = {k: np.array([float(v) for v in vs]) for k, vs in GOOD.items()}
    variables.update(changes)
    return {k: v for k, v in variables.items() if v is not None}


MAT_CASES = [
    ("length-mismatch", mat_variables(x=np.zeros(5)), ["'x'", "5 samples", "'t' has 6"]),
    ("missing-pA", mat_variables(pA=None), ["'pA'", "missing required column"]),
    ("text-signal", mat_variables(u="hello"), ["'u'", "non-numeric"]),
    ("matrix", mat_variables(pB=np.zeros((6, 2))), ["'pB'", "matrix"]),
    ("complex", mat_variables(pB=np.full(6, 1e5 + 1j)), ["'pB'", "complex"]),
    ("nan-in-t", mat_variables(t=np.array([0, 0.01, np.nan, 0.03, 0.04, 0.05])), ["'t'", "data row 3"]),
    ("t-backwards", mat_variables(t=np.array([0, 0.01, 0.02, 0.01, 0.04, 0.05])), ["'t'", "data row 4"]),
    ("bar", mat_variables(pB=np.full(6, 2.0)), ["'pB'", "looks like bar or MPa"]),
    ("description-number", mat_variables(description=np.ones(3)), ["'description'", "text"]),
]


@pytest.mark.parametrize("variables, words", [c[1:] for c in MAT_CASES], ids=[c[0] for c in MAT_CASES])
def test_bad_mat_is_refused_with_a_precise_message(tmp_path, variables, words):
    path = tmp_path / "bad_run.mat"
    scipy.io.savemat(path, variables)
    with pytest.raises(RecordingError) as err:
        read_recording(path)
    message = str(err.value)
    assert "bad_run.mat" in message
    for word in words:
        assert word in message


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("absent.csv", None, ["does not exist"]),
        ("empty.csv", b"", ["empty"]),
        ("empty.mat", b"", ["empty"]),
        ("garbage.mat", b"t,u,pA\n1,2,3\n", ["not a readable MATLAB"]),
        ("latin1.csv", "# Bediener: Jürgen\nt,u,pA,pB,x\n".encode("latin-1"), ["not UTF-8"]),
        ("run.txt", b"t,u,pA,pB,x\n", ["unknown recording type", ".csv or .mat"]),
    ],
)
def test_unusable_file_is_refused(tmp_path, name, content, words):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(RecordingError) as err:
        read_recording(path)
    assert name in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_recording_error_is_a_user_error():
    assert issubclass(RecordingError, UserError)


# ---------------------------------------------------------------- reader leaves the file alone


@pytest.mark.parametrize(
    "name, content",
    [
        ("logger.csv", LOGGER_CSV.encode()),
        ("bad.csv", csv_text(changed("t", 4, "0.015")).encode()),
        ("bad.mat", None),
    ],
)
def test_reader_does_not_modify_the_file(tmp_path, name, content):
    path = tmp_path / name
    if content is None:
        scipy.io.savemat(path, mat_variables(x=np.zeros(2)))
    else:
        path.write_bytes(content)
    os.utime(path, ns=(1_000_000_000, 1_000_000_000))  # an old mtime, so any write would show
    before = (path.read_bytes(), path.stat().st_mtime_ns)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        try:
            read_recording(path)
        except RecordingError:
            pass
    assert (path.read_bytes(), path.stat().st_mtime_ns) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no stray files either


def test_read_round_trip_of_good_mat_does_not_modify_it(tmp_path):
    path = write_recording(tmp_path / "run.mat", sample_recording())
    before = (path.read_bytes(), path.stat().st_mtime_ns)
    read_recording(path)
    assert (path.read_bytes(), path.stat().st_mtime_ns) == before


# ---------------------------------------------------------------- writer


@pytest.mark.parametrize("suffix", [".csv", ".mat"])
def test_write_refuses_to_overwrite(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError) as err:
        write_recording(path, sample_recording())
    assert f"run{suffix}" in str(err.value) and "--force" in str(err.value)
    assert path.read_bytes() == b"precious"
    write_recording(path, sample_recording(), overwrite=True)
    assert_same_recording(read_recording(path), sample_recording())


def test_write_creates_parent_directories(tmp_path):
    path = write_recording(tmp_path / "a" / "b" / "run.csv", sample_recording())
    assert path.is_file()
    assert sorted(p.name for p in path.parent.iterdir()) == ["run.csv"]  # no temporary left


def bad_recording(change: str) -> Recording:
    rec = sample_recording()
    signals = dict(rec.signals)
    if change == "length":
        signals["pB"] = signals["pB"][:-1]
    if change == "unknown":
        signals["pressure"] = signals["pB"]
    if change == "missing":
        del signals["u"]
    if change == "bar":
        signals["pA"] = signals["pA"] / 1e5
    truth = {"K_int": rec.t} if change == "truth-name" else rec.truth
    metadata = {"a:b": "c"} if change == "metadata" else rec.metadata
    return Recording(rec.t, signals, truth, metadata)


@pytest.mark.parametrize(
    "change, words",
    [
        ("length", ["'pB'", "7 samples", "'t' has 8"]),
        ("unknown", ["'pressure'", "unknown signal"]),
        ("missing", ["'u'", "missing required column"]),
        ("bar", ["'pA'", "bar or MPa"]),
        ("truth-name", ["'K_int'", "true_"]),
        ("metadata", ["'a:b'"]),
    ],
)
def test_write_refuses_an_invalid_recording(tmp_path, change, words):
    path = tmp_path / "out.csv"
    with pytest.raises(RecordingError) as err:
        write_recording(path, bad_recording(change))
    assert "out.csv" in str(err.value) and "not written" in str(err.value)
    for word in words:
        assert word in str(err.value)
    assert not path.exists()


def test_write_refuses_unknown_suffix(tmp_path):
    with pytest.raises(RecordingError, match=r"run\.h5.*\.csv or \.mat"):
        write_recording(tmp_path / "run.h5", sample_recording())


# ---------------------------------------------------------------- Recording


def test_measured_drops_truth_and_leaves_the_original_alone():
    rec = sample_recording()
    seen = rec.measured()
    assert seen.truth == {}
    assert not seen.has("true_K_int") and rec.has("true_K_int")
    assert set(rec.truth) == {"true_K_int", "true_mL"}
    assert seen.signals.keys() == rec.signals.keys() and seen.metadata == rec.metadata


def test_slice_takes_a_sample_range_and_copies():
    rec = sample_recording()
    part = rec.slice(2, 5)
    assert part.n == 3
    assert_bits_equal(part.t, rec.t[2:5])
    assert_bits_equal(part.signals["u"], rec.signals["u"][2:5])
    assert_bits_equal(part.truth["true_mL"], rec.truth["true_mL"][2:5])
    assert part.dt == pytest.approx(DT)
    part.signals["u"][0] = 123.0
    assert rec.signals["u"][2] == -2.25
    assert rec.slice(-2, N).n == 2
    with pytest.raises(ValueError):
        rec.slice(5, 5)


def test_has_and_dt():
    rec = sample_recording()
    assert rec.has("t") and rec.has("pS") and not rec.has("theta") and not rec.has("v")
    assert math.isclose(rec.dt, DT)
    assert math.isnan(rec.slice(0, 1).dt)
