"""Process start-up: loading MKL for PARDISO, via pypardiso and via our look-up.

``import pypardiso`` builds a solver at import time, which (when
``ctypes.util.find_library`` fails, as in a virtualenv) globs all of
site-packages for ``mkl_rt``; :func:`idbench_fem.fem.solver._mkl` finds it in the
``mkl`` distribution's file list instead. Each is timed in fresh interpreters
(scipy imported first in both, so only the look-up differs), best of
``--repeat``; the ratio is printed.

Run ``python benchmarks/startup.py``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

PRELUDE = "import time, scipy.sparse, scipy.sparse.linalg; t = time.perf_counter(); "
CASES = {
    "pypardiso": PRELUDE + "import pypardiso; lib = pypardiso.PyPardisoSolver().libmkl",
    "idbench": PRELUDE + "from idbench_fem.fem.solver import _mkl; lib = _mkl()",
}
SUFFIX = "; print(time.perf_counter() - t)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    best = {}
    for _ in range(args.repeat):
        for name, code in CASES.items():
            out = subprocess.run(
                [sys.executable, "-c", code + SUFFIX],
                capture_output=True, text=True, check=True,
            )  # fmt: skip
            t = float(out.stdout.strip())
            best[name] = min(best.get(name, t), t)
    for name, t in best.items():
        print(f"{name:10s} {1e3 * t:8.1f} ms to load mkl_rt")
    print(f"ratio {best['pypardiso'] / best['idbench']:.0f}x")


if __name__ == "__main__":
    main()
