"""Result storage: one part per finished run, consolidated into two tables.

``DIR/parts/<run_id>.runs.parquet`` and ``.traces.parquet`` are written
atomically as each run finishes, so an interrupted sweep keeps every finished
run; :meth:`ResultStore.consolidate` gathers them into ``DIR/runs.parquet`` and
``DIR/traces.parquet``. ``DIR/manifest.json`` records the settings and
versions; reopening a DIR made with other settings is refused. One process
at a time writes a DIR: a store holds its lock (:mod:`idbench.lock`) from
opening to :meth:`ResultStore.close`.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow.parquet as pq

from idbench import lock
from idbench.files import (
    atomic_write_bytes,
    atomic_write_parquet,
    remove_stale_temporaries,
)

log = logging.getLogger(__name__)

RESUMABLE = ("timeout",)
"""Settings that do not change results: a resume may change them."""

ADDED: dict[str, Any] = {"posterior": False, "posterior_settings": {}}
"""Settings added in later versions, with the value a manifest without them meant."""


BUSY_HINT = "; wait for it (--wait) or use another --out DIR"
"""What a command refused a busy results directory may do instead."""


class ResultsError(RuntimeError):
    """A results directory cannot be used as asked."""


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
    wait
        If another process writes the directory, wait until it is done
        instead of raising :class:`~idbench.lock.FolderBusy`.

    Raises
    ------
    idbench.lock.FolderBusy
        Another process holds the directory (one line naming it).
    ResultsError
        The directory cannot be used (other settings, not writable).

    Notes
    -----
    The store holds the directory's lock until :meth:`close` (or the end of
    a ``with`` block, or of the process). Opening it removes the temporary
    files of writers that are gone (killed mid-write), in the directory and
    in ``parts/``; another live process's are kept.
    """

    def __init__(
        self,
        root: Path,
        settings: dict[str, Any],
        manifest: dict[str, Any],
        *,
        wait: bool = False,
    ) -> None:
        self.root = Path(root)
        self.parts = self.root / "parts"
        self.quarantine = self.root / "quarantine"
        lock_folder(self.root, wait=wait)
        self._open = True
        try:
            self._open_locked(settings, manifest)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Release the directory's lock (idempotent)."""
        if getattr(self, "_open", False):
            self._open = False
            lock.release(self.root)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # a store dropped unclosed
            self.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _open_locked(self, settings: dict[str, Any], manifest: dict[str, Any]) -> None:
        mpath = self.root / "manifest.json"
        if mpath.exists():
            old = _read_manifest(mpath)
            if _results_settings(old["settings"]) != _results_settings(settings):
                raise ResultsError(
                    f"{self.root} holds results of a comparison with other settings; "
                    "use another --out DIR or delete it"
                )
        else:
            body = {**manifest, "settings": settings}
            text = json.dumps(body, indent=2, default=str).encode()
            try:
                atomic_write_bytes(mpath, text)
            except OSError as exc:
                raise ResultsError(f"cannot write to {self.root}: {exc}") from None
        try:
            self.parts.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ResultsError(f"cannot write to {self.root}: {exc}") from None
        removed = remove_stale_temporaries(self.root)
        removed += remove_stale_temporaries(self.parts)
        if removed:
            log.info("removed %d temporary file(s) of an interrupted write", removed)

    def discard_if_unused(self) -> None:
        """Remove this folder's manifest if no run was ever stored in it."""
        if not any(self.parts.iterdir()) and not self.quarantine.exists():
            self.parts.rmdir()
            (self.root / "manifest.json").unlink(missing_ok=True)

    def finished(self) -> set[str]:
        """Run ids whose both parts are on disk and readable.

        A part that is not readable parquet (damaged by a crash or by hand) is
        moved to ``DIR/quarantine/`` with its sibling, with a warning, and its
        run counts as not finished, so it is done again.
        """
        return set(self.scan())

    def scan(self) -> dict[str, bool]:
        """Finished run id -> whether to run it again (failed, or no status).

        See :meth:`finished` for what counts as finished.
        """
        done = {}
        for p in self.parts.glob("*.runs.parquet"):
            run_id = p.name.removesuffix(".runs.parquet")
            tables = self._read(run_id)
            if tables is not None:  # no status column: not ours, run it again
                status = tables[0].get("status", pd.Series(["failed"]))
                done[run_id] = bool((status == "failed").any())
        return done

    def _read(self, run_id: str) -> tuple[pd.DataFrame, pd.DataFrame] | None:
        """Both parts of ``run_id``; None if missing, or unreadable (quarantined)."""
        runs = self.parts / f"{run_id}.runs.parquet"
        traces = self.parts / f"{run_id}.traces.parquet"
        if not (runs.exists() and traces.exists()):
            return None
        try:  # the whole table: a footer can be intact over damaged pages
            return pq.read_table(runs).to_pandas(), pq.read_table(traces).to_pandas()
        except Exception as exc:
            self._quarantine(run_id, exc)
            return None

    def _quarantine(self, run_id: str, exc: Exception) -> None:
        self.quarantine.mkdir(exist_ok=True)
        for kind in ("runs", "traces"):
            part = self.parts / f"{run_id}.{kind}.parquet"
            if part.exists():
                part.replace(self.quarantine / part.name)
        log.warning(
            "run %s: its stored result is unreadable (%s); moved to %s, "
            "running it again",
            run_id,
            exc,
            self.quarantine,
        )

    def failed(self) -> set[str]:
        """Run ids stored with status ``failed``.

        A crash, a lost worker or a timeout: a resume tries them again; ok,
        diverged and skipped runs are results and are kept.
        """
        return {run_id for run_id, failed in self.scan().items() if failed}

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
        """Write ``runs.parquet`` and ``traces.parquet`` for the runs in ``order``.

        Runs not finished (or whose parts are unreadable) are left out.
        """
        parts = [t for t in map(self._read, order) if t is not None]
        runs = _concat([r for r, _ in parts])
        traces = _concat([t for _, t in parts if len(t)])
        atomic_write_parquet(runs, self.root / "runs.parquet")
        atomic_write_parquet(traces, self.root / "traces.parquet")
        return runs, traces


def lock_folder(root: str | Path, *, wait: bool = False) -> None:
    """Take the lock of the results directory ``root`` (see :mod:`idbench.lock`).

    Give it back with :func:`idbench.lock.release`.

    Raises
    ------
    idbench.lock.FolderBusy
        Another process holds it (and ``wait`` is false).
    ResultsError
        ``root`` is no directory path, or cannot be created or written.
    """
    path = Path(root)
    if str(root) == "" or (path.exists() and not path.is_dir()):
        raise ResultsError(f"--out {str(root)!r}: need a directory path")
    try:
        lock.acquire(path, wait=wait, hint=BUSY_HINT)
    except OSError as exc:
        raise ResultsError(f"cannot write to {path}: {exc}") from None


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame:
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _roundtrip(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=str))


def _results_settings(settings: Any) -> Any:
    """The settings that decide the results (``RESUMABLE`` ones left out)."""
    plain = _roundtrip(settings)
    if isinstance(plain, dict):
        for key in RESUMABLE:
            plain.pop(key, None)
        for key, default in ADDED.items():
            if plain.get(key, default) == default:
                plain.pop(key, None)
        for table in ("model_settings", "estimator_settings"):
            # an empty table means the defaults, as no table does
            if isinstance(plain.get(table), dict):
                plain[table] = {k: v for k, v in plain[table].items() if v != {}}
    return plain


def _read_manifest(path: Path) -> dict[str, Any]:
    try:
        body = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ResultsError(
            f"{path} is unreadable ({exc}); use another --out DIR or delete it"
        ) from None
    if not isinstance(body, dict) or not isinstance(body.get("settings"), dict):
        raise ResultsError(
            f"{path} is not an idbench manifest; use another --out DIR or delete it"
        )
    return body
