"""Shared fixtures: every test must stop the threads it starts."""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as the CLI does; before numpy is imported

import atexit  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

# The filter design cache (rtsid.ident.designs) of this test run: a fresh folder, removed at
# exit, so the tests never write into the user's ~/.cache and start from a cold cache each run
# (the spawned processes of the tests inherit it).
_DESIGN_CACHE = tempfile.mkdtemp(prefix="rtsid-test-designs-")
os.environ.setdefault("RTSID_DESIGN_CACHE", _DESIGN_CACHE)
atexit.register(shutil.rmtree, _DESIGN_CACHE, ignore_errors=True)

import socket  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# Property-based (fuzz) tests: a small fixed budget in CI ("ci"), a long one for a nightly-style
# run: RTSID_HYPOTHESIS_PROFILE=nightly python -m pytest tests -k fuzz (see docs/io.md), or
# pytest --hypothesis-profile nightly. register_profile replaces a profile of the same name.
settings.register_profile("ci", max_examples=50, deadline=None)
settings.register_profile("nightly", max_examples=2000, deadline=None)
settings.load_profile(os.environ.get("RTSID_HYPOTHESIS_PROFILE", "ci"))

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
REKLAB = SHARED_DATA / "reklab_ankle_z.npz"


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    """Fail a test that leaves a thread it started running."""
    before = set(threading.enumerate())
    yield
    leaked = []
    for thread in set(threading.enumerate()) - before:
        thread.join(timeout=5.0)
        if thread.is_alive():
            leaked.append(thread.name)
    assert not leaked, f"threads left running by the test: {leaked}"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def reklab_path() -> Path:
    """The real ankle recording in ../shared/data (skipped with a reason when absent)."""
    if not REKLAB.exists():
        pytest.skip(f"reference recording not found at {REKLAB} (clone with ../shared beside it)")
    return REKLAB


@pytest.fixture
def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_for(predicate: Callable[[], object], timeout_s: float = 10.0, what: str = "it") -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"{what} did not happen within {timeout_s} s"
        time.sleep(0.01)


@pytest.fixture
def wait_for() -> Callable[..., None]:
    """``wait_for(predicate, timeout_s, what)``: poll every 10 ms, fail after the timeout."""
    return _wait_for
