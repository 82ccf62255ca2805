"""The renderer and `twin render`: Cycles on the CPU renders the *built* packages (their
.glb, through Blender's glTF importer), never the sources. The runtime's own models
drive it: the sun (pipeline.sun) gives direction and irradiance, the camera model
(runtime.camera) FOV and clip planes from the zoom, the render node's mapping
(runtime.nodes.visual_states) the pointer pose and the oil column's shape weights.

- sensor:   the phone camera (exposure, white balance, glare, noise) on linear renders
- cycles:   the Cycles scene (the only module here that touches bpy)
- frames:   rendering a sequence of shots, their labels, image and JSON writers
- scenario: `twin render SCENARIO`
- study:    `twin render --study` (its constants in SOURCES/study.toml)

Uses the runtime core (runtime.site, runtime.camera), perception (the image metrics,
the dial) and geometry.pinhole; used by datasets and the bench.
"""
