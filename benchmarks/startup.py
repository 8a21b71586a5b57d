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

import subprocess
import sys

from _timing import one_blas_thread, parser, ratio

PRELUDE = "import time, scipy.sparse, scipy.sparse.linalg; t = time.perf_counter(); "
CASES = {
    "pypardiso": PRELUDE + "import pypardiso; lib = pypardiso.PyPardisoSolver().libmkl",
    "idbench": PRELUDE + "from idbench_fem.fem.solver import _mkl; lib = _mkl()",
}
SUFFIX = "; print(time.perf_counter() - t)"


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    best = {}
    with one_blas_thread():  # as in the other benchmarks (the children inherit it)
        for _ in range(args.repeat):
            for name, code in CASES.items():
                out = subprocess.run(
                    [sys.executable, "-c", code + SUFFIX],
                    capture_output=True, text=True, check=True,
                )  # fmt: skip
                t = float(out.stdout.strip())  # the child's own clock: no start-up
                best[name] = min(best.get(name, t), t)
    for name, t in best.items():
        print(f"{name:10s} {1e3 * t:8.1f} ms to load mkl_rt")
    print(f"ratio {ratio(best['pypardiso'], best['idbench'], 0)}")


if __name__ == "__main__":
    main()
