"""Identification of the GPI model from measurements: noise, least squares, posterior,
diagnosis, reports and batch runs. Command line: ``python -m identify --help``.

The Python API (what the command line itself calls; defaults in :mod:`identify.defaults`)::

    from identify import Model, diagnose, load_record, study

    record = load_record("data/bench_default.csv")
    result = study(record, Model(["thermal"]), out="results/bench", seed=0)
    print(result.status, result.summary["posterior"]["n_steps"], result.paths["report"])

The names are imported when first used, so ``import identify`` (and ``--help``) stays fast.
The package is laid out by stage, each importing only from the ones before it:
:mod:`identify.data` (records, files), :mod:`identify.fitting` (noise, parametrisation,
least squares, posterior), :mod:`identify.diagnosis`, :mod:`identify.output` (results
folder, figures, reports), :mod:`identify.workflows` (study, use, batch, reproduce),
:mod:`identify.bench` (the simulated bench) and :mod:`identify.cli` (the commands).
"""

import importlib

from .version import __version__

#: public name -> module it lives in (imported on first use).
API = {
    "Model": "model",
    "load_record": "identify.data.records",
    "write_record": "identify.data.records",
    "Record": "identify.data.records",
    "estimate_noise": "identify.fitting.noise",
    "normalised_model": "identify.fitting.parametrisation",
    "fit_least_squares": "identify.fitting.lsq",
    "fit_records": "identify.workflows.fit",
    "diagnose": "identify.diagnosis.diagnose",
    "study": "identify.workflows.study",
    "StudyResult": "identify.workflows.study",
    "write_report": "identify.output.report",
    "load_study": "identify.workflows.use",
    "predict": "identify.workflows.use",
    "compensate": "identify.workflows.use",
    "simulate": "identify.bench.synthetic",
    "design": "identify.workflows.design",
}

__all__ = ["__version__", *API]


def __getattr__(name):
    """Import an API name from its module on first use (PEP 562)."""
    module = API.get(name)
    if module is None:
        raise AttributeError(f"module 'identify' has no attribute {name!r}")

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(API))
