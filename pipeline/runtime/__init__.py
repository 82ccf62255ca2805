"""The state graph and what reads the built scene for it (DESIGN.md section 6).

- graph:   the graph of a scenario (nodes, wiring), run in topological order
- nodes:   the node types (oil tank, bushings, sun, camera, render node's mappings)
- camera:  the study's zoom model (FOV, clip planes)
- site:    what a build and site.toml say about the site (Site), one frame's inputs (Shot)
- run:     `twin run SCENARIO`: states over time into OUT/runs/<scenario>/
- apply_usd, apply_gltf, apply_sdf: the appliers that write a run onto the packages

Stands on the sun (pipeline.sun), export's names and geometry's transforms; never on
render, datasets or perception.
"""
