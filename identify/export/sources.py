"""The C sources of an export: the generic step functions, the parameter set, a README and an example.

``msma_gpi.c`` (package data, the same for every export) is the forward model and the
inverse as streaming step functions; ``msma_gpi.h`` is its header with the model's number
of operators; ``msma_params.c`` is written here from an :class:`~identify.export.spec.ExportSpec`
(every value as Python's shortest round-trip decimal, so the C double is the Python float);
``example.c`` is the README's usage example, which the tests compile and run.
"""

from __future__ import annotations

import json
from importlib import resources

from model import THETA_NAMES

from .spec import C_EFFECTS, HORIZON_EFFECTS, ExportSpec

__all__ = [
    "C_FILES",
    "COMPILE_FLAGS",
    "c_sources",
    "package_text",
    "c_string",
    "provenance_lines",
]

#: The files of ``OUT/c/`` that make the library (the example and the README aside).
C_FILES = ("msma_gpi.h", "msma_gpi.c", "msma_params.c")
#: Flags of every build: C99, optimised, no floating-point contraction (the Python kernels do not
#: contract a * b + c into one rounding, so neither may the C, for their figures to rounding).
COMPILE_FLAGS = ("-std=c99", "-O2", "-ffp-contract=off")


def package_text(name: str) -> str:
    """A file of the package's ``c/`` folder."""
    return resources.files(__package__).joinpath("c", name).read_text(encoding="utf-8")


def c_string(text: str) -> str:
    """``text`` as a C string literal (ASCII; backslashes, quotes and line breaks escaped)."""
    escaped = text.encode("ascii", "replace").decode("ascii")
    escaped = escaped.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("?", "\\?")
    return f'"{escaped}"'


def _number(value: float) -> str:
    """A double literal: Python's shortest round-trip ``repr``, with a decimal point."""
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def provenance_lines(spec: ExportSpec) -> list[str]:
    """The provenance as ``key: value`` lines (comments and the provenance string)."""
    lines = [f"{key}: {value}" for key, value in spec.provenance.items() if not isinstance(value, dict)]
    lines.append(f"model: {json.dumps(spec.model.to_dict())}")
    if spec.uses_horizon():
        uses = [e for e in spec.effects if e in HORIZON_EFFECTS]
        lines.append(f"horizon: {spec.horizon!r} s (the run's length for {', '.join(uses)})")
    return lines


def _params_c(spec: ExportSpec) -> str:
    units, values = spec.units_of(), spec.c_values()
    lines = [
        "/* msma_params.c: the exported parameter set of the identified model. Written by `python -m identify "
        "export`. */",
        "/*",
        *(f" * {line}" for line in provenance_lines(spec)),
        " */",
        '#include "msma_gpi.h"',
        "",
        "void msma_default_params(msma_params *p) {",
        "    /* GPI (Table 1's order) */",
    ]
    for name in THETA_NAMES:
        lines.append(f"    p->{name} = {_number(values[name])}; /* {units.get(name) or '-'} */")
    reading = spec.model.reading
    lines.append(f"    p->rising_is_a = {1 if reading == 'swapped' else 0}; /* reading {reading!r} */")
    for effect, names in C_EFFECTS.items():
        present = effect in spec.effects
        lines.append(f"    /* {effect}: {'in the model' if present else 'not in the model (off values)'} */")
        lines.append(f"    p->has_{effect} = {1 if present else 0};")
        for name in names:
            unit = units.get(name) if present else None
            lines.append(f"    p->{name} = {_number(values[name])};" + (f" /* {unit} */" if unit else ""))
    lines.append(f"    p->horizon = {_number(spec.horizon)}; /* s */")
    modes, logs, count = spec.creep_constants()
    lines.append(
        "    /* the creep modes' time constants (model.effects' values; msma_creep_constants recomputes them) */"
    )
    for m, tau in enumerate(modes):
        lines.append(f"    p->creep_mode_tau[{m}] = {_number(tau)};")
    for m, tau in enumerate(logs):
        lines.append(f"    p->creep_log_tau[{m}] = {_number(tau)};")
    lines.append(f"    p->creep_log_modes = {count};")
    lines.append("}")
    lines.append("")
    text = (
        "\n".join(provenance_lines(spec))
        + "\n"
        + "\n".join(f"{name} = {spec.values[name]!r}" for name in spec.model.names)
    )
    lines.append(f"const char *msma_provenance(void) {{ return {c_string(text)}; }}")
    lines.append("")
    return "\n".join(lines)


def example_c(spec: ExportSpec) -> str:
    """The README's usage example: the compensator's current for a sine, through the model."""
    lo, hi = spec.current_range
    return "\n".join(
        [
            "/* example.c: the compensator's current for a 60-240 um sine, and the model driven with it. */",
            "#include <math.h>",
            "#include <stdio.h>",
            '#include "msma_gpi.h"',
            "",
            "int main(void) {",
            "    msma_params p; msma_forward model; msma_inverse comp; int k, status;",
            "    msma_default_params(&p); /* the exported parameter set */",
            f"    if (msma_forward_init(&model, &p) || msma_inverse_init(&comp, &p, {_number(lo)}, {_number(hi)}, "
            f"{_number(spec.output_scale)})) return 1;",
            "    for (k = 0; k <= 2000; k++) { /* 20 s at 100 Hz */",
            "        double t = 0.01 * k, target = 150.0 - 90.0 * cos(2.0 * 3.141592653589793 * 0.1 * t);",
            "        double i = msma_inverse_step(&comp, t, target, &status); /* the feedforward current */",
            "        double y = msma_forward_step(&model, t, i);              /* the model driven with it */",
            '        if (k % 200 == 0) printf("t %5.2f s target %8.3f current %7.4f model %8.3f status %d\\n", t, '
            "target, i, y, status);",
            "    }",
            "    return 0;",
            "}",
            "",
        ]
    )


def _readme(spec: ExportSpec, example: str) -> str:
    lo, hi = spec.current_range
    unit_in, unit_out = spec.units["input"], spec.units["output"]
    flags = " ".join(COMPILE_FLAGS)
    effects = ", ".join(spec.effects) or "none"
    horizon = ""
    if spec.uses_horizon():
        horizon = (
            f"\n`p.horizon` = {spec.horizon:g} s is the run's length: the logarithmic creep's modes reach ten "
            "times it and the sensor drift's time is normalised by it, as the Python model takes the record's "
            "duration. Set it to your run's length before the init call.\n"
        )
    return f"""# The identified GPI model and its inverse in C

Written by `python -m identify export` from the study `{spec.provenance.get("study", "?")}`
({spec.provenance.get("parameters", "?")}). Model: {spec.n_operators} operators, reading
`{spec.model.reading}`, effects: {effects}. Drive in {unit_in}, displacement in {unit_out}, time in s.

C99 with no dependency beyond libm; no allocation, no global state: every model is a struct
you own (`msma_forward` for the model, `msma_inverse` for the compensator), initialised from
the parameters (`msma_default_params`: the exported values, in `msma_params.c`) and stepped
one sample at a time with the sample's time:

```sh
cc {flags} -o example example.c msma_gpi.c msma_params.c -lm && ./example
```

```c
{example.strip()}
```

- `msma_forward_step(&m, t, i)`: the displacement at time `t` [s] for the drive `i`; the first
  call is the first sample, where the model starts from its identified initial state
  (thermal at the rises the record started with, cold unless the study found a warm start;
  training virgin, creep at rest), as `Model.evaluate` does at a record's start.
- `msma_inverse_step(&c, t, y, &status)`: the drive in `[lo, hi]` that makes the model follow
  the target `y`, exactly as `python -m identify compensate` computes it (model/inverse.py,
  sample by sample). `status` is `MSMA_EXACT`, `MSMA_SATURATED` (the current at a limit, the
  target not reached) or `MSMA_BRANCH` (an Omega gap). At a reversal of the target the
  current steps across the dead zone to take Omega's jump back; a target outside what the
  model reaches within `[lo, hi]` keeps the current at the limit (flagged) where `compensate`
  refuses the whole target. Defaults of this export: `lo, hi` = {lo:g}, {hi:g} {unit_in};
  `scale` = {spec.output_scale:.6g} {unit_out} (the output's scale for the root find's rounding
  tolerance: `compensate` takes max |target|, at least 1).
- Times must increase; the filters use the actual step `t_k - t_(k-1)`, so the sampling may vary.
- `-ffp-contract=off` keeps the arithmetic of the Python kernels (no fused multiply-add), so
  the figures agree with Python to rounding (tested to 1e-9); the code is plain C99 without it.
{horizon}
Provenance (also `msma_provenance()`):

{chr(10).join("    " + line for line in provenance_lines(spec))}
"""


def c_sources(spec: ExportSpec) -> dict[str, str]:
    """``{file name: text}`` of ``OUT/c/``."""
    header = package_text("msma_gpi.h.in").replace("@N_OPERATORS@", str(int(spec.n_operators)))
    example = example_c(spec)
    return {
        "msma_gpi.h": header,
        "msma_gpi.c": package_text("msma_gpi.c"),
        "msma_params.c": _params_c(spec),
        "example.c": example,
        "README.md": _readme(spec, example),
    }
