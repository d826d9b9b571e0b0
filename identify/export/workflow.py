"""``export(study, out)``: a finished study's model and its inverse as C and as FMI units.

Writes ``OUT`` all at once (built in a temporary folder beside it and renamed):

``OUT/c/``
    ``msma_gpi.h``, ``msma_gpi.c``, ``msma_params.c`` (the parameter set), ``example.c`` and
    ``README.md`` (:mod:`identify.export.sources`).
``OUT/model.fmu``, ``OUT/compensator.fmu``
    FMI 2.0 co-simulation units built from the same C with the local compiler
    (:mod:`identify.export.fmu`).
``OUT/export.json``
    What was exported: provenance, parameters with units, the units' GUIDs, the compiler,
    the horizon, the current range, notes.

The parameters are the posterior median (``summary.json``'s medians, as ``compensate``
takes them) or one posterior draw (``draw``: an index into the posterior samples). Bad
input (not a finished study, an unknown draw, an effect that cannot be streamed) raises
before anything is written; with no C compiler ``OUT/c/`` and ``export.json`` are written
and :class:`~identify.export.compiler.CompilerError` is raised after.
"""

from __future__ import annotations

import datetime as _datetime
import json
import shutil
import tempfile
import time as _time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from model import EFFECTS

from ..data.fileio import move_folder_into_place
from ..version import __version__
from ..workflows.use import Study, default_current_range, load_study, reachable_range
from .compiler import CompilerError, find_compiler
from .fmu import FMU_NAMES, build_fmu
from .sources import c_sources
from .spec import HORIZON_EFFECTS, ExportError, ExportSpec, export_spec

__all__ = ["Export", "export", "study_spec", "EXPORT_FILE"]

#: The export's own record (and the marker that a folder holds an export).
EXPORT_FILE = "export.json"


@dataclass
class Export:
    """What :func:`export` wrote."""

    out: Path
    spec: ExportSpec
    files: list = field(default_factory=list)
    fmus: dict = field(default_factory=dict)
    compiler: str | None = None
    fmu_error: str | None = None
    seconds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        spec = self.spec
        units = spec.units_of()
        return {
            "provenance": spec.provenance,
            "model": spec.model.to_dict(),
            "units": spec.units,
            "parameters": {name: {"value": spec.values[name], "unit": units[name]} for name in spec.model.names},
            "horizon": spec.horizon,
            "current_range": list(spec.current_range),
            "output_scale": spec.output_scale,
            "files": self.files,
            "fmus": self.fmus,
            "compiler": self.compiler,
            "fmu_error": self.fmu_error,
            "notes": spec.notes,
            "seconds": self.seconds,
        }


def _compensator_theta(study: Study, theta):
    """``theta`` with ``sensor_drift`` at its off values (the compensator leaves it out, as compensate does)."""
    model = study.model
    theta = np.array(theta, dtype=float)
    if "sensor_drift" in model.effect_names:
        sl = model.effect_slice("sensor_drift")
        off = EFFECTS["sensor_drift"].off
        theta[sl] = [off[name] for name in model.names[sl]]
    return theta


def study_spec(study, *, draw=None, horizon=None, current_range=None) -> ExportSpec:
    """The :class:`ExportSpec` of a finished study (a :class:`Study` or its folder).

    Raises
    ------
    identify.workflows.use.UseError
        Not a finished study.
    ExportError
        An unknown draw, an effect that cannot be streamed, a bad horizon or range.
    """
    if not isinstance(study, Study):
        study = load_study(study)
    model = study.model
    n_samples = study.samples.shape[0]
    if draw is None:
        theta, what = study.median, "posterior median"
    else:
        if isinstance(draw, bool) or not isinstance(draw, (int, np.integer)) or not 0 <= int(draw) < n_samples:
            raise ExportError(
                f"{study.path}: no posterior draw {draw!r}: the posterior has {n_samples} samples (draws 0 to "
                f"{n_samples - 1})"
            )
        theta, what = study.samples[int(draw)], f"posterior draw {int(draw)} of {n_samples}"
    record = study.record
    duration = float(record.time[-1] - record.time[0])
    horizon = duration if horizon is None else float(horizon)
    limits = default_current_range(study) if current_range is None else tuple(float(x) for x in current_range)
    manifest = study.manifest
    data, git = manifest.get("data", {}), manifest.get("git", {})

    provenance = {
        "study": str(study.path),
        "parameters": what,
        "converged": bool(study.converged),
        "data_file": data.get("file"),
        "data_sha256": data.get("sha256"),
        "data_samples": data.get("n_samples"),
        "git_commit": git.get("commit"),
        "git_dirty": git.get("dirty"),
        "study_seed": manifest.get("seed"),
        "exported_by": f"msma-gpi {__version__}",
    }
    notes = []
    if not study.converged:
        notes.append("the study's posterior is NOT CONVERGED: its median is provisional")
    if "sensor_drift" in model.effect_names:
        notes.append("sensor_drift: in the model unit only; the compensator leaves it out (compensate does)")
    uses = [e for e in model.effect_names if e in HORIZON_EFFECTS]
    if uses:
        notes.append(
            f"{', '.join(uses)}: the streaming form takes the run's length, horizon = {horizon:g} s "
            f"({'the study record' if horizon == duration else 'given'}; a parameter of the C and the units)"
        )
    spec = export_spec(
        model,
        theta,
        units={"input": record.input_unit, "output": record.output_unit},
        horizon=horizon,
        current_range=limits,
        provenance=provenance,
        notes=notes,
    )
    theta_c = _compensator_theta(study, theta)
    y_low, y_high = reachable_range(model, theta_c, record.time, spec.current_range)
    return replace(spec, output_scale=max(1.0, abs(y_low), abs(y_high)))


def _prepare_out(out: Path) -> None:
    """Refuse an ``out`` that is a file or a folder holding other files (an earlier export is replaced)."""
    if out.exists():
        if not out.is_dir():
            raise ExportError(f"{out}: exists and is not a folder; choose another --out")
        if any(out.iterdir()) and not (out / EXPORT_FILE).exists():
            raise ExportError(f"{out}: exists and holds other files (no {EXPORT_FILE}); choose another --out")


def export(study, out, *, draw=None, horizon=None, current_range=None, compiler=None, progress=None) -> Export:
    """Export a finished study's model and inverse as C (``OUT/c/``) and FMI 2.0 units (module docstring).

    Parameters
    ----------
    study : Study or path
    out : path
    draw : int, optional
        A posterior draw (index into the posterior samples); default the posterior median.
    horizon : float, optional
        The run's length [s] for ``creep``'s logarithmic modes and ``sensor_drift``; default the
        study record's duration.
    current_range : (float, float), optional
        The compensator's current limits; default as ``compensate`` (the rig's 0-5 A for a study in A).
    compiler : str, optional
        The C compiler (default ``$CC``, then ``cc``, ``gcc``, ``clang``).
    progress : callable(str), optional

    Returns
    -------
    Export

    Raises
    ------
    identify.workflows.use.UseError, ExportError
        Bad input, with nothing written.
    identify.export.compiler.CompilerError
        No C compiler (or it failed): ``OUT/c/`` and ``export.json`` are written, the units are not.
    """
    say = progress or (lambda message: None)
    clock = _time.perf_counter()
    if not isinstance(study, Study):
        study = load_study(study)
    spec = study_spec(study, draw=draw, horizon=horizon, current_range=current_range)
    out = Path(out)
    _prepare_out(out)
    result = Export(out=out, spec=spec)
    sources = c_sources(spec)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    failure = None
    try:
        (staging / "c").mkdir()
        for name, text in sources.items():
            (staging / "c" / name).write_text(text, encoding="utf-8")
            result.files.append(f"c/{name}")
        result.seconds["sources"] = _time.perf_counter() - clock
        try:
            command = find_compiler(compiler)
            result.compiler = " ".join(command)
            record = _record_figures(study, spec)
            generated = _datetime.datetime.now(_datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
            for kind, (name, _, _) in FMU_NAMES.items():
                say(f"building {name} with {result.compiler}")
                clock = _time.perf_counter()
                start = record["current_start"] if kind == "model" else record["target_start"]
                result.fmus[name] = build_fmu(
                    spec,
                    kind,
                    staging / name,
                    input_start=start,
                    step_size=record["step"],
                    generated=generated,
                    compiler=command,
                )
                result.files.append(name)
                result.seconds[name] = _time.perf_counter() - clock
        except CompilerError as exc:
            failure = exc
            result.fmu_error = str(exc)
            for name in list(result.fmus):
                (staging / name).unlink(missing_ok=True)
            result.fmus.clear()
            result.files = [f for f in result.files if f.startswith("c/")]
        result.files.append(EXPORT_FILE)
        (staging / EXPORT_FILE).write_text(json.dumps(result.to_dict(), indent=2, default=str) + "\n")
        move_folder_into_place(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if failure is not None:
        raise CompilerError(f"{failure}: wrote {out / 'c'} and {out / EXPORT_FILE}, not the FMUs") from None
    return result


def _record_figures(study: Study, spec: ExportSpec) -> dict:
    """The study record's figures the units take: its mean sample step (the default
    experiment's step size), the first drive (the model unit's input start) and the exported
    model's output there (the compensator's target start)."""
    record = study.record
    step = float((record.time[-1] - record.time[0]) / (record.time.size - 1))
    current0 = float(record.current[0])
    theta = _compensator_theta(study, spec.model.theta_from_dict(spec.values))
    y, _ = spec.model.evaluate(theta, np.array([0.0, step]), np.array([current0, current0]))
    return {"step": step, "current_start": current0, "target_start": float(y[0, 0])}
