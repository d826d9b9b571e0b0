"""``python -m identify batch CONFIG.toml``: many records x model variants, in parallel, one summary table."""

from __future__ import annotations

import sys

from . import options

__all__ = ["HELP", "add_arguments", "run"]

HELP = "run fit/diagnose/study over many records and model variants in parallel (TOML config); one summary table"


def add_arguments(parser) -> None:
    """Options of the ``batch`` command."""
    parser.add_argument("config", help="batch configuration (TOML); see examples/ and docs/batch.md")
    parser.add_argument(
        "--workers",
        type=options.positive_int,
        default=None,
        help="jobs at the same time (overrides the config's 'workers')",
    )
    parser.add_argument(
        "--executor", default=None, help="executor name (overrides the config's 'executor'): local | dask"
    )
    parser.add_argument("--rerun", action="store_true", help="redo finished runs too (default: skip them)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--dry-run", action="store_true", help="check the config and print the jobs' command lines; run nothing"
    )


def run(args) -> int:
    """Run the batch; exit code 0 when every job succeeded, 1 when some failed or did not converge
    (solver or chain), 2 for a bad config
    (or a batch folder in use), 130 when stopped by Ctrl-C or SIGTERM (rerun it to resume)."""
    # deferred (--help imports every command's module): dataclasses: inspect, ast, dis, +6 ms
    from dataclasses import replace

    # deferred (--help imports every command's module): workflows.batch: +40 ms (its code, csv, subprocess)
    from ..workflows.batch import EXECUTORS, BatchConfigError, expand_jobs, load_config, run_batch

    try:
        config = load_config(args.config)
        if args.workers is not None:
            if args.workers < 1:
                raise BatchConfigError(f"--workers must be >= 1, got {args.workers}")
            config = replace(config, workers=args.workers)
        if args.executor is not None:
            if args.executor not in EXECUTORS:
                raise BatchConfigError(f"--executor must be one of {', '.join(EXECUTORS)}, got {args.executor!r}")
            config = replace(config, executor=args.executor)
        jobs = expand_jobs(config)
    except BatchConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        print(f"{len(jobs)} job(s) -> {config.out} ({config.executor}, {config.workers} worker(s))")
        for job in jobs:
            print(f"  {job.key}: python -m identify {' '.join(job.argv)}")
        return 0

    def header():  # printed once the folder is locked and this configuration's: a refused batch prints only its error
        print(
            f"batch: {len(jobs)} run(s) ({len(config.records)} record(s) x {len(config.variants)} variant(s)) of "
            f"'{config.task}' -> {config.out}, executor {config.executor}, {config.workers} worker(s)",
            flush=True,
        )

    # -q (identify.logs) hides the bar too; --no-progress is kept as the bar-only switch
    try:
        result = run_batch(config, progress=not (args.no_progress or args.quiet), rerun=args.rerun, announce=header)
    except BatchConfigError as exc:  # the folder belongs to another configuration: nothing was changed
        print(f"error: {exc}", file=sys.stderr)
        return 2
    n_skipped = sum(r.status == "skipped" for r in result.results)
    interrupted = f", {result.n_interrupted} interrupted" if result.n_interrupted else ""
    print(
        f"batch: {result.n_ok} ok ({n_skipped} finished earlier, skipped; {result.n_not_converged} of them NOT "
        f"converged), {result.n_failed} failed{interrupted}, "
        f"{result.seconds:.1f} s. Summary: {config.out / 'summary.md'}, {config.out / 'index.html'}"
    )
    for r in result.results:
        if r.status == "failed":
            print(f"  FAILED {r.key}: {r.error}", file=sys.stderr)
        elif r.not_converged:
            print(f"  NOT CONVERGED {r.key}: {r.verdict}", file=sys.stderr)
    if result.n_interrupted:
        print(
            f"interrupted: {result.n_interrupted} run(s) stopped or cancelled, their completed work kept; "
            f"rerun 'python -m identify batch {args.config}' to resume them",
            file=sys.stderr,
        )
        return 130
    return 1 if result.n_failed or result.n_not_converged else 0
