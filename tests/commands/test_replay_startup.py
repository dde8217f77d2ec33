"""What a ``rtsid replay DIR --jobs N`` process imports before its first window."""

from __future__ import annotations

import subprocess
import sys


def _modules_after(code: str) -> set[str]:
    probe = f"{code}; import sys; print(' '.join(sorted(sys.modules)))"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True
    )
    return set(done.stdout.split())


def test_a_replay_childs_preload_imports_the_replay_and_no_scipy():
    # every process of --jobs N pays its preload; scipy.signal was 0.6-1 s of it (it imports
    # scipy.stats), and the designs it was imported for are numpy's or the cache's now
    loaded = _modules_after("from rtsid.commands.replay import _preload; _preload()")
    assert "rtsid.replay" in loaded
    assert not {m for m in loaded if m == "scipy" or m.startswith("scipy.")}
