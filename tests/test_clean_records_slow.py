"""No false alarm on clean records written blind to the library (slow).

A subset of ``benchmarks/clean_records.py``: the first records of the independent
generator's clean suite (``benchmarks/independent/generator.py``: eq. (5) with every GPI
parameter within +-10 % of Table 1, on both sides of where the operator bounds start to
cross; both input readings; 100 Hz and 1 kHz; white and AR(1) noise, sigma 0.3-1 um).
On each, the diagnosis' baseline least squares must reach a residual RMS no worse than
the true parameters' on the same record (within 0.5 %: the global optimum) and the
verdict must be ``adequate``. The full table over 100 records is in docs/benchmarks.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "independent"))

#: Records of the subset: the first of the suite (index 4 is at 1 kHz, 70001 samples).
SUBSET = 6
#: Records of the 100 where the baseline least squares once ended in a local optimum
#: (docs/benchmarks.md): 54 (1 kHz, negative thresholds; every start's dogbox screen ranked
#: the start that trf takes to the global optimum last) and 57.
ONCE_FAILED = (54, 57)


@pytest.mark.slow
@pytest.mark.parametrize("index", [*range(SUBSET), *ONCE_FAILED])
def test_clean_record_fits_to_the_truth_and_is_adequate(index, tmp_path):
    import generator
    from clean_records import RMS_TOLERANCE, score_record

    spec = generator.clean_records(max(SUBSET, index + 1), 0)[index]
    generator.write_record(spec, str(tmp_path))
    figures = score_record(tmp_path / f"{spec['stem']}.csv", tmp_path / f"{spec['stem']}.npz")
    print(figures)
    assert figures["ratio"] <= RMS_TOLERANCE, figures
    assert figures["status"] == "adequate", figures
