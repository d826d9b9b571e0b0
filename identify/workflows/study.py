"""The whole identification of one record into a results folder, resumable: :func:`study`.

Steps: the noise model from the record's unenergised start; least squares (multi-start)
of the normalised model (alpha pinned, see :mod:`identify.fitting.parametrisation`);
identifiability (exact and near-degenerate directions); emcee posterior until converged
or the step cap; when the residual is above the noise, the diagnosis (which effect is
missing: :func:`identify.diagnosis.diagnose`, into ``DIR/diagnosis.json`` and
``DIR/diagnosis/*.png``, as ``python -m identify diagnose --out DIR`` writes them); the
comparison with an earlier study of the same record (``compare``: the study this one adds an
effect to); the report (:func:`identify.output.report.write_report`). Results go to
``out`` as described in :mod:`identify.output.results`. ``python -m identify study`` is
this function behind its options (:mod:`identify.cli.study`), with the same defaults
(:mod:`identify.defaults`).

Rerunning the same study resumes: the stored least-squares fit is reused and the chain
continues from its last saved step; a finished study is left as it is (nothing is
rewritten). Before anything is written the folder is locked (:mod:`identify.data.locks`:
a second process is refused at once), the record's noise is estimated and the folder's
state is read (:func:`identify.output.results.inspect_run`): a damaged ``manifest.json``,
``fit.json`` or ``chain.h5`` is one error saying what to do, and a folder holding a run
with other data, seed or settings is refused unless ``force`` (which deletes that run's
files first). Only ``max_steps`` (to extend a chain that did not converge, never below the
steps the chain holds), ``report`` and the path of the data file (the data are compared
by SHA-256) may change between runs. A priors file (``priors``, :mod:`identify.fitting.priors`)
is checked before anything is written too; it changes the posterior only (its content is a
setting, compared by SHA-256). A fresh run that fails before its first result
leaves nothing behind; one that fails later is marked ``failed`` in the manifest and is
replaced by the next run with other settings. See docs/reliability.md.

Example
-------
>>> from identify import load_record, study                      # doctest: +SKIP
>>> result = study(load_record("data/bench_default.csv"), out="results/bench", seed=0)
>>> result.summary["posterior"]["converged"], result.paths["report"]
"""

from __future__ import annotations

from pathlib import Path

from ..data.locks import FolderLock
from ..data.records import Record, load_record
from ..defaults import DEFAULT_CHECK_EVERY, DEFAULT_MAX_STEPS, DEFAULT_N_STARTS
from ..fitting.joint import check_records
from ..logs import show_progress
from .joint_run import study_records
from .study_run import (
    RESUMABLE_SETTINGS,
    StudyResult,
    StudyRun,
    api_settings,
    check_priors,
    check_walkers,
    default_model,
    priors_settings,
    sampled_dimension,
)

__all__ = [
    "study",
    "StudyResult",
    "RESUMABLE_SETTINGS",
    "check_walkers",
    "check_priors",
    "priors_settings",
    "sampled_dimension",
]


def study(
    record,
    model=None,
    *,
    out,
    seed: int = 0,
    noise_sigma=None,
    n_starts: int = DEFAULT_N_STARTS,
    walkers: int | None = None,
    max_steps: int = DEFAULT_MAX_STEPS,
    check_every: int = DEFAULT_CHECK_EVERY,
    moves: str = "de",
    priors=None,
    select_terms: bool = True,
    force: bool = False,
    report: bool = True,
    diagnose: bool = True,
    compare=None,
    progress: bool | None = None,
    quiet: bool = False,
    settings: dict | None = None,
    lock: bool = True,
) -> StudyResult:
    """Identify ``model`` on ``record`` into the results folder ``out`` (see the module docstring).

    Parameters
    ----------
    record : identify.data.records.Record or str or os.PathLike
        The record, or the path of a CSV read with the default columns
        (:func:`identify.data.records.load_record`).
    model : model.Model, optional
        Default: the paper's GPI (12 operators, reading ``swapped``, no effects). Its alpha
        is pinned (:func:`identify.fitting.parametrisation.normalised_model`) unless it
        already is.
    out : str or os.PathLike
        Results folder (created; a rerun resumes).
    seed : int, default 0
        Seed of the one random generator (least-squares starts, then the chain).
    noise_sigma : float or "free" or None
        Sensor noise std in the output unit, ``"free"`` to identify it; None: estimated
        from the record's unenergised start.
    n_starts, walkers, max_steps, check_every, moves
        Least-squares starts; emcee walkers (None: 2 x dimension, even, >= 32); cap on
        the chain length; convergence check interval; ``"de"`` or ``"stretch"`` moves.
        The defaults are the command line's (:mod:`identify.defaults`).
    priors : str or os.PathLike, optional
        A TOML priors file (:mod:`identify.fitting.priors`, ``study --priors``): the
        distribution and bounds of some parameters for the posterior; the others keep the
        defaults. Checked before anything is written. The priors used are in the summary's
        ``priors``.
    select_terms : bool, default True
        Pin off the optional effect terms the record does not support (BIC, after the
        least squares: :func:`identify.fitting.terms.select_terms`; e.g. the second node
        of a two-node ``thermal`` on a record whose heating is one-pole, which would
        otherwise leave the posterior three unidentified directions). False
        (``--all-terms``) samples every term.
    force : bool, default False
        Discard a different (or damaged) run already in ``out``.
    report : bool, default True
        Write ``report.html`` at the end.
    diagnose : bool, default True
        When the least-squares residual is above the noise (the report's rule:
        :func:`identify.output.report.residual_above_noise`), run the diagnosis and store it in
        ``out`` (``diagnosis.json``, ``diagnosis/*.png``); the report's "At a glance" then
        states the verdict and the command to run next. False (``--no-diagnose``) skips it.
    compare : str or os.PathLike, optional
        An earlier study of the same record (``study --compare DIR``), e.g. the one whose
        diagnosis named the effect this study adds: the report shows the error before and
        after. Default: found among the sibling folders of ``out`` through their manifests
        (same record by SHA-256, fewer effects; :func:`identify.output.diagnosis_files.earlier_study`).
    progress : bool or None
        The progress (:mod:`identify.fitting.progress`): True a bar whose total is the
        projected chain length (50 tau); False none; None (default) the bar when stderr is a
        terminal or in a notebook, else a line every 10 s (none when ``quiet``). Unless
        :mod:`logging` is configured, the progress lines go to stderr
        (:func:`identify.logs.show_progress`), as emcee's and lmfit's do.
    quiet : bool, default False
        No progress lines and no tables (stdout).
    settings : dict, optional
        The manifest's settings (the command line passes its options); default: these
        arguments with the command line's keys.
    lock : bool, default True
        Lock ``out`` while the study runs (the command line locks it itself, first).

    Returns
    -------
    StudyResult
        Also when the chain did NOT CONVERGE (``status == "not converged"``,
        :attr:`StudyResult.exit_code` 1): a result with a finding, not an error.

    Raises
    ------
    identify.workflows.fit.FitFailedError
        The least squares could not run.
    identify.output.results.RunMismatchError, identify.output.results.DamagedResultsError
        ``out`` holds another run or damaged files (and ``force`` is not set).
    identify.data.locks.FolderBusyError
        Another process holds ``out``.
    identify.fitting.priors.PriorsError
        A priors file that cannot be used (the message names the file and the parameter).
    ValueError
        Invalid ``walkers``, or no quiet segment to estimate the noise from.

    Every exception is raised before anything is written, except an interruption or a
    failure of the computation itself; the command line maps them to exit code 2 (bad
    input) and 130 (interrupted).
    """
    if isinstance(record, (list, tuple)):  # several records of one transducer
        records = check_records([r if isinstance(r, Record) else load_record(r) for r in record])
        if len(records) > 1:
            return study_records(
                records,
                model,
                out=out,
                settings=settings,
                lock=lock,
                quiet=quiet,
                seed=seed,
                noise_sigma=noise_sigma,
                n_starts=n_starts,
                walkers=walkers,
                max_steps=max_steps,
                check_every=check_every,
                moves=moves,
                priors=priors,
                select_terms=select_terms,
                force=force,
                report=report,
                diagnose=diagnose,
                compare=compare,
                progress=progress,
            )
        record = records[0]  # one record: the study of one record, unchanged
    if not isinstance(record, Record):
        record = load_record(record)
    if progress is not False and not quiet:
        show_progress()  # from Python the lines would otherwise go nowhere
    if compare is not None and not (Path(compare) / "summary.json").is_file():
        raise ValueError(f"compare {compare}: not a results folder of a study (no summary.json)")
    model = default_model(model)
    check_walkers(walkers, model, noise_sigma)
    check_priors(priors, model)
    if settings is None:
        settings = api_settings(
            record,
            model,
            seed=seed,
            noise_sigma=noise_sigma,
            n_starts=n_starts,
            walkers=walkers,
            max_steps=max_steps,
            check_every=check_every,
            moves=moves,
            report=report,
            priors=priors,
            select_terms=select_terms,
            diagnose=diagnose,
        )
    if quiet and progress is None:
        progress = False  # quiet: no bar and no progress lines
    run = StudyRun(
        Path(out),
        record,
        model,
        settings,
        seed=seed,
        noise_sigma=noise_sigma,
        n_starts=n_starts,
        walkers=walkers,
        max_steps=max_steps,
        check_every=check_every,
        moves=moves,
        priors=priors,
        select_terms=select_terms,
        force=force,
        report=report,
        diagnose=diagnose,
        compare=compare,
        progress=progress,
        quiet=quiet,
    )
    if not lock:
        return run.execute()
    with FolderLock(run.out, command=f"identify.study({str(record.source)!r}, out={str(out)!r})") as held:
        if held.stale_note():
            run.log(f"note: {held.stale_note()}")
        return run.execute()
