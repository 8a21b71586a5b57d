"""An output folder's lock follows no link, and a failed start leaves nothing.

A symbolic ``.lock`` is refused (it would have truncated the file it points
to); a start that fails (a full disk, no permission, bad settings) leaves no
empty folder and no lock file behind, and says which path and why; a process
that waited on a lock whose folder was abandoned locks the new one.
"""

from __future__ import annotations

import errno
import os
import threading
from pathlib import Path

import pytest

from idbench.cli.commands import main
from idbench.store import files, lock
from idbench.store.lock import LOCK_NAME

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "5", "--seeds",
        "1", "--estimators", "rls"]  # fmt: skip


def compare(out: Path, *extra: str) -> int:
    return main(["compare", *TINY, "--out", str(out), *extra])


def test_a_symlinked_lock_is_refused_and_its_target_untouched(tmp_path, capsys):
    victim = tmp_path / "precious.txt"
    victim.write_text("my thesis\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).symlink_to(victim)
    assert compare(out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "is a symbolic link" in err and str(out / LOCK_NAME) in err, err
    assert victim.read_text() == "my thesis\n"


def test_a_lock_that_is_no_regular_file_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    (out / LOCK_NAME).mkdir(parents=True)
    assert compare(out) == 2
    assert "is not a regular file" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("code", "words"),
    [
        (errno.ENOSPC, "No space left on device (the disk is full"),
        (errno.EACCES, "Permission denied (no permission to write there"),
    ],
)
def test_a_failed_start_leaves_no_folder_and_names_path_and_cause(
    tmp_path, capsys, monkeypatch, code, words
):
    def full(tmp: Path) -> None:
        raise OSError(code, os.strerror(code))

    real = files.atomic_write

    def failing(path, write):
        return real(path, full if Path(path).name == "manifest.json" else write)

    monkeypatch.setattr(files, "atomic_write", failing)
    out = tmp_path / "new" / "out"
    assert compare(out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert words in err and str(out / "manifest.json") in err, err
    assert not (tmp_path / "new").exists(), sorted(tmp_path.rglob("*"))


def test_bad_settings_leave_no_folder(tmp_path, capsys):
    out = tmp_path / "out"
    assert compare(out, "--estimators", "no-such") == 2
    assert not out.exists()


def test_an_existing_folder_is_kept_after_a_failed_start(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert compare(out, "--estimators", "no-such") == 2
    assert (out / "notes.txt").read_text() == "keep me"


def test_a_waiter_on_an_abandoned_folder_locks_the_new_lock_file(tmp_path):
    folder = tmp_path / "fresh"
    lock.acquire(folder)  # this hold creates the folder
    opened, got = threading.Event(), threading.Event()

    def wait() -> None:  # another thread stands in for another process
        fd = lock._open(folder / LOCK_NAME)  # what a waiter holds open
        opened.set()
        lock._lock(fd)  # blocks until the abandon below unlocks the old file
        got.set()
        assert not lock._still_there(fd, folder / LOCK_NAME)
        os.close(fd)

    waiter = threading.Thread(target=wait)
    waiter.start()
    assert opened.wait(timeout=30)
    lock.abandon(folder)
    waiter.join(timeout=30)
    assert got.is_set()
    assert not folder.exists()
