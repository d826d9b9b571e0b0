"""The diagnosis on the independent bench: confusion matrix, first names, repairs, time.

Run from the repository root (resumable: rerun the same command after an interruption)::

    python benchmarks/independent_diagnosis.py --out reports/independent            # effects suite
    python benchmarks/independent_diagnosis.py --out reports/independent_clean --suite clean --n 20

1. The independent generator (``benchmarks/independent/generator.py`` of the main
   checkout, written blind to this library; ``--generator`` to point elsewhere) writes
   the suite into ``OUT/records`` (once; each record ``STEM.csv`` + ``STEM.truth.json``).
2. Every record is diagnosed with the command a user runs (``python -m identify diagnose
   STEM.csv --json ...``, a fresh process each); when an effect is named it is added
   (``--effects``) and the record diagnosed again, until ``adequate``, ``unexplained`` or
   ``--rounds`` rounds (default 3). Each record's rounds are written to
   ``OUT/results/STEM.json`` atomically when the record is done, so an interrupted run
   resumes at the first record without a result.
3. Prints (and writes ``OUT/summary.md``) the confusion matrix of the true physics
   (``physics`` of the truth file; the generator's ``first_cycle`` is this library's
   ``incomplete_reset``, and its outside form ``rate_dependent_width`` this library's
   ``rate_width``) against the first verdict, then per physics: first name right,
   final verdict, final RMS / sigma, time; and the issue's targets.

What counts as right (issue 16): a single library physics is named first and, with it
added, the record ends ``adequate`` with RMS within 10 % of sigma; a pair has one of its
two named first and both found one after the other; clean records end ``adequate`` with
nothing named; ``initial_state`` (whose level is an exact reparametrisation of the GPI and
whose prior excursion the GPI may absorb) ends ``adequate`` with nothing named or with
``initial_state`` named, and a record that has it beside another physics may name it too;
``outside`` (physics outside the library) ends ``unexplained`` with nothing named.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's library, also when run from a worktree

from identify.data.fileio import atomic_write

DEFAULT_GENERATOR = Path("/work/main/benchmarks/independent/generator.py")
#: the generator's category names -> this library's effect names
LIBRARY_NAME = {"first_cycle": "incomplete_reset"}
#: the generator's forms of physics it counted outside the library, that the library has since
#: gained -> their effect's name (the generator's "rate_dependent_width", thresholds growing with
#: the input's rate, is ``rate_width``)
LIBRARY_FORM = {"rate_dependent_width": "rate_width"}
#: physics the GPI may absorb (in part an exact reparametrisation): naming it is right, and
#: so is leaving it unnamed when the record ends adequate
OPTIONAL = {"initial_state"}


def generate(
    generator: Path, suite: str, out: Path, seed: int, per_form: int | None, n: int | None, extra: tuple = ()
) -> Path:
    """``out/records``, generated unless it already holds records: those of the same settings
    are reused, and records of other settings are never overwritten (a draw's results are
    scored against them; regenerating another seed over them once mixed two draws)."""
    records = out / "records"
    done = records / ".generated.json"
    settings = {"generator": str(generator), "suite": suite, "seed": seed, "per_form": per_form, "n": n}
    if extra:  # the generator's further options (drives, new forms): part of the draw's settings
        settings["options"] = list(extra)
    if done.exists():
        earlier = json.loads(done.read_text())
        if earlier == settings:
            return records
        raise SystemExit(
            f"error: {records} holds records generated with {earlier}; this run asks for {settings}. "
            "Give the same --seed/--per-form/--n/--suite, or another --out."
        )
    if records.exists() and any(records.glob("*.csv")):
        raise SystemExit(f"error: {records} holds records without {done.name}; give another --out")
    records.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, str(generator), "--suite", suite, "--out", str(records), "--seed", str(seed)]
    if per_form is not None:
        command += ["--per-form", str(per_form)]
    if n is not None:
        command += ["--n", str(n)]
    subprocess.run(command + list(extra), check=True)
    atomic_write(done, json.dumps(settings))
    return records


def diagnose_once(csv: Path, effects: list[str], workdir: Path) -> dict:
    out = workdir / (csv.stem + "." + ("+".join(effects) or "plain") + ".diagnosis.json")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    # workers run side by side: numba's OpenMP threads wait passively between kernel calls,
    # or each diagnosis keeps a core spinning (benchmarks/diagnose.py --side-by-side 2)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    command = [sys.executable, "-m", "identify", "diagnose", str(csv), "--json", str(out), "--quiet"]
    if effects:
        command += ["--effects", ",".join(effects)]
    timing = out.with_suffix(".seconds")
    if out.exists() and timing.exists():  # finished before an interruption: reuse it
        seconds = float(timing.read_text())
        run = None
    else:
        started = time.perf_counter()
        run = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - started
        if run.returncode == 0 and out.exists():
            atomic_write(timing, repr(seconds))
    if run is not None and (run.returncode != 0 or not out.exists()):
        return {
            "effects": effects,
            "status": "error",
            "missing": None,
            "error": (run.stderr or run.stdout)[-2000:],
            "seconds": seconds,
        }
    result = json.loads(out.read_text())
    return {
        "effects": effects,
        "status": result["status"],
        "missing": result["missing"],
        "tied": result.get("tied", []),
        "rms_over_sigma": result["rms"] / result["noise_sigma"],
        "reason": result["reason"],
        "ranking": [
            (c["effect"], c["delta_bic"], c["explained_fraction"], c.get("adequate_after"))
            for c in result["ranking"][:4]
        ],
        "seconds": seconds,
    }


def diagnose_record(csv: Path, rounds: int, workdir: Path) -> list[dict]:
    effects: list[str] = []
    history = []
    for _ in range(rounds):
        one = diagnose_once(csv, effects, workdir)
        history.append(one)
        if one["status"] != "missing_effect" or one["missing"] in effects:
            break
        effects = effects + [one["missing"]]
    return history


def truth_of(csv: Path) -> tuple[list[str], dict]:
    path = csv.with_suffix(".truth.json")
    truth = json.loads(path.read_text()) if path.exists() else {}
    physics = [LIBRARY_NAME.get(p, p) for p in truth.get("physics", []) if p not in ("none", "clean")]
    forms = truth.get("forms", [])
    if physics == ["outside"] and len(forms) == 1 and forms[0] in LIBRARY_FORM:
        physics = [LIBRARY_FORM[forms[0]]]
    return physics, truth


def saved_diagnoses(out: Path):
    """Every diagnosis a run into ``out`` saved, with its record's truth: yields ``(record stem,
    the model's effects as in the file name ("plain" or "a+b"), the diagnosis JSON, the true
    physics in this library's names)``, in file-name order."""
    for path in sorted((out / "work").glob("*.diagnosis.json")):
        stem, model = path.name.split(".")[:2]
        physics, _ = truth_of(out / "records" / f"{stem}.csv")
        yield stem, model, json.loads(path.read_text()), physics


def check_outputs(parser, outs) -> None:
    """Stop ``parser`` with a clear error when a folder of ``outs`` holds no saved diagnoses."""
    for out in outs:
        if not (out / "work").is_dir():
            parser.error(f"{out}: no work/ folder (not an output of benchmarks/independent_diagnosis.py)")


def refitted_singles(diagnosis: dict) -> list[dict]:
    """The ranking entries of ``diagnosis`` (its JSON) for single candidates refitted on the whole record."""
    return [c for c in diagnosis["ranking"] if c.get("refitted") and "+" not in c["effect"]]


def verdict_label(round_result: dict) -> str:
    if round_result["status"] == "missing_effect":
        return round_result["missing"]
    if round_result["status"] == "tied":
        return "tied"
    return round_result["status"]


def score(physics: list[str], history: list[dict]) -> dict:
    """Right or wrong against the diagnosis issue's definitions (module docstring): a name never
    wrong; a tie right when it lists every true effect still missing (among its explanations'
    members) and names nothing wrong; physics outside the library never named."""
    first = verdict_label(history[0])
    final = history[-1]
    named = [h["missing"] for h in history if h["status"] == "missing_effect"]
    nameable = [p for p in physics if p not in OPTIONAL and p != "outside"]
    optional = [p for p in physics if p in OPTIONAL]
    final_rms = final.get("rms_over_sigma", float("nan"))
    tied_members = {n for name in final.get("tied") or [] for n in name.split("+")}
    still_missing = set(nameable) - set(named)
    wrong = [n for n in named if n not in nameable + optional]
    if "outside" in physics:
        kind = "outside"
        first_ok = first in ("unexplained", "tied")
        final_ok = final["status"] in ("unexplained", "tied") and not named
    elif not nameable:
        kind = "clean" if not physics else "initial_state"
        first_ok = first == "adequate" or first in optional
        final_ok = final["status"] == "adequate" and set(named) <= set(optional)
    else:
        kind = "single" if len(nameable) == 1 else "pair"
        first_ok = first in nameable or first in optional
        final_ok = (
            final["status"] == "adequate"
            and set(nameable) <= set(named) <= set(nameable) | set(optional)
            and abs(final_rms - 1.0) <= 0.10
        )
    tie_ok = final["status"] == "tied" and not wrong and bool(still_missing) and still_missing <= tied_members
    return {
        "kind": kind,
        "first": first,
        "first_ok": first_ok,
        "final_ok": final_ok,
        "tie_ok": tie_ok,
        "wrong_first": history[0]["status"] == "missing_effect" and first not in nameable + optional,
        "wrong_names": wrong,
        "named": named,
        "final": verdict_label(final),
        "final_rms_over_sigma": final_rms,
    }


def summarise(results: dict) -> str:
    rows = defaultdict(list)
    for _stem, r in sorted(results.items()):
        rows["+".join(r["physics"]) or "none (clean)"].append(r)
    columns = sorted({r["score"]["first"] for r in results.values()} - {"adequate", "tied", "unexplained", "error"})
    columns += ["adequate", "tied", "unexplained", "error"]
    lines = [
        "| true physics \\ first verdict | "
        + " | ".join(columns)
        + " | first right | ends right | final RMS/sigma (median) | time per record (median) |",
        "|---|" + "---|" * (len(columns) + 4),
    ]
    for label, group in sorted(rows.items()):
        counts = Counter(r["score"]["first"] for r in group)
        rms = sorted(r["score"]["final_rms_over_sigma"] for r in group)
        secs = sorted(sum(h["seconds"] for h in r["history"]) for r in group)
        lines.append(
            f"| {label} | "
            + " | ".join(str(counts.get(c, 0)) for c in columns)
            + f" | {sum(r['score']['first_ok'] for r in group)}/{len(group)} | "
            f"{sum(r['score']['final_ok'] for r in group)}/{len(group)}"
            + f" | {rms[len(rms) // 2]:.3f} | {secs[len(secs) // 2]:.0f} s |"
        )
    by_kind = defaultdict(list)
    for r in results.values():
        by_kind[r["score"]["kind"]].append(r)
    lines.append("")
    targets = {
        "single": ("named first and repaired to adequate (RMS within 10 % of sigma)", ">= 90 %", "final_ok"),
        "pair": ("both found one after the other, then adequate", ">= 80 %", "final_ok"),
        "clean": ("adequate, nothing named", ">= 99 %", "final_ok"),
        "initial_state": ("adequate, nothing named or initial_state named", "-", "final_ok"),
        "outside": ("unexplained, nothing named", "all", "final_ok"),
    }
    for kind, (what, target, key) in targets.items():
        group = by_kind.get(kind, [])
        if group:
            ok = sum(r["score"][key] for r in group)
            lines.append(f"* {kind}: {what}: {ok}/{len(group)} = {100 * ok / len(group):.0f} % (target {target})")
    for kind in ("single", "pair"):
        group = by_kind.get(kind, [])
        if group:
            ties = sum(r["score"].get("tie_ok", False) for r in group)
            lines.append(f"* {kind}: ended tied with every missing true effect listed: {ties}/{len(group)}")
    wrong = [stem for stem, r in results.items() if r["score"].get("wrong_names", r["score"]["wrong_first"])]
    lines.append(
        f"* wrong names (an effect that is not there named, in any round): {len(wrong)}"
        + (f" ({', '.join(wrong)})" if wrong else "")
    )
    total = sum(sum(h["seconds"] for h in r["history"]) for r in results.values())
    lines.append(
        f"* {len(results)} records, {sum(len(r['history']) for r in results.values())} diagnoses, {total / 60:.1f} min"
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--suite", default="effects", choices=("effects", "clean", "all"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--per-form", type=int, default=None, help="the generator's records per single form (its default: 3)"
    )
    parser.add_argument(
        "--n", type=int, default=None, help="the generator's number of clean records (its default: 100)"
    )
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--drive",
        default=None,
        choices=("paper", "holds", "triangle", "mixed"),
        help="the generator's drive (its default: the paper's)",
    )
    parser.add_argument("--new-forms", action="store_true", help="the generator's forms added later")
    parser.add_argument("--generator", type=Path, default=DEFAULT_GENERATOR)
    parser.add_argument("--summary-only", action="store_true", help="only summarise the records diagnosed so far")
    parser.add_argument(
        "--reverse",
        action="store_true",
        help="work from the end of the list (a second worker beside a first one; records are locked)",
    )
    parser.add_argument(
        "--only", default="", help="comma-separated substrings: diagnose only records whose stem contains one"
    )
    args = parser.parse_args(argv)
    if args.summary_only:  # only what is there: never generate
        records = args.out / "records"
        if not records.is_dir():
            raise SystemExit(f"error: no records in {records}")
    else:
        extra = (("--drive", args.drive) if args.drive else ()) + (("--new-forms",) if args.new_forms else ())
        records = generate(args.generator, args.suite, args.out, args.seed, args.per_form, args.n, extra)
    results_dir = args.out / "results"
    work = args.out / "work"
    results_dir.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    csvs = sorted(records.glob("*.csv"))
    # round robin over the physics (the generator writes them grouped), so that an
    # interrupted run has covered every kind of record
    position, seen = {}, Counter()
    for csv in csvs:
        kind = "+".join(truth_of(csv)[0]) or "none"
        position[csv] = (seen[kind], kind)
        seen[kind] += 1
    csvs.sort(key=lambda c: position[c])
    if args.only:
        keys = [k for k in args.only.split(",") if k]
        csvs = [c for c in csvs if any(k in c.stem for k in keys)]
    if args.reverse:
        csvs = csvs[::-1]
    results = {}
    for csv in csvs:
        target = results_dir / (csv.stem + ".json")
        physics, _ = truth_of(csv)
        if target.exists():
            results[csv.stem] = json.loads(target.read_text())
            continue
        if args.summary_only:
            continue
        lock = results_dir / (csv.stem + ".lock")
        try:
            descriptor = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)  # another worker has it
        except FileExistsError:
            continue
        os.close(descriptor)
        history = diagnose_record(csv, args.rounds, work)
        result = {"physics": physics, "history": history, "score": score(physics, history)}
        atomic_write(target, json.dumps(result, indent=1))
        lock.unlink(missing_ok=True)
        results[csv.stem] = result
        s = result["score"]
        print(
            f"{csv.stem:<40} truth {'+'.join(physics) or 'none':<28} -> "
            + " -> ".join(
                verdict_label(h) + (f" ({h['rms_over_sigma']:.3f})" if "rms_over_sigma" in h else "") for h in history
            )
            + f"  [{'ok' if s['final_ok'] else 'tie' if s['tie_ok'] else 'WRONG' if s['wrong_names'] else 'miss'}] "
            f"{sum(h['seconds'] for h in history):.0f} s",
            flush=True,
        )
    text = summarise(results)
    atomic_write(args.out / "summary.md", text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
