"""MATLAB ``.mat`` files (the lab in the paper records with MATLAB/dSPACE): the file format.

:func:`read_mat_variables` reads the named variables of a ``.mat`` file;
:func:`identify.data.records.load_record` turns them into a
:class:`identify.data.records.Record` with the same strict checks as the CSV loader for
any file ending in ``.mat``, so every command takes a ``.mat`` record where it takes a CSV::

    python -m identify fit run7.mat --input-column i_coil --output-column x_laser

The record's columns are MATLAB **variables** of those names: top-level variables, or
fields of one top-level struct that holds all of them (a dSPACE/ControlDesk export
typically saves one struct). Each must be a real numeric vector (``1 x T`` or ``T x 1``).

Versions: v4, v6 and v7 files are read with :func:`scipy.io.loadmat`; v7.3 files are HDF5
and are read with :mod:`h5py` (top-level datasets, or the datasets of one group). A file
that cannot be read is a :class:`MatFileError`; the loader reports it, and every problem
with the variables, as a :class:`identify.data.records.RecordError` naming the file, the
variable and what is wrong (a missing variable lists those present and close matches; a
value that is not finite names the 1-based sample).

This module knows nothing of records (of the package it imports only
:mod:`identify.data.hdf5`), so :mod:`identify.data.records` can import it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .hdf5 import open_hdf5

__all__ = ["read_mat_variables", "MatFileError", "MAT_SUFFIX"]

#: File suffix read as a MATLAB file by :func:`identify.data.records.load_record`.
MAT_SUFFIX = ".mat"


class MatFileError(ValueError):
    """A file that is no readable MATLAB ``.mat`` file; the message says why (not the path)."""


def read_mat_variables(path, wanted) -> tuple[dict, str]:
    """The variables ``wanted`` of the ``.mat`` file ``path`` and where they were found.

    Parameters
    ----------
    path : str or path-like
        An existing ``.mat`` file (v4-v7 through scipy, v7.3 through h5py).
    wanted : sequence of str
        Variable names: top-level variables, or fields of the one top-level struct (group)
        that holds all of them.

    Returns
    -------
    variables : dict
        ``{name: numpy array}`` holding every wanted variable found; when not all were
        found, every name present (structs' fields as ``struct.field``, mapped to None when
        not read), for the caller's message.
    where : str
        Where they were found, for a note (e.g. ``"fields of struct 'run'"``).

    Raises
    ------
    MatFileError
        The file is no readable MATLAB file.
    """
    return _read_v5(Path(path), list(wanted))


def _read_v5(path: Path, wanted) -> tuple[dict, str]:
    """``{name: array}`` of the top-level variables (or one struct's fields) and a description."""
    import scipy.io  # deferred: ~0.8 s to import, needed only for a MATLAB v5 record

    try:
        contents = scipy.io.loadmat(str(path), squeeze_me=False, struct_as_record=True)
    except NotImplementedError:  # v7.3: HDF5
        return _read_v73(path, wanted)
    except (ValueError, TypeError, OSError, EOFError, scipy.io.matlab.MatReadError) as exc:
        raise MatFileError(f"not a readable MATLAB .mat file ({' '.join(str(exc).split())[:200]})") from None
    variables = {k: v for k, v in contents.items() if not k.startswith("__")}
    if all(name in variables for name in wanted):
        return variables, "variables"
    structs = [k for k, v in variables.items() if isinstance(v, np.ndarray) and v.dtype.names]
    holding = [k for k in structs if all(name in variables[k].dtype.names for name in wanted)]
    if len(holding) == 1:
        struct = variables[holding[0]]
        if struct.size != 1:
            raise MatFileError(f"struct {holding[0]!r} is an array of {struct.size} structs; expected one struct")
        fields = {name: struct[name].flat[0] for name in struct.dtype.names}
        return fields, f"fields of struct {holding[0]!r}"
    present = list(variables) + [f"{k}.{f}" for k in structs for f in variables[k].dtype.names]
    return {**variables, **{p: None for p in present if p not in variables}}, "variables"


def _read_v73(path: Path, wanted) -> tuple[dict, str]:
    """As :func:`_read_v5` for a v7.3 (HDF5) file."""
    import h5py  # deferred: h5py costs ~0.6 s to import, needed only for a v7.3 file

    try:
        with open_hdf5(path, "r") as f:
            datasets = {k: f[k] for k in f.keys() if isinstance(f[k], h5py.Dataset)}
            if all(name in datasets for name in wanted):
                return {k: np.asarray(datasets[k][()]) for k in wanted}, "variables (v7.3)"
            groups = [k for k in f.keys() if isinstance(f[k], h5py.Group) and not k.startswith("#")]
            holding = [
                g for g in groups if all(name in f[g] and isinstance(f[g][name], h5py.Dataset) for name in wanted)
            ]
            if len(holding) == 1:
                g = f[holding[0]]
                return {k: np.asarray(g[k][()]) for k in wanted}, f"fields of struct {holding[0]!r} (v7.3)"
            present = list(datasets) + [f"{g}.{k}" for g in groups for k in f[g].keys()]
            return dict.fromkeys(present), "variables (v7.3)"
    except OSError as exc:
        raise MatFileError(f"not a readable MATLAB v7.3 (HDF5) .mat file ({exc})") from None
