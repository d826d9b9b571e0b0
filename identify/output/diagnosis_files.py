"""The diagnosis in a results folder: ``DIR/diagnosis.json`` and the figures ``DIR/diagnosis/*.png``.

One writer for ``python -m identify diagnose --out DIR`` and for the diagnosis a study runs
itself (:func:`identify.workflows.study.study`, ``diagnose=True``); the study report
(:mod:`identify.output.report`) reads them back. Every file is written to a temporary name
and renamed, so an interrupted run leaves no half-written file.
"""

from __future__ import annotations

import shlex
from pathlib import Path

from ..data.fileio import atomic_write_bytes
from .page import png_bytes
from .results import read_json, write_json

__all__ = ["DIAGNOSIS_FILE", "DIAGNOSIS_FIGURES", "COMPARISON_FILE", "write_diagnosis", "next_step", "earlier_study"]

#: The diagnosis' content (:meth:`identify.diagnosis.diagnose.Diagnosis.to_dict`) in a results folder.
DIAGNOSIS_FILE = "diagnosis.json"
#: Folder (inside the results folder) of the diagnosis' figures.
DIAGNOSIS_FIGURES = "diagnosis"
#: Names the earlier study this one is compared with (``study --compare DIR``): ``{"earlier": path, "found": how}``.
COMPARISON_FILE = "comparison.json"


def write_diagnosis(diagnosis, record, *, json_path=None, out_dir=None) -> list[str]:
    """Write the JSON and (with ``out_dir``) the figures; returns the paths written.

    Parameters
    ----------
    diagnosis : Diagnosis or JointDiagnosis
    record : Record or list of Record
        The record (each record of a joint diagnosis: its figures are those of the record alone,
        ``record<k>_<stem>.png``).
    json_path : path-like, optional
        Gets the JSON alone.
    out_dir : path-like, optional
        Gets ``diagnosis.json`` and ``diagnosis/<stem>.png`` for every figure (the figures of an
        earlier diagnosis there are removed first, so they never mix).
    """
    content = diagnosis.to_dict()
    written = []
    if json_path is not None:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        write_json(json_path, content)
        written.append(str(json_path))
    if out_dir is None:
        return written
    # deferred: matplotlib, about 0.5 s of CPU, for the figures alone
    from .diagnosis_plots import diagnosis_figures

    out = Path(out_dir)
    figure_dir = out / DIAGNOSIS_FIGURES
    figure_dir.mkdir(parents=True, exist_ok=True)
    for stale in figure_dir.glob("*.png"):
        stale.unlink()
    records = record if isinstance(record, (list, tuple)) else [record]
    alone = getattr(diagnosis, "alone", None) or [diagnosis]
    for r, (one, rec) in enumerate(zip(alone, records), start=1):
        prefix = f"record{r}_" if len(records) > 1 else ""  # each record's own figures
        for stem, figure in diagnosis_figures(one, rec).items():
            path = figure_dir / f"{prefix}{stem}.png"
            atomic_write_bytes(path, png_bytes(figure, 100))  # a 256-colour PNG, as the report's
            written.append(str(path))
    write_json(out / DIAGNOSIS_FILE, content)
    written.append(str(out / DIAGNOSIS_FILE))
    return written


def _quoted(path) -> str:
    """A path as a shell word (quoted only when it needs to be)."""
    return shlex.quote(str(path))


def next_step(diagnosis: dict, *, data_file, effects, out_dir) -> tuple[str, str | None]:
    """The verdict of a study's diagnosis in one sentence, and the command to run next.

    Parameters
    ----------
    diagnosis : dict
        ``diagnosis.json`` (``status``, ``missing``, ``tied``).
    data_file : str
        The record's path as the study was given it (the manifest's ``data.file``).
    effects : sequence of str
        The effects of the studied model.
    out_dir : str or Path
        The study's results folder.

    Returns
    -------
    sentence : str
        Plain text, e.g. "The model misses the effect thermal: add it and compare.".
    command : str or None
        ``python -m identify study DATA --effects ... --out DIR-<effect> --compare DIR`` for a
        missing effect; ``python -m identify design DATA --out DIR-design`` for a tie; None when
        there is nothing to run (an adequate model, or structure no effect explains).
    """
    status = str(diagnosis.get("status"))
    out = str(out_dir).rstrip("/")
    if status == "missing_effect" and diagnosis.get("missing"):
        missing = str(diagnosis["missing"])
        added = ",".join([*effects, missing])
        command = (
            f"python -m identify study {_quoted(data_file)} --effects {added} "
            f"--out {_quoted(out + '-' + missing)} --compare {_quoted(out)}"
        )
        return f"The model misses the effect {missing}: study it again with {missing} added.", command
    if status == "tied":
        names = " or ".join(str(name) for name in diagnosis.get("tied") or []) or "several effects"
        command = f"python -m identify design {_quoted(data_file)} --out {_quoted(out + '-design')}"
        return (
            f"The record cannot tell {names} apart: design the experiment that decides between them, measure it, "
            "then diagnose both records together.",
            command,
        )
    if status == "adequate":
        return "The diagnosis finds nothing to add: the residual's structure is within the noise tests.", None
    return (
        "Structure remains in the residual that no effect of the library explains (see the diagnosis section).",
        None,
    )


def earlier_study(out_dir, sha256: str, effects) -> Path | None:
    """The study this one adds an effect to, found through the manifests of its sibling folders.

    A sibling of ``out_dir`` (same parent folder) qualifies when its ``manifest.json`` names a
    record with the same SHA-256, its study finished (``summary.json`` holds a posterior) and
    its effects are a strict subset of ``effects``; of several, the one whose diagnosis named an
    effect that was added, then the most recent. None when nothing qualifies.
    """
    out = Path(out_dir).resolve()
    wanted = set(effects)
    found = []
    for folder in sorted(p for p in out.parent.iterdir() if p.is_dir() and p.resolve() != out):
        try:
            manifest = read_json(folder / "manifest.json")
            summary = read_json(folder / "summary.json")
        except (OSError, ValueError):
            continue
        settings = manifest.get("settings") or {}
        theirs = {name for name in str(settings.get("effects") or "").split(",") if name}
        if (manifest.get("data") or {}).get("sha256") != sha256 or not summary.get("posterior"):
            continue
        if not theirs < wanted:
            continue
        named = False
        if (folder / DIAGNOSIS_FILE).exists():
            try:
                named = read_json(folder / DIAGNOSIS_FILE).get("missing") in wanted - theirs
            except (OSError, ValueError):
                named = False
        found.append((named, str(manifest.get("finished") or manifest.get("started") or ""), folder))
    return max(found)[2] if found else None
