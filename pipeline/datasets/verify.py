"""Whether a dataset's annotations are its masks: every annotation of a frame's record
(instances, parts, gauges) decoded from its RLE against the pixels the frame's mask
images say it covers, its box and area against those pixels, and every instance and
(instance, part) pair in the images annotated once. What the bench checks on frames
with the sun in view (issue 38 item 8), where glare is in the picture, never in the
labels. Pure numpy, OpenCV and pycocotools."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import parts as part_labels


def verify_frame(folder: Path, record: dict) -> tuple[int, list[str]]:
    """(annotations checked, problems) of one frame's record in dataset `folder`."""
    import cv2

    def image(rel: str) -> np.ndarray:
        return cv2.imread(str(Path(folder) / rel), cv2.IMREAD_UNCHANGED)

    ids, parts, behind = image(record["mask"]), image(record["parts"]), image(record["behind_glass"])
    glass = np.isin(parts, part_labels.GLASS)
    through = np.where(np.isin(behind, part_labels.GLASS), 0, behind)
    fid, problems = record["frame_id"], []
    expected = {}
    for iid in np.unique(ids[ids > 0]):
        expected[("instance", int(iid), 0)] = ids == iid
    for layer in (np.where(glass, parts, 0), through):
        keys = (ids.astype(np.uint32) << 16 | layer.astype(np.uint32))[(ids > 0) & (layer > 0)]
        for key in np.unique(keys):
            iid, pid = int(key >> 16), int(key & 0xFFFF)
            expected[("part", iid, pid)] = (ids == iid) & (layer == pid)
    gauge = np.isin(parts, part_labels.GAUGE)
    seen = set()
    for kind, key in (("instance", "annotations"), ("part", "part_annotations"), ("gauge", "gauge_annotations")):
        for a in record.get(key, []):
            name = (kind, a["instance_id"], a["category_id"] if kind == "part" else 0)
            pixels = (ids == a["instance_id"]) & gauge if kind == "gauge" else expected.get(name)
            if pixels is None or name in seen:
                problems.append(f"{fid}: {kind} {a['tag']} {name[2] or ''}: no such pixels, or annotated twice")
                continue
            seen.add(name)
            problems += [f"{fid}: {kind} {a['tag']} {name[2] or ''}: {p}" for p in _mismatch(a, pixels)]
    problems += [f"{fid}: {k[0]} {k[1]} {k[2] or ''}: in the images, not annotated" for k in expected if k not in seen]
    count = sum(len(record.get(k, [])) for k in ("annotations", "part_annotations", "gauge_annotations"))
    return count, problems


def _mismatch(a: dict, pixels: np.ndarray) -> list[str]:
    from pycocotools import mask as rle

    out = []
    if not np.array_equal(rle.decode(a["segmentation"]).astype(bool), pixels):
        out.append("its RLE is not its mask")
    rows, cols = np.nonzero(pixels)
    box = [int(cols.min()), int(rows.min()), int(cols.max() - cols.min() + 1), int(rows.max() - rows.min() + 1)] \
        if rows.size else None
    if a["bbox"] != box or a["area"] != int(rows.size):
        out.append(f"box {a['bbox']} area {a['area']}, the mask's {box} {int(rows.size)}")
    if "keypoints" in a and a["num_keypoints"] != sum(1 for v in a["keypoints"][2::3] if v > 0):
        out.append("num_keypoints is not the count of labelled keypoints")
    return out


def verify_dataset(folder: Path) -> dict:
    """Every frame of a finished dataset: {"frames", "annotations", "problems"}, and
    coco.json's and coco_parts.json's annotations the records' own."""
    folder = Path(folder)
    records = [json.loads((folder / "records" / f"{json.loads(line)['frame_id']}.json").read_text())
               for line in (folder / "frames.jsonl").read_text().splitlines()]
    total, problems = 0, []
    for r in records:
        n, found = verify_frame(folder, r)
        total += n
        problems += found
    for name, keys in (("coco.json", ("annotations", "gauge_annotations")), ("coco_parts.json", ("part_annotations",))):
        coco = json.loads((folder / name).read_text())
        got = sorted(json.dumps({k: v for k, v in a.items() if k not in ("id", "image_id", "category_id")},
                                sort_keys=True) for a in coco["annotations"])
        want = sorted(json.dumps({k: v for k, v in a.items() if k != "category_id"}, sort_keys=True)
                      for r in records for key in keys for a in r.get(key, []))
        if got != want:
            problems.append(f"{name}: its annotations are not the records'")
    return {"frames": len(records), "annotations": total, "problems": problems}
