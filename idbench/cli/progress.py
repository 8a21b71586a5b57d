"""Progress of a comparison on stderr, for a terminal or a log.

Used by ``idbench compare``: :class:`CompareProgress` is the ``progress``
callback of :func:`idbench.run.compare.compare` and listens to the truth's
log (``idbench.truth``: its step records and its cache's warnings) while
truths are simulated.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import Any

from idbench.core.sanitize import printable, rich_markup

log = logging.getLogger("idbench")


class CompareProgress:
    """Progress of a comparison on stderr: truths being simulated, then runs.

    On a terminal: a bar whose label names what is running. Elsewhere (a pipe,
    a log file): one line per truth step and per finished run, at most about
    50 run lines per comparison (every run that is not ok is always shown).
    Truth steps arrive as log records of ``idbench.truth.simulate``, taken
    with its cache's from their parent ``idbench.truth``.

    With ``jobs > 1`` the bar is redrawn on each truth step, finished run
    and :meth:`tick` (about once a second while workers run), not by a thread
    of its own: this process then runs one thread, and its workers can be
    forked from it (:func:`idbench.run.executors.start_method`).
    """

    def __init__(self, runs: list[Any], out: Path, jobs: int, quiet: bool) -> None:
        from rich.console import Console

        self.console = Console(stderr=True)
        self.terminal = self.console.is_terminal
        self.quiet = quiet
        self.order = list(runs)
        parts = out / "parts"
        self.reported = {
            r.run_id for r in runs if (parts / f"{r.run_id}.runs.parquet").exists()
        }
        self.jobs = jobs
        self.every = max(1, -(-len(runs) // 50))
        self.t0 = time.perf_counter()
        self.bar: Any = None
        self.handler = _TruthLog(self)
        self.truth_log = logging.getLogger("idbench.truth")
        self.saved = (self.truth_log.level, self.truth_log.propagate)

    def __enter__(self) -> CompareProgress:
        if self.quiet:
            return self
        from rich.progress import (
            BarColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
            disable=not self.terminal,
            auto_refresh=self.jobs == 1,
        )
        self.bar.__enter__()
        first = self.next_run()
        label = f"preparing truths, then {first}" if first else "preparing"
        self.task = self.bar.add_task(rich_markup(label), total=len(self.order))
        self.truth_log.addHandler(self.handler)
        self.truth_log.setLevel(logging.INFO)
        self.truth_log.propagate = log.getEffectiveLevel() <= logging.INFO
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.__exit__(*exc)
            self.truth_log.removeHandler(self.handler)
            self.truth_log.setLevel(self.saved[0])
            self.truth_log.propagate = self.saved[1]

    def next_run(self) -> str:
        """The run a serial sweep does next (plan order), or "" when none is left."""
        nxt = next((r for r in self.order if r.run_id not in self.reported), None)
        if nxt is None:
            return ""
        return printable(f"{nxt.estimator} {nxt.mesh} {nxt.scenario}")

    def elapsed(self) -> str:
        """Seconds since the comparison started, as text."""
        return f"{time.perf_counter() - self.t0:.0f} s"

    def tick(self) -> None:
        """Redraw the bar (its clock) without a thread: called by the pool."""
        if self.bar is not None and self.jobs > 1:
            self.bar.refresh()

    def truth(self, message: str) -> None:
        """A truth step finished (``message`` from idbench.truth.simulate's log)."""
        if self.bar is None:
            return
        message = printable(message, join_lines=True)
        self.bar.update(
            self.task, description=rich_markup(message), refresh=self.jobs > 1
        )
        if not self.terminal:
            print(f"[{self.elapsed()}] {message}", file=sys.stderr, flush=True)

    def __call__(self, done: int, total: int, row: dict[str, Any]) -> None:
        """A run finished (the ``progress`` callback of :func:`compare`)."""
        self.reported.add(row["run_id"])
        if self.bar is None:
            return
        what = describe_run(row)
        nxt = self.next_run()
        if not nxt:
            running = "done"
        elif self.jobs == 1:
            running = f"running {nxt}"
        else:
            running = f"running on {self.jobs} workers"
        self.bar.update(
            self.task,
            completed=done,
            total=total,
            description=rich_markup(f"runs: {running}"),
            refresh=self.jobs > 1,
        )
        if not self.terminal and (
            done % self.every == 0 or done == total or row["status"] != "ok"
        ):
            print(
                f"[{self.elapsed()}] run {done}/{total} finished: {what}",
                file=sys.stderr,
                flush=True,
            )


class _TruthLog(logging.Handler):
    """Forwards the truth's step records to a :class:`CompareProgress`."""

    def __init__(self, progress: CompareProgress) -> None:
        super().__init__(logging.INFO)
        self.progress = progress

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith("truth "):
            self.progress.truth(message)


def describe_run(row: dict[str, Any]) -> str:
    """A finished run in a few words: estimator, mesh, scenario, axes, status.

    Printable text (:func:`idbench.core.sanitize.printable`): names and the error
    come from plugins.
    """
    parts = [str(row.get(k, "")) for k in ("estimator", "mesh", "scenario")]
    if row.get("observe", "markers") != "markers":
        parts.append(f"observe={row['observe']}")
    for k in ("obs_every", "obs_points", "noise", "seed"):
        if k in row:
            parts.append(
                f"{k}={row[k]:g}" if isinstance(row[k], float) else f"{k}={row[k]}"
            )
    status = row.get("status", "")
    if status != "ok" and row.get("error"):
        status = f"{status} ({str(row['error']).splitlines()[0]})"
    return printable(" ".join(parts) + f": {status}", join_lines=True)
