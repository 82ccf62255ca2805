"""The pipeline's tasks on the engine: which tasks a set of sources makes (tasks.plan)
and each kind's action: source (read and clean, the only task that needs Blender),
geometry (collision, LOD), asset (the package), terrain, scene, tiles, libs, viewer.
`run` puts them on the engine's scheduler. The engine (pipeline.engine) knows none of
this; this folder imports every stage.
"""
