"""Name → controller class (see ``cape.registry``): ``@register_controller("name")``."""

from __future__ import annotations

from typing import Any

from cape.registry import Registry

CONTROLLERS: Registry[Any] = Registry(
    "controller",
    {
        "pid": "cape.controllers.pid",
        "rise": "cape.controllers.rise",
        "nmpc": "cape.controllers.nmpc",
        "anmpc": "cape.controllers.anmpc",
        "rnmpc": "cape.controllers.rnmpc",
    },
)
register_controller = CONTROLLERS.register
controller_class = CONTROLLERS.get
