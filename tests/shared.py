"""What a test run makes once for all its pytest-xdist workers: a clone, a build.

`once(factory, name, make)` runs `make(directory)` in the first worker that asks, under a
file lock in the run's temporary directory (the one every worker's `tmp_path_factory`
lives in), and hands every later caller in any worker what it returned (pickled), or the
skip or error it ended with, without running it again.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")


def run_dir(factory: pytest.TempPathFactory) -> Path:
    """The temporary directory of this test run, shared by its xdist workers."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextmanager
def locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on `path` (created if need be)."""
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def once(factory: pytest.TempPathFactory, name: str, make: Callable[[Path], T]) -> T:
    """`make(directory)`'s result, made by the first caller of this run and kept for the
    rest; a skip or an error is handed on as such."""
    directory = run_dir(factory) / name
    outcome_file = directory.with_name(f"{name}.outcome")
    with locked(directory.with_name(f"{name}.lock")):
        if not outcome_file.exists():
            shutil.rmtree(directory, ignore_errors=True)  # what a killed worker left
            directory.mkdir(parents=True)
            try:
                outcome: tuple[str, object] = ("made", make(directory))
            except pytest.skip.Exception as skipped:
                outcome = ("skipped", skipped.msg)
            except Exception as exc:
                outcome = ("failed", f"{type(exc).__name__}: {exc}")
                outcome_file.write_bytes(pickle.dumps(outcome))
                raise
            outcome_file.write_bytes(pickle.dumps(outcome))
        else:
            outcome = pickle.loads(outcome_file.read_bytes())
    kind, value = outcome
    if kind == "skipped":
        pytest.skip(str(value))
    if kind == "failed":
        raise RuntimeError(f"{name} failed in another worker of this run: {value}")
    return value  # type: ignore[return-value]
