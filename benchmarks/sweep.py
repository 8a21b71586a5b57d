"""Serial vs local process pool on a 16-run sweep, or on the default compare.

Run: ``python benchmarks/sweep.py [--jobs 2] [--default | --quick] [--repeat 2]``
(``--quick``: a 4-run sweep on tiny meshes, to check the script runs). The
truth is computed into the cache first (a temporary one, or
``$IDBENCH_CACHE_DIR`` with ``--default``, where the 11,664-node truth is worth
keeping), so no timing includes it. Each timing is one ``compare()`` call in a
fresh Python process, as a user's ``idbench compare`` runs (the interpreter
and imports are not timed: the same for both sides), writing to a fresh
results folder so no run is skipped; the two sides alternate ``--repeat``
times and the best of each is reported.
Target: speedup >= 1.8x on 2 cores on the default compare.
Both sides run one BLAS/MKL thread per process (the workers always do), so the
ratio measures the pool, not a thread-count difference. Each try also times
``--jobs`` serial compares side by side (fresh processes, separate folders):
``jobs`` x serial / that time is the bound, what the cores make of ``jobs``
times the work with no pool at all (cores that slow each other down slow
these too); the last line is the pool's share of it.

Measured on an idle 2-core VM (``--default --repeat 4``, two runs): serial
22.2 / 22.6 s, 2 jobs 12.0 / 12.5 s, 1.84 / 1.82x (each try's ratio
1.75-1.87x, medians 1.80 / 1.84x); bound 1.93 / 1.96x (two serial compares
side by side; 1.89-2.01x by try), the pool at 0.93-0.95 of it. With
``IDBENCH_START_METHOD=spawn``: 1.69x, 0.86 of the bound (before workers were
forked: 1.75x, first run 0.9 s after ``compare()``). What bounds it: the
parent plans for 0.75 s before it forks the workers and writes the final
tables for 0.3 s after the last run; the runs, costliest first, pack the two
cores to 0.1 s. Forked workers start with the parent's imports, built models
and probed truths; workers pass each other reference fits and direct runs, and
a free worker skips a run whose inputs another worker is computing.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _timing import one_blas_thread, parser, ratio

from idbench.plan.config import CompareConfig
from idbench.run.compare import plan, prepare
from idbench.run.session import Session

SMALL = {
    "truth_mesh": "40x5x5",
    "meshes": ("14x3x3",),
    "steps": 20,
    "seeds": 4,
    "estimators": ("ro-ukf", "rls", "lms", "batch-ls"),
}

TINY = {
    "truth_mesh": "10x2x2",
    "meshes": ("4x1x1",),
    "steps": 3,
    "seeds": 2,
    "estimators": ("rls", "batch-ls"),
}

CHILD = """
import sys, time
from pathlib import Path
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare
config = CompareConfig(**eval(sys.argv[1]))
start = time.perf_counter()
runs, _ = compare(config, Path(sys.argv[2]), jobs=int(sys.argv[3]))
elapsed = time.perf_counter() - start
bad = runs[~runs["status"].isin(["ok", "skipped"])]
if len(bad):
    raise SystemExit(f"{len(bad)} runs failed:\\n{bad[['run_id', 'error']]}")
print(elapsed)
"""


def timed(config: dict[str, object], out: Path, jobs: int) -> float:
    """Seconds of one ``compare()`` in a fresh process."""
    done = subprocess.run(
        [sys.executable, "-c", CHILD, repr(config), str(out), str(jobs)],
        check=True,
        capture_output=True,
        text=True,
    )
    return float(done.stdout.strip().splitlines()[-1])


def side_by_side(config: dict[str, object], root: Path, n: int) -> float:
    """Mean seconds of ``n`` serial ``compare()`` calls run at once.

    Each in its own fresh process and folder: ``n`` cores doing ``n`` times
    the serial work with nothing shared and no pool, the most a pool of ``n``
    jobs could make of this machine (cores that slow each other down, through
    shared caches or a hypervisor, slow these too).
    """
    children = [
        subprocess.Popen(
            [sys.executable, "-c", CHILD, repr(config), str(root / f"apart{i}"), "1"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(n)
    ]
    times = []
    try:
        for child in children:
            out, err = child.communicate()
            if child.returncode:
                raise SystemExit(f"a serial compare failed:\n{err}")
            times.append(float(out.strip().splitlines()[-1]))
    finally:
        for child in children:  # after a failure: none left running
            child.kill()
            child.wait()
    return sum(times) / n


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    which = ap.add_mutually_exclusive_group()
    which.add_argument(
        "--default", action="store_true", help="the default compare (all defaults)"
    )
    which.add_argument("--quick", action="store_true", help="a 4-run check")
    args = ap.parse_args()
    config: dict[str, object] = {} if args.default else TINY if args.quick else SMALL
    with one_blas_thread(), tempfile.TemporaryDirectory(prefix="idbench-") as tmp:
        root = Path(tmp)
        if not (args.default and os.environ.get("IDBENCH_CACHE_DIR")):
            os.environ["IDBENCH_CACHE_DIR"] = str(root / "cache")
        session = Session()
        the_plan = plan(CompareConfig(**config), session)  # type: ignore[arg-type]
        prepare(the_plan.runs, session)
        print(f"runs: {len(the_plan.runs)}  (truth in the cache)")
        serial, parallel, apart = [], [], []
        for i in range(args.repeat):  # alternating: machine load drifts
            serial.append(timed(config, root / f"serial{i}", 1))
            parallel.append(timed(config, root / f"parallel{i}", args.jobs))
            apart.append(side_by_side(config, root / f"try{i}", args.jobs))
            pair = (
                ratio(serial[-1], parallel[-1]),
                ratio(args.jobs * serial[-1], apart[-1]),
            )
            print(f"  try {i + 1}: serial {serial[-1]:.2f} s, jobs={args.jobs} "
                  f"{parallel[-1]:.2f} s ({pair[0]}); {args.jobs} serial side "
                  f"by side {apart[-1]:.2f} s each (bound {pair[1]})")  # fmt: skip
    speedup = min(serial) / min(parallel)
    bound = args.jobs * min(serial) / min(apart)
    median = ratio(
        statistics.median(s / p for s, p in zip(serial, parallel, strict=True)), 1
    )
    print(f"serial:   {min(serial):.2f} s (best of {args.repeat})")
    print(f"jobs={args.jobs}:   {min(parallel):.2f} s")
    print(f"speedup:  {ratio(speedup, 1)} (each try's: median {median})")
    print(f"bound:    {ratio(bound, 1)} ({args.jobs} serial compares side by side take "
          f"{min(apart):.2f} s each: what {args.jobs} cores make of "
          f"{args.jobs} x the work)")  # fmt: skip
    print(f"speedup / bound: {speedup / bound:.2f}")


if __name__ == "__main__":
    main()
