r"""Use an identified model: predict another record (validation), and compensate the hysteresis.

Two workflows on a finished study (a results folder written by ``python -m identify
study``), neither of which refits anything:

:func:`predict`
    The study's posterior draws and its least-squares vector applied to another record of
    the same rig: bands, validation RMS and max error beside the training figures, the
    "where it fails" profile of the validation residual and the diagnosis' verdict on it.
:func:`compensate`
    The inverse of the identified model (:func:`model.inverse.invert`): the drive current
    that makes the model follow a desired displacement trajectory, for the posterior
    median and for posterior draws, and the tracking error the posterior predicts for it.

Both return result objects (:class:`Prediction`, :class:`Compensation`) whose ``to_dict``
is the JSON the commands write; :func:`write_prediction` and :func:`write_compensation`
write a result's whole output folder at once (built in a temporary folder beside it and
renamed into place, so an interrupted or failed run leaves nothing half-written). Every
input problem raises :class:`UseError` with one line naming the file and what is wrong.

Modules: this module is the public face of both workflows (every name below is importable
from here); the code lives in :mod:`identify.workflows.use_study` (the finished study, the
bands and what both workflows share), :mod:`identify.workflows.prediction` and
:mod:`identify.workflows.compensation`.

Layers: these modules use the model (:mod:`model`, :mod:`model.inverse`), the identification
results (:mod:`identify.output.results`, :mod:`identify.fitting.noise`, :mod:`identify.diagnosis.residuals`,
:mod:`identify.diagnosis.diagnose`) and, for writing, :mod:`identify.output.use_report`; the command-line
shells :mod:`identify.cli.predict` and :mod:`identify.cli.compensate` call them.
"""

from __future__ import annotations

from .compensation import (
    COMPENSATION_BANDS_CSV,
    COMPENSATION_CSV,
    COMPENSATION_FILE,
    REACH_TOLERANCE,
    Compensation,
    Target,
    compensate,
    default_current_range,
    load_target,
    reachable_range,
    write_compensation,
)
from .prediction import PREDICTION_FILE, VERDICTS, Prediction, predict, write_prediction
from .use_study import Bands, Study, UseError, bands_of, check_units, load_record_for_study, load_study

__all__ = [
    "UseError",
    "Study",
    "Target",
    "Bands",
    "Prediction",
    "Compensation",
    "load_study",
    "load_record_for_study",
    "check_units",
    "default_current_range",
    "reachable_range",
    "load_target",
    "predict",
    "compensate",
    "write_prediction",
    "write_compensation",
    "bands_of",
    "VERDICTS",
    "PREDICTION_FILE",
    "COMPENSATION_FILE",
    "COMPENSATION_CSV",
    "COMPENSATION_BANDS_CSV",
    "REACH_TOLERANCE",
]
