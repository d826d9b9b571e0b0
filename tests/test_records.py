"""Tests of identify.data.records: every load error names file, line and problem; exact round trip."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from identify.data.records import Record, RecordError, load_record, sidecar_path, write_record

N_ROWS = 250  # above the default min_samples = 200


def _arrays(n=N_ROWS):
    time = np.arange(n) / 100.0
    current = np.where(time < 1.0, 0.0, 2.5 - 2.5 * np.cos(0.2 * np.pi * time))
    displacement = 40.0 * current + np.sin(time) / 3.0
    return time, current, displacement


def _write_text(tmp_path, text, name="rec.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _csv_lines(n=N_ROWS, header="time,current,displacement"):
    time, current, displacement = _arrays(n)
    return [header] + [f"{t!r},{c!r},{d!r}" for t, c, d in zip(time.tolist(), current.tolist(), displacement.tolist())]


def _load_error(path, **kwargs) -> str:
    with pytest.raises(RecordError) as info:
        load_record(path, **kwargs)
    message = str(info.value)
    assert str(path) in message, message
    return message


# -- round trip ---------------------------------------------------------------------


def test_round_trip_is_exact_and_bytes_are_deterministic(tmp_path):
    time, current, displacement = _arrays()
    sidecar = {"seed": 3, "theta": {"rho": 5.6438}, "effects": ["thermal"]}
    path = tmp_path / "a.csv"
    write_record(path, (time, current, displacement), sidecar)
    record = load_record(path)
    np.testing.assert_array_equal(record.time, time)
    np.testing.assert_array_equal(record.current, current)
    np.testing.assert_array_equal(record.displacement, displacement)
    assert record.sidecar == sidecar
    assert record.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert record.source == str(path)
    assert path.read_text().splitlines()[0] == "time,current,displacement"
    # Writing the loaded record again gives the same bytes (CSV and sidecar).
    other = tmp_path / "b.csv"
    write_record(other, record)
    assert other.read_bytes() == path.read_bytes()
    assert sidecar_path(other).read_bytes() == sidecar_path(path).read_bytes()
    # No temporary files left behind.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json", "b.csv", "b.json"]


def test_round_trip_with_custom_names_and_units(tmp_path):
    time, voltage, displacement = _arrays()
    record = Record(time, voltage, displacement, source="piezo", sha256="", input_name="voltage", input_unit="V")
    path = tmp_path / "piezo.csv"
    write_record(path, record)
    assert path.read_text().splitlines()[0] == "time,voltage,displacement"
    loaded = load_record(path, input_column="voltage", input_unit="V")
    assert (loaded.input_name, loaded.input_unit, loaded.output_unit) == ("voltage", "V", "um")
    np.testing.assert_array_equal(loaded.current, voltage)
    assert loaded.sidecar is None


def test_write_without_sidecar_removes_a_stale_one(tmp_path):
    path = tmp_path / "r.csv"
    write_record(path, _arrays(), {"old": True})
    assert sidecar_path(path).exists()
    write_record(path, _arrays())
    assert not sidecar_path(path).exists()
    assert load_record(path).sidecar is None


def test_write_refuses_bad_input_and_writes_nothing(tmp_path):
    time, current, displacement = _arrays()
    path = tmp_path / "r.csv"
    with pytest.raises(ValueError, match="equal lengths"):
        write_record(path, (time, current, displacement[:-1]))
    with pytest.raises(ValueError, match="strictly increasing"):
        write_record(path, (time[::-1], current, displacement))
    with pytest.raises(ValueError, match="non-finite"):
        write_record(path, (time, np.full_like(current, np.nan), displacement))
    with pytest.raises(ValueError, match="JSON-serialisable"):
        write_record(path, (time, current, displacement), {"x": object()})
    assert list(tmp_path.iterdir()) == []


def test_no_time_column_synthesises_sample_index(tmp_path):
    time, current, displacement = _arrays()
    lines = ["current,displacement"] + [f"{c!r},{d!r}" for c, d in zip(current.tolist(), displacement.tolist())]
    path = _write_text(tmp_path, "\n".join(lines) + "\n")
    record = load_record(path, time_column=None)
    np.testing.assert_array_equal(record.time, np.arange(N_ROWS, dtype=float))
    np.testing.assert_array_equal(record.current, current)
    assert any("no time column" in note and "sample index" in note for note in record.notes)


def test_comments_blank_lines_and_case_are_noted(tmp_path):
    lines = _csv_lines(header="Time,Current,Displacement")
    text = "# rig 2, 2024-01-01\n" + "\n".join(lines) + "\n\n"
    record = load_record(_write_text(tmp_path, text))
    assert len(record) == N_ROWS
    assert any("skipped 2" in note for note in record.notes)
    assert any("letter case" in note for note in record.notes)


# -- every error ----------------------------------------------------------------------


def test_empty_file(tmp_path):
    message = _load_error(_write_text(tmp_path, ""))
    assert "empty" in message
    message = _load_error(_write_text(tmp_path, "  \n\n", name="blank.csv"))
    assert "empty" in message


def test_missing_file(tmp_path):
    assert "no such file" in _load_error(tmp_path / "nope.csv")


def test_no_header(tmp_path):
    lines = _csv_lines()[1:]
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 1" in message and "no header" in message


def test_misnamed_column_lists_present_and_suggests(tmp_path):
    lines = _csv_lines(header="time,curent,displacement")
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 1" in message
    assert "missing column(s) 'current'" in message
    assert "did you mean 'curent'" in message
    assert "Columns present: 'time', 'curent', 'displacement'" in message


def test_missing_column(tmp_path):
    lines = ["time,current"] + [line.rsplit(",", 1)[0] for line in _csv_lines()[1:]]
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "missing column(s) 'displacement'" in message and "'time', 'current'" in message


def test_duplicate_column_name(tmp_path):
    lines = _csv_lines(header="time,current,current")
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 1" in message and "'current' appears twice" in message


def test_non_numeric_cell(tmp_path):
    lines = _csv_lines()
    lines[5] = "0.04,abc,1.0"
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 6" in message and "column 'current'" in message and "'abc' is not a number" in message


def test_empty_cell(tmp_path):
    lines = _csv_lines()
    lines[9] = "0.08,1.0,"
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 10" in message and "column 'displacement' is empty" in message


def test_wrong_cell_count(tmp_path):
    lines = _csv_lines()
    lines[3] = "0.02,0.0"
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 4" in message and "2 cells" in message and "3 columns" in message


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf"])
def test_nan_and_inf(tmp_path, bad):
    lines = _csv_lines()
    lines[20] = f"0.19,1.0,{bad}"
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 21" in message and "column 'displacement'" in message and "not a finite number" in message


def test_duplicate_time(tmp_path):
    lines = _csv_lines()
    lines[12] = lines[11]  # line 13 repeats line 12
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 13" in message and "repeats" in message and "line 12" in message


def test_decreasing_time(tmp_path):
    lines = _csv_lines()
    lines[30] = "0.001,0.0,0.0"
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "line 31" in message and "smaller than" in message and "strictly increase" in message
    assert "time 0.001 is smaller than" in message and "np.float64" not in message  # plain numbers


def test_too_few_samples(tmp_path):
    lines = _csv_lines(n=150)
    message = _load_error(_write_text(tmp_path, "\n".join(lines)))
    assert "only 150 data row(s)" in message and "200" in message
    # The threshold is configurable.
    assert len(load_record(tmp_path / "rec.csv", min_samples=150)) == 150


def test_malformed_sidecar(tmp_path):
    path = _write_text(tmp_path, "\n".join(_csv_lines()))
    side = sidecar_path(path)
    side.write_text('{\n  "seed": 1,\n  "theta": [1, 2,,]\n}\n')
    with pytest.raises(RecordError) as info:
        load_record(path)
    message = str(info.value)
    assert str(side) in message and "line 3" in message and "malformed JSON sidecar" in message
    side.write_text(json.dumps([1, 2]))
    with pytest.raises(RecordError, match="must be an object"):
        load_record(path)


def test_not_utf8(tmp_path):
    path = tmp_path / "bin.csv"
    path.write_bytes(b"time,current,displacement\n0,0,\xff\xfe\n")
    message = _load_error(path)
    assert "line 2" in message and "UTF-8" in message


def test_keep_every_keeps_the_reversals_so_the_gpi_output_is_unchanged():
    """Thinning by 7 keeps every input extremum (peaks of the decaying sine fall between
    multiples of 7), so the GPI at the kept samples equals the GPI of the whole record
    there, bit for bit."""
    from identify.bench import simulate
    from identify.data.records import keep_every
    from identify.data.reversals import find_reversals
    from model import TABLE1, gpi

    record = simulate(fs=100.0, seed=1).record
    thin = keep_every(record, 7)
    kept = np.searchsorted(record.time, thin.time)
    assert np.array_equal(record.time[kept], thin.time)
    assert set(find_reversals(record.current).index) <= set(kept.tolist())
    assert not set(find_reversals(record.current).index) <= set(range(0, len(record), 7))  # the test is not vacuous
    assert kept[-1] == len(record) - 1 and len(thin) < len(record) / 6
    assert np.array_equal(gpi(TABLE1, record.current)[kept], gpi(TABLE1, thin.current))
    assert thin.notes[-1].startswith("thinned (--every 7)") and f"{len(thin)} of {len(record)}" in thin.notes[-1]
    assert thin.sha256 == record.sha256 and thin.input_unit == record.input_unit
    assert keep_every(record, 1) is record
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="integer N >= 1"):
            keep_every(record, bad)


def test_thinning_keeps_the_samples_around_each_reversal_when_asked():
    from identify.data.records import thinning_indices

    current = np.sin(np.linspace(0.0, 6.0 * np.pi, 601))
    reversals = np.array([0, 50, 150, 250, 350, 450, 550, 600])
    plain = thinning_indices(current, 10, reversals)
    wide = thinning_indices(current, 10, reversals, around=3)
    assert set(plain.tolist()) < set(wide.tolist())
    for r in reversals:
        near = [k for k in range(r - 3, r + 4) if 0 <= k < len(current)]
        assert set(near) <= set(wide.tolist())
    assert wide.min() == 0 and wide.max() == len(current) - 1  # clipped to the record
    assert not {47, 53} & set(plain.tolist()) and {47, 53} <= set(wide.tolist())
    with pytest.raises(ValueError, match="around must be >= 0"):
        thinning_indices(current, 10, reversals, around=-1)


def test_every_option_thins_the_record_and_rejects_bad_values(tmp_path, capsys):
    from identify.bench import simulate
    from identify.cli import main

    path = tmp_path / "r.csv"
    write_record(path, simulate(fs=20.0, seed=2).record)
    assert main(["fit", str(path), "--every", "4", "--n-starts", "1"]) == 0
    printed = capsys.readouterr()
    assert "note: thinned (--every 4)" in printed.out + printed.err
    with pytest.raises(SystemExit):
        main(["fit", str(path), "--every", "0"])
    assert "expected an integer >= 1, got 0" in capsys.readouterr().err
