"""The two FMI 2.0 co-simulation units of an export: the model and the compensator.

Each unit is a zip with ``modelDescription.xml``, ``sources/`` (the export's C, the FMI
wrapper ``fmu_wrapper.c``, its generated ``fmu_variables.h`` and ``fmi2_declarations.h``, the
FMI 2.0 types written for this project from the standard) and
``binaries/<platform>/<model>.so`` built with the local C compiler.

``model.fmu``
    input ``current`` [input unit], output ``displacement`` [output unit]; every parameter
    of the model (and ``horizon`` where an effect needs the run's length) as a fixed parameter.
``compensator.fmu``
    input ``target`` [output unit], outputs ``current`` [input unit], ``model_displacement``
    (the model's output on that current) and the Integer ``status`` (0 exact, 1 saturated,
    2 an Omega gap); parameters ``current_min``, ``current_max`` (the current range),
    ``output_scale`` and the model's (``sensor_drift`` left out, as ``compensate`` does).

Time: one model sample per communication step (the wrapper's header comment). Both units
carry the study's provenance in their model description (``description``, the parameters'
start values and a ``VendorAnnotations`` tool entry ``msma-gpi``).
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

from ..version import __version__
from .compiler import shared_library
from .sources import C_FILES, c_sources, package_text
from .spec import ExportSpec

__all__ = ["FmuVariable", "FMU_NAMES", "model_identifier", "unit_variables", "model_description", "build_fmu"]

#: kind -> (file name, model identifier, what it is)
FMU_NAMES = {
    "model": ("model.fmu", "msma_gpi_model", "the identified GPI model: coil current in, displacement out"),
    "compensator": (
        "compensator.fmu",
        "msma_gpi_compensator",
        "the inverse of the identified GPI model: target displacement in, feedforward current out",
    ),
}
#: The effect parameters that set the creep modes' time constants (recomputed in C when set).
_CREEP_INPUTS = ("creep_tau", "creep_decades", "creep_log_onset", "horizon")
#: Units the model description can state in SI base units: name -> (exponents, factor).
_BASE_UNITS = {
    "A": ({"A": 1}, 1.0),
    "mA": ({"A": 1}, 1e-3),
    "V": ({"kg": 1, "m": 2, "s": -3, "A": -1}, 1.0),
    "um": ({"m": 1}, 1e-6),
    "mm": ({"m": 1}, 1e-3),
    "nm": ({"m": 1}, 1e-9),
    "m": ({"m": 1}, 1.0),
    "s": ({"s": 1}, 1.0),
    "um/A": ({"m": 1, "A": -1}, 1e-6),
    "1/A": ({"A": -1}, 1.0),
    "s/A": ({"s": 1, "A": -1}, 1.0),
}


@dataclass(frozen=True)
class FmuVariable:
    """One ScalarVariable: name, value reference, causality, type, start, unit, description, and
    where the C reads it (a field of ``msma_params``, or the wrapper's settings slot 0-2)."""

    name: str
    vr: int
    causality: str
    kind: str = "Real"
    start: float | None = None
    unit: str = ""
    description: str = ""
    field: str | None = None
    setting: int | None = None


def model_identifier(kind: str) -> str:
    return FMU_NAMES[kind][1]


def platform_folder() -> tuple[str, str]:
    """``(binaries/<folder>, library suffix)`` of this machine, as FMI 2.0 names them."""
    bits = "64" if sys.maxsize > 2**32 else "32"
    system = platform.system()
    if system == "Darwin":
        return f"darwin{bits}", ".dylib"
    if system == "Windows":
        return f"win{bits}", ".dll"
    return f"linux{bits}", ".so"


def unit_variables(spec: ExportSpec, kind: str, *, input_start: float) -> list[FmuVariable]:
    """The unit's variables in value-reference order (inputs and outputs first, then parameters)."""
    unit_in, unit_out = spec.units["input"], spec.units["output"]
    if kind == "model":
        variables = [
            FmuVariable("current", 0, "input", start=input_start, unit=unit_in, description="coil current (drive)"),
            FmuVariable("displacement", 1, "output", unit=unit_out, description="the model's displacement"),
        ]
    else:
        lo, hi = spec.current_range
        variables = [
            FmuVariable("target", 0, "input", start=input_start, unit=unit_out, description="desired displacement"),
            FmuVariable("current", 1, "output", unit=unit_in, description="feedforward current"),
            FmuVariable(
                "model_displacement", 2, "output", unit=unit_out, description="the model's output on that current"
            ),
            FmuVariable(
                "status",
                0,
                "output",
                kind="Integer",
                description="0 the target reproduced, 1 the current at a limit, 2 an Omega gap (model.inverse)",
            ),
            FmuVariable(
                "current_min", 5, "parameter", start=lo, unit=unit_in, description="lower current limit", setting=0
            ),
            FmuVariable(
                "current_max", 6, "parameter", start=hi, unit=unit_in, description="upper current limit", setting=1
            ),
            FmuVariable(
                "output_scale",
                7,
                "parameter",
                start=spec.output_scale,
                unit=unit_out,
                description="the output's scale for the root find's rounding tolerance: about the largest "
                "|displacement| (compensate: max |target|); far smaller puts it under the output's rounding",
                setting=2,
            ),
        ]
    units, descriptions = spec.units_of(), spec.descriptions()
    vr = 10
    for name in spec.model.names:
        if kind == "compensator" and name.startswith("sensor_drift_"):
            continue  # the compensator leaves the sensor's drift out (compensate does)
        variables.append(
            FmuVariable(
                name,
                vr,
                "parameter",
                start=spec.values[name],
                unit=units[name],
                description=descriptions[name],
                field=name,
            )
        )
        vr += 1
    needs_horizon = "creep" in spec.effects or (kind == "model" and "sensor_drift" in spec.effects)
    if needs_horizon:
        variables.append(
            FmuVariable(
                "horizon",
                vr,
                "parameter",
                start=spec.horizon,
                unit="s",
                description="the run's length: the logarithmic creep's modes reach 10 x it, the sensor drift's time "
                "is normalised by it",
                field="horizon",
            )
        )
    return variables


def _number(value: float) -> str:
    return repr(float(value))


def _variables_header(spec: ExportSpec, kind: str, variables, guid: str) -> str:
    lo, hi = spec.current_range
    outputs = {v.name: v.vr for v in variables if v.causality == "output"}
    lines = [
        f"/* fmu_variables.h: the {kind} unit's variables. Written by `python -m identify export`. */",
        "#ifndef FMU_VARIABLES_H",
        "#define FMU_VARIABLES_H",
        "#include <stddef.h>",
        "",
        f"#define FMU_KIND {0 if kind == 'model' else 1}",
        f'#define FMU_GUID "{guid}"',
        f'#define FMU_MODEL_IDENTIFIER "{model_identifier(kind)}"',
        "#define FMU_VR_INPUT 0u",
        "#define FMU_VR_OUTPUT 1u",
        f"#define FMU_VR_MODEL_OUTPUT {'2u' if kind == 'compensator' else '0xffffffffu'}",
        f"#define FMU_VR_STATUS {'0u' if 'status' in outputs else '0xffffffffu'}",
        f"#define FMU_INPUT_START {_number(next(v.start for v in variables if v.causality == 'input'))}",
        f"#define FMU_CURRENT_MIN {_number(lo)}",
        f"#define FMU_CURRENT_MAX {_number(hi)}",
        f"#define FMU_OUTPUT_SCALE {_number(spec.output_scale)}",
        "",
        "typedef struct {",
        "    unsigned int vr;",
        "    int in_settings; /* 1: the wrapper's settings[offset], 0: a field of msma_params at offset */",
        "    size_t offset;",
        "    int creep;       /* setting it makes the creep modes' time constants be computed again */",
        "} fmu_parameter;",
        "",
        "static const fmu_parameter FMU_PARAMETERS[] = {",
    ]
    for v in variables:
        if v.causality != "parameter":
            continue
        creep = 1 if v.name in _CREEP_INPUTS else 0
        if v.setting is not None:
            lines.append(f"    {{{v.vr}u, 1, {v.setting}, 0}}, /* {v.name} */")
        else:
            lines.append(f"    {{{v.vr}u, 0, offsetof(msma_params, {v.field}), {creep}}}, /* {v.name} */")
    lines += [
        "};",
        "#define FMU_N_PARAMETERS (sizeof FMU_PARAMETERS / sizeof FMU_PARAMETERS[0])",
        "",
        "#endif /* FMU_VARIABLES_H */",
        "",
    ]
    return "\n".join(lines)


def _unit_element(parent, name: str) -> None:
    unit = ET.SubElement(parent, "Unit", name=name)
    known = _BASE_UNITS.get(name)
    if known:
        exponents, factor = known
        attributes = {key: str(value) for key, value in exponents.items()}
        if factor != 1.0:
            attributes["factor"] = repr(factor)
        ET.SubElement(unit, "BaseUnit", attributes)


def model_description(spec: ExportSpec, kind: str, variables, guid: str, *, step_size: float, generated: str) -> str:
    """``modelDescription.xml`` (FMI 2.0, co-simulation) of the unit ``kind``."""
    prov = spec.provenance
    what = FMU_NAMES[kind][2]
    description = (
        f"{what}; {prov.get('parameters', '')} of the study {prov.get('study', '?')} "
        f"(data sha256 {prov.get('data_sha256', '?')}, commit {prov.get('git_commit', '?')}); "
        f"effects: {', '.join(spec.effects) or 'none'}"
    )
    root = ET.Element(
        "fmiModelDescription",
        {
            "fmiVersion": "2.0",
            "modelName": model_identifier(kind),
            "guid": guid,
            "description": description,
            "version": __version__,
            "generationTool": f"msma-gpi {__version__} (python -m identify export)",
            "generationDateAndTime": generated,
            "variableNamingConvention": "flat",
            "numberOfEventIndicators": "0",
        },
    )
    cs = ET.SubElement(
        root,
        "CoSimulation",
        {
            "modelIdentifier": model_identifier(kind),
            "needsExecutionTool": "false",
            "canHandleVariableCommunicationStepSize": "true",
            "canInterpolateInputs": "false",
            "canRunAsynchronuously": "false",
            "canBeInstantiatedOnlyOncePerProcess": "false",
            "canNotUseMemoryManagementFunctions": "false",
            "canGetAndSetFMUstate": "false",
            "canSerializeFMUstate": "false",
            "providesDirectionalDerivative": "false",
        },
    )
    files = ET.SubElement(cs, "SourceFiles")
    for name in ("msma_gpi.c", "msma_params.c", "fmu_wrapper.c"):
        ET.SubElement(files, "File", name=name)
    units = sorted({v.unit for v in variables if v.unit})
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for name in units:
            _unit_element(definitions, name)
    categories = ET.SubElement(root, "LogCategories")
    ET.SubElement(categories, "Category", name="logStatusError", description="errors of the unit")
    ET.SubElement(
        root, "DefaultExperiment", startTime="0.0", stopTime=repr(float(spec.horizon)), stepSize=repr(float(step_size))
    )
    annotations = ET.SubElement(root, "VendorAnnotations")
    tool = ET.SubElement(annotations, "Tool", name="msma-gpi")
    provenance = ET.SubElement(
        tool,
        "Provenance",
        {key: str(value) for key, value in prov.items() if not isinstance(value, (dict, list))},
    )
    for name in spec.model.names:
        ET.SubElement(provenance, "Parameter", name=name, value=repr(spec.values[name]), unit=spec.units_of()[name])
    for note in spec.notes:
        ET.SubElement(provenance, "Note").text = note
    model_variables = ET.SubElement(root, "ModelVariables")
    for v in variables:
        attributes = {"name": v.name, "valueReference": str(v.vr), "causality": v.causality}
        if v.description:
            attributes["description"] = v.description
        if v.causality == "parameter":
            attributes["variability"] = "fixed"
        elif v.kind == "Integer":
            attributes["variability"] = "discrete"
        else:
            attributes["variability"] = "continuous"
        if v.causality == "output":
            attributes["initial"] = "calculated"
        element = ET.SubElement(model_variables, "ScalarVariable", attributes)
        typed = {}
        if v.unit:
            typed["unit"] = v.unit
        if v.start is not None:
            typed["start"] = repr(float(v.start)) if v.kind == "Real" else str(int(v.start))
        ET.SubElement(element, v.kind, typed)
    index = {id(v): n for n, v in enumerate(variables, start=1)}
    inputs = [index[id(v)] for v in variables if v.causality == "input"]
    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    initial = ET.SubElement(structure, "InitialUnknowns")
    for v in variables:
        if v.causality == "output":
            depends = " ".join(str(i) for i in inputs)
            ET.SubElement(outputs, "Unknown", index=str(index[id(v)]), dependencies=depends)
            ET.SubElement(initial, "Unknown", index=str(index[id(v)]))
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _guid(spec: ExportSpec, kind: str, sources: dict) -> str:
    """A GUID determined by the unit's content (the same export gives the same GUID)."""
    digest = hashlib.sha256()
    digest.update(kind.encode())
    digest.update(json.dumps(spec.values, sort_keys=True).encode())
    digest.update(json.dumps(spec.provenance, sort_keys=True, default=str).encode())
    for name in sorted(sources):
        digest.update(name.encode() + b"\0" + sources[name].encode())
    return "{" + str(uuid.UUID(digest.hexdigest()[:32])) + "}"


#: Every entry of a unit's zip gets this time stamp (the same content gives the same bytes).
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def build_fmu(
    spec: ExportSpec, kind: str, output, *, input_start: float, step_size: float, generated: str, compiler=None
) -> dict:
    """Write the unit ``kind`` (``"model"`` or ``"compensator"``) to ``output`` (a ``.fmu`` zip).

    Returns ``{"guid", "platform", "model_identifier", "variables"}``. Raises
    :class:`~identify.export.compiler.CompilerError` when the library cannot be built.
    """
    library_sources = c_sources(spec)
    variables = unit_variables(spec, kind, input_start=input_start)
    sources = {name: library_sources[name] for name in C_FILES}
    sources["fmi2_declarations.h"] = package_text("fmi2_declarations.h")
    sources["fmu_wrapper.c"] = package_text("fmu_wrapper.c")
    guid = _guid(spec, kind, sources)
    sources["fmu_variables.h"] = _variables_header(spec, kind, variables, guid)
    description = model_description(spec, kind, variables, guid, step_size=step_size, generated=generated)
    folder, suffix = platform_folder()
    identifier = model_identifier(kind)
    with tempfile.TemporaryDirectory(prefix="msma-fmu-") as work:
        work = Path(work)
        for name, text in sources.items():
            (work / name).write_text(text, encoding="utf-8")
        library = shared_library(
            [work / "msma_gpi.c", work / "msma_params.c", work / "fmu_wrapper.c"],
            work / f"{identifier}{suffix}",
            compiler=compiler,
            extra_flags=(f"-I{work}", "-fvisibility=hidden"),
        )
        binary = library.read_bytes()
    entries = {"modelDescription.xml": description.encode("utf-8")}
    entries.update({f"sources/{name}": text.encode("utf-8") for name, text in sorted(sources.items())})
    entries[f"binaries/{folder}/{identifier}{suffix}"] = binary
    with zipfile.ZipFile(output, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries.items():
            info = zipfile.ZipInfo(name, date_time=_ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, data)
    return {
        "guid": guid,
        "platform": folder,
        "model_identifier": identifier,
        "variables": [v.name for v in variables],
    }
