"""CSV loading: column choice, unit parsing, and one clear error per malformed file."""

import numpy as np
import pytest

from fitter.data.recordings import Recording, RecordingError, check_samples, load_recording, load_recordings, split_unit


def write(tmp_path, text, name="rec.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


GOOD = "time,u,y\n0,0,0\n0.1,0.5,0.25\n0.2,1,0.75\n0.3,0.5,0.6\n"


def test_loads_default_columns(tmp_path):
    rec = load_recording(write(tmp_path, GOOD))
    assert isinstance(rec, Recording)
    np.testing.assert_array_equal(rec.t, [0, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(rec.u, [0, 0.5, 1, 0.5])
    np.testing.assert_array_equal(rec.y, [0, 0.25, 0.75, 0.6])
    assert rec.name == "rec" and rec.source.endswith("rec.csv")


@pytest.mark.parametrize(
    "header,expected",
    [
        ("voltage_V", ("voltage", "V")),
        ("polarization_uC_per_cm2", ("polarization", "uC/cm2")),
        ("position_mm", ("position", "mm")),
        ("pressure_bar", ("pressure", "bar")),
        ("x_increasing_mm_per_s", ("x_increasing", "mm/s")),
        ("Force [N]", ("Force", "N")),
        ("speed (m/s)", ("speed", "m/s")),
        ("u_min", ("u_min", "")),
        ("y", ("y", "")),
        ("force_x", ("force_x", "")),
    ],
)
def test_unit_rule(header, expected):
    assert split_unit(header) == expected


def test_columns_by_base_name_index_and_units(tmp_path):
    p = write(tmp_path, "time_ms,voltage_V,note,polarization_uC_per_cm2\n0,1,a,2\n500,3,b,4\n1000,5,c,6\n")
    rec = load_recording(p, "time", "voltage", 3)
    np.testing.assert_allclose(rec.t, [0, 0.5, 1.0])  # ms converted to s
    np.testing.assert_array_equal(rec.u, [1, 3, 5])
    np.testing.assert_array_equal(rec.y, [2, 4, 6])
    assert (rec.input.name, rec.input.unit) == ("voltage", "V")
    assert (rec.output.name, rec.output.unit) == ("polarization", "uC/cm2")
    rec2 = load_recording(p, "0", "voltage_V", "polarization_uC_per_cm2")
    np.testing.assert_array_equal(rec2.u, rec.u)


def test_time_none_uses_sample_index(tmp_path):
    rec = load_recording(write(tmp_path, "u,y\n1,2\n3,4\n5,6\n"), time=None)
    np.testing.assert_array_equal(rec.t, [0, 1, 2])


def test_skips_blank_lines_and_accepts_semicolons(tmp_path):
    rec = load_recording(write(tmp_path, "time;u;y\n0;1;2\n\n1;2;3\n2;3;4\n"))
    np.testing.assert_array_equal(rec.y, [2, 3, 4])


def test_skips_comment_lines_before_the_header_and_keeps_line_numbers(tmp_path):
    """Instruments write '# ...' lines before the data; a bad cell after them is still named by its line."""
    rec = load_recording(write(tmp_path, "# rig 3\n  # 2024-01-01\ntime,u,y\n0,1,2\n1,2,3\n2,3,4\n"))
    np.testing.assert_array_equal(rec.y, [2, 3, 4])
    msg = error_of(tmp_path, "# rig 3\ntime,u,y\n0,0,0\n1,1,1\n2,abc,2\n3,3,3\n")
    assert "line 5" in msg and "column 'u'" in msg


def test_skips_comment_lines_among_the_data_and_keeps_line_numbers(tmp_path):
    """A '# ...' line among the data rows (also one with delimiters) is skipped as before the header."""
    rec = load_recording(write(tmp_path, "time,u,y\n0,1,2\n# re-zeroed, 3 s\n1,2,3\n  # note\n2,3,4\n"))
    np.testing.assert_array_equal(rec.t, [0, 1, 2])
    np.testing.assert_array_equal(rec.y, [2, 3, 4])
    msg = error_of(tmp_path, "time,u,y\n0,0,0\n# gap\n1,1,1\n2,abc,2\n")
    assert "line 5, column 'u': 'abc' is not a number" in msg


def test_a_file_without_header_is_refused(tmp_path):
    msg = error_of(tmp_path, "# rig 3\n0,1,2\n1,2,3\n2,3,4\n")
    assert (
        "rec.csv: line 2: the first row '0,1,2' is numbers, not a header: a header line naming the columns is "
        "needed" in msg
    )


def test_decimal_commas_get_a_hint(tmp_path):
    msg = error_of(tmp_path, "time;u;y\n0;0,5;1\n1;1,5;2\n2;2,5;3\n")
    assert msg.endswith("line 2, column 'u': '0,5' is not a number (a decimal comma? write a decimal point: 0.5)")
    msg = error_of(tmp_path, "time,u,y\n0,0,5,1\n1,1,5,2\n2,2,5,3\n")
    assert msg.endswith(
        "line 2 has 4 fields but the header has 3 (decimal commas? write decimal points, or "
        "separate the columns by ';')"
    )
    assert error_of(tmp_path, "time;u;y\n0;x;1\n1;1;2\n2;2;3\n").endswith("'x' is not a number")  # no hint


def test_a_field_over_the_csv_limit_names_its_line(tmp_path):
    msg = error_of(tmp_path, 'time,u,y\n0,1,2\n1,"' + "1" * 200_000 + '",3\n2,3,4\n')
    assert msg.startswith(
        str(tmp_path / "rec.csv") + ": line 3: a field of more than 131072 characters (csv's field size limit)"
    )
    msg = error_of(tmp_path, 'time,"' + "u" * 200_000 + '",y\n0,1,2\n')
    assert ": line 1: a field of more than 131072 characters" in msg


def error_of(tmp_path, text, **kw):
    with pytest.raises(RecordingError) as exc:
        load_recording(write(tmp_path, text), **kw)
    msg = str(exc.value)
    assert "\n" not in msg and "rec.csv" in msg
    return msg


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match=r"nope\.csv: no such file"):
        load_recording(tmp_path / "nope.csv")


def test_empty_file(tmp_path):
    assert "empty file" in error_of(tmp_path, "")
    assert "no data rows" in error_of(tmp_path, "time,u,y\n")


def test_missing_column_lists_available(tmp_path):
    msg = error_of(tmp_path, "time_s,voltage_V,pol\n0,1,2\n1,2,3\n2,3,4\n")
    assert "input column 'u' not found" in msg
    assert "'time_s', 'voltage_V', 'pol'" in msg


def test_index_out_of_range(tmp_path):
    assert "column index 7 out of range" in error_of(tmp_path, GOOD, output=7)


def test_ambiguous_column(tmp_path):
    msg = error_of(tmp_path, "time,u_V,u_A,y\n0,1,2,3\n1,1,2,3\n2,1,2,3\n")
    assert "ambiguous" in msg and "'u_V'" in msg and "'u_A'" in msg


def test_non_numeric_cell_names_line_column_value(tmp_path):
    msg = error_of(tmp_path, "time,u,y\n0,0,0\n1,1,1\n2,abc,2\n3,3,3\n")
    assert "line 4" in msg and "column 'u'" in msg and "'abc' is not a number" in msg


def test_empty_cell(tmp_path):
    msg = error_of(tmp_path, "time,u,y\n0,0,0\n1,1,\n2,2,2\n")
    assert "line 3" in msg and "column 'y'" in msg and "empty cell" in msg


@pytest.mark.parametrize("value", ["nan", "inf", "-Infinity"])
def test_non_finite(tmp_path, value):
    msg = error_of(tmp_path, f"time,u,y\n0,0,0\n1,1,{value}\n2,2,2\n")
    assert "line 3" in msg and "column 'y'" in msg and "not finite" in msg and value in msg


def test_non_increasing_time(tmp_path):
    msg = error_of(tmp_path, "time,u,y\n0,0,0\n1,1,1\n1,2,2\n3,3,3\n")
    assert "line 4" in msg and "does not increase" in msg and "line 3" in msg


def test_ragged_row(tmp_path):
    assert "line 3 has 2 fields but the header has 3" in error_of(tmp_path, "time,u,y\n0,0,0\n1,1\n")


def test_too_few_samples(tmp_path):
    assert "too few samples: 2 data rows, at least 3" in error_of(tmp_path, "time,u,y\n0,0,0\n1,1,1\n")


def test_unselected_columns_may_be_text(tmp_path):
    rec = load_recording(write(tmp_path, "time,label,u,y\n0,a,0,0\n1,b,1,1\n2,,2,2\n"))
    assert len(rec) == 3


def test_load_recordings_checks_same_signals(tmp_path):
    a = write(tmp_path, "time,u_V,y_m\n0,0,0\n1,1,1\n2,2,2\n", "a.csv")
    b = write(tmp_path, "time,u_mV,y_m\n0,0,0\n1,1,1\n2,2,2\n", "b.csv")
    assert len(load_recordings([a, a])) == 2
    with pytest.raises(RecordingError, match=r"b\.csv: input column is 'u' \[mV\] but .*a\.csv has 'u' \[V\]"):
        load_recordings([a, b], input="u", output="y")


# --------------------------------------------------------------------------- samples checked at construction


def test_recording_checks_time_finite_values_and_length():
    t = np.array([0.0, 1.0, 1.0, 2.0])
    with pytest.raises(
        RecordingError,
        match=r"^r: row 2, column 't': time 1\.0 does not increase "
        r"\(row 1 has 1\.0\)$",
    ):
        Recording(t, np.zeros(4), np.zeros(4), name="r")
    with pytest.raises(RecordingError, match=r"^data\.csv: row 3, column 'u': value nan is not finite"):
        Recording(np.arange(5.0), [0, 1, 2, np.nan, 4], np.zeros(5), name="r", source="data.csv")
    with pytest.raises(RecordingError, match=r"row 0, column 'y': value -inf is not finite"):
        Recording(np.arange(3.0), np.zeros(3), [-np.inf, 0, np.nan])
    with pytest.raises(RecordingError, match=r"too few samples: 1, at least 2 needed"):
        Recording([0.0], [1.0], [2.0])
    with pytest.raises(
        RecordingError, match=r"t, u, y must be 1-D arrays of equal length \(shapes \(3,\), \(3,\), \(2,\)\)"
    ):
        Recording(np.arange(3.0), np.zeros(3), np.zeros(2))


def test_input_only_recording_has_all_nan_output(tmp_path):
    rec = Recording(np.arange(3.0), [0.0, 1.0, 0.0], np.full(3, np.nan))
    assert np.isnan(rec.y).all() and rec.label == "recording"
    rec = load_recording(write(tmp_path, GOOD), output=None)
    assert np.isnan(rec.y).all() and rec.label.endswith("rec.csv")


def test_check_samples_names_file_lines_and_columns():
    t, u, y = check_samples([0, 1, 2], [3, 4, 5], source="x")
    assert t.dtype == float and u.tolist() == [3.0, 4.0, 5.0] and y is None
    with pytest.raises(
        RecordingError,
        match=r"^f\.csv: line 4, column 'time_s': time 0\.5 does not increase "
        r"\(line 3 has 2\.0\)$",
    ):
        check_samples([1, 2, 0.5], [0, 1, 2], source="f.csv", names=("time_s", "u_V"), rows=[2, 3, 4])
    with pytest.raises(RecordingError, match=r"too few samples: 2 data rows, at least 3 needed"):
        check_samples([0, 1], [0, 1], source="f.csv", rows=[2, 3], min_samples=3)


# --------------------------------------------------------------------------- large files: read and written in blocks


def test_blocks_read_as_one(tmp_path, monkeypatch):
    """The reader takes the file a block of lines at a time (a block of simple lines at once, any other
    row by row): tiny blocks give the values, line numbers and messages of one block."""
    from fitter.data import csv_table

    rows = ["%.10g,%.17g,%.6g" % (0.1 * k, np.sin(k), np.cos(k)) for k in range(60)]
    rows[7] = ""  # a blank line
    rows[20] = '"2",2,3'  # a quoted cell: read row by row
    rows[30] = "  "
    good = "time,u,y\r\n" + "\r\n".join(rows) + "\r\n"
    bad = good.replace(rows[45], rows[45].replace(",", ",x", 1))  # a non-number in u
    ragged = good.replace(rows[50], rows[50] + ",1")
    cases = [("good.csv", good), ("bad.csv", bad), ("ragged.csv", ragged)]
    outcomes = {}
    for block in (1 << 20, 7, 64):
        monkeypatch.setattr(csv_table, "_BLOCK_CHARS", block)
        for name, text in cases:
            path = tmp_path / name
            path.write_bytes(text.encode())
            try:
                rec = load_recording(path)
                outcomes.setdefault(name, set()).add((rec.t.tobytes(), rec.u.tobytes(), rec.y.tobytes()))
            except RecordingError as exc:
                outcomes.setdefault(name, set()).add(str(exc))
    assert all(len(v) == 1 for v in outcomes.values())
    assert "line 47, column 'u': 'x" in next(iter(outcomes["bad.csv"]))
    assert "line 52 has 4 fields" in next(iter(outcomes["ragged.csv"]))
    t = np.frombuffer(next(iter(outcomes["good.csv"]))[0])
    assert len(t) == 58 and t[19] == 2.0


def test_save_columns_writes_the_text_of_savetxt(tmp_path):
    from fitter.data.recordings import save_columns

    rng = np.random.default_rng(0)
    cols = [
        np.linspace(0, 2, 1001),
        rng.standard_normal(1001) * 1e-300,
        np.r_[rng.standard_normal(998), -0.0, np.nan, 5e-324],
    ]
    np.savetxt(tmp_path / "a.csv", np.column_stack(cols), delimiter=",", fmt="%.17g", header="time,u,y", comments="")
    save_columns(tmp_path / "b.csv", ["time", "u", "y"], cols, block=64)
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    rec = load_recording(tmp_path / "b.csv", output="u")
    assert np.array_equal(rec.u, cols[1])


def test_a_glitch_row_is_named_and_an_ordinary_column_has_none(tmp_path):
    """One input row of 1e6 in a +-1 sine (a wrong row that a fit would follow): `load_recording`'s `warn` gets one
    line naming the file, the line as numbered in the file, the column and the value; the clean file gives none,
    and neither does a noisy input or a step (a step is many samples, not one far from its neighbours)."""
    from fitter.data.recordings import spikes

    t = np.linspace(0.0, 10.0, 500)
    u = np.sin(t)
    u_glitch = u.copy()
    u_glitch[123] = 1e6
    path = tmp_path / "g.csv"
    rows = "\n".join(f"{a},{b},{c}" for a, b, c in zip(t, u_glitch, np.tanh(u)))
    path.write_text("time,u,y\n" + rows + "\n")
    said = []
    load_recording(path, warn=said.append)
    assert len(said) == 1 and "line 125, column 'u': value 1000000.0" in said[0] and str(path) in said[0]
    rng = np.random.default_rng(0)
    assert spikes(u).size == 0 and spikes(u + 0.05 * rng.standard_normal(500)).size == 0
    assert spikes(np.r_[np.zeros(250), np.ones(250)]).size == 0
    assert list(spikes(u_glitch)) == [123]
