"""What a run leaves behind: the results folder (:mod:`identify.output.results`), the
figures and the HTML reports of a study, a diagnosis, a prediction and a compensation."""
