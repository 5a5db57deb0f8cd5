"""Deep Pacejka Model (Kim et al. 2022), SPEC §4.1.

Φ = [Bf, Cf, Df, Ef, Br, Cr, Dr, Er, Frx], unbounded (no physics guard). The longitudinal force
is predicted directly, so the model has no throttle path and no drivetrain parameters; no
Sh/Sv offsets; Iz fixed at its known value. Its fixed-parameter variant has no Frx and uses
the drivetrain law with the true Cm1, Cm2, Cr0, Cr2 instead.
"""

from __future__ import annotations

from typing import Any

from cape.models.physics import ModelPhysics
from cape.models.registry import register_model


@register_model("dpm")
class DeepPacejka(ModelPhysics):
    param_names = ("Bf", "Cf", "Df", "Ef", "Br", "Cr", "Dr", "Er", "Frx")
    fixed = ("lf", "lr", "m", "Iz")
    throttle_path = False
    bounded = False

    def equation_terms(self, p: dict[str, Any]) -> dict[str, Any]:
        # the frozen variant replaces the predicted force by the drivetrain law (SPEC §4.5)
        return {"frx": p["Frx"]} if "Frx" in p else {}
