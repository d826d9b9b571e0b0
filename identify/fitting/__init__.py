"""The statistics of one fit: the noise model, the parametrisation and identifiability,
the multi-start least squares, the emcee posterior and its ArviZ export."""
