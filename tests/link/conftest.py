"""Fixtures of the link tests: private virtual channels and a fast plant configuration."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import can
import pytest
from can.interfaces import virtual

from rtsid.link.config import PlantConfig


@pytest.fixture
def channel() -> Iterator[str]:
    """A private python-can ``virtual`` channel; fails the test if a bus on it stays open."""
    name = f"test-{uuid.uuid4().hex[:10]}"
    yield name
    assert name not in virtual.channels, "a virtual bus was left open (bus.shutdown() missing)"


@pytest.fixture
def fast_plant_cfg() -> PlantConfig:
    """Simulated ankle as fast as possible, no diagnostics noise in the counts."""
    return PlantConfig(realtime=False, max_samples=12_000, diagnostics_hz=0.0, block_s=0.1)


def virtual_bus(channel: str, **kwargs: object) -> can.BusABC:
    return can.Bus(interface="virtual", channel=channel, **kwargs)


@pytest.fixture
def vbus():
    """``vbus(channel, **kwargs)`` opens a python-can virtual bus."""
    return virtual_bus
