r"""Real measured hysteresis records from other groups: converters, load options, and a peer model.

Three records measured by others sit in the shared folder ``../shared/realdata/`` (see its
``README.md``, ``PEERS.md`` and each ``PROVENANCE.md``):

``piezo_smarthysteresis`` (MIT)
    A piezo actuator driven by a 1 Hz, +-150 V sine, 5 kHz, 10 s, with a real unenergised
    start (0-3.2570 s). :func:`convert_smarthysteresis` writes the project's copy
    ``data/piezo_smarthysteresis.csv`` (columns ``time,voltage,displacement`` in s, V, um).
``piezo_micromanipulator_dbo`` (MIT)
    A piezo micromanipulator, 200 Hz, 1 Hz sine with amplitude ramps and nested minor
    loops. :func:`convert_micromanipulator` writes rows 0-7431 of ``Test_Vi_Do_Di.dat``
    (the uncompensated open-loop drive) to ``data/piezo_micromanipulator.csv``.
    It has **no unenergised segment**: the drive is *held* at 1.83 V for rows 3881-5071,
    so the sensor noise is estimated from that hold with :func:`held_input_noise_sigma`
    and passed to the identification as a user value (``--noise-sigma``).
``sma_morphing_wing_ga`` (no licence)
    An SMA mechanism's quasi-static loops with reversal curves, **no time base** and no
    quiet segment. It may only be *read* from the shared folder (tests), never copied
    into the project. :func:`load_sma_sequence` reads it; :func:`basaeri_gpi` is a port
    of the published 21-operator GPI fit to it (PEERS.md item 1), and
    :func:`basaeri_theta` maps that fit exactly onto this project's GPI parameters.

The converters copy every number **verbatim** (the same decimal text as the source),
only reordering columns and adding a header (and, for the 200 Hz record, a time column
``k / 200`` s), so the shipped values are the measured values bit for bit. They write to
a temporary file renamed into place.

Peer model (``PI_11P.m`` of HaammiiD/Genetic-Algorithm-System-Identification, commit
9ff1fb4f, as described in PEERS.md; no code copied), with input samples :math:`v_t`:

.. math::

    \gamma_R(v) = P_1 \tanh(P_2 v + P_3) + P_4, \qquad
    \gamma_L(v) = P_5 \tanh(P_6 v + P_7) + P_8, \\
    r_i = P_{11} i,\quad p_i = P_9 e^{-P_{10} r_i},\quad i = 0 \dots 20, \\
    F_i \leftarrow \max(\gamma_L(v_t) - r_i, \min(\gamma_R(v_t) + r_i, F_i)),\quad
    F_i(\text{start}) = \gamma_R(v_1) + r_i, \\
    y_t = 17.72 + \textstyle\sum_i p_i F_i .

The same response in this project's GPI (:mod:`model.gpi`, reading ``"swapped"``,
:math:`r_j = \alpha j,\ j = 1 \dots N`, lower bound :math:`\gamma_a - r_j`, upper
:math:`\gamma_b + r_j`) with :math:`N = 21`: :math:`\alpha = -P_{11}`,
:math:`\gamma_a = \gamma_L - P_{11} N`, :math:`\gamma_b = \gamma_R + P_{11} N` (so operator
``j`` here is the peer's ``i = N - j``), :math:`\tau = P_{10}`,
:math:`\rho = P_9 e^{-P_{10} P_{11} N}`, a constant :math:`\Omega = 17.72` (``c0 = d0 = 0``)
and an initial memory above every upper bound (each operator starts at its upper bound,
the peer's initial state).
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .fileio import atomic_write, toml_module
from .records import load_record

__all__ = [
    "shared_realdata_dir",
    "RealRecord",
    "REAL_RECORDS",
    "ConversionResult",
    "convert_smarthysteresis",
    "convert_micromanipulator",
    "load_sma_sequence",
    "held_input_noise_sigma",
    "drop_window",
    "BASAERI_PARAMETERS",
    "BASAERI_OFFSET",
    "BASAERI_N_OPERATORS",
    "basaeri_gpi",
    "basaeri_theta",
    "SMARTHYSTERESIS_SWITCH_ON_S",
    "MICROMANIPULATOR_HOLD_ROWS",
]

#: Time of the switch-on step of the SmartHysteresis record [s] (row 16286: 0 V -> -87.1 V).
SMARTHYSTERESIS_SWITCH_ON_S = 3.2572
#: Rows (0-based, end exclusive) of the converted micromanipulator record where the drive
#: is held at 1.830 V (energised, mid-stroke): the segment used for the noise estimate.
MICROMANIPULATOR_HOLD_ROWS = (3881, 5072)
#: Sampling rate of the micromanipulator record [Hz] (``Fs=200`` in the authors' scripts).
_MICROMANIPULATOR_FS = 200.0

#: The published GA fit P1..P11 of PEERS.md item 1 (``PI_11P.m``), on ``input_data``.
BASAERI_PARAMETERS = (15.7940, 2.7649, -5.6356, 15.5400, 0.8380, 6.4364, -9.9631, 0.5618, 10.9590, 2.5785, 0.0395)
#: The constant output offset of that fit (``y = 17.72 + sum p_i F_i``).
BASAERI_OFFSET = 17.72
#: Its number of operators (``i = 0 .. 20``).
BASAERI_N_OPERATORS = 21


def shared_realdata_dir() -> Path:
    """The shared folder of real records: ``$MSMA_SHARED_REALDATA``, else ``<project>/../shared/realdata``.

    The folder may be absent (e.g. on CI); callers check ``.is_dir()``.
    """
    env = os.environ.get("MSMA_SHARED_REALDATA")
    if env:
        return Path(env)
    project = Path(__file__).resolve().parents[2]  # identify/data/realdata.py -> the project
    return project.parent / "shared" / "realdata"


@dataclass(frozen=True)
class RealRecord:
    """A real record the project knows: where it comes from and how to load it.

    Attributes
    ----------
    name : str
        Folder name in the shared realdata folder.
    licence : str
        ``"MIT"`` or ``"none"`` (then it may not be copied into the project).
    shipped : str or None
        Path of the converted copy inside the project (relative to the project root), or
        None when it may not be shipped.
    load_options : dict
        Keyword arguments of :func:`identify.data.records.load_record` for that file.
    assumptions : tuple of str
        What the identification must assume for this record, in plain words.
    """

    name: str
    licence: str
    shipped: str | None
    load_options: dict
    assumptions: tuple[str, ...]


#: The columns and units of the CSV files the converters below write (``time,voltage,displacement``).
CONVERTED_COLUMNS = dict(
    time_column="time", input_column="voltage", output_column="displacement", input_unit="V", output_unit="um"
)


def _read_registry(path: Path) -> dict:
    """The :class:`RealRecord` of each table of ``real_records.toml`` (TOML has no null: a
    ``false`` column is None, e.g. no time column)."""
    records = {}
    for name, entry in toml_module().loads(path.read_text(encoding="utf-8")).items():
        columns = entry["columns"]
        load_options = (
            dict(CONVERTED_COLUMNS)
            if columns == "converted"
            else {k: (None if v is False else v) for k, v in columns.items()}
        )
        records[name] = RealRecord(
            name, entry["licence"], entry.get("shipped"), load_options, tuple(entry["assumptions"])
        )
    return records


#: The known real records, by name (read from ``real_records.toml`` beside this module).
REAL_RECORDS = _read_registry(Path(__file__).with_name("real_records.toml"))


@dataclass(frozen=True)
class ConversionResult:
    """What a converter wrote.

    Attributes
    ----------
    destination : Path
        The CSV written.
    n_rows : int
        Data rows written (the header excluded).
    source_sha256, sha256 : str
        SHA-256 of the source file and of the written file.
    """

    destination: Path
    n_rows: int
    source_sha256: str
    sha256: str


def _write_ascii(path: Path, text: str) -> str:
    """Write ``text`` (ASCII, ``\\n`` line ends) to ``path`` via a temporary file; return its SHA-256."""
    data = text.encode("ascii")
    atomic_write(path, data, make_parents=True)
    return hashlib.sha256(data).hexdigest()


def _check_number(text: str, source: Path, line: int, what: str) -> str:
    """Return ``text`` stripped, after checking it is a finite decimal number."""
    cell = text.strip()
    try:
        value = float(cell)
    except ValueError:
        raise ValueError(f"{source}, line {line}: {what} {cell[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{source}, line {line}: {what} {cell!r} is not finite")
    return cell


def convert_smarthysteresis(source, destination) -> ConversionResult:
    """Convert SmartHysteresis' ``hysteresis_v_150_1hz.csv`` to ``time,voltage,displacement``.

    The source has no header and the columns ``,<t>,<y>,<v>`` (an empty leftover index,
    time [s], displacement [um], commanded voltage [V]). All 50,001 rows are written,
    every number copied as the same decimal text.

    Parameters
    ----------
    source : path-like
        ``piezo_smarthysteresis/hysteresis_v_150_1hz.csv``.
    destination : path-like
        The CSV to write (e.g. ``data/piezo_smarthysteresis.csv``); its folder is created.

    Returns
    -------
    ConversionResult

    Raises
    ------
    ValueError
        A row without 4 cells, a non-numeric cell, or times that do not increase (naming
        the source line); nothing is written then.
    """
    source = Path(source)
    raw = source.read_bytes()
    lines = raw.decode("ascii").splitlines()
    out = ["time,voltage,displacement"]
    previous_time = -math.inf
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != 4:
            raise ValueError(f"{source}, line {number}: expected 4 cells ',t,y,v', got {len(cells)}")
        time_text = _check_number(cells[1], source, number, "time")
        displacement_text = _check_number(cells[2], source, number, "displacement")
        voltage_text = _check_number(cells[3], source, number, "voltage")
        if float(time_text) <= previous_time:
            raise ValueError(f"{source}, line {number}: time {time_text} does not increase")
        previous_time = float(time_text)
        out.append(f"{time_text},{voltage_text},{displacement_text}")
    sha = _write_ascii(Path(destination), "\n".join(out) + "\n")
    return ConversionResult(Path(destination), len(out) - 1, hashlib.sha256(raw).hexdigest(), sha)


def convert_micromanipulator(source, destination, rows=(0, 7432)) -> ConversionResult:
    """Convert rows of the DBO micromanipulator's ``Test_Vi_Do_Di.dat`` to ``time,voltage,displacement``.

    The source is whitespace-separated, no header, 11 columns; column 1 is the voltage
    sent to the actuator [V] and column 5 the capacitive-sensor displacement [um, with an
    offset]. Time is synthesised as ``row / 200`` s, written with 3 decimals (exact
    multiples of 5 ms), relative to the first row written.

    Parameters
    ----------
    source : path-like
        ``piezo_micromanipulator_dbo/Test_Vi_Do_Di.dat``.
    destination : path-like
        The CSV to write; its folder is created.
    rows : (int, int), default (0, 7432)
        0-based ``[start, stop)`` rows of the source: the default is the uncompensated
        open-loop drive (PROVENANCE.md: rows 0-7431); later rows are the authors'
        inverse-compensator test.

    Returns
    -------
    ConversionResult

    Raises
    ------
    ValueError
        Bad ``rows``, a row with fewer than 5 columns or a non-numeric cell (naming the line).
    """
    source = Path(source)
    start, stop = (int(rows[0]), int(rows[1]))
    if not (0 <= start < stop):
        raise ValueError(f"rows must be (start, stop) with 0 <= start < stop, got {rows!r}")
    raw = source.read_bytes()
    lines = [ln for ln in raw.decode("ascii").splitlines() if ln.strip()]
    if stop > len(lines):
        raise ValueError(f"{source}: rows {rows!r} reach beyond the {len(lines)} rows of the file")
    out = ["time,voltage,displacement"]
    for k, number in enumerate(range(start, stop)):
        cells = lines[number].split()
        if len(cells) < 5:
            raise ValueError(f"{source}, line {number + 1}: expected at least 5 columns, got {len(cells)}")
        voltage_text = _check_number(cells[0], source, number + 1, "voltage (column 1)")
        displacement_text = _check_number(cells[4], source, number + 1, "displacement (column 5)")
        out.append(f"{k / _MICROMANIPULATOR_FS:.3f},{voltage_text},{displacement_text}")
    sha = _write_ascii(Path(destination), "\n".join(out) + "\n")
    return ConversionResult(Path(destination), len(out) - 1, hashlib.sha256(raw).hexdigest(), sha)


def load_sma_sequence(path=None):
    """Load ``sma_morphing_wing_ga/input_data_sequence.csv`` (read-only, from the shared folder).

    Parameters
    ----------
    path : path-like, optional
        Default: ``shared_realdata_dir() / "sma_morphing_wing_ga" / "input_data_sequence.csv"``.

    Returns
    -------
    identify.data.records.Record
        773 samples; time is the sample index (the file has none) and the record's notes
        say so. Input ``v_input`` [V, unconfirmed], output ``y_output`` [unknown units].
    """
    if path is None:
        path = shared_realdata_dir() / "sma_morphing_wing_ga" / "input_data_sequence.csv"
    return load_record(path, **REAL_RECORDS["sma_morphing_wing_ga"].load_options)


def held_input_noise_sigma(displacement, rows) -> float:
    """Sensor noise std from a stretch where the drive is held constant (not necessarily off).

    Uses the first differences, ``std(diff(y)) / sqrt(2)``, which ignore a slow drift or
    a constant offset across the hold.

    Parameters
    ----------
    displacement : array_like, shape (T,)
        Output samples [output units].
    rows : (int, int)
        ``[start, stop)`` of the hold, at least 20 samples.

    Returns
    -------
    float
        Noise standard deviation [output units].
    """
    y = np.asarray(displacement, dtype=float)
    start, stop = int(rows[0]), int(rows[1])
    if y.ndim != 1 or not (0 <= start < stop <= y.size) or stop - start < 20:
        raise ValueError(f"rows {rows!r} must be a stretch of >= 20 samples inside the {y.size}-sample record")
    return float(np.std(np.diff(y[start:stop]), ddof=1) / math.sqrt(2.0))


def drop_window(record, start, stop):
    """The record without the samples with ``start <= time < stop``, and a note saying so.

    For a rate-independent model (the GPI without time-dependent effects) dropping
    samples inside one monotone stretch of the input leaves the output at every kept
    sample unchanged (the operators only see the sequence of input values), so this is
    the same as leaving those samples out of the fit. If the window holds an input
    extremum, the memory it left differs until a larger excursion wipes it out.

    Used for the switch-on ringing of the SmartHysteresis record: the drive steps to
    -87.1 V at 3.2572 s (before the sensor has moved) and the displacement rings for
    about 12 ms, real dynamics a rate-independent model cannot fit.
    ``drop_window(record, 3.2572, 3.2772)`` leaves out 20 ms (100 samples); the
    dropped step sample is an input minimum 3 V below the next kept one, so the memory
    differs until the first +150 V peak, 0.35 s later (3.606 s), resets every operator
    narrower than that swing (tested for plays up to 150 V wide).
    With time-dependent effects (lag, creep) a gap changes their integration, so do
    not drop windows then.

    Parameters
    ----------
    record : identify.data.records.Record
    start, stop : float
        Window [s] (record time units), ``start < stop``.

    Returns
    -------
    identify.data.records.Record
        Same source, hash, units and notes, plus one note naming the window and the
        number of samples dropped.

    Raises
    ------
    ValueError
        ``start >= stop``, or the window holds no sample or every sample.
    """
    if not (np.isfinite(start) and np.isfinite(stop) and start < stop):
        raise ValueError(f"drop_window needs start < stop (finite), got {start!r}, {stop!r}")
    time = np.asarray(record.time)
    inside = (time >= start) & (time < stop)
    n_dropped = int(inside.sum())
    if n_dropped == 0 or n_dropped == time.size:
        raise ValueError(
            f"the window [{start}, {stop}) s holds {n_dropped} of {time.size} samples; nothing sensible to drop"
        )
    keep = ~inside
    note = (
        f"samples with {start:g} <= time < {stop:g} s dropped ({n_dropped} samples): "
        "left out of the fit (valid for a rate-independent model)"
    )
    return replace(
        record,
        time=record.time[keep],
        current=record.current[keep],
        displacement=record.displacement[keep],
        notes=tuple(record.notes) + (note,),
    )


def _check_basaeri(parameters) -> np.ndarray:
    p = np.asarray(parameters, dtype=float)
    if p.shape != (11,) or not np.isfinite(p).all():
        raise ValueError(f"the peer GPI needs 11 finite parameters P1..P11, got shape {p.shape}")
    return p


def basaeri_gpi(voltage, parameters=BASAERI_PARAMETERS, n_operators=BASAERI_N_OPERATORS, offset=BASAERI_OFFSET):
    """The peer GPI of PEERS.md item 1, ported plainly from its description (one loop over samples).

    Parameters
    ----------
    voltage : array_like, shape (T,)
        Input samples [V].
    parameters : sequence of 11 float, default :data:`BASAERI_PARAMETERS`
        ``P1 .. P11`` (see the module docstring).
    n_operators : int, default 21
        Operators ``i = 0 .. n_operators - 1``.
    offset : float, default 17.72
        The constant added to the output.

    Returns
    -------
    ndarray, shape (T,)
        Model output, in the record's output units.
    """
    p = _check_basaeri(parameters)
    v = np.asarray(voltage, dtype=float)
    if v.ndim != 1 or v.size < 1:
        raise ValueError(f"voltage must have shape (T,), T >= 1, got {v.shape}")

    def descending(x):
        return p[0] * np.tanh(p[1] * x + p[2]) + p[3]

    def ascending(x):
        return p[4] * np.tanh(p[5] * x + p[6]) + p[7]

    thresholds = p[10] * np.arange(n_operators)
    weights = p[8] * np.exp(-p[9] * thresholds)
    state = descending(v[0]) + thresholds
    out = np.empty(v.size)
    for t, vt in enumerate(v):
        state = np.maximum(ascending(vt) - thresholds, np.minimum(descending(vt) + thresholds, state))
        out[t] = offset + weights @ state
    return out


def basaeri_theta(parameters=BASAERI_PARAMETERS, n_operators=BASAERI_N_OPERATORS, offset=BASAERI_OFFSET):
    """The peer fit as this project's 19 GPI parameters (reading ``"swapped"``), plus its initial memory.

    Parameters
    ----------
    parameters, n_operators, offset
        As in :func:`basaeri_gpi`.

    Returns
    -------
    theta : ndarray, shape (19,)
        In :data:`model.gpi.THETA_NAMES` order; use with ``n_operators`` operators.
    initial_memory : float
        A level above every operator's upper bound, so each starts at its upper bound
        (the peer's ``F_i = gamma_R(v_1) + r_i``).
    """
    p = _check_basaeri(parameters)
    step = p[10]
    shift = step * n_operators
    theta = np.array(
        [
            -step,
            p[8] * math.exp(-p[9] * step * n_operators),
            p[9],
            p[4],
            p[5],
            p[6],
            p[7] - shift,
            p[0],
            p[1],
            p[2],
            p[3] + shift,
            0.0,
            1.0,
            0.0,
            offset,
            0.0,
            1.0,
            0.0,
            offset,
        ]
    )
    initial_memory = 1e6 * (1.0 + abs(p[0]) + abs(p[3]) + shift)
    return theta, float(initial_memory)
