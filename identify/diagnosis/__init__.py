"""Is the residual noise, and which physical effect is missing? Residual statistics
(:mod:`identify.diagnosis.residuals`) and the diagnosis (:mod:`identify.diagnosis.diagnose`)."""
