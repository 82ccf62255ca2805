"""What a camera's image says about the equipment: no Blender here (the architecture
test keeps bpy out of everything this folder reaches).

- metrics:      the study's image metrics C, S and H on a gauge crop (PAPER_NOTES.md)
- gauge:        the one dial model: a dial from its placement's pointer binding (centre,
                normal, radii, the level -> angle map), its rim and box in a frame
- gauge_reader: the study's gauge reader, made to read a dial from any view
- baseline:     `twin baseline`, the reader over a dataset's conditions

Stands on the runtime core (runtime.site) and geometry.pinhole; render, datasets and
the bench use it.
"""
