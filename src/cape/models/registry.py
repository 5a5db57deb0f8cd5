"""Name → learned-model class (see ``cape.registry``): ``@register_model("name")``."""

from __future__ import annotations

from typing import Any

from cape.registry import Registry

MODELS: Registry[Any] = Registry(
    "model", {"dpm": "cape.models.dpm", "ddm": "cape.models.ddm", "epm": "cape.models.epm"}
)
register_model = MODELS.register
model_class = MODELS.get


def build_physics(name: str, spec: dict[str, Any], ts: float) -> Any:
    """The physics of config entry ``name``: its class (``spec['type']`` or ``name``) built
    with ``spec``; an entry that reuses another's class (``ddm_tuned: {type: ddm}``) keeps its
    own name, so its trainings, draws and runs are its own."""
    physics = model_class(name, spec)(spec, ts)
    physics.name = name
    return physics
