"""Identification of the GPI model from measurements: noise, least squares, posterior,
diagnosis, reports and batch runs. Command line: ``python -m identify --help``."""

__version__ = "0.1.0"
