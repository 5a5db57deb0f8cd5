"""Deep Dynamics Model (Chrosniak et al. 2024), SPEC §4.2.

Φ = the 17 parameters of the single-track model (tyres, drivetrain, Iz, offsets), each kept
inside its physical bounds by the guard. Its structure contains the data-generating model.
"""

from __future__ import annotations

from cape.models.physics import ModelPhysics
from cape.models.registry import register_model

DDM_PARAMS = (
    "Bf", "Cf", "Df", "Ef", "Br", "Cr", "Dr", "Er",
    "Cm1", "Cm2", "Cr0", "Cr2", "Iz", "Shf", "Svf", "Shr", "Svr",
)  # fmt: skip


@register_model("ddm")
class DeepDynamics(ModelPhysics):
    param_names = DDM_PARAMS
