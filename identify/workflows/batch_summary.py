"""What a batch's finished jobs say, and the batch's summary files.

:class:`JobResult` is how one job ended and its figures: one row of the summary.
:data:`COLLECTORS` read a finished run's folder (its ``fit.json``, ``summary.json`` or
diagnosis JSON, and ``manifest.json``) into those figures; :func:`assumptions_from_options`
states in words what a job's options make the run assume; :func:`error_from_log` picks the
telling line of a failed command's output and :func:`exit_is_finding` tells a finding (the
solver or chain did not converge: exit code 1) from a failure. :func:`write_summary` writes
``summary.csv``, ``summary.md`` and ``index.html`` (links to each run's report and log). The
batch itself is described in :mod:`identify.workflows.batch`; running it in
:mod:`identify.workflows.batch_run`.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..data.fileio import atomic_write
from ..output.page import escape, html_page, plain_text
from ..output.plots import unit_label
from .batch_config import BatchConfig

__all__ = [
    "JobResult",
    "LOG_FILE",
    "COLLECTORS",
    "read_json_or_none",
    "assumptions_from_options",
    "error_from_log",
    "exit_is_finding",
    "write_summary",
    "unit_text",
]

#: In a job's folder: the task command's output (the summary links to it).
LOG_FILE = "batch.log"


@dataclass
class JobResult:
    """How one job ended, and its figures (one row of the summary).

    Attributes
    ----------
    key, task, record, variant : str
        As in :class:`identify.workflows.batch_config.Job`.
    status : {"ok", "failed", "skipped", "interrupted", "pending"}
        ``"skipped"``: finished by an earlier run of the same config (figures from its marker);
        ``"interrupted"``: stopped (or cancelled before it started) by Ctrl-C or SIGTERM, redone
        (resumed) by the next run of the config.
    rms : float or None
        Residual RMS over the energised part [output unit].
    max_error_pct : float or None
        Largest residual over the energised part, % of the measured range.
    statistic_name : str
        Which comparison statistic ``statistic`` is (``"reduced_chi2"`` for fit and
        study; the diagnosis' ranking statistic for diagnose).
    statistic : float or None
    verdict : str
        Fit: ``converged``/``not converged``; study: the posterior's convergence; diagnose:
        the diagnosis status (and its top-ranked effect).
    seconds : float
        Wall time of the job's command [s] (of the original run for ``"skipped"``).
    error : str
        The error, for a failed job (``""`` otherwise).
    output_unit : str
        Unit of ``rms`` when the run states it.
    report : str
        The run's report relative to the batch folder: ``report.html`` (study), else its
        result JSON (``diagnosis.json``, ``fit.json``); ``""`` for a run that wrote none.
    notes : str
        Assumptions the run states (e.g. no time column, noise fallback), ``"; "``-joined.
    """

    key: str
    task: str
    record: str
    variant: str
    status: str
    rms: float | None = None
    max_error_pct: float | None = None
    statistic_name: str = ""
    statistic: float | None = None
    verdict: str = ""
    seconds: float = 0.0
    error: str = ""
    output_unit: str = ""
    report: str = ""
    notes: str = ""

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def not_converged(self) -> bool:
        """A finished run (ok or skipped) whose solver or chain did not converge (its verdict
        says ``not converged``): a finding, exit code 1 of the batch."""
        return self.status in ("ok", "skipped") and "not converged" in self.verdict.lower()

    @classmethod
    def from_dict(cls, d: dict) -> JobResult:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


# -- a finished run's folder ----------------------------------------------------------------


def read_json_or_none(path: Path):
    """The JSON document in ``path``, or None when it is missing, unreadable or not JSON.

    Parameters
    ----------
    path : Path

    Returns
    -------
    object or None
        The parsed document (a dict for the files a run writes).
    """
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _notes_from(*documents) -> str:
    notes = []
    for doc in documents:
        if not isinstance(doc, dict):
            continue
        for key in ("notes", "assumptions"):
            value = doc.get(key)
            if isinstance(value, str):
                value = [value]
            if isinstance(value, list):
                notes.extend(str(v) for v in value if str(v) not in notes)
        record = doc.get("record")
        if isinstance(record, dict):
            notes.extend(str(v) for v in record.get("notes", []) or [] if str(v) not in notes)
    return "; ".join(notes)


def _output_unit(folder: Path) -> str:
    summary = read_json_or_none(folder / "summary.json")
    if isinstance(summary, dict) and isinstance(summary.get("units"), dict):
        return str(summary["units"].get("output", ""))
    data = folder / "data.npz"
    if data.is_file():
        try:
            with np.load(data, allow_pickle=False) as z:
                return str(z["output_unit"]) if "output_unit" in z.files else ""
        except (OSError, ValueError, KeyError):
            return ""
    return ""


def _collect_fit(folder: Path) -> dict:
    fit = read_json_or_none(folder / "fit.json")
    if not isinstance(fit, dict):
        raise RuntimeError("the command finished but wrote no readable fit.json")
    success = fit.get("success")
    return _fit_columns(folder, fit, "" if success is None else ("converged" if success else "not converged"), fit)


def _fit_columns(folder: Path, fit: dict, verdict: str, source: dict) -> dict:
    """A summary row of a fit's numbers (``fit``: rms, max_error_pct, reduced_chi2), the
    ``verdict``, the output unit and the notes of ``source`` and the manifest."""
    return dict(
        rms=_number(fit.get("rms")),
        max_error_pct=_number(fit.get("max_error_pct")),
        statistic_name="reduced_chi2",
        statistic=_number(fit.get("reduced_chi2")),
        verdict=verdict,
        output_unit=_output_unit(folder),
        notes=_notes_from(source, read_json_or_none(folder / "manifest.json")),
    )


def _collect_study(folder: Path) -> dict:
    summary = read_json_or_none(folder / "summary.json")
    if not isinstance(summary, dict):
        raise RuntimeError("the command finished but wrote no readable summary.json")
    fit = summary.get("fit") or {}
    posterior = summary.get("posterior") or {}
    converged = posterior.get("converged")
    verdict = "" if converged is None else ("posterior converged" if converged else "posterior NOT converged")
    return _fit_columns(folder, fit, verdict, summary)


def _collect_diagnose(folder: Path) -> dict:
    candidates = [folder / "diagnosis.json", *sorted(folder.glob("diagnos*.json"))]
    diagnosis = next((d for d in map(read_json_or_none, candidates) if isinstance(d, dict)), None)
    if diagnosis is None:
        raise RuntimeError("the command finished but wrote no readable diagnosis JSON")
    ranking = [c for c in diagnosis.get("ranking") or [] if isinstance(c, dict)]
    statistic_name = str(diagnosis.get("statistic") or "delta_bic")
    statistic, top = None, ""
    if ranking:
        top = str(ranking[0].get("effect") or "")
        statistic = _number(ranking[0].get(statistic_name))
    status = str(diagnosis.get("status", ""))
    missing = diagnosis.get("missing")
    tied = [str(name) for name in diagnosis.get("tied") or []]
    if missing:
        verdict = f"{status}: add {missing}"
    elif tied:
        verdict = f"{status}: {' | '.join(tied)}"
    elif top:
        verdict = f"{status} (best candidate {top})"
    else:
        verdict = status
    return dict(
        rms=_number(diagnosis.get("rms")),
        max_error_pct=_number(diagnosis.get("max_error_pct")),
        statistic_name=f"{statistic_name}[{top}]" if top else statistic_name,
        statistic=statistic,
        verdict=verdict,
        output_unit=_output_unit(folder),
        notes=_notes_from(diagnosis, read_json_or_none(folder / "manifest.json")),
    )


#: task -> function reading a finished run's folder into summary figures.
COLLECTORS: dict[str, Callable[[Path], dict]] = {
    "fit": _collect_fit,
    "study": _collect_study,
    "diagnose": _collect_diagnose,
}


def assumptions_from_options(argv) -> list[str]:
    """What a job's options make the run assume, in plain words (for the summary's notes).

    Parameters
    ----------
    argv : sequence of str
        The job's command-line words (:attr:`identify.workflows.batch_config.Job.argv`).

    Returns
    -------
    list of str
        One sentence per assumption: ``--time-column none`` (time is the sample index),
        ``--noise-sigma free`` or a given sigma (no quiet segment used); empty when none.
    """
    argv = list(argv)

    def value(flag):
        return argv[argv.index(flag) + 1] if flag in argv[:-1] else None

    notes = []
    time_column = value("--time-column")
    if time_column is not None and time_column.lower() == "none":
        notes.append("no time column: time is the sample index (time constants in samples)")
    sigma = value("--noise-sigma")
    if sigma is not None and sigma.lower() == "free":
        notes.append("no quiet segment used: noise sigma is a free parameter, estimated from the residual")
    elif sigma is not None:
        notes.append(f"no quiet segment used: noise sigma = {sigma} given in the config")
    return notes


def error_from_log(log_text: str, returncode: int) -> str:
    """The most telling line of a failed command's output (its last error line).

    Parameters
    ----------
    log_text : str
        The command's output (``batch.log``).
    returncode : int
        Its exit code.

    Returns
    -------
    str
        The last line starting with ``error`` or naming an ``...Error``/``...Exception``
        (at most 500 characters), else ``"exit code N: <last line>"``.
    """
    lines = [ln.strip() for ln in log_text.splitlines() if ln.strip()]
    for line in reversed(lines):
        if re.match(r"^(error|[A-Za-z_.]*(Error|Exception))\b", line, flags=re.IGNORECASE):
            return line[:500]
    tail = lines[-1][:500] if lines else "(no output)"
    return f"exit code {returncode}: {tail}"


def exit_is_finding(log_text: str) -> bool:
    """Whether a command's exit code 1 is a finding (its solver or chain did NOT converge,
    :data:`identify.defaults.EXIT_FINDING`) rather than a failure (an ``error:`` line).

    Parameters
    ----------
    log_text : str
        The command's output (``batch.log``).

    Returns
    -------
    bool
        True when a line starting ``exit code 1`` says NOT CONVERGED and no line starts with
        ``error``.
    """
    lines = [ln.strip() for ln in log_text.splitlines()]
    return any("NOT CONVERGE" in ln.upper() and ln.startswith("exit code 1") for ln in lines) and not any(
        ln.lower().startswith("error") for ln in lines
    )


# -- summary ----------------------------------------------------------------------------------

_COLUMNS = (
    "key",
    "record",
    "variant",
    "task",
    "status",
    "rms",
    "max_error_pct",
    "statistic_name",
    "statistic",
    "verdict",
    "seconds",
    "error",
    "report",
    "notes",
)


def _fmt(value, digits=4) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _status_counts(results) -> str:
    """``"6 runs: 3 ok, 1 finished earlier (skipped), 1 failed, 1 pending."``"""
    labels = (
        ("ok", "ok"),
        ("skipped", "finished earlier (skipped)"),
        ("failed", "failed"),
        ("interrupted", "interrupted (rerun to resume)"),
        ("pending", "pending"),
    )
    parts = [f"{sum(r.status == key for r in results)} {label}" for key, label in labels]
    parts = [p for p in parts if not p.startswith("0 ")] or ["none"]
    n_not_converged = sum(r.not_converged for r in results)
    if n_not_converged:
        parts.append(f"{n_not_converged} of the finished NOT converged")
    return f"{len(results)} runs: {', '.join(parts)}."


def _md(value) -> str:
    """Text for a Markdown table cell, shown as written: HTML escaped (``<`` ``>`` ``&``), the
    Markdown marks that format or link (``\\ ` * [ ] | !`` and ``_`` outside a word) escaped
    by a backslash, line breaks as spaces."""
    text = html.escape(" ".join(str(value).split()), quote=False)
    text = re.sub(r"([\\`*\[\]|!])", r"\\\1", text)
    return re.sub(r"(?<![A-Za-z0-9_])_|_(?![A-Za-z0-9_])", r"\\_", text)


def _md_url(path: str) -> str:
    """A relative link target for Markdown: every character but ``A-Z a-z 0-9 / . - _ ~`` percent-encoded."""
    return quote(str(path), safe="/.-_~")


def write_summary(out, results: list[JobResult], config: BatchConfig | None = None) -> None:
    """Write ``summary.csv``, ``summary.md`` and ``index.html`` into ``out`` (each atomically).

    Parameters
    ----------
    out : path-like
        The batch folder.
    results : list of JobResult
        One row each, in the given order.
    config : BatchConfig, optional
        Named in the page headings.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(_COLUMNS)
    for r in results:
        row = r.to_dict()
        writer.writerow(
            [("" if row[c] is None else (repr(row[c]) if isinstance(row[c], float) else row[c])) for c in _COLUMNS]
        )
    atomic_write(out / "summary.csv", buffer.getvalue())

    title = f"Batch {config.task} runs from {config.source.name}" if config else "Batch runs"
    counts = _status_counts(results)
    md = [f"# {_md(title)}", "", _md(counts), ""]
    md.append("| run | status | RMS | max error % | statistic | verdict | time [s] | error / notes |")
    md.append("|---|---|---|---|---|---|---|---|")
    for r in results:
        link = f"[{_md(r.key)}]({_md_url(r.report)})" if r.report else _md(r.key)
        stat = f"{r.statistic_name} = {_fmt(r.statistic)}" if r.statistic is not None else ""
        unit = f" {r.output_unit}" if r.output_unit and r.rms is not None else ""
        md.append(
            f"| {link} | {_md(r.status)} | {_md(_fmt(r.rms) + unit)} | {_md(_fmt(r.max_error_pct, 3))} | {_md(stat)} | "
            f"{_md(r.verdict)} | {r.seconds:.1f} | {_md(r.error or r.notes)} |"
        )
    atomic_write(out / "summary.md", "\n".join(md) + "\n")

    atomic_write(out / "index.html", _index_page(title, counts, results))


#: A diagnosis' status in the verdict column, in words.
_STATUS_WORDS = {"missing_effect": "an effect is missing", "not_adequate": "not adequate"}


def _statistic_label(name: str) -> str:
    """A summary row's statistic name for a person: ``reduced_chi2`` -> "reduced χ²",
    ``delta_bic[thermal]`` -> "BIC gain of <code>thermal</code>" (markup)."""
    base, _, effect = name.partition("[")
    label = {"reduced_chi2": "reduced χ²", "delta_bic": "BIC gain"}.get(base, base.replace("_", " "))
    return escape(label) + (f" of <code>{escape(effect.rstrip(']'))}</code>" if effect else "")


def _index_page(title: str, counts: str, results: list[JobResult]) -> str:
    """``index.html``: one row per run, links to each run's report and log (:func:`identify.output.page.html_page`)."""
    rows = []
    for r in results:
        link = f'<a href="{escape(r.report)}">{escape(r.key)}</a>' if r.report else plain_text(r.key)
        log = f' <a href="{escape(r.key)}/{LOG_FILE}">log</a>'
        css = f' class="{r.status}"' if r.status in ("failed", "interrupted") else ""
        stat = f"{_statistic_label(r.statistic_name)} = {_fmt(r.statistic)}" if r.statistic is not None else ""
        verdict = str(r.verdict or "")
        for word, words in _STATUS_WORDS.items():
            verdict = verdict.replace(word, words)
        unit = escape(unit_text(r.output_unit)) if r.rms is not None else ""
        rows.append(
            f"<tr{css}><td>{link}{log}</td><td>{plain_text(r.record)}</td><td>{plain_text(r.variant)}</td>"
            f"<td>{escape(r.status)}</td><td>{_fmt(r.rms)} {unit}</td><td>{_fmt(r.max_error_pct, 3)}</td>"
            f"<td>{stat}</td><td>{plain_text(verdict)}</td><td>{r.seconds:.1f}</td>"
            f"<td>{plain_text(r.error or r.notes or '')}</td></tr>"
        )
    header = (
        "<tr><th>run</th><th>record</th><th>variant</th><th>status</th><th>residual RMS</th><th>max error [%]</th>"
        "<th>comparison statistic</th><th>verdict</th><th>run time [s]</th><th>error / assumptions</th></tr>"
    )
    return html_page(
        title,
        [
            f"<p>{escape(counts)} RMS and max error over the energised part of each record; max error in % of the "
            "measured output range. Each run name links to its report (when it has one).</p>",
            '<div class="table-box"><table id="runs">',
            header,
            *rows,
            "</table></div>",
        ],
    )


def unit_text(unit) -> str:
    """A unit as a page shows it (``um`` -> ``µm``)."""
    return unit_label(unit) if unit else ""
