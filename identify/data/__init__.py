"""Records and files: loading and writing measurement records, real-data converters,
atomic file writes and folder locks (the lowest stage: imports only :mod:`model` and the
standard numerical libraries)."""
