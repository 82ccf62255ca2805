"""The web viewer and the 3D Tiles of a built scene.

- `page`: build/viewer/: index.html (three.js: the scene .glb with its instances,
  inspection cameras, sun by date and local time, LOD by distance, state variants,
  scenario runs), globe.html (CesiumJS: the tileset on the globe), their data
  (twin.json, the sun table) and the libraries copied from tools/node_modules.
- `tiles`: build/tiles/: an OGC 3D Tiles 1.1 tileset of the same scene.
- `sun_table`: the runtime's ephemeris sampled for the page, and the site's clock.
- `tasks`: the build tasks' actions (builder.tasks declares them).
- `serve`: `twin view`.
"""
