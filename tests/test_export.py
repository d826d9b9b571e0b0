"""``export`` (identify/export/, issue 68): the identified model and its inverse as C and as FMI units.

The C is compiled with the system compiler and run sample by sample; its forward model is
compared with :meth:`model.Model.evaluate` and its inverse with :func:`model.inverse.invert` and
the ``compensate`` workflow, on the bundled record and on a random drive. Tolerance 1e-9 (of the
output's range, of the current range): the issue's. What it allows for: the forward kernel's
tanh is a polynomial within 4 ulp of libm's (model/gpi.py), the C calls libm's, so the forward
agrees to 7.7e-16 of the range or better (measured); the C inverse repeats model/inverse.py's
arithmetic (libm tanh and exp there too, no contraction) and agrees to the bit where measured.
The FMUs are checked with fmpy (the test extra): its validation, its simulation, and a
sample-by-sample master. The closed loop drives the bench's true transducer with the
compensator unit's current (issue 17's goals).
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import json
import os
import re
import shutil
import subprocess
import zipfile
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import model
from identify.cli import main as identify_main
from identify.data.records import load_record
from identify.export import REFUSED, ExportError, NativeModel, export, export_spec
from identify.export import workflow as export_workflow
from identify.export.sources import c_sources
from identify.workflows.use import Target, compensate, load_study
from model.inverse import invert

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "data" / "bench_default.csv"
TOLERANCE = 1e-9


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = identify_main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def _random_drive(seed=5, n=3000, fs=100.0):
    """A random walk in 0-5 A with holds (repeated samples) and jittered sample times (+-20 %)."""
    rng = np.random.default_rng(seed)
    steps = (1.0 + rng.uniform(-0.2, 0.2, n)) / fs
    time = np.concatenate([[0.0], np.cumsum(steps[1:])])
    walk = np.clip(2.5 + np.cumsum(rng.normal(0.0, 0.06, n)), 0.0, 5.0)
    walk[rng.random(n) < 0.1] = np.nan  # holds: repeat the previous sample
    for k in range(1, n):
        if np.isnan(walk[k]):
            walk[k] = walk[k - 1]
    walk[0] = 0.0
    return time, walk


def _native(spec, directory) -> NativeModel:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in c_sources(spec).items():
        (directory / name).write_text(text)
    return NativeModel(directory)


def _table1(m, **values):
    return m.theta_from_dict({**dict(zip(model.THETA_NAMES, model.TABLE1)), **values})


def _without_drift(m, theta):
    theta = np.array(theta, dtype=float)
    if "sensor_drift" in m.effect_names:
        sl = m.effect_slice("sensor_drift")
        theta[sl] = [model.EFFECTS["sensor_drift"].off[n] for n in m.names[sl]]
    return theta


# -- the C against the Python model, effect by effect (no study) ----------------------------------
CASES = {
    "gpi": ([], {}),
    "gpi, literal reading, 7 operators": ([], {}),
    **{name: ([name], model.EFFECTS[name].get_test_parameters()) for name in model.EFFECTS if name not in REFUSED},
    "creep, both forms, part from the leg's end": (
        ["creep"],
        {"creep_amplitude": -0.05, "creep_log_rate": 0.02, "creep_log_hold": 0.5, "creep_log_onset": 0.05},
    ),
    "thermal, two nodes": (
        ["thermal"],
        {"thermal_tau": 20.0, "thermal_sensitivity": 0.08, "thermal_expansion": 3.0}
        | {"thermal_tau_core": 200.0, "thermal_sensitivity_core": 0.03, "thermal_expansion_core": -1.0},
    ),
    "thermal, two nodes, a warm start": (
        ["thermal"],
        {"thermal_tau": 20.0, "thermal_sensitivity": 0.08, "thermal_expansion": 3.0}
        | {"thermal_tau_core": 200.0, "thermal_sensitivity_core": 0.03, "thermal_expansion_core": -1.0}
        | {"thermal_initial": 0.3, "thermal_initial_core": 0.5},
    ),
    "training, every part": (
        ["training"],
        {"training_deficit": 0.1, "training_threshold": 0.2, "training_gain": 0.1, "training_width": 0.3}
        | {"training_shape": 2.0},
    ),
    "initial_state, every part": (
        ["initial_state"],
        {"initial_state_excursion": 1.0, "initial_state_held": 0.3, "initial_state_held_slope": 0.2},
    ),
    "sensor_drift, every part": (
        ["sensor_drift"],
        {"sensor_drift_linear": 2.0, "sensor_drift_quadratic": 1.0, "sensor_drift_settling": 1.5}
        | {"sensor_drift_ambient_sine": 1.0, "sensor_drift_ambient_cosine": 0.5},
    ),
    "every exportable effect": (
        ["lag", "training", "initial_state", "creep", "thermal", "sensor_drift"],
        {"lag_tau": 0.02, "training_deficit": 0.1, "creep_amplitude": 0.05, "creep_log_rate": 0.01}
        | {"thermal_sensitivity": 0.05, "thermal_expansion": 1.0, "sensor_drift_linear": 1.0},
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_c_is_the_python_model_and_its_inverse(case, tmp_path):
    """Forward: C = Model.evaluate to 1e-9 of the output's range (measured ~1e-15); inverse: C =
    model.inverse.invert to 1e-9 of the current range, the same status at every sample (measured:
    the same bits). On the paper's input (quiet start, dead zones, reversals) at 20 Hz and on a
    random drive with holds and uneven steps."""
    effects, values = CASES[case]
    literal = "literal" in case
    m = model.Model(effects, n_operators=7 if literal else 12, reading="literal" if literal else "swapped")
    theta = _table1(m, **values)
    paper = model.paper_current(fs=20.0)
    for label, (time, current) in {"paper input": paper, "random drive": _random_drive()}.items():
        horizon = float(time[-1] - time[0])  # the record's duration, as Model.evaluate takes it
        spec = export_spec(m, theta, horizon=horizon, current_range=(0.0, 5.0), output_scale=300.0)
        native = _native(spec, tmp_path / label.replace(" ", "_"))
        y = m(theta, time, current)
        assert np.abs(native.forward(time, current) - y).max() <= TOLERANCE * np.ptp(y), (case, label)
        theta_c = _without_drift(m, theta)  # compensate leaves the sensor's drift out; so does the C inverse
        target = m(theta_c, time, current)
        python = invert(m, theta_c, time, target, current_range=(0.0, 5.0))
        current_c, output_c, status_c = native.inverse(time, target, (0.0, 5.0), max(1.0, np.abs(target).max()))
        assert np.abs(current_c - python.current).max() <= TOLERANCE * 5.0, (case, label)
        assert np.abs(output_c - python.output).max() <= TOLERANCE * np.ptp(target), (case, label)
        assert np.array_equal(status_c, python.status), (case, label)


def test_the_creep_constants_the_c_computes_are_the_pythons(tmp_path):
    """msma_creep_constants (after a change of creep_tau, creep_decades, creep_log_onset or the
    horizon) gives the model.effects time constants to rounding: the same forward model to 1e-9."""
    m = model.Model(["creep"])
    theta = _table1(m, creep_amplitude=0.05, creep_log_rate=0.02, creep_log_hold=0.3)
    time, current = model.paper_current(fs=20.0)
    spec = export_spec(m, theta, horizon=float(time[-1]))
    native = _native(spec, tmp_path)
    native.library.msma_creep_constants.argtypes = [native.library.msma_default_params.argtypes[0]]
    native.library.msma_creep_constants(native._params)
    y = m(theta, time, current)
    assert np.abs(native.forward(time, current) - y).max() <= TOLERANCE * np.ptp(y)


@pytest.mark.parametrize(
    "effects, values, named",
    [
        (["incomplete_reset"], {"incomplete_reset_strain": 6.0}, ["incomplete_reset", "largest strain excursion"]),
        (["rate_width"], {"rate_width_coefficient": 0.1}, ["rate_width", "no inverse step"]),
        (["lag"], {"lag_tau": 0.05, "lag_delay": 0.02}, ["lag", "dead time lag_delay = 0.02 s"]),
        (["thermal", "rate_width"], {}, ["rate_width"]),
    ],
)
def test_an_effect_that_cannot_be_streamed_is_refused_by_name(effects, values, named):
    m = model.Model(effects)
    with pytest.raises(ExportError) as caught:
        export_spec(m, _table1(m, **values), horizon=70.0)
    message = str(caught.value)
    assert "\n" not in message and message.startswith("cannot export")
    for text in named:
        assert text in message


def test_a_lag_without_dead_time_is_exported():
    m = model.Model(["lag"])
    spec = export_spec(m, _table1(m, lag_tau=0.05), horizon=70.0)
    assert spec.effects == ("lag",)


def test_the_test_extra_installs_fmpy():
    import tomllib

    extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    assert any(re.match(r"fmpy\b", requirement) for requirement in extra)


def test_the_units_parameters_are_set_before_the_initialization(tmp_path):
    """A model unit with logarithmic creep exported for a 700 s run (10 modes), given the horizon of
    the 70 s paper record (8 modes) before its initialization, is Model.evaluate on that record
    (the modes' time constants computed again in C, to 1e-9); the compensator given
    current_max = 4 A is invert with (0, 4)."""
    from identify.export.fmu import build_fmu

    m = model.Model(["creep", "thermal"])
    theta = _table1(m, creep_amplitude=0.05, creep_log_rate=0.02, thermal_sensitivity=0.05, thermal_expansion=1.0)
    spec = export_spec(m, theta, horizon=700.0, current_range=(0.0, 5.0), output_scale=300.0)
    for kind in ("model", "compensator"):
        build_fmu(
            spec, kind, tmp_path / f"{kind}.fmu", input_start=0.0, step_size=0.05, generated="2026-12-03T00:00:00Z"
        )
    time, current = model.paper_current(fs=20.0)
    y = m(theta, time, current)
    after, _ = _fmu_driver(
        tmp_path / "model.fmu", time, current, "current", ["displacement"], parameters={"horizon": 40.0}
    )
    assert np.abs(after[:, 0] - y).max() <= TOLERANCE * np.ptp(y)
    stale, _ = _fmu_driver(tmp_path / "model.fmu", time, current, "current", ["displacement"])
    assert np.abs(stale[:, 0] - y).max() > 1e-3  # the 700 s horizon is another model on this record
    target = 30.0 + 200.0 * np.abs(np.sin(2 * np.pi * time / 20.0))
    after, _ = _fmu_driver(
        tmp_path / "compensator.fmu",
        time,
        target,
        "target",
        ["current"],
        parameters={"current_max": 4.0, "horizon": 70.0, "output_scale": max(1.0, target.max())},
    )
    python = invert(m, theta, time, target, current_range=(0.0, 4.0))
    assert np.abs(after[:, 0] - python.current).max() <= TOLERANCE * 4.0 and after[:, 0].max() <= 4.0


# -- a study, exported ----------------------------------------------------------------------
@pytest.fixture(scope="session")
def study_dir(tmp_path_factory, worker_id):
    """A short study of the bundled bench record (hidden thermal) with --effects thermal, every 5th
    sample: about 25 s. One per test run: the xdist workers share it (a lock file), the first builds it."""
    base = tmp_path_factory.getbasetemp()
    root = base if worker_id == "master" else base.parent
    out = root / "export-study"
    with open(root / "export-study.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "chain.h5").exists():
            code, stdout, stderr = _run(
                ["study", BENCH, "--effects", "thermal", "--every", 5, "--out", out, "--seed", 1]
                + ["--n-starts", 1, "--max-steps", 300, "--check-every", 150, "--progress", "off", "--no-report"]
            )
            assert code in (0, 1) and (out / "summary.json").exists(), stdout + stderr
    return out


@pytest.fixture(scope="session")
def exported(study_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "out"
    code, stdout, stderr = _run(["export", study_dir, "--out", out])
    assert code == 0, stderr
    return out


def test_export_writes_the_c_the_units_and_the_provenance(study_dir, exported):
    assert sorted(p.name for p in exported.iterdir()) == ["c", "compensator.fmu", "export.json", "model.fmu"]
    assert sorted(p.name for p in (exported / "c").iterdir()) == sorted(
        ["README.md", "example.c", "msma_gpi.c", "msma_gpi.h", "msma_params.c"]
    )
    record = json.loads((exported / "export.json").read_text())
    study = load_study(study_dir)
    manifest = json.loads((study_dir / "manifest.json").read_text())
    assert record["provenance"]["parameters"] == "posterior median"
    assert record["provenance"]["data_sha256"] == manifest["data"]["sha256"]
    assert record["provenance"]["git_commit"] == manifest["git"]["commit"]
    assert record["parameters"]["thermal_tau"]["value"] == study.median[study.model.names.index("thermal_tau")]
    assert record["current_range"] == [0.0, 5.0]
    for unit in ("model.fmu", "compensator.fmu"):
        with zipfile.ZipFile(exported / unit) as archive:
            names = archive.namelist()
            description = archive.read("modelDescription.xml").decode()
        assert any(n.startswith("binaries/") and n.endswith(".so") for n in names), names
        assert "sources/msma_gpi.c" in names and "sources/fmu_wrapper.c" in names
        assert manifest["data"]["sha256"] in description and manifest["git"]["commit"] in description
        for name, value in zip(study.model.names, study.median.tolist()):
            assert f'name="{name}" value="{value!r}"' in description  # every parameter, to the bit
    params_c = (exported / "c" / "msma_params.c").read_text()
    for name, value in zip(study.model.names, study.median.tolist()):
        assert f"p->{name} = {value!r};" in params_c or f"p->{name} = {value!r}.0;" in params_c


def test_the_readme_compiler_line_builds_the_example_and_it_tracks(exported, tmp_path):
    """The README's one compiler line, run as written in a copy of OUT/c: the example's compensator
    current drives the model onto the sine (status 0, model = target to the printed digits)."""
    work = tmp_path / "c"
    shutil.copytree(exported / "c", work)
    readme = (work / "README.md").read_text()
    (line,) = re.findall(r"```sh\n(.*?)\n```", readme, re.S)
    assert line.startswith("cc ") and line.endswith("-lm && ./example")
    done = subprocess.run(line, shell=True, cwd=work, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = [re.findall(r"[-\d.]+", row) for row in done.stdout.splitlines()]
    assert len(rows) == 11
    for _time, target, current, y, status in rows:
        assert status == "0" and target == y and 0.0 <= float(current) <= 5.0


def test_the_c_forward_and_inverse_equal_model_and_compensate(study_dir, exported):
    """On the bundled record (all 7001 samples; the study saw every 5th) and on a random drive: the
    C forward model = Model.evaluate of the posterior median, and the C compensator = compensate's
    feedforward current for the median model's own output as the target, both to 1e-9."""
    study = load_study(study_dir)
    native = NativeModel(exported / "c")
    bench = load_record(BENCH)
    for time, current in ((bench.time, bench.current), _random_drive(seed=9)):
        y = study.model(study.median, time, current)
        assert np.abs(native.forward(time, current) - y).max() <= TOLERANCE * np.ptp(y)
        result = compensate(study, Target(time, y), n_draws=2)
        current_c, output_c, status_c = native.inverse(time, y, (0.0, 5.0), max(1.0, np.abs(y).max()))
        assert np.abs(current_c - result.current).max() <= TOLERANCE * 5.0
        assert np.array_equal(status_c, result.status)  # thermal: not every sample of its own output is exact


def _fmu_driver(path, time, values, input_name, output_names, *, peek=False, parameters=None):
    """A sample-by-sample master (fmpy's FMU2Slave): set ``parameters`` (name -> value) before the
    initialization, then per sample set the input, (peek at the outputs), step from t_k by
    t_(k+1) - t_k, read the outputs. Returns the outputs after each step, and the peeked ones."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    description = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in description.modelVariables}
    unzipped = extract(str(path))
    unit = FMU2Slave(
        guid=description.guid,
        unzipDirectory=unzipped,
        modelIdentifier=description.coSimulation.modelIdentifier,
        instanceName="test",
    )
    reals = [vr[n] for n in output_names]
    after, before = np.empty((time.size, len(reals))), np.empty((time.size, len(reals)))
    try:
        unit.instantiate()
        for name, value in (parameters or {}).items():
            unit.setReal([vr[name]], [float(value)])
        unit.setupExperiment(startTime=float(time[0]))
        unit.enterInitializationMode()
        unit.exitInitializationMode()
        for k in range(time.size):
            unit.setReal([vr[input_name]], [float(values[k])])
            if peek:
                before[k] = unit.getReal(reals)
            step = time[k + 1] - time[k] if k + 1 < time.size else time[k] - time[k - 1]
            unit.doStep(currentCommunicationPoint=float(time[k]), communicationStepSize=float(step))
            after[k] = unit.getReal(reals)
        unit.terminate()
        unit.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return after, before


def test_the_units_pass_fmpy_validation_and_simulate_to_the_same_outputs(study_dir, exported):
    """fmpy finds no problem in either unit; fmpy's own simulation of the bundled record (100 Hz) gives
    Model.evaluate (model) and compensate's current (compensator; to 1e-9 up to the first dead band,
    the same output after it: fmpy's time grid, below), each sample one communication step later
    (fmpy reads the outputs before it sets the next input; see docs/use.md);
    a sample-by-sample master on a random drive with uneven steps sees each sample at its own time,
    before the step (direct feedthrough) as after it."""
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    for unit in ("model.fmu", "compensator.fmu"):
        assert validate_fmu(str(exported / unit)) == [], unit
    study = load_study(study_dir)
    bench = load_record(BENCH)
    time, current = bench.time, bench.current
    y = study.model(study.median, time, current)
    step = float(time[1] - time[0])
    signal = np.array(list(zip(time, current)), dtype=[("time", float), ("current", float)])
    simulated = simulate_fmu(str(exported / "model.fmu"), stop_time=time[-1] + step, output_interval=step, input=signal)
    assert simulated.size == time.size + 1
    assert np.abs(simulated["displacement"][1:] - y).max() <= TOLERANCE * np.ptp(y)
    compensation = compensate(study, Target(time, y), n_draws=2)
    signal = np.array(list(zip(time, y)), dtype=[("time", float), ("target", float)])
    simulated = simulate_fmu(
        str(exported / "compensator.fmu"),
        stop_time=time[-1] + step,
        output_interval=step,
        input=signal,
        start_values={"output_scale": _compensate_scale(y)},
    )
    # fmpy steps on its own time grid, up to 1.4e-14 s off the record's times: the thermal node's
    # filter coefficients differ in the last bits, and where the target lies in the dead band after
    # the top peak (the output flat in the current to rounding) that picks another current, one
    # that realises the same output (test_the_compensator_unit_is_compensate: the record's times).
    realised = study.model(study.median, time, simulated["current"][1:])
    python_realised = study.model(study.median, time, compensation.current)
    assert np.abs(realised - python_realised).max() <= 1e-6 * np.ptp(y)
    first = np.flatnonzero(np.abs(simulated["current"][1:] - compensation.current) > TOLERANCE * 5.0)
    assert first.size == 0 or first[0] > np.argmax(time > 10.0), first[:5]  # the same up to that dead band
    assert np.array_equal(simulated["status"][1:], compensation.status)

    time, current = _random_drive(seed=13, n=1500)
    y = study.model(study.median, time, current)
    after, before = _fmu_driver(exported / "model.fmu", time, current, "current", ["displacement"], peek=True)
    assert np.abs(after[:, 0] - y).max() <= TOLERANCE * np.ptp(y)
    assert np.array_equal(before, after)


def test_the_compensator_unit_is_compensate(study_dir, exported):
    """The compensator FMU stepped at the record's times (a sample-by-sample master) with compensate's
    output scale gives compensate's whole current to 1e-9 of the current range (measured: the same
    bits), on the bundled record (through the dead bands of its thermal model) and on a random drive.

    The scale matters: the root find's rounding tolerance is relative to it, and where the target lies
    in a dead band (the output flat in the current to rounding) a tolerance 2 % apart (the unit's
    default, the model's reach, 289.5 um against max |target| 294.9 um) picks another current from
    15.06 s of the record on, one that realises the same output to 2e-7 of the range (docs/use.md)."""
    study = load_study(study_dir)
    bench = load_record(BENCH)
    for time, current in ((bench.time, bench.current), _random_drive(seed=13, n=1500)):
        y = study.model(study.median, time, current)
        compensation = compensate(study, Target(time, y), n_draws=2)
        after, _ = _fmu_driver(
            exported / "compensator.fmu",
            time,
            y,
            "target",
            ["current"],
            parameters={"output_scale": _compensate_scale(y)},
        )
        assert np.abs(after[:, 0] - compensation.current).max() <= TOLERANCE * 5.0


def _compensate_scale(target):
    """The output scale of the root find's rounding tolerance that ``compensate`` takes for ``target``
    (``model.inverse``: max |target|, at least 1); the compensator unit's ``output_scale``."""
    return max(1.0, float(np.abs(target).max()))


def test_closed_loop_the_compensator_unit_drives_the_true_transducer(study_dir, exported):
    """Issue 68's closed loop: the compensator FMU's current for a 60-240 um sine (0.1 Hz, 64 s at
    100 Hz), through the bench's TRUE transducer (data/bench_default.json: Table 1 with thermal):
    tracking RMS < 0.25 % and max < 1 % of the range, as the Python compensate does (docs/use.md)."""
    sidecar = json.loads(BENCH.with_suffix(".json").read_text())
    truth = model.Model.from_dict(sidecar["model"])
    truth_theta = truth.theta_from_dict(sidecar["theta"])
    time = np.arange(6400) / 100.0
    target = 150.0 - 90.0 * np.cos(2.0 * np.pi * 0.1 * time)
    after, _ = _fmu_driver(exported / "compensator.fmu", time, target, "target", ["current", "model_displacement"])
    realised = truth(truth_theta, time, after[:, 0]) - target
    rms, worst = np.sqrt(np.mean(realised**2)) / 180.0, np.abs(realised).max() / 180.0
    assert rms < 0.0025 and worst < 0.01, (rms, worst)
    assert np.abs(after[:, 1] - target).max() < 1e-9 * 240.0  # the median model follows it exactly
    linear = truth(truth_theta, time, np.clip(target / 240.0 * 5.0, 0.0, 5.0)) - target
    assert np.sqrt(np.mean(linear**2)) / 180.0 > 20 * rms  # what compensation buys


def test_a_posterior_draw_is_exported_with_its_values(study_dir, tmp_path):
    out = tmp_path / "draw"
    code, _, stderr = _run(["export", study_dir, "--out", out, "--draw", 3])
    assert code == 0, stderr
    study = load_study(study_dir)
    record = json.loads((out / "export.json").read_text())
    assert record["provenance"]["parameters"] == f"posterior draw 3 of {study.samples.shape[0]}"
    values = {name: entry["value"] for name, entry in record["parameters"].items()}
    assert list(values.values()) == list(study.samples[3])


# -- bad input: one line, exit 2, nothing written ----------------------------------------------
def _refused(argv, out):
    code, stdout, stderr = _run(argv)
    lines = stderr.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, stderr)
    assert not out.exists()
    return lines[0]


def test_a_folder_without_a_finished_study_is_refused(study_dir, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "data.npz is missing" in _refused(["export", empty, "--out", tmp_path / "o1"], tmp_path / "o1")
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    for name in ("data.npz", "fit.json"):
        shutil.copy(study_dir / name, unfinished / name)
    line = _refused(["export", unfinished, "--out", tmp_path / "o2"], tmp_path / "o2")
    assert "not a finished study" in line


def test_an_unknown_draw_is_refused(study_dir, tmp_path):
    n = load_study(study_dir).samples.shape[0]
    line = _refused(["export", study_dir, "--out", tmp_path / "o", "--draw", n], tmp_path / "o")
    assert f"no posterior draw {n}" in line and f"{n} samples" in line


def test_an_effect_that_cannot_be_streamed_is_refused_with_nothing_written(study_dir, tmp_path, monkeypatch):
    """The study's model with incomplete_reset added (as a study of it would have): the command names
    the effect and the reason, exits 2 and writes nothing."""
    study = load_study(study_dir)
    m = study.model + "incomplete_reset"
    median = m.theta_from_dict({**study.model.theta_dict(study.median), "incomplete_reset_strain": 3.0})
    fake = replace(study, fit=SimpleNamespace(model=m), median=median, samples=np.repeat(median[None, :], 4, axis=0))
    monkeypatch.setattr(export_workflow, "load_study", lambda directory: fake)
    line = _refused(["export", study_dir, "--out", tmp_path / "o"], tmp_path / "o")
    assert "incomplete_reset" in line and "record's largest strain excursion" in line
    with pytest.raises(ExportError):
        export(fake, tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_an_out_folder_holding_other_files_is_refused(study_dir, tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "mine.txt").write_text("keep me")
    code, _, stderr = _run(["export", study_dir, "--out", out])
    assert code == 2 and "holds other files" in stderr
    assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]


def test_without_a_compiler_the_c_is_written_and_the_line_says_what_was_tried(study_dir, tmp_path, monkeypatch):
    empty = tmp_path / "bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    monkeypatch.delenv("CC", raising=False)
    out = tmp_path / "o"
    code, _, stderr = _run(["export", study_dir, "--out", out])
    lines = stderr.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: no C compiler found"), stderr
    assert "tried cc, gcc, clang" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == ["c", "export.json"]
    assert json.loads((out / "export.json").read_text())["fmus"] == {}
    assert os.path.exists(out / "c" / "msma_gpi.c")
