"""Does a calibration recover the operator? (issue 28, point 3; method.md §10)

End to end over zenoh on loopback, as a lab would run it: ``legws operator calibrate
--profile sim --targets 20`` (the daemon in calibration mode on the MuJoCo stand-in, in real
time) with ``legws joystick sim-user`` steering as a simulated operator of known O (a
member of §10's grid; sigma 0.03 m/s; publishing at 50 Hz with continuous-time AR(1) noise,
the robot clipping |u| <= 1). Each run's fitted model and 95 % intervals are compared with
the truth: coverage of each interval, and the error of each estimate, with their medians
over the seeds.

Usage:
    python benchmarks/calibration_recovery.py [--seeds 0,1,2] [--targets 20] [--parallel 2]
        [--out docs/results/calibration_recovery.json] [--work .cache/bench/calibration]
        [--refit]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from legws_daemon.core.operator import OperatorModel
from legws_daemon.formats.operator_file import load_operator

REPO = Path(__file__).resolve().parents[1]
LEGWS = [sys.executable, "-m", "legws_daemon"]
#: Four operators of method.md §10's grid.
TRUTHS = (
    OperatorModel(1.0, 0.03, 0.0, 0.0, "free"),
    OperatorModel(0.6, 0.03, 0.8, 10.0, "free"),
    OperatorModel(1.0, 0.03, 0.5, -20.0, "axes"),
    OperatorModel(0.6, 0.03, 0.0, 0.0, "axes+diagonals"),
)
#: The issue's tolerances on the medians of the estimates.
TOLERANCE = {"rho": ("abs", 0.05), "sigma": ("rel", 0.10), "bias_deg": ("abs", 3.0),
             "speed": ("abs", 0.05)}  # fmt: skip


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def key(op: OperatorModel) -> str:
    return f"s{op.speed:g}_r{op.rho:g}_b{op.bias_deg:+g}_{op.steering}"


def run_one(
    truth: OperatorModel, seed: int, targets: int, work: Path, refit: bool = False
) -> dict[str, Any]:
    """One calibration of ``truth`` over loopback zenoh; the fit against the truth.
    ``refit``: a calibration done before is fitted again from its trace with this code
    (``legws operator fit``, the seed and resamples ``calibrate`` uses: the file it would
    write now)."""
    folder = work / f"{key(truth)}_seed{seed}"
    out = folder / "operator.json"
    traces = sorted(folder.glob("*.trace.jsonl"))
    if refit and traces and (folder / "result.json").is_file():
        before = json.loads((folder / "result.json").read_text())
        subprocess.run(
            [*LEGWS, "operator", "fit", str(traces[0]), "--out", str(out), "--name",
             key(truth).replace("+", "p"), "--profile", str(folder / "sim.toml"), "--seed",
             str(seed)],
            check=True, capture_output=True,
        )  # fmt: skip
        return _result(truth, seed, before["seconds"], out, folder)
    if out.is_file() and (folder / "result.json").is_file():
        return dict(json.loads((folder / "result.json").read_text()))
    folder.mkdir(parents=True, exist_ok=True)
    port = free_port()
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    profile = folder / "sim.toml"
    profile.write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}"))
    env = dict(os.environ, CI="true", PYTHONUNBUFFERED="1")
    started = time.monotonic()
    with (folder / "calibrate.log").open("wb") as log:
        calibrate = subprocess.Popen(
            [*LEGWS, "operator", "calibrate", "--profile", str(profile), "--targets",
             str(targets), "--seed", str(seed), "--out", str(out), "--name",
             key(truth).replace("+", "p")],
            stdout=log, stderr=subprocess.STDOUT, env=env,
        )  # fmt: skip
        try:
            with (folder / "sim-user.log").open("wb") as user_log:
                subprocess.run(
                    [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--sigma",
                     str(truth.sigma), "--speed", str(truth.speed), "--rho", str(truth.rho),
                     "--bias", str(truth.bias_deg), "--steering", truth.steering, "--rate", "50",
                     "--seed", str(1000 + seed), "--duration", str(40 * targets)],
                    stdout=user_log, stderr=subprocess.STDOUT, env=env, check=False,
                    timeout=60 * targets,
                )  # fmt: skip
            code = calibrate.wait(120)
        finally:
            if calibrate.poll() is None:
                calibrate.terminate()
                calibrate.wait(10)
    if code != 0 or not out.is_file():
        raise RuntimeError(f"calibrate exited {code}: {(folder / 'calibrate.log').read_text()}")
    return _result(truth, seed, time.monotonic() - started, out, folder)


def _result(
    truth: OperatorModel, seed: int, seconds: float, out: Path, folder: Path
) -> dict[str, Any]:
    fit = load_operator(out)
    result = {
        "truth": truth.as_dict(),
        "seed": seed,
        "seconds": seconds,
        "fitted": fit.fitted.as_dict(),
        "intervals": {k: list(v) for k, v in fit.intervals.items()},
        "certify_with": fit.certify_with.as_dict(),
        "covered": {k: lo <= getattr(truth, k) <= hi for k, (lo, hi) in fit.intervals.items()},
        "steering_right": fit.fitted.steering == truth.steering,
        "segments": fit.segments,
        "ticks": fit.ticks,
    }
    (folder / "result.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for truth in TRUTHS:
        rows = [r for r in results if r["truth"] == truth.as_dict()]
        if not rows:
            continue
        entry: dict[str, Any] = {"runs": len(rows), "steering_right": sum(r["steering_right"]
                                 for r in rows)}  # fmt: skip
        for k, (kind, tol) in TOLERANCE.items():
            median = statistics.median(r["fitted"][k] for r in rows)
            true = getattr(truth, k)
            error = median - true
            ok = abs(error) <= (tol * true if kind == "rel" else tol)
            entry[k] = {"median": median, "truth": true, "error": error, "within": ok,
                        "covered": sum(r["covered"][k] for r in rows)}  # fmt: skip
        out[key(truth)] = entry
    return out


def markdown(results: list[dict[str, Any]], summ: dict[str, Any]) -> str:
    lines = [
        "| true operator | runs | steering right | speed: median (covered) | sigma m/s | rho "
        "| bias ° |",
        "|---|---|---|---|---|---|---|",
    ]
    for truth in TRUTHS:
        e = summ.get(key(truth))
        if e is None:
            continue

        def cell(k: str, digits: int, e: dict[str, Any] = e) -> str:
            v = e[k]
            mark = "" if v["within"] else " **(off)**"
            return f"{v['median']:.{digits}f}{mark} ({v['covered']}/{e['runs']})"

        lines.append(
            f"| {truth.describe()} | {e['runs']} | {e['steering_right']}/{e['runs']} | "
            f"{cell('speed', 2)} | {cell('sigma', 4)} | {cell('rho', 2)} | {cell('bias_deg', 1)} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--parallel", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("docs/results/calibration_recovery.json"))
    ap.add_argument("--work", type=Path, default=Path(".cache/bench/calibration"))
    ap.add_argument(
        "--refit", action="store_true",
        help="fit the calibrations done before again from their traces (this code's fit)",
    )  # fmt: skip
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    jobs = [(t, s) for t in TRUTHS for s in seeds]
    with ThreadPoolExecutor(args.parallel) as pool:
        results = list(
            pool.map(lambda j: run_one(j[0], j[1], args.targets, args.work, args.refit), jobs)
        )
    summ = summary(results)
    args.out.write_text(json.dumps({"targets": args.targets, "seeds": seeds, "runs": results,
                                    "summary": summ}, indent=1) + "\n")  # fmt: skip
    text = markdown(results, summ)
    args.out.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
