"""Result storage: one part per finished run, consolidated into two tables.

``DIR/parts/<run_id>.runs.parquet`` and ``.traces.parquet`` are written
atomically as each run finishes, so an interrupted sweep keeps every finished
run; :meth:`ResultStore.consolidate` gathers them into ``DIR/runs.parquet`` and
``DIR/traces.parquet``. ``DIR/manifest.json`` records the settings, the
versions of idbench and of the plugins the runs used, and what each model
read (its ``describe()``, with a digest of each file's content); reopening a
DIR made with other settings, versions or file contents is refused, naming
what differs and both values. A part whose rows name another run than its
file name is quarantined, like an unreadable one. One process
at a time writes a DIR: a store holds its lock (:mod:`idbench.store.lock`) from
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

from idbench.store import lock
from idbench.store.files import (
    atomic_write_bytes,
    atomic_write_parquet,
    describe,
    remove_stale_temporaries,
)

log = logging.getLogger(__name__)

RESUMABLE = ("timeout",)
"""Settings that do not change results: a resume may change them."""

ADDED: dict[str, Any] = {
    "posterior": False,
    "posterior_settings": {},
    "calibration": {},
}
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
        Extra manifest entries (versions, solver backend, threads). Those of
        :data:`CHECKED` that it holds must also equal the existing
        manifest's (see :func:`mismatch`).
    wait
        If another process writes the directory, wait until it is done
        instead of raising :class:`~idbench.store.lock.FolderBusy`.

    Raises
    ------
    idbench.store.lock.FolderBusy
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
        self._open = False
        self._unused = False
        lock_folder(self.root, wait=wait)
        self._open = True
        try:
            self._open_locked(settings, manifest)
        except BaseException:
            self._unused = True
            self.close()
            raise

    def close(self) -> None:
        """Release the directory's lock (idempotent).

        A folder this store created and left unused (a failed start, or
        :meth:`discard_if_unused`) is removed with its lock file.
        """
        if self._open:
            self._open = False
            if self._unused:
                lock.abandon(self.root)
            else:
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
            problem = mismatch(old, {**manifest, "settings": settings})
            if problem:
                raise ResultsError(
                    f"{self.root} {problem}; use another --out DIR or delete it"
                )
        else:
            body = {**manifest, "settings": settings}
            text = json.dumps(body, indent=2, default=str).encode()
            try:
                atomic_write_bytes(mpath, text)
            except OSError as exc:
                where = f"cannot write to {self.root}"
                raise ResultsError(f"{where}: {describe(exc)}") from None
        try:
            self.parts.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            where = f"cannot write to {self.root}"
            raise ResultsError(f"{where}: {describe(exc)}") from None
        removed = remove_stale_temporaries(self.root)
        removed += remove_stale_temporaries(self.parts)
        if removed:
            log.info("removed %d temporary file(s) of an interrupted write", removed)

    def discard_if_unused(self) -> None:
        """Remove this folder's manifest if no run was ever stored in it."""
        if not any(self.parts.iterdir()) and not self.quarantine.exists():
            self.parts.rmdir()
            (self.root / "manifest.json").unlink(missing_ok=True)
            self._unused = True

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
            tables = pq.read_table(runs).to_pandas(), pq.read_table(traces).to_pandas()
        except Exception as exc:
            self._quarantine(run_id, f"is unreadable ({exc})")
            return None
        for kind, table in zip(("runs", "traces"), tables, strict=True):
            if kind == "traces" and not len(table):
                continue
            ids = sorted(map(str, set(table.get("run_id", pd.Series(["(none)"])))))
            if ids != [run_id]:  # copied or moved under another run's name
                self._quarantine(
                    run_id, f"belongs to run {', '.join(ids)} (its {kind} part)"
                )
                return None
        return tables

    def _quarantine(self, run_id: str, why: str) -> None:
        self.quarantine.mkdir(exist_ok=True)
        for kind in ("runs", "traces"):
            part = self.parts / f"{run_id}.{kind}.parquet"
            if part.exists():
                part.replace(self.quarantine / part.name)
        log.warning(
            "run %s: its stored result %s; moved to %s, running it again",
            run_id,
            why,
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
    """Take the lock of the results directory ``root`` (see :mod:`idbench.store.lock`).

    Give it back with :func:`idbench.store.lock.release`.

    Raises
    ------
    idbench.store.lock.FolderBusy
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
        raise ResultsError(f"cannot write to {path}: {describe(exc)}") from None


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


CHECKED = ("plugins", "inputs")
"""Manifest entries a resume must match (beside the settings and idbench's
version), when the caller records them."""


def mismatch(old: dict[str, Any], new: dict[str, Any]) -> str:
    """Why a folder of manifest ``old`` cannot take the runs of ``new`` ("": it can).

    Checked in this order: idbench's version, that ``old`` records the
    :data:`CHECKED` entries ``new`` has, the versions of the plugins both
    used, the settings (:func:`_results_settings`), the plugins used, what
    each model read. The reason names what differs and both values.
    """
    before, now = (m.get("versions", {}).get("idbench") for m in (old, new))
    if "versions" in new and before != now:
        return f"was written by idbench {_show(before)}, now {_show(now)}"
    missing = [key for key in CHECKED if key in new and key not in old]
    if missing:
        return (
            "was written by an idbench that did not record "
            + " and ".join({"plugins": "plugin versions",
                            "inputs": "what its models read"}[k] for k in missing)
        )  # fmt: skip
    plugins = (old.get("plugins") or {}, new.get("plugins") or {})
    for name in sorted(set(plugins[0]) & set(plugins[1])):
        if plugins[0][name] != plugins[1][name]:
            return (
                f"was written with plugin {name!r} {_show(plugins[0][name])}, "
                f"now {_show(plugins[1][name])}"
            )
    diffs = _differences(
        _results_settings(old["settings"]), _results_settings(new["settings"])
    )
    if diffs:
        path, before, now = diffs[0]
        return (
            "holds results of a comparison with other settings: "
            f"{path or 'the settings'} was {_show(before)}, now {_show(now)}"
        )
    for name in sorted(set(plugins[0]) ^ set(plugins[1])):
        before, now = (_show(p[name]) if name in p else "none" for p in plugins)
        return f"was written with plugin {name!r} {before}, now {now}"
    if "inputs" in new:
        return _inputs_difference(old["inputs"], _roundtrip(new["inputs"]))
    return ""


def _inputs_difference(old: Any, new: list[dict[str, Any]]) -> str:
    """The first model whose ``describe()`` differs, naming the key ("": none)."""
    entries = old if isinstance(old, list) else []
    known = {e.get("key"): e for e in entries if isinstance(e, dict)}
    for entry in new:
        what = (
            f"{'truth mesh' if entry['role'] == 'truth' else 'mesh'} "
            f"{entry['mesh']!r} (scenario {entry['scenario']!r})"
        )
        before = known.get(entry["key"])
        if before is None:
            return f"was written without a model of {what}"
        diffs = _differences(before.get("describe"), entry["describe"])
        if diffs:  # a file's content digest first: it says why the rest differs
            diffs.sort(key=lambda d: not (_is_digest(d[1]) or _is_digest(d[2])))
            path, was, now = diffs[0]
            also = f" (also {', '.join(d[0] for d in diffs[1:4])})" if diffs[1:] else ""
            return (
                f"was written with {what} of {path or 'description'} {_show(was)}, "
                f"now {_show(now)}{also}"
            )
    return ""


def _differences(old: Any, new: Any, path: str = "") -> list[tuple[str, Any, Any]]:
    """Every entry where ``old`` and ``new`` differ: path and both values.

    Nested tables are compared entry by entry, in ``new``'s order (then the
    entries only ``old`` has); anything else as a whole.
    """
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in [*new, *(k for k in old if k not in new)]:
            a, b = old.get(key, _UNSET), new.get(key, _UNSET)
            out += _differences(a, b, f"{path}.{key}" if path else str(key))
        return out
    return [] if old == new else [(path, old, new)]


def _is_digest(value: Any) -> bool:
    return isinstance(value, str) and len(value) >= 32 and set(value) <= set(HEX)


_UNSET = object()
HEX = "0123456789abcdef"


def _show(value: Any) -> str:
    """A value for a message: short, digests cut to 12 characters."""
    if value is _UNSET or value is None:
        return "unset" if value is _UNSET else "none"
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    if _is_digest(value):
        return value[:12] + "..."
    return text if len(text) <= 60 else text[:57] + "..."


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
