"""Is the residual noise, and which physical effect is missing?

The diagnosis is one method in five steps, each a module:

=====================  =========================================================================
module                 what it holds
=====================  =========================================================================
``residuals``          the residual's statistics: the noise reference, the tests, where it fails
``adequacy``           the thresholds and the adequacy rule (is it noise?), the practical size
``screening``          a linearised score of every candidate at the baseline
``fits``, ``starts``   the working copy, short refits and finishes; the start strategies
``baseline``           the baseline in each threshold sign, its challenges
``search``, ``pairs``  the search: candidates and pairs refitted and finished
``candidates``         one candidate measured (:class:`CandidateResult`)
``evidence``           the evidence: explanations and the gaps between them
``decision``           the decision, a pure function of the evidence (:data:`RULES`)
``explanation``        the decision in sentences
``diagnose``           :func:`diagnose`, the steps in order, and :class:`Diagnosis`
=====================  =========================================================================
"""

from .adequacy import Adequacy, Thresholds, assess_adequacy
from .baseline import fit_baseline
from .candidates import CandidateResult
from .decision import RULES, STATUSES, Decision, decide
from .diagnose import Diagnosis, diagnose
from .evidence import Evidence, Explanation, Gap
from .explanation import explain
from .joint import JointDiagnosis

__all__ = [
    "diagnose",
    "Diagnosis",
    "JointDiagnosis",
    "STATUSES",
    "RULES",
    "Thresholds",
    "Adequacy",
    "assess_adequacy",
    "fit_baseline",
    "CandidateResult",
    "Evidence",
    "Explanation",
    "Gap",
    "Decision",
    "decide",
    "explain",
]
