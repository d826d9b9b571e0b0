"""Whole tasks, callable from Python: the study, the fit, the paper's figures, the use of a
finished study (predict, compensate), the batch and reproduce. The command line
(:mod:`identify.cli`) is arguments plus a call into one of these."""
