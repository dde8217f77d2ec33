import os
import struct

import pytest

from rtsid.errors import ConfigError
from rtsid.runtime.power import cpu_latency_request


def open_paths() -> set[str]:
    fds = "/proc/self/fd"
    return {os.path.realpath(os.path.join(fds, fd)) for fd in os.listdir(fds)}


def test_request_is_written_and_held_for_the_block_only(tmp_path):
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    with cpu_latency_request(0, str(device)) as held:
        assert held
        assert struct.unpack("i", device.read_bytes()) == (0,)
        assert str(device) in open_paths()  # the kernel keeps the request while it is open
    assert str(device) not in open_paths()


def test_negative_latency_makes_no_request(tmp_path):
    device = tmp_path / "absent"
    with cpu_latency_request(-1, str(device)) as held:
        assert not held
    assert not device.exists()


def test_unopenable_device_is_a_config_error_naming_the_key_and_the_fix(tmp_path):
    with pytest.raises(ConfigError, match=r"daemon\.cpu_latency_us.*cpu_latency_us = -1"):
        with cpu_latency_request(0, str(tmp_path / "no" / "such" / "device")):
            pass


def fifo(tid: int) -> bool:
    return os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO


def test_every_thread_runs_real_time_for_the_block_only_and_a_refusal_names_the_key(
    monkeypatch,
):
    import threading

    from rtsid.runtime.power import realtime_process

    release = threading.Event()
    thread = threading.Thread(target=release.wait, args=(10,))
    thread.start()
    try:
        tid = thread.native_id
        assert tid is not None
        with realtime_process(0) as raised:  # 0: nothing changes
            assert raised == 0 and not fifo(tid) and not fifo(0)
        try:
            with realtime_process(5) as raised:
                assert raised >= 2 and fifo(tid) and fifo(0)
                assert os.sched_getparam(tid).sched_priority == 5
                assert os.sched_getscheduler(tid) & os.SCHED_RESET_ON_FORK  # children: normal
        except ConfigError:
            pytest.skip("this machine does not allow real-time scheduling (not root)")
        assert not fifo(tid) and not fifo(0)  # given back
    finally:
        release.set()
        thread.join(10)

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with pytest.raises(ConfigError, match=r"daemon\.realtime_priority.*LimitRTPRIO.*= 0"):
        with realtime_process(10):
            pass
