"""Simulated joints built on the identification core's excitation signals."""

from rtsid.sim.joint import (
    JointParameters,
    StiffnessProfile,
    add_noise,
    derivatives,
    robot_servo,
    simulate_admittance,
    simulate_impedance,
)

__all__ = [
    "JointParameters",
    "StiffnessProfile",
    "add_noise",
    "derivatives",
    "robot_servo",
    "simulate_admittance",
    "simulate_impedance",
]
