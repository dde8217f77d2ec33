"""The plant's sample sources continue seamlessly across blocks, and the player resamples."""

import numpy as np
import pytest
from scipy import signal

from rtsid.errors import InputDataError
from rtsid.link.config import PlantConfig, StiffnessConfig, TorqueMultisineConfig
from rtsid.link.signals import PlayerSource, SimSource, TorqueMultisineSource, load_recording
from rtsid.sim.joint import JointParameters, robot_servo, simulate_impedance
from rtsid.sim.ltv import simulate_ltv_admittance


@pytest.mark.parametrize("kind", ["prbs", "filtered_noise", "multisine"])
def test_blocks_equal_one_continuous_simulation(kind):
    cfg = PlantConfig(
        perturbation=kind,
        noise_percent=0.0,
        block_s=0.05,
        robot_inertia=0.002,
        stiffness_profile=StiffnessConfig(kind="linear", k0=100.0, k1=300.0, t0_s=0.0, t1_s=0.4),
    )
    source = SimSource(cfg)
    blocks = [source.next_block() for _ in range(8)]
    position = np.concatenate([b.position_rad for b in blocks])
    torque = np.concatenate([b.torque_nm for b in blocks])
    assert [b.first_index for b in blocks] == list(range(0, 8 * 125, 125))
    # the same stream generated at once: the position is smooth (servo output) and the
    # torque is the impedance of that whole position signal, block seams included
    joint = JointParameters(cfg.inertia + cfg.robot_inertia, cfg.damping, 0.0)
    inertial = simulate_impedance(position, cfg.fs_hz, joint)
    k = source.truth.stiffness_at(np.arange(position.size) / cfg.fs_hz)
    interior = slice(4, -4)
    assert np.allclose(torque[interior], (inertial + k * position)[interior], rtol=0, atol=1e-9)
    assert np.max(np.abs(position)) <= cfg.amplitude_rad * 1.2
    assert np.std(position) > 0.2 * cfg.amplitude_rad
    assert blocks[0].discontinuity[0] and not np.any(blocks[1].discontinuity)


def test_streamed_servo_equals_robot_servo():
    cfg = PlantConfig(noise_percent=0.0, block_s=0.02)
    source = SimSource(cfg)
    commands = []
    original = source._perturbation.next

    def spy(n):
        out = original(n)
        commands.append(out)
        return out

    source._perturbation.next = spy
    position = np.concatenate([source.next_block().position_rad for _ in range(10)])
    command = np.concatenate([np.zeros(4), *commands])  # the stream starts 4 samples at rest
    expected = robot_servo(command, cfg.fs_hz, cfg.servo_bandwidth_hz)[: position.size]
    assert np.allclose(position, expected, atol=1e-12)


def test_player_resamples_to_the_bus_rate_and_flags_each_loop(tmp_path):
    fs_file = 1000.0
    t = np.arange(400) / fs_file
    path = tmp_path / "rec.npz"
    np.savez(
        path, position_rad=0.02 * np.sin(2 * np.pi * 5 * t), torque_nm=3 * np.cos(t), fs_hz=fs_file
    )
    cfg = PlantConfig(mode="player", player_file=str(path), block_s=0.1, player_torque_sign=-1.0)
    source = PlayerSource(cfg)
    assert source.position.size == 1000  # 400 samples at 1 kHz -> 1000 at 2.5 kHz
    t_bus = np.arange(1000) / cfg.fs_hz
    inner = slice(50, -50)
    assert np.allclose(
        source.position[inner], 0.02 * np.sin(2 * np.pi * 5 * t_bus)[inner], atol=2e-4
    )
    blocks = [source.next_block() for _ in range(12)]
    flags = np.concatenate([b.discontinuity for b in blocks])
    assert np.flatnonzero(flags).tolist() == [0, 1000, 2000]
    assert np.allclose(source.torque[inner], -3 * np.cos(t_bus)[inner], atol=5e-3)  # sign -1
    assert np.array_equal(blocks[0].torque_nm, source.torque[:250])


def test_player_errors_name_the_file_and_the_fix(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, position_rad=np.zeros(100))
    with pytest.raises(
        InputDataError, match=r"bad\.npz.*lacks torque_nm, fs_hz.*\[plant\] player_file"
    ):
        load_recording(bad, 2500.0)
    with pytest.raises(InputDataError, match="missing.npz.*does not exist"):
        load_recording(tmp_path / "missing.npz", 2500.0)


def test_real_recording_streams(reklab_path):
    position, torque = load_recording(reklab_path, 2500.0)
    assert position.size == torque.size == 150_000
    raw = np.load(reklab_path)
    expected = signal.resample_poly(raw["position_rad"], 5, 2)
    assert np.array_equal(position, expected)


def torque_multisine_plant(**overrides) -> PlantConfig:
    values = {
        "mode": "torque_multisine",
        "block_s": 0.13,  # 325 samples: seams fall mid-period
        "noise_percent": 0.0,
        "robot_inertia": 0.002,
        "torque_multisine": TorqueMultisineConfig(period_s=0.4, f_max_hz=20.0, rms_nm=2.0),
        "stiffness_profile": StiffnessConfig(
            kind="raised_cosine", k0=20.0, k1=150.0, t0_s=0.0, t1_s=2.0
        ),
    }
    return PlantConfig(**{**values, **overrides})


def test_torque_multisine_blocks_equal_one_long_simulation():
    cfg = torque_multisine_plant()
    source = TorqueMultisineSource(cfg)
    blocks = [source.next_block() for _ in range(8)]
    angle = np.concatenate([b.position_rad for b in blocks])
    torque = np.concatenate([b.torque_nm for b in blocks])
    assert [b.first_index for b in blocks] == list(range(0, 8 * 325, 325))
    ms = cfg.torque_multisine.multisine(cfg.fs_hz)
    joint = JointParameters(cfg.inertia + cfg.robot_inertia, cfg.damping, 0.0)
    whole = simulate_ltv_admittance(
        ms.evaluate, cfg.fs_hz, angle.size, joint, source.truth.profile, substeps=1
    )
    np.testing.assert_allclose(angle, whole, rtol=0, atol=1e-12 * np.max(np.abs(whole)))
    # the torque is the multisine from sample 0: whole periods carry only the excited bins
    n = (torque.size // ms.period_samples) * ms.period_samples
    np.testing.assert_allclose(torque[:n], ms.samples(n // ms.period_samples), atol=1e-12)
    assert blocks[0].discontinuity[0] and blocks[0].perturbation_on
    assert np.std(angle) > 1e-3  # 2 N·m rms moves a 20…150 N·m/rad joint by ~0.01 rad


def test_torque_multisine_noise_and_a_later_start():
    quiet = TorqueMultisineSource(torque_multisine_plant()).next_block()
    cfg = torque_multisine_plant(
        noise_percent=1.0,
        position_noise_rad=1e-4,
        torque_multisine=TorqueMultisineConfig(period_s=0.4, rms_nm=2.0, start_index=100),
    )
    source = TorqueMultisineSource(cfg)
    block = source.next_block()
    assert np.std(block.torque_nm[:100]) == pytest.approx(0.02, rel=0.3)  # 1 % of 2 N·m
    assert np.std(block.position_rad[:100]) == pytest.approx(1e-4, rel=0.3)  # at rest + noise
    # from sample 100 on, the same multisine as the plant started at 0, delayed by 100
    np.testing.assert_allclose(block.torque_nm[100:325], quiet.torque_nm[:225], atol=0.1)
    source.apply(source.command)  # commands are accepted and ignored


def test_the_plant_reflex_in_blocks_equals_one_continuous_reflex():
    from rtsid.link.config import ReflexConfig
    from rtsid.sim.joint import derivatives
    from rtsid.sim.reflex import reflex_torque

    reflex = ReflexConfig(enabled=True, gain=12.0, delay_s=0.04)
    cfg = PlantConfig(noise_percent=0.0, block_s=0.05, reflex=reflex)
    source = SimSource(cfg)
    blocks = [source.next_block() for _ in range(20)]
    position = np.concatenate([b.position_rad for b in blocks])
    torque = np.concatenate([b.torque_nm for b in blocks])
    joint = JointParameters(cfg.inertia, cfg.damping, cfg.stiffness)
    # the plant starts at rest: the samples before 0 are at 0 rad
    velocity = derivatives(np.concatenate([np.zeros(4), position]), cfg.fs_hz)[0][4:]
    expected = simulate_impedance(position, cfg.fs_hz, joint) + reflex_torque(
        velocity, cfg.fs_hz, reflex.parameters()
    )
    interior = slice(4, -4)
    assert np.allclose(torque[interior], expected[interior], rtol=0, atol=1e-6)
    reflex_part = torque - simulate_impedance(position, cfg.fs_hz, joint)
    assert np.std(reflex_part[interior]) > 0.05 * np.std(torque)  # the reflex is there
    assert source.truth.reflex == reflex.parameters()


def test_a_plant_reflex_setting_out_of_range_names_the_key():
    from rtsid.errors import ConfigError
    from rtsid.link.config import plant_config_from_mapping

    with pytest.raises(ConfigError, match=r"plant\.reflex.*delay_s"):
        plant_config_from_mapping({"reflex": {"enabled": True, "delay_s": -0.01}})
