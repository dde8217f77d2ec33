"""Recordings and the outside world: MCAP logging and reading, zenoh publishing.

- :mod:`rtsid.io.schemas` — the JSON payloads (estimate, samples, status, CAN frames) with
  their JSON schemas; one place, documented in ``docs/io.md``.
- :mod:`rtsid.io.mcap_log` — :class:`~rtsid.io.mcap_log.McapLogger`, a writer thread behind a
  bounded queue (never blocks the caller), zstd chunks flushed periodically, rotation.
- :mod:`rtsid.io.mcap_read` — read recordings, including ones that lost their footer, and
  rewrite them as valid files.
- :mod:`rtsid.io.zenoh_link` — :class:`~rtsid.io.zenoh_link.ZenohPublisher`: estimate, status
  and samples keys, a liveliness token and queryables; never raises into the caller.

Submodules are imported on use so that ``import rtsid.io`` stays cheap.
"""
