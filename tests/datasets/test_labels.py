"""A frame's labels without rendering (datasets/labels.py): the pointer's pixels and
the glare over them, a gauge's keypoints, the parts and their annotations."""

from __future__ import annotations

import numpy as np

from pipeline.geometry.pinhole import intrinsics
from pipeline.perception.gauge import Dial


def _dial_facing_the_camera():
    axis, up = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    dial = Dial(np.zeros(3), axis, up, np.cross(axis, up), {"variable": "level", "range": [-2.0, 2.0]})
    pose = np.eye(4)
    pose[2, 3] = 0.6  # 0.6 m in front of the dial, looking down -Z at it
    return dial, pose, intrinsics(np.radians(40.0), 64, 48)


def test_the_pointers_pixels_are_its_outline_projected_at_its_angle():
    from pipeline.datasets import labels

    dial, pose, k = _dial_facing_the_camera()
    up = labels.pointer_pixels(dial, 0.0, pose, k)
    rows, cols = np.nonzero(up)
    assert up.shape == (48, 64) and len(rows) >= 5
    # upright from its hub (3 cm below the pivot, the frame's centre) to its tip
    assert rows.min() < 8 and 24 < rows.max() < 30 and rows.mean() < 20 and abs(cols.mean() - 31.5) < 1.0
    left = labels.pointer_pixels(dial, np.pi / 2.0, pose, k)  # +90 deg: towards the dial's left (-x here)
    rows, cols = np.nonzero(left)
    assert cols.min() < 16 and 32 < cols.max() < 38 and cols.mean() < 28 and abs(rows.mean() - 23.5) < 1.0
    behind = pose.copy()
    behind[2, 3] = -0.6  # the camera behind the dial, looking away from it
    assert not labels.pointer_pixels(dial, 0.0, behind, k).any()


def test_glare_hides_a_pointer_when_the_sensor_clipped_most_of_its_pixels():
    from pipeline.datasets import labels

    dial, pose, k = _dial_facing_the_camera()
    pointer = labels.pointer_pixels(dial, 0.0, pose, k)
    top = np.zeros((48, 64), bool)
    top[:24] = True  # a clipped patch over the upper half: the pointer at 0 deg lies in it
    hidden = labels.pointer_glare(pointer, top)  # all but its hub's tail
    assert hidden["glare_hides_pointer"] and 0.6 < hidden["pointer_clipped_share"] < 0.9
    assert hidden["pointer_px"] == int(pointer.sum())
    seen = labels.pointer_glare(pointer, ~top)
    assert not seen["glare_hides_pointer"] and seen["pointer_clipped_share"] < 0.4
    assert not labels.pointer_glare(np.zeros_like(top), top)["glare_hides_pointer"]  # no pointer, nothing hidden


def test_gauge_keypoints_are_projected_with_their_visibility():
    from pipeline.datasets import labels

    dial, pose, k = _dial_facing_the_camera()
    ids = np.full((48, 64), 5, np.uint16)
    depth = np.full((48, 64), 0.6, np.float32)
    kp = np.array(labels.gauge_keypoints(dial, 0.0, pose, k, ids, depth, 5)).reshape(-1, 3)
    assert kp.shape == (len(labels.KEYPOINTS), 3) and (kp[:, 2] == 2).all()
    assert np.allclose(kp[0, :2], [32.0, 24.0])  # the pivot at the frame's centre
    assert kp[1, 1] < 24.0 and abs(kp[1, 0] - 32.0) < 1e-6  # the tip straight up at angle 0
    # the scale's ends at -2 and +2 rad: mirror images about the vertical through the pivot
    assert abs((kp[2, 0] - 32.0) + (kp[3, 0] - 32.0)) < 1e-6 and abs(kp[2, 1] - kp[3, 1]) < 1e-6
    tip = kp[1, :2].astype(int)
    ids[tip[1], tip[0]] = 9  # something else in front of the tip
    hidden = np.array(labels.gauge_keypoints(dial, 0.0, pose, k, ids, depth, 5)).reshape(-1, 3)
    assert hidden[1, 2] == 1 and (hidden[[0, 2, 3], 2] == 2).all()
    behind = pose.copy()
    behind[2, 3] = -0.6
    assert labels.gauge_keypoints(dial, 0.0, behind, k, ids, depth, 5) == [0.0, 0.0, 0] * len(labels.KEYPOINTS)


# --- parts (issue 38 item 1; no rendering) --------------------------------------------------


def test_parts_come_from_the_packages_object_names():
    from pipeline.datasets import labels

    pid = labels.PART_ID
    assert labels.part_of("gauge_tank_pointer") == pid["gauge_pointer"]
    assert labels.part_of("gauge_tank_glass") == pid["gauge_glass"]
    assert labels.part_of("gauge_tank_dial_red") == labels.part_of("gauge_tank_dial_white") == pid["gauge_dial"]
    assert labels.part_of("gauge_b1_oil") == labels.part_of("gauge_b2_tube") == pid["sight_glass"]
    assert labels.part_of("bushing_hv_sheds") == pid["bushing"]  # a bushing's sheds are the bushing's
    assert labels.part_of("column_1_insulator") == labels.part_of("chamber_2_insulator") == pid["insulator"]
    assert labels.part_of("base_tank") == labels.part_of("conservator") == 0
    assert [c["id"] for c in labels.part_categories()] == list(range(1, len(labels.PARTS) + 1))


def test_part_annotations_name_their_parent_instance():
    from pycocotools import mask as rle

    from pipeline.datasets import labels

    ids = np.zeros((6, 8), np.uint16)
    parts = np.zeros((6, 8), np.uint16)
    ids[1:5, 1:7] = 3  # an instance with a pointer and a glass part, and some of it no part
    parts[1:3, 2:4] = labels.PART_ID["gauge_pointer"]
    parts[3:5, 5:7] = labels.PART_ID["gauge_glass"]
    parts[0, 0] = labels.PART_ID["gauge_glass"]  # a part on the background is no one's
    anns = labels.part_annotations(ids, parts, {3: "RE-A1"})
    assert [(a["instance_id"], a["tag"], a["category_id"]) for a in anns] == [
        (3, "RE-A1", labels.PART_ID["gauge_pointer"]), (3, "RE-A1", labels.PART_ID["gauge_glass"])]
    assert anns[0]["bbox"] == [2, 1, 2, 2] and anns[0]["area"] == 4
    assert np.array_equal(rle.decode(anns[1]["segmentation"]).astype(bool), (ids == 3) & (parts == 2))
