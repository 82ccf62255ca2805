"""Render-in-the-loop image sets: `twin render SCENARIO` and `twin render --study`.

Cycles on the CPU renders the *built* packages (their .glb, through Blender's glTF
importer), never the sources. The runtime's own models drive everything: the sun node
(sun.py) gives direction and irradiance, the camera model (camera.py) gives FOV and clip
planes from the zoom, the render node's mapping (nodes.visual_states) gives the pointer
pose and oil-column shape weights from the state.

- sensor:   the phone camera (exposure, white balance, glare, noise) on linear renders
- pinhole:  camera poses, intrinsics, projection, frustum culling
- gauge:    the main-tank dial's geometry and the pointer's mapping
- site:     what a build and site.toml tell the renderer (Site), one frame's inputs (Shot)
- cycles:   the Cycles scene (the only module that touches bpy)
- frames:   rendering a sequence of shots, labels, image and JSON writers
- scenario: `twin render SCENARIO`
- study:    `twin render --study` (its constants in sources/study.toml)
- dataset_config, dataset_plan, dataset, labels: `twin dataset CONFIG`, frames as
            independent tasks, instance masks, depth and COCO from Cycles' own passes
- gauge_reader, baseline: `twin baseline`, the study's gauge reader over a dataset
"""
