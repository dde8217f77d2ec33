"""Every config loader under hostile input: arbitrary bytes, binary and non-UTF-8 files,
directories, adversarial TOML values (types, ranges, huge numbers, nested tables, unknown
keys). Only rtsid's own errors may escape (one line on the command line, exit 2), or the
config loads. Issue 20."""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rtsid.cli import main
from rtsid.config import MAX_CONFIG_BYTES, load_toml, to_toml
from rtsid.errors import ConfigError, RtsidError
from rtsid.link.config import load_link_configs
from rtsid.runtime.daemon import SECTIONS, DaemonConfig
from rtsid.runtime.router import load_router_config

HERE = Path(__file__).resolve().parent
REFERENCE = HERE.parent / "replay" / "reference"
FUZZ = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])


def _loaders(path: Path) -> list[Any]:
    return [
        lambda: DaemonConfig.load(path),
        lambda: load_link_configs(path),
        lambda: load_router_config(path),
    ]


def loads_or_refuses(path: Path) -> None:
    """Every loader of a config file either loads it or raises rtsid's own error."""
    for load in _loaders(path):
        try:
            load()
        except RtsidError:
            pass


# ---------------------------------------------------------------------------------- files


@FUZZ
@given(data=st.binary(max_size=512))
@example(data=b"\xff\xfe\x00\x01binary\x80")
@example(data=b"[link]\nhost = '\xe9'\n")
@example(data=b"a = " + b"[" * 5000)
def test_fuzz_arbitrary_bytes_load_or_give_a_config_error(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "c.toml"
    path.write_bytes(data)
    loads_or_refuses(path)


@FUZZ
@given(data=st.data())
def test_fuzz_mutated_valid_config_files(tmp_path: Path, data: st.DataObject) -> None:
    original = (REFERENCE / "record.toml").read_bytes()
    mutated = bytearray(original[: data.draw(st.integers(0, len(original)), label="cut")])
    for _ in range(data.draw(st.integers(0, 4), label="flips")):
        if mutated:
            at = data.draw(st.integers(0, len(mutated) - 1))
            mutated[at] ^= 1 << data.draw(st.integers(0, 7))
    path = tmp_path / "c.toml"
    path.write_bytes(bytes(mutated))
    loads_or_refuses(path)


def test_non_utf8_text_is_one_config_error_naming_the_byte(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes("[zenoh]\nrobot = 'bürste'\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin1\.toml' is not UTF-8 text \(byte 18 is 0xfc\)"):
        load_toml(path)


def test_a_directory_or_an_oversized_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="is a directory; pass the path of a .toml file"):
        load_toml(tmp_path)
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * MAX_CONFIG_BYTES)
    with pytest.raises(ConfigError, match="larger than 1024 KiB"):
        load_toml(big)


# ---------------------------------------------------------------------------------- values

_SCALARS = st.one_of(
    st.booleans(),
    st.integers(),
    st.sampled_from([0, -1, 1, 2**31, 2**63, -(2**63), 10**30, 10**400]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 5e-324, 1e300, -1e300, math.nan, math.inf]),
    st.text(max_size=12),
    st.sampled_from(["", "0.0.0.0", "tcp/[::1]:0", "../x", "\x00", "é" * 300]),
    st.datetimes(),
    st.dates(),
    st.times(),
)
_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)


def _fields(cls: Any) -> dict[str, Any]:
    return {f.name: f.default for f in dataclasses.fields(cls) if f.init}


_DEFAULTS = DaemonConfig()
_KEYS = {name: _fields(type(getattr(_DEFAULTS, name))) for name in SECTIONS}
for _sub in ("faults", "stiffness_profile", "torque_multisine", "reflex"):
    _KEYS[f"plant.{_sub}"] = _fields(type(getattr(_DEFAULTS.plant, _sub)))


@st.composite
def _near_default(draw: st.DrawFn, default: Any) -> Any:
    """A value of the default's type, pushed to edges (zero, negative, tiny, huge)."""
    if isinstance(default, bool):
        return draw(st.booleans())
    if isinstance(default, int):
        return draw(st.sampled_from([0, -1, 1, default * 1000, 2**62, -(2**62), default + 1]))
    if isinstance(default, float):
        return draw(
            st.sampled_from([0.0, -1.0, 1e-9, 1e12, 1e300, default * 1e6, default / 1e6, -default])
        )
    if isinstance(default, str):
        return draw(st.sampled_from(["", "x", "sim", "player", "peer", "client", "router"]))
    return draw(_VALUES)


@st.composite
def documents(draw: st.DrawFn) -> dict[str, Any]:
    """A parsed TOML document: known and unknown sections and keys, hostile values."""
    document: dict[str, Any] = {}
    for section in draw(st.lists(st.sampled_from(sorted(_KEYS)), max_size=4, unique=True)):
        keys = _KEYS[section]
        table: dict[str, Any] = {}
        for key in draw(st.lists(st.sampled_from(sorted(keys)), max_size=4, unique=True)):
            near = _near_default(keys[key])
            table[key] = draw(st.one_of(near, near, _VALUES))
        target = document
        for part in section.split(".")[:-1]:
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                break
        else:
            target[section.split(".")[-1]] = table
    if draw(st.booleans()):
        document[draw(st.text(max_size=8))] = draw(_VALUES)  # unknown section or a bare key
    return document


@given(document=documents())
@example(document={"link": {"options": 5}})
@example(document={"link": 5})
@example(document={"plant": {"faults": [1]}})
@example(document={"worker": {"window_s": 10**400}})
@example(document={"plant": {"fs_hz": 1e300, "block_s": 10.0}})
def test_fuzz_adversarial_documents_give_config_errors(document: dict[str, Any]) -> None:
    try:
        DaemonConfig.from_mapping(document)
    except RtsidError:
        pass


@given(table=st.dictionaries(st.sampled_from(["listen", "config_file", "x"]), _VALUES, max_size=3))
@example(table={"config_file": 5})
def test_fuzz_router_tables_give_config_errors(tmp_path_factory: Any, table: Any) -> None:
    path = tmp_path_factory.mktemp("router") / "router.toml"
    try:
        path.write_text(to_toml({"router": table}))
    except TypeError:  # a value TOML cannot hold (e.g. a datetime): not a file a user writes
        return
    try:
        load_router_config(path)
    except RtsidError:
        pass


def test_link_options_must_be_a_table() -> None:
    with pytest.raises(ConfigError, match=r"'link\.options' = 5 .*a value of type table"):
        DaemonConfig.from_mapping({"link": {"options": 5}})
    assert DaemonConfig.from_mapping({"link": {"options": {"fd": True}}}).link.options == {
        "fd": True
    }


def test_an_integer_beyond_a_float_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"'worker\.window_s' = 1000.* a finite number"):
        DaemonConfig.from_mapping({"worker": {"window_s": 10**400}})


def test_datetimes_are_refused_like_any_wrong_type() -> None:
    with pytest.raises(ConfigError, match=r"'zenoh\.robot'"):
        DaemonConfig.from_mapping({"zenoh": {"robot": dt.datetime(2026, 1, 1)}})


# ---------------------------------------------------------------------------------- commands


def _one_error_line(capsys: pytest.CaptureFixture[str], command: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert "Traceback" not in captured.err + captured.out
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(f"rtsid {command}: error: ")
    return lines[0]


@pytest.mark.parametrize(
    ("command", "args"),
    [
        ("run", []),
        ("plant", []),
        ("router", []),
        ("identify", ["{tmp}/samples.csv"]),
        ("replay", [str(REFERENCE / "sim_3s.mcap")]),
        ("convert", ["{tmp}/samples.csv", "-o", "{tmp}/out.mcap"]),
    ],
)
@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\xff\xfe\x00\x01\x80binary", "is not UTF-8 text"),
        (b"[link]\noptions = 5\n", "'link.options' = 5"),
        (None, "is a directory"),
    ],
)
def test_every_command_refuses_a_bad_config_in_one_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    args: list[str],
    content: bytes | None,
    message: str,
) -> None:
    """Issue 20: a binary config gave a UnicodeDecodeError traceback in run, plant, router,
    identify, replay and convert; `[link] options = 5` a TypeError; a folder IsADirectoryError."""
    if command == "router" and b"link" in (content or b""):
        message = "unknown config section [link]"  # the router reads only [router]
    if command == "identify" and b"link" in (content or b""):  # it reads only [estimator]
        content, message = b"estimator = 5\n", "'estimator' = 5 is not accepted"
    if content is None:
        config = tmp_path / "folder"
        config.mkdir()
    else:
        config = tmp_path / "c.toml"
        config.write_bytes(content)
    (tmp_path / "samples.csv").write_text("t_s,position_rad,torque_nm\n0,0,0\n0.1,0,0\n")
    argv = [command, *(a.format(tmp=tmp_path) for a in args), "--config", str(config)]
    assert main(argv) == 2
    assert message in _one_error_line(capsys, command)
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("port", ["70000", "-1", "65536"])
def test_plant_port_out_of_range_is_one_line(capsys: pytest.CaptureFixture[str], port: str) -> None:
    """Issue 20: `rtsid plant --port 70000` ended in an OverflowError traceback."""
    assert main(["plant", "--port", port]) == 2
    assert f"--port {port} is not a TCP port; pass 0..65535" in _one_error_line(capsys, "plant")
