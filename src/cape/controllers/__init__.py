"""Controllers behind one interface and a registry (SPEC §7)."""

from cape.controllers.registry import controller_class, register_controller

__all__ = ["controller_class", "register_controller"]
