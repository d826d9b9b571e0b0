"""MATLAB ``.mat`` records (the lab in the paper records with MATLAB/dSPACE).

:func:`load_mat_record` reads a ``.mat`` file into a :class:`identify.records.Record`
with the same strict checks as the CSV loader (:func:`identify.records.load_record`,
which calls it for any file ending in ``.mat``, so every command takes a ``.mat`` record
where it takes a CSV)::

    python -m identify fit run7.mat --input-column i_coil --output-column x_laser

The record's columns are MATLAB **variables** of those names: top-level variables, or
fields of one top-level struct that holds all of them (a dSPACE/ControlDesk export
typically saves one struct). Each must be a real numeric vector (``1 x T`` or ``T x 1``).

Versions: v4, v6 and v7 files are read with :func:`scipy.io.loadmat`; v7.3 files are HDF5
and are read with :mod:`h5py` (top-level datasets, or the datasets of one group). Any
problem is a :class:`identify.records.RecordError` naming the file, the variable and what
is wrong (a missing variable lists those present and close matches; a value that is not
finite names the 1-based sample).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from .records import MAX_ABS_TIME, MAX_ABS_VALUE, Record, RecordError, _suggest

__all__ = ["load_mat_record", "MAT_SUFFIX"]

#: File suffix read as a MATLAB file by :func:`identify.records.load_record`.
MAT_SUFFIX = ".mat"


def _fail(path, problem) -> RecordError:
    return RecordError(f"{path}: {problem}")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _read_v5(path: Path, wanted) -> tuple[dict, str]:
    """``{name: array}`` of the top-level variables (or one struct's fields) and a description."""
    import scipy.io

    try:
        contents = scipy.io.loadmat(str(path), squeeze_me=False, struct_as_record=True)
    except NotImplementedError:  # v7.3: HDF5
        return _read_v73(path, wanted)
    except (ValueError, TypeError, OSError, EOFError, scipy.io.matlab.MatReadError) as exc:
        raise _fail(path, f"not a readable MATLAB .mat file ({' '.join(str(exc).split())[:200]})") from None
    variables = {k: v for k, v in contents.items() if not k.startswith("__")}
    if all(name in variables for name in wanted):
        return variables, "variables"
    structs = [k for k, v in variables.items() if isinstance(v, np.ndarray) and v.dtype.names]
    holding = [k for k in structs if all(name in variables[k].dtype.names for name in wanted)]
    if len(holding) == 1:
        struct = variables[holding[0]]
        if struct.size != 1:
            raise _fail(path, f"struct {holding[0]!r} is an array of {struct.size} structs; expected one struct")
        fields = {name: struct[name].flat[0] for name in struct.dtype.names}
        return fields, f"fields of struct {holding[0]!r}"
    present = list(variables) + [f"{k}.{f}" for k in structs for f in variables[k].dtype.names]
    return {**variables, **{p: None for p in present if p not in variables}}, "variables"


def _read_v73(path: Path, wanted) -> tuple[dict, str]:
    """As :func:`_read_v5` for a v7.3 (HDF5) file."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            datasets = {k: f[k] for k in f.keys() if isinstance(f[k], h5py.Dataset)}
            if all(name in datasets for name in wanted):
                return {k: np.asarray(datasets[k][()]) for k in wanted}, "variables (v7.3)"
            groups = [k for k in f.keys() if isinstance(f[k], h5py.Group) and not k.startswith("#")]
            holding = [g for g in groups if all(name in f[g] and isinstance(f[g][name], h5py.Dataset) for name in wanted)]
            if len(holding) == 1:
                g = f[holding[0]]
                return {k: np.asarray(g[k][()]) for k in wanted}, f"fields of struct {holding[0]!r} (v7.3)"
            present = list(datasets) + [f"{g}.{k}" for g in groups for k in f[g].keys()]
            return dict.fromkeys(present), "variables (v7.3)"
    except OSError as exc:
        raise _fail(path, f"not a readable MATLAB v7.3 (HDF5) .mat file ({exc})") from None


def _vector(path, name, value, limit) -> np.ndarray:
    """``value`` as a checked float vector, or a RecordError naming variable ``name``."""
    if value is None:
        raise _fail(path, f"variable {name!r} is not a numeric array")
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        kind = "complex" if arr.dtype.kind == "c" else f"of type {arr.dtype}"
        raise _fail(path, f"variable {name!r} is {kind}; expected a real numeric vector")
    if arr.ndim > 2 or (arr.ndim == 2 and min(arr.shape) != 1):
        raise _fail(path, f"variable {name!r} has shape {arr.shape}; expected a vector (1 x T or T x 1)")
    arr = arr.astype(float).ravel()
    bad = ~(np.abs(arr) <= limit)
    if bad.any():
        k = int(np.argmax(bad))
        value = float(arr[k])
        if not np.isfinite(value):
            raise _fail(path, f"variable {name!r}, sample {k + 1}: {value!r} is not a finite number (NaN or infinity)")
        raise _fail(path, f"variable {name!r}, sample {k + 1}: {value:.6g} is beyond any physical range "
                    f"(|value| > {limit:.0e} in any unit); a corrupted value?")  # fmt: skip
    return arr


def load_mat_record(
    path,
    *,
    time_column="time",
    input_column="current",
    output_column="displacement",
    input_unit="A",
    output_unit="um",
    min_samples=200,
) -> Record:
    """Load a MATLAB ``.mat`` record, checking everything; raise RecordError on any problem.

    Parameters
    ----------
    path : str or path-like
        The ``.mat`` file (v4-v7 through scipy, v7.3 through h5py).
    time_column : str or None, default "time"
        Variable holding the sample times [s], shape (T,). None: no time variable; time
        is the sample index 0, 1, 2, ... and a note says so.
    input_column, output_column : str, default "current", "displacement"
        Variables holding the drive and the output, shape (T,) each.
    input_unit, output_unit : str, default "A", "um"
        Their units, stored on the record.
    min_samples : int, default 200
        Fewest samples accepted.

    Returns
    -------
    Record
        ``sha256`` of the file's bytes; :attr:`Record.notes` says where the variables came from.

    Raises
    ------
    RecordError
        Missing file, not a MATLAB file, a missing variable (listing those present and
        close matches), a variable that is not a real numeric vector, vectors of different
        lengths, a NaN, infinite or absurd value (naming variable and sample), times that
        do not strictly increase, or fewer than ``min_samples`` samples.
    """
    path = Path(path)
    wanted = [c for c in (time_column, input_column, output_column) if c is not None]
    if len(set(wanted)) != len(wanted):
        raise ValueError(f"time/input/output variable names must differ, got {wanted}")
    if not path.exists():
        raise _fail(path, "no such file")
    if path.is_dir():
        raise _fail(path, "is a folder, not a record file")
    digest = _sha256(path)
    variables, where = _read_v5(path, wanted)
    missing = [name for name in wanted if name not in variables]
    if missing:
        present = sorted(variables)
        hints = "; ".join(f"{m!r}{_suggest(m, present)}" for m in missing)
        raise _fail(path, f"missing variable(s) {hints}. Variables present: {', '.join(map(repr, present)) or 'none'}. "
                    "Pass the names (--time-column/--input-column/--output-column; 'none' for no time).")  # fmt: skip
    arrays = {
        name: _vector(path, name, variables[name], MAX_ABS_TIME if name == time_column else MAX_ABS_VALUE) for name in wanted
    }
    lengths = {name: arr.size for name, arr in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise _fail(path, "the variables have different lengths: " + ", ".join(f"{k} {v}" for k, v in lengths.items()))
    n = next(iter(lengths.values()))
    if n < min_samples:
        raise _fail(path, f"only {n} samples, fewer than the {min_samples} required (a record needs a quiet start and several cycles)")
    notes = [f"read {', '.join(wanted)} from the MATLAB file's {where}"]
    if time_column is None:
        time = np.arange(n, dtype=float)
        notes.append("the file has no time variable: time is the sample index 0, 1, 2, ... (time constants in samples)")
    else:
        time = arrays[time_column]
        steps = np.diff(time)
        bad = np.flatnonzero(steps <= 0)
        if bad.size:
            k = int(bad[0])
            kind = "repeats" if steps[k] == 0 else "is smaller than"
            raise _fail(path, f"variable {time_column!r}, sample {k + 2}: time {time[k + 1]!r} {kind} the previous "
                        f"time {time[k]!r}; times must strictly increase")  # fmt: skip
    return Record(
        time=time, current=arrays[input_column], displacement=arrays[output_column], source=str(path), sha256=digest,
        input_name=input_column, input_unit=input_unit, output_name=output_column, output_unit=output_unit,
        notes=tuple(notes), time_name=time_column if time_column is not None else "time",
    )  # fmt: skip
