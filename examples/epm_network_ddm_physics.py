"""Worked example (docs/extending.md): EPM's network with DDM's physics.

Does the Enhanced Physics Model's gain come from its physics terms (load transfer, actuator
lags) or from its network? This model keeps DDM's single-track physics (the 17 parameters
of SPEC §4.2, inside DDM's bounds) and gives it EPM's network (GRU, trunk, layer norms,
history and training recipe, set in config/examples/epm_network_ddm_physics.yaml). Against
EPM it isolates the physics terms; against DDM, the network. It serves every controller,
the NMPCs included, since its physics reads the inputs as DDM's does.
"""

from __future__ import annotations

from cape.models import register_model
from cape.models.ddm import DeepDynamics


@register_model("epmnet")
class EPMNetworkDDMPhysics(DeepDynamics):
    """DDM's physics; the network is the config entry's (EPM's)."""
