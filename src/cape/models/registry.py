"""Name → learned-model class (see ``cape.registry``): ``@register_model("name")``."""

from __future__ import annotations

from typing import Any

from cape.registry import Registry

MODELS: Registry[Any] = Registry(
    "model", {"dpm": "cape.models.dpm", "ddm": "cape.models.ddm", "epm": "cape.models.epm"}
)
register_model = MODELS.register
model_class = MODELS.get
