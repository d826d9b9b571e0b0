"""Batch identification runs: many records times many model variants, in parallel, one summary.

A batch is described by a TOML file (see ``examples/*.toml`` and docs/batch.md)::

    task = "fit"                  # fit | diagnose | study: the command each job runs
    out = "../reports/batch"      # results folder (relative to this file)
    workers = 2                   # jobs run at the same time (default: the machine's cores)
    executor = "local"            # local (process pool, default) | dask
    timeout = 3600                # optional: seconds before a job is stopped and marked failed

    [options]                     # options of the task command, for every job
    n_starts = 4                  #   -> --n-starts 4

    [[records]]                   # one table per file or glob
    path = "../data/piezo_smarthysteresis.csv"   # or: glob = "../data/*.csv"
    name = "smarthysteresis"      # optional, default: the file's stem
    input_column = "voltage"      # any other key: a task option for this record
    input_unit = "V"

    [[variants]]                  # model variants; default: one variant with no options
    name = "gpi12"
    n_operators = 12
    effects = ["lag"]

    [executor_options]            # passed to the executor (e.g. address = "tcp://host:8786" for dask)

Jobs are the product records x variants. Each job runs the task command
``python -m identify TASK RECORD --out OUT/JOB ...`` in its **own subprocess**, so a
crash, a runaway memory use or a hang (``timeout``) in one job cannot take the others
down, and the command does exactly what it does from the shell. The options of a job are
``[options]``, updated by the record's keys, updated by the variant's keys; each
``key = value`` becomes ``--key-with-dashes value`` (``true`` -> the bare flag for switches,
``false`` -> omitted, a list -> comma-separated, or repeated values for options that take
several). Every job's arguments are checked against the command's own argument parser
before anything runs, so a misspelt option is a :class:`BatchConfigError` naming the key
and the file.

Completion and resuming
-----------------------
A job's folder ``OUT/<record>__<variant>/`` gets ``batch_job.json`` (what runs),
``batch.log`` (the command's output) and, **last and atomically**, either the completion
marker ``batch_done.json`` (the run's figures) or ``batch_failed.json`` (its error). Rerunning
the same config skips jobs whose marker is present and whose job description (arguments
and the record file's SHA-256) is unchanged, and redoes failed, interrupted or changed ones
(a ``study`` resumes its chain). After every finished job the summary is rewritten
(atomically): ``summary.csv``, ``summary.md`` and ``index.html`` (links to each run's
report) in ``OUT``.

One configuration per folder
----------------------------
``OUT`` belongs to the configuration that first ran into it: ``OUT/batch_config.json``
records its file and the SHA-256 of what defines its runs (task, options, records,
variants). The same file (edited: changed runs are redone) or an identical configuration
may run there again; another configuration is refused in one line naming both, before
anything in ``OUT`` is touched (it would replace the summary and the runs' bookkeeping).

One writer, and stopping
------------------------
The batch locks ``OUT`` and each job locks its run folder (:mod:`identify.data.locks`) before
writing there; the job's command inherits that lock, so a second batch on the same
folder is refused at once, and so is a command started by hand in a run folder.
Ctrl-C or SIGTERM stops the batch: the queue is cancelled, every running command gets
one SIGTERM (a ``study`` stops between two steps and keeps every completed one), the
batch waits for them, marks their rows and the cancelled ones ``interrupted`` and exits
with code 130; rerunning the config resumes them. A second signal kills the commands at
once. The commands run in their own sessions (the terminal's Ctrl-C reaches only the
batch) and end with SIGTERM if the batch dies (Linux ``PR_SET_PDEATHSIG``), so no process
outlives the batch. The stop request is the file ``OUT/.batch_stop``, which jobs on other
machines (dask) see too.

Executors
---------
:data:`EXECUTORS` maps a name to a class with ``submit_all(fn, jobs)`` yielding
``(job, result)`` as jobs finish, ``cancel()`` (drop the jobs not started yet) and
``close()``. ``"local"`` runs the jobs' subprocesses from ``workers`` threads of the batch
process (:class:`concurrent.futures.ThreadPoolExecutor`: each job is a subprocess already,
so no pool of worker processes is needed); ``"dask"`` runs on a
``dask.distributed`` cluster (a ``LocalCluster`` by default, or a running scheduler given
by ``executor_options.address``), installed with ``pip install .[dask]``. Register more
with :func:`register_executor`.

Modules
-------
This module is the batch's public face: every name below is importable from here. The code
lives in four modules, each holding one part of the work:

- :mod:`identify.workflows.batch_config`: the configuration read and checked
  (:func:`load_config`, :func:`parse_config`), the jobs and their command lines
  (:func:`expand_jobs`), what makes two configurations the same (:func:`config_identity`);
- :mod:`identify.workflows.batch_run`: running the jobs and the batch (:func:`run_job`,
  :func:`run_batch`), completion markers, resuming (:func:`finished_result`), stopping;
- :mod:`identify.workflows.batch_summary`: what a finished job's folder says
  (:data:`COLLECTORS`, :class:`JobResult`) and the summary files (:func:`write_summary`);
- :mod:`identify.workflows.batch_executors`: where the jobs run (:data:`EXECUTORS`).
"""

from __future__ import annotations

from .batch_config import (
    TASKS,
    BatchConfig,
    BatchConfigError,
    Job,
    RecordSpec,
    VariantSpec,
    config_identity,
    expand_jobs,
    load_config,
    parse_config,
)
from .batch_executors import EXECUTORS, DaskExecutor, LocalExecutor, get_executor, register_executor
from .batch_run import (
    CONFIG_FILE,
    DONE_MARKER,
    FAILED_MARKER,
    STOP_FILE,
    BatchResult,
    finished_result,
    run_batch,
    run_job,
)
from .batch_summary import COLLECTORS, JobResult, write_summary

__all__ = [
    "TASKS",
    "BatchConfigError",
    "RecordSpec",
    "VariantSpec",
    "BatchConfig",
    "Job",
    "JobResult",
    "BatchResult",
    "load_config",
    "parse_config",
    "expand_jobs",
    "run_job",
    "finished_result",
    "run_batch",
    "write_summary",
    "EXECUTORS",
    "register_executor",
    "get_executor",
    "LocalExecutor",
    "DaskExecutor",
    "COLLECTORS",
    "DONE_MARKER",
    "FAILED_MARKER",
    "STOP_FILE",
    "CONFIG_FILE",
    "config_identity",
]
