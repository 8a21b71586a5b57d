"""Result storage: one part per finished run, consolidated into two tables.

``DIR/parts/<run_id>.runs.parquet`` and ``.traces.parquet`` are written
atomically as each run finishes, so an interrupted sweep keeps every finished
run; :meth:`ResultStore.consolidate` gathers them into ``DIR/runs.parquet`` and
``DIR/traces.parquet``. ``DIR/manifest.json`` records the settings and
versions; reopening a DIR made with other settings is refused.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pandas as pd


class ResultsError(RuntimeError):
    """A results directory cannot be used as asked."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_parquet(df: pd.DataFrame, path: Path) -> None:
    """Write ``df`` as parquet to ``path`` atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".parquet")
    os.close(fd)
    try:
        df.to_parquet(tmp, index=False)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ResultStore:
    """A results directory.

    Parameters
    ----------
    root
        The directory (created if missing).
    settings
        The sweep's settings; must equal those in an existing manifest.
    manifest
        Extra manifest entries (versions, solver backend, threads).
    """

    def __init__(
        self, root: Path, settings: dict[str, Any], manifest: dict[str, Any]
    ) -> None:
        self.root = Path(root)
        self.parts = self.root / "parts"
        mpath = self.root / "manifest.json"
        if mpath.exists():
            try:
                old = json.loads(mpath.read_text())
            except (OSError, ValueError) as exc:
                raise ResultsError(f"{mpath} is unreadable: {exc}") from exc
            if old.get("settings") != _roundtrip(settings):
                raise ResultsError(
                    f"{self.root} holds results of a comparison with other settings; "
                    "use another --out DIR or delete it"
                )
        else:
            body = {**manifest, "settings": settings}
            atomic_write_bytes(mpath, json.dumps(body, indent=2, default=str).encode())
        self.parts.mkdir(parents=True, exist_ok=True)

    def finished(self) -> set[str]:
        """Run ids whose both parts are on disk and readable."""
        done = set()
        for p in self.parts.glob("*.runs.parquet"):
            run_id = p.name.removesuffix(".runs.parquet")
            if (self.parts / f"{run_id}.traces.parquet").exists():
                done.add(run_id)
        return done

    def failed(self) -> set[str]:
        """Run ids stored with status ``failed``.

        A crash, a lost worker or a timeout: a resume tries them again; ok,
        diverged and skipped runs are results and are kept.
        """
        out = set()
        for run_id in self.finished():
            part = pd.read_parquet(
                self.parts / f"{run_id}.runs.parquet", columns=["status"]
            )
            if (part["status"] == "failed").any():
                out.add(run_id)
        return out

    def write(self, run: dict[str, Any], traces: list[dict[str, Any]]) -> None:
        """Store one finished run (traces first, so a run part implies both)."""
        run_id = run["run_id"]
        tr = pd.DataFrame(traces) if traces else pd.DataFrame({"run_id": []})
        atomic_write_parquet(tr, self.parts / f"{run_id}.traces.parquet")
        atomic_write_parquet(pd.DataFrame([run]), self.parts / f"{run_id}.runs.parquet")

    def load(
        self, run_ids: Iterable[str] | None = None
    ) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Read the parts of ``run_ids`` (default: all finished runs)."""
        ids = sorted(self.finished()) if run_ids is None else list(run_ids)
        runs = [pd.read_parquet(self.parts / f"{i}.runs.parquet") for i in ids]
        traces = [pd.read_parquet(self.parts / f"{i}.traces.parquet") for i in ids]
        runs_df = pd.concat(runs, ignore_index=True) if runs else pd.DataFrame()
        traces = [t for t in traces if len(t)]
        traces_df = pd.concat(traces, ignore_index=True) if traces else pd.DataFrame()
        return runs_df, traces_df

    def consolidate(self, order: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Write ``runs.parquet`` and ``traces.parquet`` for the runs in ``order``."""
        done = self.finished()
        ids = [i for i in order if i in done]
        runs, traces = self.load(ids)
        if len(runs):
            runs = runs.set_index("run_id").loc[ids].reset_index()
        atomic_write_parquet(runs, self.root / "runs.parquet")
        atomic_write_parquet(traces, self.root / "traces.parquet")
        return runs, traces


def _roundtrip(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=str))
