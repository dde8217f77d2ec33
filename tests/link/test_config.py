from pathlib import Path

import pytest

from rtsid.errors import ConfigError
from rtsid.link.config import (
    LinkConfig,
    PlantConfig,
    link_configs_from_mapping,
    load_link_configs,
)

HW = Path(__file__).resolve().parents[2] / "hw" / "configs"


@pytest.mark.parametrize("path", sorted(HW.glob("*.toml")), ids=lambda p: p.name)
def test_every_example_config_loads(path):
    link, plant = load_link_configs(path)
    rate = 2000.0 if path.name == "twoframe-plant.toml" else 2500.0  # the second protocol's
    assert link.fs_hz == rate and link.capacity_rows == round(30 * rate)  # 30 s
    assert plant.fs_hz == link.fs_hz


def test_defaults_are_the_embedded_virtual_plant():
    link, plant = link_configs_from_mapping({})
    assert link.interface == "embedded" and link.channel == "rtsid"
    assert plant == PlantConfig() and plant.mode == "sim"
    assert LinkConfig(interface="socketcand").channel == "can0"
    assert LinkConfig(interface="kvaser").channel == 0


@pytest.mark.parametrize(
    ("document", "pattern"),
    [
        ({"link": {"interfce": "pcan"}}, r"unknown config key link\.interfce; accepted keys"),
        ({"link": {"interface": "udp_multicast"}}, r"'link\.interface' = 'udp_multicast'"),
        ({"link": {"fs_hz": "fast"}}, r"'link\.fs_hz' = 'fast'.*float"),
        ({"link": {"stale_after_s": 0}}, r"'link\.stale_after_s' = 0\.0"),
        ({"plant": {"perturbation": "chirp"}}, r"'plant\.perturbation' = 'chirp'.*'prbs'"),
        ({"plant": {"faults": {"drop_rate": 0.9}}}, r"'plant\.faults\.drop_rate' = 0\.9"),
        ({"plant": {"faults": {"dorp_rate": 0.1}}}, r"unknown config key plant\.faults\.dorp_rate"),
        ({"plant": {"faults": 3}}, r"'plant\.faults' = 3.*table"),
        (
            {"plant": {"stiffness_profile": {"kind": "linear", "t1_s": -1.0}}},
            r"'plant\.stiffness_profile\.t1_s' = -1\.0",
        ),
        ({"plant": {"mode": "player"}}, r"'plant\.player_file' = ''"),
        ({"plant": {"fs_hz": 1000.0}}, r"'plant\.fs_hz' = 1000\.0.*link\.fs_hz"),
        (
            {"plant": {"mode": "torque_multisine"}},
            r"'plant\.torque_multisine\.period_s' = 0\.0.*period > 0",
        ),
        (
            {"plant": {"mode": "torque_multisine", "torque_multisine": {"period_s": 1.0001}}},
            r"'plant\.torque_multisine\.period_s' = 1\.0001.*whole number of samples",
        ),
        (
            {"plant": {"torque_multisine": {"every": 0}}},
            r"'plant\.torque_multisine\.every' = 0",
        ),
        (
            {"plant": {"torque_multisine": {"perod_s": 1.0}}},
            r"unknown config key plant\.torque_multisine\.perod_s",
        ),
    ],
)
def test_config_errors_are_one_line_naming_the_key(document, pattern):
    with pytest.raises(ConfigError, match=pattern) as info:
        link_configs_from_mapping(document)
    assert "\n" not in str(info.value)


def test_relative_player_file_is_relative_to_the_config_file(tmp_path):
    (tmp_path / "sub").mkdir()
    cfg = tmp_path / "sub" / "c.toml"
    cfg.write_text('[plant]\nmode = "player"\nplayer_file = "../rec.npz"\n')
    _, plant = load_link_configs(cfg)
    assert Path(plant.player_file).resolve() == (tmp_path / "rec.npz").resolve()
