"""Deep Pacejka Model (Kim et al. 2022), SPEC §4.1.

Φ = [Bf, Cf, Df, Ef, Br, Cr, Dr, Er, Frx], unbounded (no physics guard). The longitudinal force
is predicted directly, so the model has no throttle path and no drivetrain parameters; no
Sh/Sv offsets; Iz fixed at its known value.
"""

from __future__ import annotations

from typing import Any

from torch import nn

from cape.models.base import LearnedModel
from cape.models.registry import register_model


@register_model("dpm")
class DeepPacejkaModel(LearnedModel):
    param_names = ("Bf", "Cf", "Df", "Ef", "Br", "Cr", "Dr", "Er", "Frx")
    fixed = ("lf", "lr", "m", "Iz")
    throttle_path = False

    def make_output(self, width: int) -> nn.Module:
        return nn.Linear(width, len(self.param_names))

    def equation_terms(self, p: dict[str, Any]) -> dict[str, Any]:
        return {"frx": p["Frx"]}
