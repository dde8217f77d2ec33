"""What a ``rtsid replay DIR --jobs N`` process imports before its first window."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


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


def test_a_replay_childs_preload_imports_no_live_machinery():
    # a replay reads a configuration and the status schema's counter names: it needs neither
    # the daemon, the acquisition thread, the virtual plant and its simulation, python-can
    # (asyncio, sqlite3, ssl), the MCAP writer nor the zenoh publisher (2.28 G -> 1.67 G
    # instructions a child's preload took)
    loaded = _modules_after("from rtsid.commands.replay import _preload; _preload()")
    live = {
        "rtsid.runtime.daemon",
        "rtsid.link.acquisition",
        "rtsid.link.open",
        "rtsid.link.plant",
        "rtsid.link.socketcand",
        "rtsid.sim",
        "rtsid.io.mcap_log",
        "rtsid.io.zenoh_link",
        "rtsid.io.history",
        # the CAN mapper, the UDP link and the live worker's stage and stall journals: a
        # default [link.protocol] / [link.udp] is not compiled again to check it, and a
        # replay's evaluator logs no stages (with the two below: a preload 1.72 G -> 1.59 G
        # instructions)
        "rtsid.link.mapping",
        "rtsid.link.udp",
        "rtsid.runtime.stages",
        "rtsid.runtime.stalls",
        # what only some recordings need: the robot's dynamics (a calibration), zip (.npz)
        "rtsid.ident.robot",
        "zipfile",
        # what a replay that writes no file needs none of: the summary table (rtsid summary
        # reads it, -o X.mcap writes it) and tempfile (an atomic write's; importlib.resources
        # imported it for the packaged DBC): with shutil and random, 6 ms a process here
        "rtsid.io.summary_table",
        "tempfile",
        "importlib.resources",
        # the ring buffer: the live worker's, and iter_windows' snapshots (replay_file hands
        # the evaluator the grid's rows)
        "rtsid.link.ring",
        "can",
        "asyncio",
        "sqlite3",
    }
    assert "rtsid.runtime.daemon_config" in loaded
    assert not live & loaded, sorted(live & loaded)


def test_the_moved_configuration_and_counters_are_the_same_objects_under_their_old_names():
    # one definition each: the daemon and the acquisition import them back
    from rtsid.io.mcap_config import McapConfig
    from rtsid.io.mcap_log import McapConfig as logger_config
    from rtsid.io.zenoh_config import ZenohConfig
    from rtsid.io.zenoh_link import ZenohConfig as publisher_config
    from rtsid.link import LinkCounters as lazy_counters
    from rtsid.link.acquisition import LINK_STATES as acquisition_states
    from rtsid.link.acquisition import LinkCounters as acquisition_counters
    from rtsid.link.counters import LINK_STATES, LinkCounters
    from rtsid.runtime.daemon import SECTIONS as daemon_sections
    from rtsid.runtime.daemon import DaemonConfig as daemon_config
    from rtsid.runtime.daemon_config import SECTIONS, DaemonConfig

    assert logger_config is McapConfig and publisher_config is ZenohConfig
    assert acquisition_counters is LinkCounters is lazy_counters
    assert acquisition_states is LINK_STATES
    from rtsid.link.mapping import ANKLE_MAPPING as mapper_mapping
    from rtsid.link.mapping import BUILTIN_DBC as mapper_dbc
    from rtsid.link.protocol import ANKLE_MAPPING, BUILTIN_DBC

    assert mapper_mapping is ANKLE_MAPPING and mapper_dbc is BUILTIN_DBC
    assert daemon_config is DaemonConfig and daemon_sections is SECTIONS


def test_a_replay_reads_a_default_protocol_without_cantools_and_python_can():
    # the recording's [link.protocol] is the default (the built-in ankle protocol): checking
    # it compiled the packaged DBC with cantools, which imports python-can, in every process
    recording = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"
    loaded = _modules_after(
        "from pathlib import Path; from rtsid.replay import replay_file; "
        f"assert replay_file(Path({str(recording)!r})).messages"
    )
    assert "rtsid.replay" in loaded and not {"cantools", "can"} & loaded


def test_a_replays_first_recording_imports_no_masked_arrays():
    # np.median and np.unique import numpy.ma (9 ms) at their first call: every process of
    # replay DIR paid it in its first recording, for its summary row (np.median), its reflex
    # evidence (np.median) and its first reflex fit's grid (np.unique)
    recording = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"
    loaded = _modules_after(
        "import numpy as np; from rtsid.cli import main; "
        f"assert main(['replay', {str(recording)!r}]) == 0; "
        "from rtsid.ident import reflex, reflex_lane; reflex._grid(101, 100.0); "
        "reflex_lane._median_gain(np.array([1.0, -2.0, 3.0]))"
    )
    assert "rtsid.replay" in loaded and "numpy.ma" not in loaded


def test_a_protocol_section_is_checked_unless_it_is_the_default():
    from rtsid.errors import ConfigError
    from rtsid.link.config import ProtocolConfig
    from rtsid.link.mapping import protocol_from_config

    assert ProtocolConfig().is_default() and protocol_from_config(ProtocolConfig()).builtin
    assert not ProtocolConfig(position_sign=-1.0).is_default()
    with pytest.raises(ConfigError, match="NoSuch"):
        ProtocolConfig(position="NoSuch.Signal")


def test_a_udp_layout_is_checked_unless_it_is_the_default():
    from rtsid.errors import ConfigError
    from rtsid.link.config import UdpConfig
    from rtsid.link.udp import compile_layout

    assert UdpConfig().has_default_layout() and compile_layout(UdpConfig()).datagram_bytes > 0
    assert not UdpConfig(byte_order="big").has_default_layout()
    with pytest.raises(ConfigError, match="names a field twice"):
        UdpConfig(fields=("counter", "position", "torque", "torque"))
    with pytest.raises(ConfigError, match="speed"):
        UdpConfig(fields=("counter", "position", "torque", "speed"))
