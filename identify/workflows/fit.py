"""The least-squares step of a study and of ``fit``, shared by the workflows and the command line:
effects by name, the fit with a failure explained, the parameter table and the notes.

Nothing here parses arguments: :mod:`identify.cli.common` turns options into the record,
model and noise these functions take.
"""

from __future__ import annotations

import logging
import math

from ..logs import say as _log_line

__all__ = [
    "LONG_RECORD_SAMPLES",
    "FitFailedError",
    "parse_effects",
    "fit_or_explain",
    "fit_records",
    "select_terms_of_records",
    "separate_fits_or_explain",
    "format_joint_fit_table",
    "format_fit_table",
    "print_record_notes",
    "say",
]

#: Records with at least this many samples get progress lines from the least squares.
LONG_RECORD_SAMPLES = 100_000


def say(message: str, level: int = logging.INFO) -> None:
    """One progress or note line, logged (INFO by default) through the ``identify`` logger
    (:mod:`identify.logs`: on stderr from the command line, hidden by ``-q``; a program
    shows them by configuring :mod:`logging`, e.g. ``logging.basicConfig(level=logging.INFO)``)."""
    _log_line(message, level)


def parse_effects(text) -> list[str]:
    """``"thermal, creep"`` -> ``["thermal", "creep"]``; unknown names raise a ValueError listing the known ones."""
    # deferred: --help loads this module (cli.common); model loads numpy/scipy (+0.28 s CPU)
    from model import EFFECTS

    if text is None:
        return []
    names = [n.strip() for n in str(text).split(",") if n.strip()]
    if names in (["none"], ["gpi"]):
        return []
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(map(repr, unknown))}; known effects: {', '.join(EFFECTS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"an effect is named twice in --effects {text!r}")
    return names


class FitFailedError(ValueError):
    """The least squares could not run; the message says what failed and what to try."""


def fit_or_explain(record, model, **options):
    """:func:`identify.fitting.lsq.fit_least_squares`, with a failure turned into a :class:`FitFailedError`.

    Parameters
    ----------
    record, model
        As for :func:`identify.fitting.lsq.fit_least_squares`.
    **options
        Passed on (noise, n_starts, rng, verbose, ...).

    Returns
    -------
    identify.fitting.lsq.FitResult
        The fit.

    Raises
    ------
    FitFailedError
        The fit raised a ValueError (e.g. no start with a finite model output); the message
        names the model and the record and suggests options that change the starts.
    """
    # deferred: --help loads this module (cli.common); fitting loads numpy/scipy (+0.91 s CPU)
    from ..fitting import lsq

    try:
        return lsq.fit_least_squares(record, model, **options)
    except ValueError as exc:
        raise FitFailedError(
            f"least squares of {model!r} on {record.source} failed: {exc}. Try: the paper's "
            "12 operators (--n-operators 12) or fewer, more starts (--n-starts), another --seed, "
            "or fewer --effects"
        ) from exc


def print_record_notes(record, file=None) -> None:
    """What was assumed while loading ``record`` (its ``notes``), one ``note:`` line each: logged
    (INFO, :func:`say`), or printed to ``file`` when one is given."""
    for note in getattr(record, "notes", ()):
        if file is None:
            say(f"note: {note}")
        else:
            print(f"note: {note}", file=file)


def _flat(message) -> str:
    """A solver message on one level: its inner parentheses become semicolons, so the line never
    nests parentheses in parentheses."""
    text = str(message).replace(" (", "; ").replace("(", "").replace(")", "")
    return text.replace("`", "").replace(".;", ";")


def format_fit_table(fit, record=None) -> str:
    """Human summary: parameter, value, stderr, unit, Table 1; then RMS vs noise, max error, chi2."""
    # deferred: --help loads this module (cli.common); model loads numpy/scipy (+0.28 s CPU)
    from model import TABLE1, THETA_NAMES

    # deferred: --help loads this module (cli.common); fitting.lsq loads numpy/scipy (+0.91 s CPU)
    from ..fitting.lsq import parameter_units

    units = parameter_units(fit.model, record)
    lines = [f"{'parameter':<24} {'value':>13} {'stderr':>11}  {'unit':<8} {'Table 1':>10}", "-" * 72]
    for i, name in enumerate(fit.model.names):
        stderr = "pinned" if not fit.vary[i] else f"{fit.stderr[i]:11.4g}"
        table1 = f"{TABLE1[THETA_NAMES.index(name)]:10.4f}" if name in THETA_NAMES else ""
        lines.append(f"{name:<24} {fit.theta[i]:13.6g} {stderr:>11}  {units[i]:<8} {table1:>10}")
    out_unit = getattr(record, "output_unit", "um") if record is not None else "um"
    noise = fit.noise
    sigma_note = {
        "quiet_segment": f"from {noise.n_quiet} quiet samples",
        "user": "user-given",
        "free": "estimated (free)",
    }[noise.source]
    ratio = fit.rms / noise.sigma if noise.sigma > 0 else math.nan
    lines += [
        "-" * 72,
        f"noise: sigma = {noise.sigma:.4g} {out_unit} ({sigma_note}), {noise.kind}"
        + (f", lag-1 rho = {noise.rho:.3f}" if noise.kind == "ar1" else ""),
        f"residual RMS (energised part) = {fit.rms:.4g} {out_unit} = {ratio:.3f} x noise sigma",
        f"max |error| = {fit.max_error_pct:.3f} % of the displacement range",
        f"reduced chi-square = {fit.reduced_chi2:.4f}",
        f"starts: {fit.n_agree} of {fit.n_starts} reached the best chi-square (within 1; fewer than all means the "
        "optimum is hard to find, more starts make it surer)",
        f"solver: {'converged' if fit.success else 'NOT converged'}: {_flat(fit.message)}; {fit.seconds:.1f} s",
    ]
    return "\n".join(lines)


def fit_records(records, model, *, noises=None, n_starts: int = 4, rng=None, progress=None, separate=None):
    """Least squares of ``model`` on several records of one transducer at once
    (:func:`identify.fitting.joint.fit_joint`: the transducer shared, each record's run
    parameters and sensor zero its own, each whitened with its own noise), with a failure
    turned into a :class:`FitFailedError`.

    Parameters
    ----------
    records : sequence of Record
        Two or more records in the same units (:func:`identify.fitting.joint.check_records`).
    model : model.Model
        Normalised (alpha pinned).
    noises : sequence of NoiseModel, optional
        Default: each record's own quiet start.
    n_starts : int, default 4
        Starts of each record's separate fit.
    rng : numpy.random.Generator, optional
    progress : callable(str), optional
    separate : sequence of FitResult, optional
        The records' separate fits, when already made (they start the joint fit).

    Returns
    -------
    identify.fitting.joint.JointFit
    """
    # deferred: --help loads this module (cli.common); fitting.joint loads numpy/scipy (+0.93 s CPU)
    from ..fitting.joint import check_records, fit_joint, record_noises

    records = check_records(records)  # refused naming the record, before any fit
    noises = record_noises(records) if noises is None else list(noises)
    try:
        return fit_joint(records, model, noises, n_starts=n_starts, rng=rng, progress=progress, separate=separate)
    except FitFailedError:
        raise
    except ValueError as exc:
        names = ", ".join(str(r.source) for r in records)
        raise FitFailedError(
            f"least squares of {model!r} on the records {names} failed: {exc}. Try fewer --effects, more "
            "starts (--n-starts) or another --seed"
        ) from exc


def format_joint_fit_table(fit) -> str:
    """Human summary of a joint fit: the shared parameters once (value, stderr), each record's own
    run parameters and zero, then one line per record (samples, noise, RMS, max error, its RMS
    alone) and the consistency test."""
    # deferred: --help loads this module (cli.common); fitting.lsq loads numpy/scipy (+0.91 s CPU)
    from ..fitting.lsq import parameter_units

    record = fit.records[0]
    model = fit.model
    units = dict(zip(model.names, parameter_units(model, record)))
    lines = [f"{'parameter':<28} {'value':>13} {'stderr':>11}  {'unit':<8}", "-" * 64]
    for i, name in enumerate(fit.joint.names):
        base = name.rsplit("_r", 1)[0] if i >= model.n_parameters else name
        unit = units.get(base, record.output_unit if name.startswith("zero_r") else "")
        pinned = not fit.joint.parameters.vary[i]
        stderr = "pinned" if pinned else f"{fit.stderr[i]:11.4g}"
        lines.append(f"{name:<28} {fit.theta[i]:13.6g} {stderr:>11}  {unit:<8}")
    out_unit = record.output_unit
    lines.append("-" * 64)
    for r, (rec, f, alone) in enumerate(zip(fit.records, fit.fits, fit.separate), start=1):
        ratio = f.rms / f.noise.sigma if f.noise.sigma > 0 else math.nan
        lines.append(
            f"record {r} {rec.source}: {len(rec.time)} samples, noise sigma {f.noise.sigma:.4g} {out_unit}; "
            f"RMS {f.rms:.4g} {out_unit} = {ratio:.3f} x sigma (alone {alone.rms:.4g}); max |error| "
            f"{f.max_error_pct:.3f} %"
        )
    check = fit.consistency
    verdict = "consistent" if check.get("consistent") else "NOT consistent"
    lines.append(
        f"consistency of the records: {verdict} (excess chi-square {check.get('statistic', 0.0):.1f} on "
        f"{check.get('dof')} degrees of freedom, p = {check.get('p', 1.0):.2g}); {fit.seconds:.1f} s"
    )
    return "\n".join(lines)


def separate_fits_or_explain(records, model, noises, *, n_starts: int = 4, rng=None, log=None) -> list:
    """Each record fitted alone (:func:`identify.fitting.joint.separate_fits`), a failure turned
    into a :class:`FitFailedError` naming the records."""
    # deferred: --help loads this module (cli.common); fitting.joint loads numpy/scipy (+0.93 s CPU)
    from ..fitting.joint import separate_fits

    try:
        return separate_fits(records, model, noises, n_starts=n_starts, rng=rng, progress=log)
    except ValueError as exc:
        names = ", ".join(str(r.source) for r in records)
        raise FitFailedError(
            f"least squares of {model!r} on the records {names} failed: {exc}. Try fewer --effects, more starts "
            "(--n-starts) or another --seed"
        ) from exc


def select_terms_of_records(records, separate, *, rng=None, log=None) -> list:
    """The records' separate fits with the optional effect terms none of them supports pinned off
    (:func:`identify.fitting.terms.select_terms` on each): a term is pinned off for the joint fit
    only when every record's selection pins it off, since one record that needs it is evidence
    the transducer has it. Returns the selected fits when every record pins off the same terms,
    else the fits given (every term kept)."""
    # deferred: --help loads this module (cli.common); fitting.terms loads numpy/scipy (+1.14 s CPU)
    from ..fitting.terms import select_terms

    selected = [select_terms(record, fit, rng=rng, log=log) for record, fit in zip(records, separate)]
    pinned = [frozenset(n for n, v in zip(f.model.names, f.vary) if not v) for f in selected]
    if all(p == pinned[0] for p in pinned):
        return selected
    if log is not None:
        log("terms: the records do not agree on the optional terms to pin off; every term is kept in the joint fit")
    return list(separate)
