"""Defaults shared by the Python API and the command line (one source; importing this
module is cheap, so ``--help`` stays fast)."""

#: Cap on the chain length [steps]: :func:`identify.fitting.posterior.sample_posterior` and
#: ``study --max-steps``. The bundled record's posterior converges after 35500-54000 steps
#: depending on the random stream (tau_max 708-1080 with the corrected snooker move); the
#: cap leaves room for an autocorrelation time up to 1200 steps (docs/method.md).
DEFAULT_MAX_STEPS = 60000
#: Convergence check interval [steps] (API and ``study --check-every``).
DEFAULT_CHECK_EVERY = 500
