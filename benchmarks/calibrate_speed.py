"""Speed of the calibration on the simulated HSR-JR680 (issue 2/3 targets), medians of one run.

    python benchmarks/calibrate_speed.py [--repeats 7] [--process-only]

- LMLC table solve in-process (setup fit and identification done once beforehand), and the same
  residuals and Jacobian solved by scipy.optimize.least_squares (trf, linear loss): median and ratio;
- the whole in-process pipeline (setup fit, identification, robust LMLC, uncertainty, workspace);
- MCS choosing 72 of 200 configurations;
- the whole ``station calibrate`` process (lmlc and mcs-lmlc with the table alone, and lmlc with
  ``--model auto``, the default: terms chosen by cross-validation), interpreter start included;
- responsiveness (issue 15), in the same run: ``station --help``, and ``station calibrate`` on
  210 samples (3 lines; the default ``--model auto``, the table alone, ``--model geometric``, and
  the default without the residual map, ``--no-map``: what the map costs a small session)
  against a bare ``python -c "import numpy, scipy.optimize, scipy.linalg"`` (medians of
  ``--process-repeats`` runs each, interleaved so that the machine's load hits all alike, after an
  untimed run that leaves the byte-code cached); ``--process-only`` runs this part alone. The
  target (issue 26): ``station calibrate`` within 1.4x the bare import, by importing only what the
  command uses (no scipy module at all on the default path: ``calib.kmeans``, numpy's solve in
  the LM step, ``calib.special``'s chi-square tails). The environment is passed on as it is: the
  station sets one BLAS thread for itself (``station.cli.BLAS_THREADS``), the bare import keeps
  OpenBLAS's default, whose threads cost it time on a loaded machine; run it again with
  ``OPENBLAS_NUM_THREADS=1`` to compare both at one thread. Every ``station calibrate`` appends to
  a new history in the run's temporary folder (``$STATION_HISTORY_DB``, unless it is set), as on a
  new station: its ``PRAGMA integrity_check`` grows with the history (about 12 ms at 1,900 records,
  24 MB), which a figure should not inherit from the machine's past runs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from scipy.optimize import least_squares

from calib.calibrate import CalibrationOptions, fit_setup, robust_fit
from sim_fixtures.scenario import write_scenario
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import calibration


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--process-repeats", type=int, default=7)
    parser.add_argument("--process-only", action="store_true", help="only the responsiveness part")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp())
    os.environ.setdefault("STATION_HISTORY_DB", str(folder / "history.sqlite"))
    if args.process_only:
        responsiveness(folder, args.process_repeats)
        return
    sc = write_scenario(folder, seed=0, n_lines=1, n_per_line=200)
    files = load_samples(sc.samples), load_robot(sc.robot), load_setup(sc.setup)
    model = calibration.build_model(*files, str(sc.setup))
    prep = fit_setup(model)
    options = CalibrationOptions(loss="linear")

    def ours():
        return robust_fit(prep.prior, prep.before.x, prep.free, options)[0]

    def scipy_lsq():
        free = prep.free

        def fun(z):
            x = prep.before.x.copy()
            x[free] = z
            return prep.prior.residuals_and_jacobian(x, False)[0]

        def jac(z):
            x = prep.before.x.copy()
            x[free] = z
            return prep.prior.residuals_and_jacobian(x)[1][:, free]

        return least_squares(fun, prep.before.x[free], jac=jac, method="trf", x_scale="jac")

    t_ours, t_scipy = median_time(ours, args.repeats), median_time(scipy_lsq, args.repeats)
    cost_ours, cost_scipy = ours().cost, scipy_lsq().cost
    t_run = median_time(lambda: calibration.calibrate_samples(*files), args.repeats)
    t_mcs = median_time(lambda: calibration.select_measurements(model, 72), args.repeats)
    print("200 samples on one gauge line (simulated HSR-JR680), 2-core machine, medians")
    print(f"| LMLC table solve, in-process | {t_ours * 1e3:.1f} ms | cost {cost_ours:.3f} |")
    print(f"| scipy least_squares (trf), same residuals | {t_scipy * 1e3:.1f} ms | cost {cost_scipy:.3f} |")
    print(f"| ratio scipy / LMLC | {t_scipy / t_ours:.1f}x | |")
    print(f"| whole pipeline in-process (robust, uncertainty, workspace) | {t_run * 1e3:.0f} ms | |")
    print(f"| MCS: 72 of 200 | {t_mcs * 1e3:.0f} ms | |")
    for method, terms in (("lmlc", "geometric"), ("mcs-lmlc", "geometric"), ("lmlc", "auto")):
        cmd = [
            sys.executable,
            "-m",
            "station.cli",
            "calibrate",
            str(sc.samples),
            "--robot",
            str(sc.robot),
            "--setup",
            str(sc.setup),
            "--out",
            str(folder / "c.toml"),
            "--method",
            method,
            "--model",
            terms,
        ]
        t = median_time(lambda cmd=cmd: subprocess.run(cmd, check=True, capture_output=True), 3)
        print(f"| whole `station calibrate --method {method} --model {terms}` process | {t:.2f} s | |")
    responsiveness(folder, args.process_repeats)


def responsiveness(folder: Path, repeats: int) -> None:
    """``station --help`` and ``station calibrate`` on 210 samples against the bare scientific
    imports, each command's runs interleaved with the others'."""
    sc = write_scenario(folder / "three", seed=0, n_lines=3, n_per_line=70)
    station = [sys.executable, "-m", "station.cli"]
    calibrate = [
        *station, "calibrate", str(sc.samples), "--robot", str(sc.robot), "--setup", str(sc.setup),
        "--out", str(folder / "three.toml"),
    ]  # fmt: skip
    commands = {
        "bare": [sys.executable, "-c", "import numpy, scipy.optimize, scipy.linalg"],
        "help": [*station, "--help"],
        "calibrate": calibrate,
        "geometric": [*calibrate, "--model", "geometric"],
        "no-map": [*calibrate, "--no-map"],
    }
    # byte-code cached as for an installed package (pip compiles numpy's and scipy's): a first,
    # untimed run writes it even where PYTHONDONTWRITEBYTECODE is set
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    times: dict[str, list[float]] = {name: [] for name in commands}
    for timed in [False] + [True] * repeats:
        for name, cmd in commands.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True, env=env)
            if timed:
                times[name].append(time.perf_counter() - t0)
    t = {name: statistics.median(v) for name, v in times.items()}
    print(f"medians of {repeats} runs each, interleaved")
    print(f"| `station --help` | {t['help']:.3f} s | <= 0.25 s |")
    print(f"| bare `import numpy, scipy.optimize, scipy.linalg` | {t['bare']:.3f} s | |")
    shown = (("calibrate", "(default: --model auto)"), ("geometric", "--model geometric"))
    for name, what in (*shown, ("no-map", "--no-map")):
        print(f"| `station calibrate {what}` on 210 samples (3 lines) | {t[name]:.3f} s | |")
        print(f"| ratio to the bare import | {t[name] / t['bare']:.2f}x | <= 1.4x |")


if __name__ == "__main__":
    main()
