"""The report of a study of several records of one transducer (``report.html``): it only reads the
results folder (:func:`identify.output.report.write_report` hands a folder of several records here).

Sections: the records (samples, noise sigma, RMS, max error, RMS alone) and their consistency;
the posterior's convergence; the shared parameters once, each with its 95 % interval from the
joint posterior beside the least-squares 95 % intervals from the joint fit and from each record
alone (what the second record adds); each record's own parameters (its run and sensor zero);
each record's loop and error over time with the posterior's 95 % bands; leave one record out.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..data.fileio import atomic_write_bytes
from ..fitting.joint import JointModel
from ..fitting.lsq import FitResult
from ..fitting.noise import NoiseModel, energised_mask
from ..fitting.posterior import ChainBackend
from . import results
from .page import embedded_figure, escape, html_page, html_table, number_cell, png_bytes, text_cell

__all__ = ["is_joint_folder", "write_joint_report", "N_BAND_DRAWS"]

#: Posterior draws pushed through the model for each record's bands.
N_BAND_DRAWS = 100
#: The normal quantile of a 95 % least-squares interval (estimate +- 1.96 stderr).
Z95 = 1.959963984540054


def is_joint_folder(result_dir) -> bool:
    """Whether ``result_dir`` holds a study of several records (its summary lists them)."""
    path = Path(result_dir) / results.FILES["summary"]
    try:
        summary = results.read_json(path)
    except (FileNotFoundError, results.DamagedResultsError):
        return False
    return len(summary.get("records") or []) > 1


def _load(directory: Path):
    """Records, joint layout, summary and fit content of the folder."""
    summary = results.read_json(directory / results.FILES["summary"])
    content = results.read_json(directory / results.FILES["fit"])
    k = len(summary["records"])
    records = [results.load_data(directory, results.record_data_file(r)) for r in range(1, k + 1)]
    model = FitResult.from_dict(content).model
    joint = JointModel(model, k, float(content["joint"]["zero_bound"]))
    return records, joint, summary, content


def _draws(directory: Path, joint, summary, rng) -> np.ndarray:
    """Full joint vectors ``(N, P_joint)`` of up to :data:`N_BAND_DRAWS` posterior draws."""
    post = summary.get("posterior") or {}
    backend = ChainBackend(str(directory / results.FILES["chain"]), name="mcmc", read_only=True)
    chain = backend.get_chain(discard=int(post.get("discard") or 0), thin=int(post.get("thin") or 1), flat=True)
    free = np.flatnonzero(joint.parameters.vary)
    if chain.shape[1] != free.size:
        raise results.DamagedResultsError(
            f"{directory / results.FILES['chain']}: {chain.shape[1]} coordinates, expected {free.size}"
        )
    chain = chain[rng.choice(chain.shape[0], size=min(N_BAND_DRAWS, chain.shape[0]), replace=False)]
    theta = np.repeat(joint.parameters.values[None, :], chain.shape[0], axis=0)
    theta[:, free] = chain
    return theta


def _record_figure(r, record, joint, theta_hat, draws, noise_sigma, quiet_noise):
    """Record ``r``'s loop (measured, model) and its error over time with the 95 % bands."""
    rows, zero = joint.record_rows(theta_hat[None, :], r)
    y_hat = joint.model(rows[0], record.time, record.current) + zero[0]
    rows, zeros = joint.record_rows(draws, r)
    y, valid = joint.model.evaluate(rows, record.time, record.current)
    y = (y + zeros[:, None])[np.asarray(valid, dtype=bool)]
    lo, hi = np.quantile(y - y_hat, [0.025, 0.975], axis=0)
    error = np.asarray(record.displacement, dtype=float) - y_hat
    figure = Figure(figsize=(11, 3.6), layout="constrained")
    loop, over_time = figure.subplots(1, 2, width_ratios=(1, 1.6))
    loop.plot(record.current, record.displacement, ".", ms=1.5, color="0.55", label="measured")
    loop.plot(record.current, y_hat, "-", lw=0.8, color="C0", label="model (joint fit)")
    loop.set(xlabel=f"drive [{record.input_unit}]", ylabel=f"output [{record.output_unit}]", title=f"record {r}")
    loop.legend(loc="upper left", fontsize=8)
    over_time.plot(record.time, error, ".", ms=1.0, alpha=0.4, color="0.3", label="measured - model")
    # the predictive band: the model's band and the noise's combined in quadrature (independent, near-Gaussian)
    centre, half = 0.5 * (lo + hi), np.sqrt((0.5 * (hi - lo)) ** 2 + (Z95 * noise_sigma) ** 2)
    for edge, label in ((centre - half, "95 % predictive band (with the noise)"), (centre + half, None)):
        over_time.plot(record.time, edge, lw=0.8, color="C1", label=label, zorder=3)
    over_time.fill_between(record.time, lo, hi, color="C0", alpha=0.8, label="95 % band of the model", zorder=4)
    over_time.set(xlabel="time [s]", ylabel=f"error [{record.output_unit}]", title=f"record {r}: error over time")
    over_time.legend(loc="upper right", fontsize=8)
    energised = energised_mask(record, quiet_noise)
    inside = float(np.mean(np.abs(error[energised] - centre[energised]) <= half[energised]))
    return figure, inside


def _records_html(summary) -> str:
    rows = []
    for r, rec in enumerate(summary["records"], start=1):
        sigma = rec["noise_sigma"]
        rows.append(
            [
                text_cell(f"{r}: {rec['file']}"),
                number_cell(rec["samples"]),
                number_cell(sigma),
                number_cell(rec["rms"]),
                number_cell(rec["rms"] / sigma if sigma else None),
                number_cell(rec["max_error_pct"]),
                number_cell(rec["rms_alone"]),
            ]
        )
    check = summary.get("consistency") or {}
    verdict = (
        f"The records are consistent with one transducer (excess chi-square {check.get('statistic', 0):.1f} on "
        f"{check.get('dof')} degrees of freedom, p = {check.get('p', 1):.2g})."
        if check.get("consistent", True)
        else f"Warning: {check.get('message')}"
    )
    table = html_table(
        "records",
        ["record", "samples", "noise sigma", "RMS", "RMS / sigma", "max |error| %", "RMS alone"],
        rows,
        caption="Each record at the joint fit (RMS and max error over its energised part) and fitted alone",
    )
    return f"<h2>Records</h2>{table}<p>{escape(verdict)}</p>"


def _interval(value, stderr):
    if value is None or stderr is None or not math.isfinite(stderr):
        return None
    return f"[{value - Z95 * stderr:.4g}, {value + Z95 * stderr:.4g}]"


def _shared_html(summary, joint) -> str:
    """The shared parameters once: the joint posterior's 95 % interval beside the least-squares
    95 % intervals of the joint fit and of each record alone, and the width ratio."""
    alone = summary.get("alone") or []
    header = ["parameter", "unit", "median", "95 % (joint posterior)", "95 % (joint LSQ)"]
    header += [f"95 % (record {r} alone, LSQ)" for r in range(1, len(alone) + 1)]
    header.append("width joint / narrowest alone")
    rows = []
    for entry in summary["parameters"][: joint.model.n_parameters]:
        if not entry["vary"] or entry["name"] in joint.per_record:
            continue
        name = entry["name"]
        lo, hi = entry.get("lo95"), entry.get("hi95")
        row = [text_cell(name), text_cell(entry["unit"]), number_cell(entry.get("median"))]
        row.append(text_cell("—" if lo is None else f"[{lo:.4g}, {hi:.4g}]"))
        row.append(text_cell(_interval(entry["lsq"], entry["lsq_stderr"]) or "—"))
        widths = []
        for one in alone:
            value, stderr = one["theta"].get(name), one["stderr"].get(name)
            row.append(text_cell(_interval(value, stderr) or "—"))
            if stderr is not None and math.isfinite(stderr):
                widths.append(2 * Z95 * stderr)
        ratio = (hi - lo) / min(widths) if lo is not None and widths and min(widths) > 0 else None
        row.append(number_cell(ratio))
        rows.append(row)
    return "<h2>Shared parameters (the transducer)</h2>" + html_table(
        "shared-parameters",
        header,
        rows,
        caption="Estimated once from every record; a width ratio below 1: the records together pin the parameter "
        "down better than the best record alone",
    )


def _own_html(summary, joint) -> str:
    names = set(joint.per_record) | set(joint.names[joint.model.n_parameters :])
    rows = [
        [
            text_cell(e["name"]),
            text_cell(e["unit"]),
            number_cell(e.get("median")),
            text_cell("—" if e.get("lo95") is None else f"[{e['lo95']:.4g}, {e['hi95']:.4g}]"),
            number_cell(e["lsq"]),
        ]
        for e in summary["parameters"]
        if e["name"] in names and e["vary"]
    ]
    return "<h2>Each record's own parameters (its run and sensor zero)</h2>" + html_table(
        "record-parameters",
        ["parameter", "unit", "median", "95 % (posterior)", "least squares"],
        rows,
        caption="Without a suffix: record 1's; _r<k>: record k's (zero_r<k>: its sensor zero against record 1's)",
    )


def _loro_html(summary) -> str:
    loro = summary.get("leave_one_record_out")
    if not loro:
        return ""
    rows = [
        [
            text_cell(f"{row['record']}: {row['source']}"),
            text_cell(", ".join(row["trained_on"])),
            number_cell(row["rms_sigma"]),
            number_cell(100 * row["inside_95"]),
            number_cell(row["max_error_pct"]),
        ]
        for row in loro
    ]
    return "<h2>Leave one record out</h2>" + html_table(
        "leave-one-record-out",
        ["record predicted", "fitted on", "RMS / noise sigma", "% inside the 95 % predictive band", "max |error| %"],
        rows,
        caption="Each record predicted from the others' least squares (its sensor zero from its own quiet start; "
        "the band: the fit's Laplace approximation plus the record's noise). A record predicted at about 1 noise "
        "sigma with about 95 % inside the band is described by what the others learned; pointwise leave-one-out "
        "is not valid for a time series with correlated residuals, so the record is the unit",
    )


def _posterior_html(summary) -> str:
    post = summary.get("posterior") or {}
    if not post:
        return "<h2>Posterior</h2><p>No posterior yet (the study has not sampled).</p>"
    return (
        f"<h2>Posterior</h2><p>{escape(post.get('message', ''))}. The likelihood is the sum "
        "over the records, each whitened with its own noise model; posterior.nc holds one observed-data, "
        "log-likelihood and posterior-predictive variable per record (displacement_record&lt;k&gt;).</p>"
    )


def write_joint_report(result_dir, *, rng=None) -> Path:
    """Write ``DIR/report.html`` (and ``DIR/record<k>_fit.png``) of a study of several records.

    Raises
    ------
    identify.output.results.DamagedResultsError, FileNotFoundError
        A file of the folder is missing or damaged.
    """
    directory = Path(result_dir)
    rng = np.random.default_rng(0) if rng is None else rng
    try:
        records, joint, summary, content = _load(directory)
    except (FileNotFoundError, KeyError, TypeError) as exc:
        raise results.DamagedResultsError(
            f"{directory}: not a complete study of several records ({type(exc).__name__}: {exc})"
        ) from None
    theta_hat = np.asarray(content["joint"]["theta_vector"], dtype=float)
    parts = [_records_html(summary), _posterior_html(summary), _shared_html(summary, joint), _own_html(summary, joint)]
    if summary.get("posterior"):
        draws = _draws(directory, joint, summary, rng)
        parts.append("<h2>Each record: loop and error with the 95 % bands</h2>")
        for r, (record, rec) in enumerate(zip(records, summary["records"]), start=1):
            noise = NoiseModel.from_dict(rec["noise"])
            figure, inside = _record_figure(r, record, joint, theta_hat, draws, rec["noise_sigma"], noise)
            png = png_bytes(figure, 110)
            atomic_write_bytes(directory / f"record{r}_fit.png", png)
            caption = (
                f"{record.source}: left the loop, right the error of the joint fit over time with the posterior's "
                f"95 % band of the model and the predictive band with the record's noise; {100 * inside:.1f} % of "
                "the energised samples inside the predictive band."
            )
            parts.append(embedded_figure(f"record{r}_fit", f"record {r}: loop and error", png, caption))
    parts.append(_loro_html(summary))
    title = f"Study of {len(records)} records of one transducer"
    page = html_page(title, parts)
    path = directory / results.FILES["report"]
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
