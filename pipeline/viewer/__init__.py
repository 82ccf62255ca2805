"""The web viewer and the 3D Tiles of a built scene.

- `page`: build/viewer/: index.html (three.js: the scene .glb with its instances,
  inspection cameras, sun by date and local time, LOD by distance, state variants,
  scenario runs), globe.html (CesiumJS: the tileset on the globe), their data
  (twin.json, the sun table); `libs`: the pages' libraries, copied from
  tools/node_modules.
- `tiles`: build/tiles/: an OGC 3D Tiles 1.1 tileset of the same scene; `packs`: one
  model at one LOD level as the tiles store it.
- `sun_table`: the runtime's ephemeris sampled for the page, and the site's clock.
- `serve`: `twin view`; `check`: the pages in a headless browser (tests, the bench).

builder.viewer_task, tiles_task and libs_task hold the build tasks that run them.
"""
