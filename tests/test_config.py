from dataclasses import dataclass

import pytest

from rtsid.config import load_toml, require_choice, require_range, section_from_mapping
from rtsid.errors import ConfigError


@dataclass(frozen=True)
class Section:
    hop_s: float = 0.02
    mode: str = "fast"
    channels: tuple[int, ...] = (1, 2)
    label: str | None = None

    def __post_init__(self) -> None:
        require_range("hop_s", self.hop_s, 0.0, 1.0, low_inclusive=False)
        require_choice("mode", self.mode, ("fast", "slow"))


def test_defaults_and_coercion():
    s = section_from_mapping(Section, {"hop_s": 1, "channels": [3, 4]}, "worker")
    assert s == Section(hop_s=1.0, channels=(3, 4))
    assert section_from_mapping(Section, None, "worker") == Section()


def test_unknown_key_names_section_key_and_accepted_keys():
    with pytest.raises(ConfigError, match=r"worker\.hopp_s.*accepted keys.*hop_s"):
        section_from_mapping(Section, {"hopp_s": 0.1}, "worker")


def test_wrong_type_names_key_value_and_type():
    with pytest.raises(ConfigError, match=r"'worker\.hop_s' = 'fast'.*float"):
        section_from_mapping(Section, {"hop_s": "fast"}, "worker")
    with pytest.raises(ConfigError, match=r"worker\.channels"):
        section_from_mapping(Section, {"channels": ["a"]}, "worker")


def test_range_and_choice_errors_carry_the_section():
    with pytest.raises(ConfigError, match=r"'worker\.hop_s' = 0\.0.*> 0\.0"):
        section_from_mapping(Section, {"hop_s": 0.0}, "worker")
    with pytest.raises(ConfigError, match=r"'worker\.mode' = 'medium'"):
        section_from_mapping(Section, {"mode": "medium"}, "worker")


def test_load_toml_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[worker\nhop_s = 1")
    with pytest.raises(ConfigError, match=r"bad\.toml.*not valid TOML"):
        load_toml(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_toml(tmp_path / "missing.toml")


def test_to_toml_round_trips_nested_tables(tmp_path):
    from rtsid.config import to_toml

    doc = {
        "a": {"x": 1, "y": [1.5, 2.0], "s": 'q"uote', "flag": True, "sub": {"z": "w"}},
        "b": {"none": None, "k": 0.25},
    }
    path = tmp_path / "c.toml"
    path.write_text(to_toml(doc))
    assert load_toml(path) == {"a": doc["a"], "b": {"k": 0.25}}
    assert "# none = (not set)" in path.read_text()


def test_print_config_is_the_full_default_configuration(tmp_path, capsys):
    from rtsid.cli import main
    from rtsid.runtime.daemon import DaemonConfig

    assert main(["run", "--print-config"]) == 0
    path = tmp_path / "full.toml"
    path.write_text(capsys.readouterr().out)
    assert DaemonConfig.load(path) == DaemonConfig()
    assert {"daemon", "link", "plant", "estimator", "worker", "mcap", "zenoh"} <= set(
        load_toml(path)
    )


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_numbers_are_refused_with_the_key(value):
    with pytest.raises(ConfigError, match=r"'worker\.hop_s' = .*finite"):
        section_from_mapping(Section, {"hop_s": value}, "worker")
    with pytest.raises(ConfigError, match=r"'hop_s' = .*finite"):
        require_range("hop_s", value, None, None)


def test_the_shipped_full_config_is_the_printed_defaults(capsys):
    from pathlib import Path

    from rtsid.cli import main

    assert main(["run", "--print-config"]) == 0
    printed = capsys.readouterr().out
    shipped = (Path(__file__).resolve().parents[1] / "hw" / "rtsid.toml").read_text()
    body = "\n".join(line for line in shipped.splitlines()[5:]) + "\n"
    assert body == printed, "hw/rtsid.toml is stale: regenerate it with rtsid run --print-config"


@pytest.mark.parametrize(
    "estimator,key,fix",
    [
        ({"lag_s": 0.15}, "estimator.lag_s", "shorten estimator.lag_s"),
        ({"lowpass_hz": 400.0, "analysis_fs_hz": 500.0}, "estimator.lowpass_hz", "Nyquist"),
        ({"lowpass_hz": 2.0}, "estimator.lowpass_hz", "lengthen worker.window_s"),
    ],
)
def test_an_analysis_no_window_can_hold_is_refused_naming_key_and_fix(estimator, key, fix):
    # Accepted before, these withheld every window as 'too_short' at run time.
    from rtsid.runtime.daemon import DaemonConfig

    with pytest.raises(ConfigError, match=key) as info:
        DaemonConfig.from_mapping({"estimator": estimator})
    assert fix in str(info.value) and "\n" not in str(info.value)
