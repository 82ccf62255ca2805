"""One writer module per output format, each exposing `write(asset: ir.Asset,
folder: Path, ...) -> list[str]` and nothing else: collada, sdf, usd, gltf,
thumbnail, textures. `package.WRITERS` maps a format to its writer and
`package.write_package` writes them all into one model folder; `names` and
`manifest` are what the readers of a package share with the writers.

This package imports nothing: the checks and the scene read `names` without loading
a writer's libraries (pycollada, pxr, pillow).
"""
