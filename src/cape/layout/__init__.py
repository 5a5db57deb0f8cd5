"""Every name and path the workflow, the ``cape`` commands and the notebooks share.

- ``cape.layout.names``: folder-safe identifiers, plant names (``PlantName``), the replicate's
  spelling (``rep<r>``);
- ``cape.layout.paths``: the folder and file templates under ``results/``;
- ``cape.layout.runs``: a run's identity (``RunId``) and its folder;
- ``cape.layout.record``: a run's three files, written together and read back checked.

Nothing else spells a path under ``results/`` or parses a plant name; nothing parses a path
to recover what its caller knew.
"""
