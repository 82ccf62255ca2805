"""Readers of sources: each returns plain data (an ir.Asset, a floor plan).

- `readers`: READERS, a source file's suffix -> its reader: `blend` (.blend through
  bpy), `cad` (STEP through OpenCASCADE, `tessellate`), `mesh` (STL, OBJ, PLY,
  glTF/GLB, COLLADA through trimesh; `gltf_file`); `units`, `textures` and `images`
  (the files a source names: where they may come from, the image caps, what was opened)
  are theirs.
- `floorplan`: the site's DXF floor plan -> placements and platforms.

This package imports nothing: the scene reads the floor plan without loading the
asset readers' libraries.
"""
