"""The parts of a frame's instances (issue 38 items 1 and 3): which object of a package
is which part, the parts' COCO annotations with their parent instances, what lies
behind a glass, and each gauge as an annotation of its own with its keypoints.

A frame has two part images from its one label pass (`split`): `parts` (the first
surface along each pixel's ray, a glass included) and `behind` (the same with the glass
transparent: under a gauge's glass its dial and pointer, in a sight glass its oil). A
glass is then labelled as glass, and the dial behind it as the dial, where generators
that label the first surface only drop it. What a ray meets behind a glass is taken to
be the glass's own instance's (a gauge's glass covers its own dial). Pure numpy and
pycocotools: no bpy."""

from __future__ import annotations

import re

import numpy as np

# Parts, from the packages' object names (sources/authoring/ASSETS.md names them so): a
# part mask value is the part's id here (1 + its rank), 0 where no part is. First match
# wins. Appended, never reordered: a part's id is its value in every dataset's masks.
PARTS = (("gauge_pointer", r"(^|_)pointer$"), ("gauge_glass", r"^gauge_.*_glass$"),
         ("gauge_dial", r"^gauge_.*_dial_(white|red)$"), ("gauge_bezel", r"^gauge_.*_bezel$"),
         ("sight_glass", r"^gauge_b\d+_tube$|^sight_glass_window$"), ("bushing", r"^bushing_"),
         ("insulator", r"(^|_)insulator$|_sheds$"), ("sight_glass_oil", r"^gauge_b\d+_oil$|^sight_glass_oil$"))
PART_ID = {name: i + 1 for i, (name, _) in enumerate(PARTS)}
GLASS = tuple(PART_ID[n] for n in ("gauge_glass", "sight_glass"))  # what a ray goes through in `behind`
GAUGE = tuple(PART_ID[n] for n in ("gauge_pointer", "gauge_glass", "gauge_dial", "gauge_bezel"))  # a dial gauge


def part_of(object_name: str) -> int:
    """The part id of a package's object (its name without Blender's .001), 0 for none."""
    return next((PART_ID[name] for name, rule in PARTS if re.search(rule, object_name)), 0)


def part_categories() -> list[dict]:
    return [{"id": PART_ID[name], "name": name, "supercategory": "part"} for name, _ in PARTS]


def split(code: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The label pass's part code (render.cycles: SEE_THROUGH x a glass's part + the part
    seen through it; a part id elsewhere) -> (parts: the first surface's part, the glass
    included; behind: the same with every glass transparent, 0 where nothing is behind).
    A code that is neither (Cycles gives a few on a glass's rim, where the ray grazes
    its edge: 3 of 120,000 pixels in a 400x300 frame) is no part in both."""
    from ..render.cycles import SEE_THROUGH

    code = code.astype(np.uint16)
    top, under = code // SEE_THROUGH, code % SEE_THROUGH
    glass = (code >= SEE_THROUGH) & np.isin(top, GLASS) & (under <= len(PARTS))
    plain = np.where(code <= len(PARTS), code, 0)
    return np.where(glass, top, plain).astype(np.uint16), np.where(glass, under, plain).astype(np.uint16)


def part_annotations(ids: np.ndarray, parts: np.ndarray, tag_of: dict[int, str],
                     behind: np.ndarray | None = None) -> list[dict]:
    """One annotation per (instance, part) present, in that order: RLE, box and area of
    its pixels, the part's category and its parent instance (id and tag). A glass's
    pixels are its own in `parts`; every other part's are those of `behind` (the glass
    transparent: the dial under a gauge's glass is the dial's), `behind_glass_px` of
    them seen through a glass. A glass and what is behind it overlap, as in the picture."""
    behind = parts if behind is None else behind
    glass = np.isin(parts, GLASS)
    layers = [np.where(glass, parts, 0), np.where(np.isin(behind, GLASS), 0, behind)]
    found = {}
    for layer in layers:
        pairs = np.unique(ids.astype(np.uint32) << 16 | layer.astype(np.uint32))
        for key in pairs[(pairs >> 16 > 0) & (pairs & 0xFFFF > 0)]:
            found[int(key >> 16), int(key & 0xFFFF)] = layer
    out = []
    for (iid, pid), layer in sorted(found.items()):
        pixels = (ids == iid) & (layer == pid)
        out.append({"instance_id": iid, "tag": tag_of[iid], "category_id": pid, **rle_box(pixels), "iscrowd": 0,
                    "behind_glass_px": 0 if pid in GLASS else int((pixels & glass).sum())})
    return out


def gauge_category(categories: list[dict], keypoints: tuple[str, ...]) -> dict:
    """The COCO category of a gauge, after the instance categories, with its keypoints
    and skeleton (each point joined to the dial's centre, the first)."""
    return {"id": max((c["id"] for c in categories), default=0) + 1, "name": "gauge", "supercategory": "part",
            "keypoints": list(keypoints), "skeleton": [[1, j] for j in range(2, len(keypoints) + 1)]}


def gauge_annotation(ids: np.ndarray, parts: np.ndarray, instance: int, tag: str, keypoints: list) -> dict | None:
    """A dial gauge as its own COCO annotation: the pixels of its parts (pointer, glass,
    dial, bezel) on its instance, their box and area, and its keypoints [x, y, v] with
    num_keypoints (those labelled, v > 0); None when none of its pixels is in the frame."""
    pixels = (ids == instance) & np.isin(parts, GAUGE)
    if not pixels.any():
        return None
    return {"instance_id": instance, "tag": tag, **rle_box(pixels), "iscrowd": 0, "keypoints": keypoints,
            "num_keypoints": sum(1 for v in keypoints[2::3] if v > 0)}


def rle_box(pixels: np.ndarray) -> dict:
    """COCO's RLE segmentation of a boolean mask, its tight box [x, y, w, h] and area."""
    from pycocotools import mask as rle

    code = rle.encode(np.asfortranarray(pixels.astype(np.uint8)))
    rows, cols = np.nonzero(pixels)
    x0, y0 = int(cols.min()), int(rows.min())
    return {"segmentation": {"size": [int(v) for v in code["size"]], "counts": code["counts"].decode("ascii")},
            "area": int(rows.size), "bbox": [x0, y0, int(cols.max()) - x0 + 1, int(rows.max()) - y0 + 1]}
