"""Export a finished study's model and its inverse as C and as FMI 2.0 co-simulation units.

``python -m identify export DIR --out OUT`` (:func:`export`): ``OUT/c/`` holds C99 source with
no dependency beyond libm (the forward model and the inverse as streaming step functions:
a state struct, one sample in, one sample out), ``OUT/model.fmu`` and ``OUT/compensator.fmu``
the same C as FMI 2.0 units built with the local compiler. The stage sits above
:mod:`identify.workflows` (it reads a study with :func:`identify.workflows.use.load_study`).

Modules: :mod:`~identify.export.spec` (what is exported; the effects refused and why),
:mod:`~identify.export.sources` (the C files), :mod:`~identify.export.fmu` (the units),
:mod:`~identify.export.compiler` (the local C compiler), :mod:`~identify.export.native` (the
C called from Python: tests, benchmarks), :mod:`~identify.export.workflow` (:func:`export`).
"""

from .compiler import CompilerError, find_compiler
from .native import NativeModel
from .spec import C_EFFECTS, REFUSED, ExportError, ExportSpec, export_spec
from .workflow import EXPORT_FILE, Export, export, study_spec

__all__ = [
    "export",
    "Export",
    "ExportError",
    "CompilerError",
    "ExportSpec",
    "export_spec",
    "study_spec",
    "find_compiler",
    "NativeModel",
    "C_EFFECTS",
    "REFUSED",
    "EXPORT_FILE",
]
