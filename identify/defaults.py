"""Defaults shared by the Python API and the command line (one source; importing this
module is cheap, so ``--help`` stays fast)."""

#: Cap on the chain length [steps]: :func:`identify.posterior.sample_posterior` and
#: ``study --max-steps``. The bundled record's posterior converges after 35500-54000 steps
#: depending on the random stream (tau_max 708-1080 with the corrected snooker move); the
#: cap leaves room for an autocorrelation time up to 1200 steps (docs/method.md).
DEFAULT_MAX_STEPS = 60000
#: Convergence check interval [steps] (API and ``study --check-every``).
DEFAULT_CHECK_EVERY = 500

#: Exit codes of every command (the meanings: :data:`identify.cli.EXIT_CODES`, docs/reproducibility.md).
EXIT_OK = 0
#: Done, but with a finding the user must look at: a study whose chain did NOT CONVERGE, a
#: fit whose solver did not converge, a batch with a failed or unconverged run, a rerun
#: that differs (``reproduce``); also an unexpected failure (one error line).
EXIT_FINDING = 1
#: Bad input or usage (an invalid option, an unreadable record or priors file, ...).
EXIT_INPUT = 2
#: Interrupted by Ctrl-C or SIGTERM; completed work is kept.
EXIT_INTERRUPTED = 130
