"""Identification of the GPI model from measurements: noise, least squares, posterior,
diagnosis, reports and batch runs. Command line: ``python -m identify --help``."""

from .version import __version__
