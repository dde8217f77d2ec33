"""The ``[mcap]`` config section (:class:`McapConfig`): how the daemon records.

Apart from :mod:`rtsid.io.mcap_log` (the writer thread, which imports it back) so that what
only reads a configuration — a replay, each spawned process of ``rtsid replay DIR --jobs N``
— does not compile and import the writer.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from rtsid.config import invalid, require_range, section_from_mapping

__all__ = ["McapConfig"]


@dataclass(frozen=True)
class McapConfig:
    """The ``[mcap]`` config section.

    Attributes
    ----------
    directory : str
        Where recordings go (created if missing).
    enabled : bool
        False: nothing is written (the logger's methods still accept messages).
    chunk_size : int
        Uncompressed bytes after which a chunk is closed, compressed (zstd) and written.
    flush_interval_s : float
        The open chunk is written and the file flushed at least this often, s. Bounds what a
        SIGKILL loses.
    rotate_size_mb : float
        Start a new file once the current one reaches this size, MiB (0: never).
    rotate_interval_s : float
        Start a new file after this long, s (0: never).
    queue_size : int
        Messages waiting for the writer thread; beyond it messages are dropped and counted.
    log_can_frames : bool
        Also record raw CAN frames (channel ``/can_frames``).
    retry_interval_s : float
        After a write error, try a new file this often, s.
    """

    directory: str = "./recordings"
    enabled: bool = True
    chunk_size: int = 64 * 1024
    flush_interval_s: float = 0.5
    rotate_size_mb: float = 1024.0
    rotate_interval_s: float = 3600.0
    queue_size: int = 4096
    log_can_frames: bool = False
    retry_interval_s: float = 5.0

    def __post_init__(self) -> None:
        require_range("chunk_size", self.chunk_size, 1024, 64 * 1024 * 1024)
        require_range("flush_interval_s", self.flush_interval_s, 0.0, 10.0, low_inclusive=False)
        require_range("rotate_size_mb", self.rotate_size_mb, 0.0)
        require_range("rotate_interval_s", self.rotate_interval_s, 0.0)
        require_range("queue_size", self.queue_size, 16, 1_000_000)
        require_range("retry_interval_s", self.retry_interval_s, 0.0, 3600.0, low_inclusive=False)
        if not self.directory:
            raise invalid("directory", self.directory, "a directory path")

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None) -> McapConfig:
        """Build from the ``[mcap]`` TOML table (unknown keys and bad values rejected)."""
        return section_from_mapping(cls, mapping, "mcap")
