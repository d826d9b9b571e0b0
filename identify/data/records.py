"""Measurement records: load and write the project's CSV format, with strict checks.

A record is one measurement: drive (current [A], or voltage [V] for a piezo) and output
(displacement [um]) sampled at strictly increasing times [s]. On disk it is a CSV file
with a header line, by default::

    time,current,displacement
    0,0,-0.31
    0.01,0,0.12
    ...

optionally with a JSON *sidecar* beside it (same stem, ``.json``) holding metadata; the
virtual bench (:mod:`identify.bench`) stores its whole truth there.

Loading never returns a partly read record: any problem raises :class:`RecordError`
naming the file, the 1-based line (the header is line 1) and what is wrong. Lines that
are empty or start with ``#`` are skipped (and counted in :attr:`Record.notes`).

Writing uses ``%.17g`` floats (exact round trip), ``\\n`` line ends and a temporary file
renamed into place, so the same arrays always give the same bytes and a crash never
leaves a half-written file.
"""

from __future__ import annotations

import codecs
import difflib
import hashlib
import json
import math
from array import array
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..logs import ordinal
from .fileio import atomic_write_bytes
from .matfile import MAT_SUFFIX, MatFileError, read_mat_variables
from .reversals import find_reversals

__all__ = [
    "Record",
    "RecordError",
    "load_record",
    "write_record",
    "sidecar_path",
    "keep_every",
    "thinning_indices",
    "suggest_every",
    "DEFAULT_COLUMNS",
    "MAX_ABS_VALUE",
    "MAX_ABS_TIME",
    "MAX_UNIT_LENGTH",
    "unit_problem",
    "check_unit",
]

#: The default header: time [s], drive [A], output [um].
DEFAULT_COLUMNS = ("time", "current", "displacement")

_DELIMITERS = (",", ";", "\t")


class RecordError(ValueError):
    """A record file that cannot be loaded; the message names the file, line and problem."""


@dataclass(frozen=True, eq=False)
class Record:
    """One measurement record.

    Parameters
    ----------
    time : ndarray, shape (T,)
        Sample times [s], strictly increasing (a unit-step sample index when the file
        had no time column; :attr:`notes` says so).
    current : ndarray, shape (T,)
        Drive signal, in :attr:`input_unit` (A by default; V for a piezo).
    displacement : ndarray, shape (T,)
        Output signal, in :attr:`output_unit` (um by default).
    source : str
        File path, or a description for records not read from a file.
    sha256 : str
        SHA-256 of the file's bytes (``""`` when not from a file).
    input_name, input_unit, output_name, output_unit : str
        Column names and units of the drive and the output.
    notes : tuple of str, default ()
        Every assumption made while loading, in plain words.
    sidecar : dict or None, default None
        The JSON sidecar (e.g. the virtual bench's truth) when one sits beside the CSV.
    time_name : str, default "time"
        Name of the time column (used when the record is written back).
    """

    time: np.ndarray
    current: np.ndarray
    displacement: np.ndarray
    source: str
    sha256: str
    input_name: str = "current"
    input_unit: str = "A"
    output_name: str = "displacement"
    output_unit: str = "um"
    notes: tuple[str, ...] = ()
    sidecar: dict | None = None
    time_name: str = field(default="time")

    def __post_init__(self):
        arrays = {}
        for name in ("time", "current", "displacement"):
            arr = np.array(getattr(self, name), dtype=float)  # a copy: the record owns its data
            if arr.ndim != 1:
                raise ValueError(f"Record.{name} must be 1-D, got shape {arr.shape}")
            arrays[name] = arr
        lengths = {name: arr.size for name, arr in arrays.items()}
        if len(set(lengths.values())) != 1:
            raise ValueError(f"Record arrays must have equal lengths, got {lengths}")
        for name, arr in arrays.items():
            if not np.isfinite(arr).all():
                k = int(np.flatnonzero(~np.isfinite(arr))[0])
                raise ValueError(f"Record.{name} has a non-finite value at sample {k} ({arr[k]})")
            object.__setattr__(self, name, arr)
        steps = np.diff(arrays["time"])
        if (steps <= 0).any():
            k = int(np.flatnonzero(steps <= 0)[0])
            raise ValueError(
                f"Record.time must be strictly increasing: sample {k + 1} ({arrays['time'][k + 1]!r}) "
                f"follows {arrays['time'][k]!r}"
            )
        object.__setattr__(self, "notes", tuple(self.notes))

    def __len__(self) -> int:
        return int(self.time.size)

    @property
    def n_samples(self) -> int:
        """Number of samples ``T``."""
        return len(self)

    @property
    def columns(self) -> tuple[str, str, str]:
        """The CSV header this record is written with: (time, input, output) names."""
        return (self.time_name, self.input_name, self.output_name)


#: Longest unit string accepted (``--input-unit``, ``--output-unit``, ``load_record``'s units).
MAX_UNIT_LENGTH = 32
#: Characters no unit holds: markup and quoting (``< > & " ' ` \\``) and ``$`` (matplotlib's math mode).
_UNIT_FORBIDDEN = set("<>&\"'`\\$")


def unit_problem(unit) -> str | None:
    """What makes ``unit`` no unit (None when it is one): a unit is a short printable string
    (at most :data:`MAX_UNIT_LENGTH` characters, no control character, none of
    ``< > & " ' ` \\ $``), such as ``um``, ``A``, ``V``, ``mm/s``, ``µm``, ``m/s^2`` or ``""``."""
    if not isinstance(unit, str):
        return f"expected a unit (text), got {type(unit).__name__}"
    if len(unit) > MAX_UNIT_LENGTH:
        return f"a unit is at most {MAX_UNIT_LENGTH} characters, got {len(unit)}"
    bad = sorted({c for c in unit if not c.isprintable() or c in _UNIT_FORBIDDEN})
    if bad:
        return (
            f"a unit is a short printable string without < > & \" ' ` \\ $, got {unit!r} "
            f"(it holds {', '.join(repr(c) for c in bad)})"
        )
    return None


def check_unit(unit, name: str = "unit") -> str:
    """``unit`` when it is one (:func:`unit_problem`), else ValueError naming ``name``."""
    problem = unit_problem(unit)
    if problem:
        raise ValueError(f"{name}: {problem}")
    return unit


def sidecar_path(path) -> Path:
    """The JSON sidecar belonging to CSV ``path``: same folder and stem, suffix ``.json``."""
    return Path(path).with_suffix(".json")


def _fail(path, line, problem) -> RecordError:
    where = f"{path}" if line is None else f"{path}, line {line}"
    return RecordError(f"{where}: {problem}")


def _suggest(wanted: str, present: list[str]) -> str:
    close = difflib.get_close_matches(wanted, present, n=3, cutoff=0.5)
    close += [p for p in present if wanted.lower() in p.lower() and p not in close]
    return f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""


def _decimal_comma_float(text: str) -> float:
    """``"-0,25"`` -> -0.25 (a decimal comma; ``"0.25"`` reads too). ValueError for anything else,
    e.g. ``"1.234,5"`` (a thousands separator is not read)."""
    return float(text.replace(",", "."))


def _looks_numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


#: Largest magnitude accepted in a drive or output column, in any unit: beyond it a value
#: is no measurement (a corrupted cell), and squares and sums of such values would
#: overflow the noise and likelihood arithmetic.
MAX_ABS_VALUE = 1e15
#: Largest magnitude accepted in the time column [s] (leaves room for epoch times in ms).
MAX_ABS_TIME = 1e18
#: Files larger than this report their loading progress through ``progress``.
_PROGRESS_BYTES = 20 * 2**20
_CHUNK = 1 << 20


def _hash_and_check_text(path: Path):
    """SHA-256 of the file and its size, checking it is UTF-8 text, in 1 MB chunks (memory O(1)).

    Raises RecordError naming the line of the first byte that is not UTF-8."""
    digest = hashlib.sha256()
    decoder = codecs.getincrementaldecoder("utf-8")()
    newlines = 0
    size = 0
    nonblank = False
    try:
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(_CHUNK), b""):
                digest.update(chunk)
                size += len(chunk)
                try:
                    decoder.decode(chunk)
                except UnicodeDecodeError as exc:
                    line = newlines + exc.object[: exc.start].count(b"\n") + 1
                    raise _fail(
                        path,
                        line,
                        f"not UTF-8 text (byte {size - len(chunk) + exc.start}); a record is a plain-text CSV file",
                    ) from None
                newlines += chunk.count(b"\n")
                nonblank = nonblank or bool(chunk.strip())
            try:
                decoder.decode(b"", final=True)
            except UnicodeDecodeError:
                raise _fail(path, newlines + 1, "not UTF-8 text (the file ends inside a character)") from None
    except FileNotFoundError:
        raise _fail(path, None, "no such file") from None
    except IsADirectoryError:
        raise _fail(path, None, "is a folder, not a record file") from None
    except OSError as exc:
        raise _fail(path, None, f"cannot read the file ({exc.strerror or exc})") from None
    return digest.hexdigest(), size, nonblank


def load_record(
    path,
    *,
    time_column="time",
    input_column="current",
    output_column="displacement",
    input_unit="A",
    output_unit="um",
    min_samples=200,
    progress=None,
) -> Record:
    """Load a CSV record, checking everything; raise :class:`RecordError` on any problem.

    The file is read as a stream (memory about 50 bytes per sample whatever the line
    length: no copy of the text is held), after a first pass that computes its SHA-256
    and checks it is UTF-8. The stages: the options and the text check, the header
    (:func:`_read_header`: format detection, :func:`_header_columns`: column checks), the
    rows (:func:`_parse_rows`), the values (:func:`_checked_arrays`, :func:`_time_axis`)
    and the sidecar (:func:`_read_sidecar`); each stage adds its notes.

    Parameters
    ----------
    path : str or path-like
        The CSV file. A JSON file with the same stem beside it is read into
        :attr:`Record.sidecar`. Columns are separated by ``,``, ``;`` or a tab (the first
        of them in the header); with ``;`` or a tab, a comma in a number is a decimal
        comma (``0,25``, as European MATLAB/Excel exports write; a note says so). A file
        ending in ``.mat`` is a MATLAB file, read by :func:`identify.data.matfile.read_mat_variables`
        (column names are then variable names).
    time_column : str or None, default "time"
        Header name of the time column [s]. ``None``: the file has no time column (any
        column named like one is ignored); the time axis becomes the sample index
        0, 1, 2, ... and a note says so.
    input_column, output_column : str, default "current", "displacement"
        Header names of the drive and output columns (e.g. ``"voltage"`` for a piezo).
        ``output_column=None``: a drive file (``time,current``, e.g. a designed next record's
        drive); the record's displacement is then zero.
    input_unit, output_unit : str, default "A", "um"
        Units of those columns, stored on the record for labels: short printable strings
        (:func:`unit_problem`; anything else is a ValueError).
    min_samples : int, default 200
        Fewest samples accepted.
    progress : callable, optional
        ``progress(message)`` is called about every 10 % of a file above 20 MB.

    Returns
    -------
    Record

    Raises
    ------
    RecordError
        Missing or unreadable file, empty file, no header, missing or misnamed columns
        (the message lists the columns present and close matches), a row with the wrong
        number of cells, an empty or non-numeric cell, NaN or infinity, a value beyond
        any physical range (:data:`MAX_ABS_VALUE`, :data:`MAX_ABS_TIME`), times that do
        not strictly increase, fewer than ``min_samples`` samples, or a malformed
        sidecar. The message names the file, the line and, for a value, the column.
    """
    path = Path(path)
    check_unit(input_unit, "input_unit")
    check_unit(output_unit, "output_unit")
    if path.suffix.lower() == MAT_SUFFIX:  # a MATLAB file: the same checks, by variable (identify.data.matfile)
        return _load_mat_record(path, time_column, input_column, output_column, input_unit, output_unit, min_samples)
    wanted = [c for c in (time_column, input_column, output_column) if c is not None]
    if len(set(wanted)) != len(wanted):
        raise ValueError(f"time/input/output column names must differ, got {wanted}")
    if isinstance(min_samples, bool) or not isinstance(min_samples, (int, np.integer)) or min_samples < 2:
        raise ValueError(f"min_samples must be an integer >= 2, got {min_samples!r}")
    digest, size, nonblank = _hash_and_check_text(path)
    if not nonblank:
        raise _fail(
            path, None, "the file is empty; expected a header line such as 'time,current,displacement' and data rows"
        )

    notes: list[str] = []
    with open(path, encoding="utf-8-sig", newline=None) as fh:
        layout = _read_header(fh, path, wanted, notes)
        layout.indices = _header_columns(path, layout, wanted, time_column, notes)
        columns, skipped_lines, decimal_comma = _parse_rows(fh, path, layout, wanted, size, progress)
    n_skipped = layout.n_skipped + len(skipped_lines)
    if n_skipped:
        notes.append(f"skipped {n_skipped} blank or comment ('#') line(s)")
    if decimal_comma:
        notes.append("decimal commas read as decimal points (e.g. 0,25 = 0.25)")
    line_of = _row_lines(layout.line, skipped_lines)
    n_samples = len(columns[0][2])
    if n_samples < min_samples:
        raise _fail(
            path,
            None,
            f"only {n_samples} data row(s), fewer than the {min_samples} samples required "
            "(a record needs a quiet start and several cycles)",
        )
    arrays = _checked_arrays(path, columns, time_column, line_of)
    time = _time_axis(path, arrays, time_column, n_samples, line_of, notes)
    sidecar = _read_sidecar(path, notes)
    return Record(
        time=time,
        current=arrays[input_column],
        displacement=arrays[output_column] if output_column is not None else np.zeros(n_samples),
        source=str(path),
        sha256=digest,
        input_name=input_column,
        input_unit=input_unit,
        output_name=output_column if output_column is not None else "none",
        output_unit=output_unit,
        notes=tuple(notes),
        sidecar=sidecar,
        time_name=time_column if time_column is not None else "time",
    )


@dataclass
class _Layout:
    """The CSV header as :func:`load_record` read it: its 1-based ``line`` and ``text``, the
    ``n_skipped`` blank or comment lines before it, the ``delimiter``, the number parser,
    the column ``names`` and (after :func:`_header_columns`) ``{wanted column: index}``."""

    line: int
    text: str
    n_skipped: int
    delimiter: str
    parse_number: object
    names: list
    indices: dict = field(default_factory=dict)


def _read_header(fh, path: Path, wanted: list, notes: list) -> _Layout:
    """Format detection: the first line that is neither blank nor a comment is the header;
    its first ``,``, ``;`` or tab is the delimiter (with ``;`` or tab, numbers may carry a
    decimal comma). Refuses a file of comments only, a header of numbers, an unnamed or a
    repeated column name."""
    header_line, header_text, n_skipped = None, "", 0
    for number, line in enumerate(fh, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            n_skipped += 1
            continue
        header_line, header_text = number, line.rstrip("\n")
        break
    if header_line is None:
        raise _fail(path, None, "the file holds only comments or blank lines; expected a header and data rows")

    delimiter = next((d for d in _DELIMITERS if d in header_text), ",")
    if delimiter != ",":
        notes.append(f"columns are separated by {delimiter!r} rather than commas")
    # with ';' or tab between columns a comma is a decimal comma (European MATLAB/Excel exports)
    parse_number = float if delimiter == "," else _decimal_comma_float
    header = [h.strip() for h in header_text.split(delimiter)]
    if all(_looks_numeric(h) for h in header if h):
        raise _fail(
            path,
            header_line,
            f"no header line: the first line is numbers ({header_text.strip()[:60]!r}); "
            f"expected column names {','.join(wanted)}",
        )
    seen = {}
    for j, h in enumerate(header):
        if not h:
            raise _fail(path, header_line, f"column {j + 1} of the header has no name")
        if h in seen:
            raise _fail(path, header_line, f"column name {h!r} appears twice (columns {seen[h] + 1} and {j + 1})")
        seen[h] = j
    return _Layout(header_line, header_text, n_skipped, delimiter, parse_number, header)


def _header_columns(path: Path, layout: _Layout, wanted: list, time_column, notes: list) -> dict:
    """Column checks: ``{wanted column: index}``, a name matching in letter case only taken
    with a note; a missing column refused with the columns present and close matches; the
    other columns ignored with a note."""
    header = layout.names
    seen = {h: j for j, h in enumerate(header)}

    def find(name):
        if name in seen:
            return seen[name]
        folded = [h for h in header if h.casefold() == name.casefold()]
        if len(folded) == 1:
            notes.append(f"column {folded[0]!r} taken as {name!r} (letter case differs)")
            return seen[folded[0]]
        return None

    indices = {}
    missing = []
    for name in wanted:
        j = find(name)
        if j is None:
            missing.append(name)
        else:
            indices[name] = j
    if missing:
        hints = "; ".join(f"{m!r}{_suggest(m, header)}" for m in missing)
        raise _fail(
            path,
            layout.line,
            f"missing column(s) {hints}. Columns present: {', '.join(repr(h) for h in header)}. "
            "Rename the header or pass the column names: --time-column/--input-column/--output-column on the "
            "command line ('--time-column none' for no time column), time_column=/input_column=/output_column= "
            "in Python.",
        )
    extra = [h for j, h in enumerate(header) if j not in indices.values()]
    if time_column is None and any(h.casefold() in ("time", "t", "t_s", "time_s") for h in extra):
        notes.append("the file's time-like column was ignored because time_column=None")
    if extra:
        notes.append(f"ignored column(s): {', '.join(extra)}")
    return indices


def _parse_rows(fh, path: Path, layout: _Layout, wanted: list, size: int, progress) -> tuple[list, list, bool]:
    """Parsing: the data rows after the header, streamed into one ``array('d')`` per wanted
    column. Returns ``([(name, index, values)], the 1-based lines of the blank or comment
    lines skipped, whether a decimal comma was read)``; a bad row raises (:func:`_row_error`)."""
    n_columns = len(layout.names)
    parse_number = layout.parse_number
    columns = [(name, layout.indices[name], array("d")) for name in wanted]
    appends = [(j, values.append) for _name, j, values in columns]
    report_every = max(1, size // 10) if (progress is not None and size > _PROGRESS_BYTES) else 0
    next_report = report_every
    read_bytes = 0
    decimal_comma = False
    skipped_lines: list[int] = []  # blank/comment lines after the header, to map rows to lines
    for number, line in enumerate(fh, start=layout.line + 1):
        cells = line.split(layout.delimiter)
        try:
            if len(cells) != n_columns:
                raise ValueError
            for j, append in appends:
                append(parse_number(cells[j]))
        except ValueError:
            stripped = line.strip()
            if not stripped or stripped.startswith("#"):
                # undo a partial row (a comment line with the right number of cells)
                n_done = len(columns[-1][2])
                for _name, _j, values in columns:
                    del values[n_done:]
                skipped_lines.append(number)
                continue
            error = _row_error(path, number, cells, layout, columns)
            if error is not None:
                raise error from None
            raise  # pragma: no cover - every cell parsed after all
        if not decimal_comma and parse_number is not float and "," in line:
            decimal_comma = True
        if report_every:
            read_bytes += len(line)
            if read_bytes >= next_report:
                progress(f"reading {path.name}: {min(100, 100 * read_bytes // size)} % ({len(columns[0][2])} rows)")
                next_report += report_every
    return columns, skipped_lines, decimal_comma


def _row_error(path: Path, number: int, cells: list, layout: _Layout, columns: list) -> RecordError | None:
    """The error of a data row that did not parse: wrong number of cells, an empty cell, or
    not a number (None if every cell parses after all)."""
    n_columns = len(layout.names)
    if len(cells) != n_columns:
        return _fail(
            path, number, f"{len(cells)} cells, but the header has {n_columns} columns ({','.join(layout.names)})"
        )
    for name, j, _values in columns:
        cell = cells[j].strip()
        if not cell:
            return _fail(path, number, f"column {name!r} is empty")
        if not _looks_numeric(cell.replace(",", ".") if layout.delimiter != "," else cell):
            return _fail(path, number, f"column {name!r}: {cell[:40]!r} is not a number")
    return None  # pragma: no cover


def _row_lines(header_line: int, skipped_lines: list):
    """``line_of(k)``: the file line (1-based) of data row ``k`` (0-based)."""

    def line_of(k: int) -> int:
        """File line (1-based) of data row ``k`` (0-based)."""
        line = header_line + 1 + k
        for s in skipped_lines:
            if s <= line:
                line += 1
            else:
                break
        return line

    return line_of


def _checked_arrays(path: Path, columns: list, time_column, line_of) -> dict:
    """``{name: float array}``, refusing NaN, infinity and values beyond any physical range."""
    arrays = {}
    for name, j, values in columns:
        arr = np.frombuffer(values, dtype=float)
        limit = MAX_ABS_TIME if name == time_column else MAX_ABS_VALUE
        bad = ~(np.abs(arr) <= limit)  # NaN and infinity included
        if bad.any():
            k = int(np.argmax(bad))
            value = float(arr[k])
            where = f"column {name!r} (column {j + 1})"
            if not math.isfinite(value):
                raise _fail(path, line_of(k), f"{where}: {value!r} is not a finite number (NaN or infinity)")
            raise _fail(
                path,
                line_of(k),
                f"{where}: {value:.6g} is beyond any physical range (|value| > {limit:.0e} in any unit); "
                "a corrupted value? Correct or remove that line",
            )
        arrays[name] = arr
    return arrays


def _time_axis(path: Path, arrays: dict, time_column, n_samples: int, line_of, notes: list) -> np.ndarray:
    """The time column, refused unless strictly increasing; the sample index (with a note) without one."""
    if time_column is None:
        notes.append(
            "the file has no time column: time is the sample index 0, 1, 2, ... (unit steps, "
            "in samples rather than seconds); time constants come out in samples"
        )
        return np.arange(n_samples, dtype=float)
    time = arrays[time_column]
    step = _first_step_back(time)
    if step is not None:
        k, kind = step
        raise _fail(
            path,
            line_of(k + 1),
            f"time {float(time[k + 1])!r} {kind} the previous time {float(time[k])!r} (line {line_of(k)}); "
            "times must strictly increase",
        )
    return time


def _first_step_back(time) -> tuple[int, str] | None:
    """``(k, how)`` for the first sample ``k + 1`` whose time does not exceed sample ``k``'s
    (``how``: "repeats" or "is smaller than"); None when the times strictly increase."""
    steps = np.diff(time)
    bad = np.flatnonzero(steps <= 0)
    if not bad.size:
        return None
    k = int(bad[0])
    return k, "repeats" if steps[k] == 0 else "is smaller than"


def _read_sidecar(path: Path, notes: list) -> dict | None:
    """The JSON sidecar beside ``path`` (an object), or None when there is none."""
    side = sidecar_path(path)
    if not (side.is_file() and side != path):
        return None
    try:
        sidecar = json.loads(side.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise _fail(side, exc.lineno, f"malformed JSON sidecar: {exc.msg} (column {exc.colno})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(side, None, f"cannot read the JSON sidecar ({exc})") from None
    if not isinstance(sidecar, dict):
        raise _fail(side, 1, f"the JSON sidecar must be an object ({{...}}), got {type(sidecar).__name__}")
    notes.append(f"read the sidecar {side.name}")
    return sidecar


# -- MATLAB .mat records (the file format: identify.data.matfile) -----------------------------


def _file_sha256(path: Path) -> str:
    """SHA-256 of a (binary) file's bytes, in 1 MB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _mat_vector(path, name, value, limit) -> np.ndarray:
    """``value`` as a checked float vector, or a RecordError naming variable ``name``."""
    if value is None:
        raise _fail(path, None, f"variable {name!r} is not a numeric array")
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        kind = "complex" if arr.dtype.kind == "c" else f"of type {arr.dtype}"
        raise _fail(path, None, f"variable {name!r} is {kind}; expected a real numeric vector")
    if arr.ndim > 2 or (arr.ndim == 2 and min(arr.shape) != 1):
        raise _fail(path, None, f"variable {name!r} has shape {arr.shape}; expected a vector (1 x T or T x 1)")
    arr = arr.astype(float).ravel()
    bad = ~(np.abs(arr) <= limit)
    if bad.any():
        k = int(np.argmax(bad))
        value = float(arr[k])
        if not np.isfinite(value):
            raise _fail(
                path, None, f"variable {name!r}, sample {k + 1}: {value!r} is not a finite number (NaN or infinity)"
            )
        raise _fail(
            path,
            None,
            f"variable {name!r}, sample {k + 1}: {value:.6g} is beyond any physical range "
            f"(|value| > {limit:.0e} in any unit); a corrupted value?",
        )
    return arr


def _load_mat_record(
    path: Path, time_column, input_column, output_column, input_unit, output_unit, min_samples
) -> Record:
    """The ``.mat`` branch of :func:`load_record`: the same arguments and checks, by variable.

    The file is read by :func:`identify.data.matfile.read_mat_variables` (top-level
    variables or one struct's fields, v4-v7 through scipy, v7.3 through h5py). The
    RecordError names a missing variable (listing those present and close matches), a
    variable that is not a real numeric vector, vectors of different lengths, or a bad
    value by variable and sample; :attr:`Record.notes` says where the variables came from.
    """
    path = Path(path)
    wanted = [c for c in (time_column, input_column, output_column) if c is not None]
    if len(set(wanted)) != len(wanted):
        raise ValueError(f"time/input/output variable names must differ, got {wanted}")
    if not path.exists():
        raise _fail(path, None, "no such file")
    if path.is_dir():
        raise _fail(path, None, "is a folder, not a record file")
    digest = _file_sha256(path)
    try:
        variables, where = read_mat_variables(path, wanted)
    except MatFileError as exc:
        raise _fail(path, None, str(exc)) from None
    missing = [name for name in wanted if name not in variables]
    if missing:
        present = sorted(variables)
        hints = "; ".join(f"{m!r}{_suggest(m, present)}" for m in missing)
        raise _fail(
            path,
            None,
            f"missing variable(s) {hints}. Variables present: {', '.join(map(repr, present)) or 'none'}. "
            "Pass the names (--time-column/--input-column/--output-column; 'none' for no time).",
        )
    arrays = {
        name: _mat_vector(path, name, variables[name], MAX_ABS_TIME if name == time_column else MAX_ABS_VALUE)
        for name in wanted
    }
    lengths = {name: arr.size for name, arr in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise _fail(
            path, None, "the variables have different lengths: " + ", ".join(f"{k} {v}" for k, v in lengths.items())
        )
    n = next(iter(lengths.values()))
    if n < min_samples:
        raise _fail(
            path,
            None,
            f"only {n} samples, fewer than the {min_samples} required (a record needs a quiet start and several "
            "cycles)",
        )
    notes = [f"read {', '.join(wanted)} from the MATLAB file's {where}"]
    if time_column is None:
        time = np.arange(n, dtype=float)
        notes.append("the file has no time variable: time is the sample index 0, 1, 2, ... (time constants in samples)")
    else:
        time = arrays[time_column]
        step = _first_step_back(time)
        if step is not None:
            k, kind = step
            raise _fail(
                path,
                None,
                f"variable {time_column!r}, sample {k + 2}: time {float(time[k + 1])!r} {kind} the previous "
                f"time {float(time[k])!r}; times must strictly increase",
            )
    return Record(
        time=time,
        current=arrays[input_column],
        displacement=arrays[output_column],
        source=str(path),
        sha256=digest,
        input_name=input_column,
        input_unit=input_unit,
        output_name=output_column,
        output_unit=output_unit,
        notes=tuple(notes),
        time_name=time_column if time_column is not None else "time",
    )


def _csv_bytes(columns, arrays) -> bytes:
    out = [",".join(columns)]
    stacked = np.column_stack(arrays)
    out.extend(f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in stacked.tolist())
    return ("\n".join(out) + "\n").encode("ascii")


def write_record(path, record_or_arrays, sidecar: dict | None = None) -> None:
    """Write a record as CSV (and its JSON sidecar), atomically and byte-reproducibly.

    Parameters
    ----------
    path : str or path-like
        The CSV file to write; its folder must exist.
    record_or_arrays : Record, or (time, current, displacement), or mapping
        A :class:`Record` (written with its own column names), or three 1-D arrays of
        equal length, or a mapping with keys ``time``, ``current``, ``displacement``
        (written with the default header ``time,current,displacement``).
    sidecar : dict, optional
        JSON-serialisable metadata written to :func:`sidecar_path` (sorted keys,
        2-space indent). When omitted, a :class:`Record`'s own ``sidecar`` is used. When
        there is none, an existing sidecar beside ``path`` is removed, because it
        described the file being replaced.

    Raises
    ------
    ValueError
        Arrays of different lengths, non-finite values, non-increasing times, or a
        sidecar that is not a JSON-serialisable dict. Nothing is written then.
    """
    path = Path(path)
    if isinstance(record_or_arrays, Record):
        record = record_or_arrays
        if sidecar is None:
            sidecar = record.sidecar
    else:
        if isinstance(record_or_arrays, Mapping):
            try:
                arrays = [record_or_arrays[k] for k in DEFAULT_COLUMNS]
            except KeyError as exc:
                raise ValueError(f"write_record: the mapping needs keys {DEFAULT_COLUMNS}, missing {exc}") from None
        else:
            arrays = list(record_or_arrays)
            if len(arrays) != 3:
                raise ValueError(
                    f"write_record expects a Record or 3 arrays (time, current, displacement), got {len(arrays)}"
                )
        record = Record(*arrays, source=str(path), sha256="")
    side_bytes = None
    if sidecar is not None:
        if not isinstance(sidecar, dict):
            raise ValueError(f"sidecar must be a dict, got {type(sidecar).__name__}")
        try:
            side_bytes = (json.dumps(sidecar, indent=2, sort_keys=True, allow_nan=False) + "\n").encode("utf-8")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"sidecar is not JSON-serialisable: {exc}") from None
    data = _csv_bytes(record.columns, (record.time, record.current, record.displacement))
    side = sidecar_path(path)
    if side == path:
        raise ValueError(f"{path}: a record file must not end in .json (that name is reserved for its sidecar)")
    atomic_write_bytes(path, data)
    if side_bytes is not None:
        atomic_write_bytes(side, side_bytes)
    elif side.exists():
        side.unlink()


def thinning_indices(current, every: int, reversals=None, around: int = 0) -> np.ndarray:
    """Sorted sample indices kept by thinning: ``0, every, 2 every, ...``, every input reversal
    (with the ``around`` samples on each side of it) and the last sample.

    Parameters
    ----------
    current : array_like, shape (T,)
        The drive.
    every : int
        Step (>= 1).
    reversals : array_like of int, optional
        Indices of the input reversals when already known; default
        :func:`identify.data.reversals.find_reversals` ``(current).index``.
    around : int, default 0
        Samples kept at the full rate on each side of every reversal (>= 0): a drive that
        lags the current (a lag, a dead time) reverses after it, and its peak is then
        computed from the same samples as on the whole record.

    Returns
    -------
    ndarray of int, shape (K,)
    """
    n = len(current)
    if reversals is None:
        reversals = find_reversals(current).index
    reversals = np.asarray(reversals, dtype=int)
    if around < 0:
        raise ValueError(f"around must be >= 0 samples, got {around!r}")
    near = (reversals[:, None] + np.arange(-int(around), int(around) + 1)[None, :]).ravel()
    keep = np.union1d(np.arange(0, n, int(every)), near[(near >= 0) & (near < n)])
    return np.union1d(keep, [n - 1])


def keep_every(record: Record, every: int) -> Record:
    """The record thinned to every ``every``-th sample, keeping every input reversal.

    For the rate-independent GPI the output at a kept sample depends only on the input
    sequence's extrema, so keeping the reversals (peaks and troughs, by
    :func:`identify.data.reversals.find_reversals`) besides every ``every``-th sample and the
    last one leaves the model output at every kept sample unchanged (exactly, when the
    input has no wiggles smaller than ``find_reversals``' 2 % swing); only the number of
    residuals (and so the information) shrinks, e.g. a 5 kHz record of a 1 Hz drive
    thinned by 10 still has 500 samples per cycle. Time-dependent effects (lag, creep,
    thermal) integrate over the kept time stamps, so thin only far below their time
    constants. The noise of the thinned record is estimated from its own quiet start.

    Parameters
    ----------
    record : Record
    every : int
        Keep sample ``0, every, 2 every, ...`` (>= 1; 1 returns ``record`` itself).

    Returns
    -------
    Record
        Same source, hash, units, columns and sidecar; one note added saying what was kept.

    Raises
    ------
    ValueError
        ``every`` is not an integer >= 1.
    """
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ValueError(f"keep every N-th sample needs an integer N >= 1, got {every!r}")
    every = int(every)
    if every == 1:
        return record
    n = len(record)
    keep = thinning_indices(record.current, every)
    note = (
        f"thinned (--every {every}): kept every {ordinal(every)} sample, every input reversal and the last sample: "
        f"{keep.size} of {n} samples"
    )
    return replace(
        record,
        time=record.time[keep],
        current=record.current[keep],
        displacement=record.displacement[keep],
        notes=(*record.notes, note),
    )


#: :func:`suggest_every` aims at about this many samples per input half-cycle.
SAMPLES_PER_HALF_CYCLE = 250


def suggest_every(
    record: Record, *, min_samples=20000, per_half_cycle=SAMPLES_PER_HALF_CYCLE
) -> tuple[int, float] | None:
    """A ``--every N`` for a record far longer than the rate-independent GPI needs, or None.

    The GPI's output depends only on the input's sequence of extrema, so a few hundred
    samples between two reversals describe a branch well; a record of ``min_samples``
    or more with four or more times that many (e.g. a 5 kHz record of a 1 Hz drive)
    costs time and memory in proportion to its length for no information the model can
    use. Reversals are counted on at most 200,000 evenly spaced samples (cheap for any
    length).

    Returns
    -------
    (every, samples_per_half_cycle) or None
        ``every`` keeps about ``per_half_cycle`` samples per half-cycle (and every
        reversal, :func:`keep_every`).
    """
    n = len(record)
    if n < min_samples:
        return None
    stride = max(1, n // 200_000)
    n_reversals = len(find_reversals(np.asarray(record.current)[::stride]).index)
    per = n / (n_reversals + 1)
    every = int(per // per_half_cycle)
    return (every, per) if every >= 4 else None
