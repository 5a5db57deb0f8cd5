"""Learned vehicle-dynamics models (SPEC §4): DPM, DDM, EPM behind one interface and a registry;
how they are trained is cape.training."""

from cape.models.registry import model_class, register_model

__all__ = ["model_class", "register_model"]
