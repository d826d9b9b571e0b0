"""Input formats beside the project's CSV (issue 18): a decimal-comma CSV (``;`` between
columns, ``,`` as the decimal mark) and MATLAB ``.mat`` files (v5 through scipy, v7.3
through h5py), with the CSV loader's strict checks and errors naming file and variable."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import scipy.io

from identify.bench import simulate
from identify.cli import main
from identify.data.records import RecordError, load_record


@pytest.fixture(scope="module")
def arrays():
    """(time [s], current [A], displacement [um]) of a small bench record (351 samples)."""
    rec = simulate(fs=5.0, seed=4).record
    return rec.time, rec.current, rec.displacement


def _decimal_comma_csv(path, arrays, header="time;current;displacement"):
    rows = [header] + [";".join(repr(float(v)).replace(".", ",") for v in row) for row in zip(*arrays)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_decimal_comma_csv_reads_the_same_numbers(tmp_path, arrays):
    path = _decimal_comma_csv(tmp_path / "export.csv", arrays)
    assert "0,2" in path.read_text()  # really decimal commas
    record = load_record(path)
    for got, want in zip((record.time, record.current, record.displacement), arrays):
        np.testing.assert_array_equal(got, want)  # repr round trip: bit for bit
    assert any("';'" in note for note in record.notes)
    assert any("decimal commas" in note for note in record.notes)


def test_decimal_comma_csv_errors_name_file_line_and_column(tmp_path, arrays):
    path = _decimal_comma_csv(tmp_path / "bad.csv", arrays)
    lines = path.read_text().splitlines()
    cells = lines[10].split(";")
    cells[2] = "1.234,5"  # a thousands separator is not a number
    lines[10] = ";".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordError, match=r"bad\.csv, line 11: column 'displacement': '1\.234,5' is not a number"):
        load_record(path)
    # a missing column lists those present
    other = _decimal_comma_csv(tmp_path / "renamed.csv", arrays, header="time;strom;displacement")
    with pytest.raises(RecordError, match=r"renamed\.csv, line 1: missing column\(s\) 'current'.*'strom'"):
        load_record(other)


def test_decimal_comma_csv_through_the_command_line(tmp_path, arrays, capsys):
    path = _decimal_comma_csv(tmp_path / "export.csv", arrays)
    out = tmp_path / "fit.json"
    assert main(["fit", str(path), "--n-starts", "1", "--json", str(out)]) == 0
    assert "decimal commas read as decimal points" in capsys.readouterr().err
    assert out.is_file()


def test_mat_v5_top_level_variables_and_a_struct(tmp_path, arrays):
    t, i, y = arrays
    flat = tmp_path / "flat.mat"
    scipy.io.savemat(flat, {"time": t, "i_coil": i[:, None], "x_laser": y})  # row and column vectors
    record = load_record(flat, input_column="i_coil", output_column="x_laser")
    np.testing.assert_array_equal(record.time, t)
    np.testing.assert_array_equal(record.current, i)
    np.testing.assert_array_equal(record.displacement, y)
    assert record.input_name == "i_coil" and len(record.sha256) == 64
    assert any("MATLAB" in note for note in record.notes)
    nested = tmp_path / "dspace.mat"
    scipy.io.savemat(nested, {"run7": {"time": t, "current": i, "displacement": y}, "comment": "bench"})
    record = load_record(nested)
    np.testing.assert_array_equal(record.displacement, y)
    assert any("struct 'run7'" in note for note in record.notes)


def test_mat_errors_name_the_file_and_the_variable(tmp_path, arrays):
    t, i, y = arrays
    cases = {
        "missing": (
            {"time": t, "curent": i, "displacement": y},
            r"missing variable\(s\) 'current' \(did you mean 'curent'\?\)",
        ),
        "matrix": (
            {"time": t, "current": np.stack([i, i]), "displacement": y},
            r"variable 'current' has shape \(2, 351\); expected a vector",
        ),
        "text": ({"time": t, "current": "not numbers", "displacement": y}, r"variable 'current' is of type <U11"),
        "lengths": (
            {"time": t, "current": i[:-1], "displacement": y},
            r"the variables have different lengths: time 351, current 350, displacement 351",
        ),
        "nan": (
            {"time": t, "current": np.where(np.arange(i.size) == 40, np.nan, i), "displacement": y},
            r"variable 'current', sample 41: nan is not a finite number",
        ),
        "time": (
            {"time": np.where(np.arange(t.size) == 5, t[3], t), "current": i, "displacement": y},
            r"variable 'time', sample 6: time .* is smaller than the previous time",
        ),
        "short": ({"time": t[:50], "current": i[:50], "displacement": y[:50]}, r"only 50 samples"),
    }
    for name, (contents, message) in cases.items():
        path = tmp_path / f"{name}.mat"
        scipy.io.savemat(path, contents)
        with pytest.raises(RecordError, match=rf"{name}\.mat: {message}"):
            load_record(path)
    garbage = tmp_path / "garbage.mat"
    garbage.write_bytes(b"this is no MATLAB file" * 10)
    with pytest.raises(RecordError, match=r"garbage\.mat: not a readable MATLAB \.mat file"):
        load_record(garbage)
    with pytest.raises(RecordError, match=r"absent\.mat: no such file"):
        load_record(tmp_path / "absent.mat")


def _write_v73(path, variables):
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 with a 512-byte header block (MATLAB stores
    a T-vector as a 1 x T dataset)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            f.create_dataset(name, data=np.asarray(value)[None, :])
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    header = header.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    with open(path, "r+b") as fh:
        fh.write(header)


def test_mat_v73_is_read_through_h5py(tmp_path, arrays):
    t, i, y = arrays
    path = tmp_path / "v73.mat"
    _write_v73(path, {"time": t, "current": i, "displacement": y})
    with pytest.raises(NotImplementedError):
        scipy.io.loadmat(path)  # scipy refuses v7.3: this is the HDF5 path
    record = load_record(path)
    np.testing.assert_array_equal(record.current, i)
    assert any("v7.3" in note for note in record.notes)
    _write_v73(tmp_path / "v73_missing.mat", {"time": t, "current": i})
    with pytest.raises(RecordError, match=r"v73_missing\.mat: missing variable\(s\) 'displacement'"):
        load_record(tmp_path / "v73_missing.mat")


def test_mat_through_the_command_line_and_a_clean_error(tmp_path, arrays, capsys):
    t, i, y = arrays
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": t, "u": i, "x": y})
    argv = ["fit", str(path), "--time-column", "t", "--input-column", "u", "--output-column", "x", "--n-starts", "1"]
    assert main(argv) == 0
    assert main(["fit", str(path), "--n-starts", "1"]) == 2
    err = capsys.readouterr().err
    assert "rig.mat: missing variable(s) 'time'" in err and "Variables present: 't', 'u', 'x'" in err
    assert "Traceback" not in err
