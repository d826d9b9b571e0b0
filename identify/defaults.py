"""Defaults shared by the Python API and the command line (one source; importing this
module is cheap, so ``--help`` stays fast)."""

#: Cap on the chain length [steps]: :func:`identify.fitting.posterior.sample_posterior` and
#: ``study --max-steps``. The bundled record's posterior converges after 35500-54000 steps
#: depending on the random stream (tau_max 708-1080 with the corrected snooker move); the
#: cap leaves room for an autocorrelation time up to 1200 steps (docs/method.md).
DEFAULT_MAX_STEPS = 60000
#: Convergence check interval [steps] (API and ``study --check-every``).
DEFAULT_CHECK_EVERY = 500
#: Least-squares starts of a fit and a study (API and ``--n-starts``).
DEFAULT_N_STARTS = 8

# Names the command line offers in its --help without importing the model (numba): kept
# equal to model.EFFECTS, model.READINGS and model.INPUT_READINGS by tests/test_layout.py.
#: The effects of the library, in model.EFFECTS' order.
EFFECT_NAMES = (
    "lag",
    "training",
    "rate_width",
    "initial_state",
    "incomplete_reset",
    "creep",
    "thermal",
    "sensor_drift",
)
#: Readings of the paper's eqs. (5)-(7).
READINGS = ("swapped", "literal")
#: Readings of the decay in the paper's eq. (16).
INPUT_READINGS = ("literal", "centred")

#: Default sensor noise standard deviation of the simulated bench [um]: about 0.2 % of the ~300 um full scale.
DEFAULT_NOISE_SIGMA = 0.5
#: Default sampling rate of the simulated bench [Hz] (7001 samples over the paper's 70 s).
DEFAULT_FS = 100.0

#: Exit codes of every command (the meanings: :data:`identify.cli.app.EXIT_CODES`, docs/reproducibility.md).
EXIT_OK = 0
#: Done, but with a finding the user must look at: a study whose chain did NOT CONVERGE, a
#: fit whose solver did not converge, a batch with a failed or unconverged run, a rerun
#: that differs (``reproduce``); also an unexpected failure (one error line).
EXIT_FINDING = 1
#: Bad input or usage (an invalid option, an unreadable record or priors file, ...).
EXIT_INPUT = 2
#: Interrupted by Ctrl-C or SIGTERM; completed work is kept.
EXIT_INTERRUPTED = 130
