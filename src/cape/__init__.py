"""CAPE: control algorithm performance evaluation under learned vehicle dynamics models.

The package holds everything the Snakemake workflow computes: the vehicle equations, the
track data and geometry, the training data, and (later) the learned models, plants,
controllers and the study's aggregation. The workflow calls it through the ``cape`` command.
"""

__version__ = "0.1.0"
