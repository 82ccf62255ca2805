"""thumbnail.png of a model package: a small headless render without Blender.

A pure-numpy z-buffer rasteriser draws the asset's triangles under a fixed 3/4 view
(orthographic, from the front-right and above: the front faces -Y), Lambert-shaded in
each visual's base colour on a white background. It is deterministic: no randomness,
stable sorts, and a PNG without metadata, so a rerun writes the same bytes.

Cost: triangles are rasterised all at once by their pixel bounding boxes (one numpy
pass over every candidate pixel centre, in bounded chunks); an asset heavier than
`MAX_TRIANGLES` at LOD0 is drawn from its coarsest LOD, which a 256 px image cannot
tell apart.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import ir
from ..files import atomic_write

FILE = "thumbnail.png"
# Above this many LOD0 triangles the coarsest LOD is drawn instead (if there is one).
MAX_TRIANGLES = 150_000
# View: azimuth from -Y towards +X, elevation above the horizon (radians).
AZIMUTH = np.radians(35.0)
ELEVATION = np.radians(25.0)
MARGIN = 0.06  # of the image size, on each side
AMBIENT = 0.3
# Visuals more transparent than this are skipped: a gauge's glass must not hide its dial.
MIN_ALPHA = 0.5
# Candidate pixel samples processed per numpy pass (bounds memory to ~100 MB).
CHUNK = 1 << 21
SUPERSAMPLE = 2
# Above this many drawn triangles the image is not supersampled (speed: 4x samples).
MAX_SUPERSAMPLED = 60_000
DEPTH_LEVELS = 1 << 30


def write(asset: ir.Asset, folder: Path, size: int = 256) -> list[str]:
    """Render `asset` to folder/thumbnail.png (size x size RGB); returns the names
    written, relative to `folder`."""
    atomic_write(Path(folder) / FILE, _png_bytes(render(asset, size)))
    return [FILE]


def render(asset: ir.Asset, size: int = 256) -> np.ndarray:
    """(size, size, 3) uint8 sRGB image of the asset."""
    triangles, colors, texturing = scene_triangles(asset)
    # Supersample (anti-alias) unless the drawn mesh is still heavy: then its pixels
    # are mostly sub-triangle detail anyway, and 4x the samples would cost ~4x.
    ss = SUPERSAMPLE if len(triangles) <= MAX_SUPERSAMPLED else 1
    linear = rasterise(triangles, colors, size * ss, view_basis(), texturing)
    # Box-filter the supersampled image, then encode sRGB.
    linear = linear.reshape(size, ss, size, ss, 3).mean(axis=(1, 3))
    return _to_srgb8(linear)


def view_basis() -> np.ndarray:
    """(3, 3) rows: screen right, screen up, towards the camera (model frame)."""
    toward = np.array([np.sin(AZIMUTH) * np.cos(ELEVATION), -np.cos(AZIMUTH) * np.cos(ELEVATION), np.sin(ELEVATION)])
    right = np.cross(-toward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -toward)
    return np.stack([right, up, toward])


@dataclass(frozen=True)
class Texturing:
    """Base-colour images of the drawn triangles: uvs (m, 3, 2) per corner (NaN where a
    triangle has none), image (m,) index into images or -1, images: linear RGB
    (h, w, 3) float arrays, each already multiplied by its material's base colour."""

    uvs: np.ndarray
    image: np.ndarray
    images: tuple[np.ndarray, ...]


def scene_triangles(asset: ir.Asset) -> tuple[np.ndarray, np.ndarray, Texturing]:
    """All drawn triangles in the model frame, their linear RGB colours and textures.

    Returns triangles: (m, 3, 3) float64, colors: (m, 3) float64, and the Texturing."""
    level = 0
    if asset.triangle_count(0) > MAX_TRIANGLES:
        level = asset.lod_count - 1
    materials = {m.name: m for m in asset.materials}
    tris, cols, uvs, which = [], [], [], []
    images: dict[str, int] = {}
    decoded: list[np.ndarray] = []
    for link, visual in asset.visuals():
        mat = materials.get(visual.material, ir.Material(visual.material))
        if mat.alpha < MIN_ALPHA:
            continue
        mesh = visual.lod(level)
        if mesh.triangle_count == 0:
            continue
        m = link.pose @ visual.pose
        v = mesh.vertices @ m[:3, :3].T + m[:3, 3]
        tris.append(v[mesh.faces])
        color = np.clip(np.array(mat.base_color[:3]) + np.array(mat.emission), 0.0, 1.0)
        cols.append(np.broadcast_to(color, (mesh.triangle_count, 3)))
        texture = mat.base_color_texture
        if texture is not None and mesh.uvs is not None:
            key = f"{texture.digest}:{color.tolist()}"
            if key not in images:
                images[key] = len(decoded)
                decoded.append(_linear_image(texture.data) * color)
            uvs.append(mesh.uvs[mesh.faces])
            which.append(np.full(mesh.triangle_count, images[key]))
        else:
            uvs.append(np.full((mesh.triangle_count, 3, 2), np.nan))
            which.append(np.full(mesh.triangle_count, -1))
    if not tris:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), Texturing(np.zeros((0, 3, 2)), np.zeros(0, int), ())
    return (np.concatenate(tris), np.concatenate(cols),
            Texturing(np.concatenate(uvs), np.concatenate(which), tuple(decoded)))


def _linear_image(data: bytes) -> np.ndarray:
    """(h, w, 3) linear RGB of a PNG or JPEG (sRGB encoded, as base colour maps are)."""
    from PIL import Image

    srgb = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.float64) / 255.0
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def _texels(texturing: Texturing, tri: np.ndarray, px: np.ndarray, py: np.ndarray,
            corners_x: tuple, corners_y: tuple) -> np.ndarray:
    """Linear RGB of each pixel (px, py: pixel centres) drawn by a textured triangle
    `tri`: its UVs interpolated with the pixel's barycentric weights, the nearest texel
    (UV origin bottom-left, repeating)."""
    x0, x1, x2 = (c[tri] for c in corners_x)
    y0, y1, y2 = (c[tri] for c in corners_y)
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    w1 = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / area
    w2 = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / area
    w = np.stack([1.0 - w1 - w2, w1, w2], axis=1)
    uv = np.einsum("kc,kcj->kj", w, texturing.uvs[tri])
    out = np.empty((len(tri), 3))
    for index, image in enumerate(texturing.images):
        mine = texturing.image[tri] == index
        h, wd = image.shape[:2]
        col = np.floor(np.mod(uv[mine, 0], 1.0) * wd).astype(np.int64).clip(0, wd - 1)
        row = np.floor((1.0 - np.mod(uv[mine, 1], 1.0)) * h).astype(np.int64).clip(0, h - 1)
        out[mine] = image[row, col]
    return out


def rasterise(triangles: np.ndarray, colors: np.ndarray, size: int, basis: np.ndarray,
              texturing: Texturing | None = None) -> np.ndarray:
    """Z-buffered, flat Lambert-shaded orthographic render.

    triangles: (m, 3, 3) float64 model frame; colors: (m, 3) linear RGB;
    basis: (3, 3) from view_basis(); texturing: base-colour images of the triangles
    that have one (their pixels take the texel instead of the flat colour). Returns
    (size, size, 3) float64 linear RGB, white where nothing is drawn. The view is
    fitted to the triangles' projected extent."""
    image = np.ones((size, size, 3))
    if len(triangles) == 0:
        return image
    # Screen x, screen y and depth (bigger = nearer) of each corner, as contiguous
    # (m,) arrays: elementwise min/max over three arrays beats axis reductions.
    corners = [triangles[:, i] @ basis.T for i in range(3)]
    sx_, sy_, dz_ = ([np.ascontiguousarray(c[:, j]) for c in corners] for j in range(3))
    lo = np.array([min(a.min() for a in sx_), min(a.min() for a in sy_)])
    hi = np.array([max(a.max() for a in sx_), max(a.max() for a in sy_)])
    scale = size * (1.0 - 2.0 * MARGIN) / max(float((hi - lo).max()), 1e-12)
    centre = (lo + hi) / 2.0
    x0, x1, x2 = ((a - centre[0]) * scale + size / 2.0 for a in sx_)  # pixel columns
    y0, y1, y2 = (size / 2.0 - (a - centre[1]) * scale for a in sy_)  # pixel rows, down
    d0, d1, d2 = dz_

    shade = _shading(triangles, basis)
    tri_color = colors * shade[:, None]

    # Doubled signed area in pixel space; 0 is a sliver we skip.
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    ids = np.flatnonzero(np.abs(area) > 1e-12)
    # Depth plane of each triangle: z = d0 + gx (x - x0) + gy (y - y0).
    with np.errstate(divide="ignore", invalid="ignore"):
        gx = ((d1 - d0) * (y2 - y0) - (d2 - d0) * (y1 - y0)) / area
        gy = ((d2 - d0) * (x1 - x0) - (d1 - d0) * (x2 - x0)) / area
    rows_tri, rows_y, span_x0, span_n = _spans(ids, (x0, x1, x2), (y0, y1, y2), size)

    # Depth as a 30-bit integer (nearer = smaller) so one integer sort orders the
    # samples by pixel, then depth; a stable sort breaks ties by triangle order.
    dlo = min(d.min() for d in (d0, d1, d2))
    dhi = max(d.max() for d in (d0, d1, d2))
    dscale = (DEPTH_LEVELS - 1) / max(dhi - dlo, 1e-12)
    best_key = np.full(size * size, np.iinfo(np.int64).max)
    best_tri = np.full(size * size, -1, dtype=np.int64)
    for rows in _chunks(np.flatnonzero(span_n), span_n):
        n = span_n[rows]
        tri = np.repeat(rows_tri[rows], n)
        iy = np.repeat(rows_y[rows], n)
        ix = np.repeat(span_x0[rows], n) + (np.arange(len(tri)) - np.repeat(np.cumsum(n) - n, n))
        z = d0[tri] + gx[tri] * (ix + 0.5 - x0[tri]) + gy[tri] * (iy + 0.5 - y0[tri])
        zq = np.clip(((dhi - z) * dscale).astype(np.int64), 0, DEPTH_LEVELS - 1)
        pix = iy * size + ix
        key = pix * DEPTH_LEVELS + zq
        order = np.argsort(key, kind="stable")
        key, pix, tri = key[order], pix[order], tri[order]
        first = np.flatnonzero(np.r_[True, pix[1:] != pix[:-1]])
        key, pix, tri = key[first], pix[first], tri[first]
        nearer = key < best_key[pix]
        best_key[pix[nearer]] = key[nearer]
        best_tri[pix[nearer]] = tri[nearer]

    drawn = best_tri >= 0
    flat = image.reshape(-1, 3)
    flat[drawn] = tri_color[best_tri[drawn]]
    if texturing is not None and texturing.images:
        pixels = np.flatnonzero(drawn)
        pixels = pixels[texturing.image[best_tri[pixels]] >= 0]
        tri = best_tri[pixels]
        texel = _texels(texturing, tri, pixels % size + 0.5, pixels // size + 0.5, (x0, x1, x2), (y0, y1, y2))
        flat[pixels] = texel * shade[tri, None]
    return image


def _spans(ids, xs, ys, size):
    """Scanline spans of triangles `ids`: for every pixel row whose centre line crosses
    a triangle, the run of pixel centres inside it. Work is proportional to the
    pixels covered, not to bounding boxes (a long diagonal sliver has a huge box).

    Returns per row: triangle, row index, first column, number of columns (>= 0)."""
    x0, x1, x2 = (x[ids] for x in xs)
    y0, y1, y2 = (y[ids] for y in ys)
    ymin = np.minimum(np.minimum(y0, y1), y2)
    ymax = np.maximum(np.maximum(y0, y1), y2)
    cy0 = np.clip(np.ceil(ymin - 0.5), 0, size).astype(np.int64)
    cy1 = np.clip(np.floor(ymax - 0.5), -1, size - 1).astype(np.int64)
    h = np.maximum(cy1 - cy0 + 1, 0)
    r = np.repeat(np.arange(len(ids)), h)
    iy = np.repeat(cy0, h) + (np.arange(len(r)) - np.repeat(np.cumsum(h) - h, h))
    sy = iy + 0.5
    xl = np.full(len(r), np.inf)
    xr = np.full(len(r), -np.inf)
    for (xa, ya), (xb, yb) in (((x0, y0), (x1, y1)), ((x1, y1), (x2, y2)), ((x2, y2), (x0, y0))):
        # Each edge from its lower to its upper end, so the two triangles sharing it
        # compute bit-identical crossings (no cracks between them).
        swap = yb < ya
        xlo, ylo = np.where(swap, xb, xa), np.where(swap, yb, ya)
        xhi, yhi = np.where(swap, xa, xb), np.where(swap, ya, yb)
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = (xhi - xlo) / (yhi - ylo)
        slope = np.where(yhi > ylo, slope, np.nan)  # horizontal edges never hit
        xlo, ylo, yhi, slope = xlo[r], ylo[r], yhi[r], slope[r]
        hit = (ylo <= sy) & (sy <= yhi) & ~np.isnan(slope)
        x = xlo + (sy - ylo) * slope
        xl = np.where(hit, np.minimum(xl, x), xl)
        xr = np.where(hit, np.maximum(xr, x), xr)
    valid = np.isfinite(xl) & np.isfinite(xr)
    first = np.clip(np.ceil(np.where(valid, xl, 0.0) - 0.5 - 1e-9), 0, size).astype(np.int64)
    last = np.clip(np.floor(np.where(valid, xr, -1.0) - 0.5 + 1e-9), -1, size - 1).astype(np.int64)
    count = np.where(valid, np.maximum(last - first + 1, 0), 0)
    return ids[r], iy, first, count


def _shading(triangles: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(m,) Lambert factor of each face under a key light from the upper left behind
    the camera; two-sided, so a face wound the wrong way is not drawn black."""
    e1 = triangles[:, 1] - triangles[:, 0]
    e2 = triangles[:, 2] - triangles[:, 0]
    n = np.stack(
        [e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1], e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2], e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]],
        axis=1,
    )
    length = np.linalg.norm(n, axis=1)
    n = n / np.where(length > 0, length, 1.0)[:, None]
    light = basis[2] * 1.0 - basis[0] * 0.4 + basis[1] * 0.6
    light /= np.linalg.norm(light)
    return AMBIENT + (1.0 - AMBIENT) * np.abs(n @ light)


def _chunks(ids: np.ndarray, counts: np.ndarray):
    """Split `ids` so that each piece's summed count stays near CHUNK."""
    if len(ids) == 0:
        return
    bounds = np.searchsorted(np.cumsum(counts), np.arange(CHUNK, counts.sum() + CHUNK, CHUNK), side="right")
    start = 0
    for end in bounds:
        end = max(int(end), start + 1)
        if start < len(ids):
            yield ids[start:end]
        start = end


def _to_srgb8(linear: np.ndarray) -> np.ndarray:
    c = np.clip(linear, 0.0, 1.0)
    srgb = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def _png_bytes(image: np.ndarray) -> bytes:
    """PNG bytes with no text chunks, time stamp or gamma chunk: pixels only."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image, mode="RGB").save(buf, format="PNG", optimize=False, compress_level=9)
    return buf.getvalue()
