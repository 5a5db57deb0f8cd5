"""The 1:43 ORCA car: parameters, the single-track equations and their integrators."""

from cape.vehicle.dynamics import (
    drivetrain_force,
    state_derivative,
    tire_forces,
    velocity_derivatives,
)
from cape.vehicle.integrators import INTEGRATORS, euler_step, rk4_step, rkf_step
from cape.vehicle.params import (
    ACTUATOR_LIMITS,
    GRAVITY,
    GROUND_TRUTH,
    ActuatorLimits,
    VehicleParams,
)

__all__ = [
    "ACTUATOR_LIMITS",
    "GRAVITY",
    "GROUND_TRUTH",
    "INTEGRATORS",
    "ActuatorLimits",
    "VehicleParams",
    "drivetrain_force",
    "euler_step",
    "rk4_step",
    "rkf_step",
    "state_derivative",
    "tire_forces",
    "velocity_derivatives",
]
