"""A frame's labels without rendering (datasets/labels.py): the pointer's pixels and
the glare over them, a gauge's keypoints, the parts and their annotations."""

from __future__ import annotations

import numpy as np

from pipeline.datasets import parts
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
    pid = parts.PART_ID
    assert parts.part_of("gauge_tank_pointer") == pid["gauge_pointer"]
    assert parts.part_of("gauge_tank_glass") == pid["gauge_glass"]
    assert parts.part_of("gauge_tank_dial_red") == parts.part_of("gauge_tank_dial_white") == pid["gauge_dial"]
    # a sight glass: the shunt reactor's tubes and the current transformer's window, the oil inside them
    assert parts.part_of("gauge_b2_tube") == parts.part_of("sight_glass_window") == pid["sight_glass"]
    assert parts.part_of("gauge_b1_oil") == parts.part_of("sight_glass_oil") == pid["sight_glass_oil"]
    assert parts.part_of("bushing_hv_sheds") == pid["bushing"]  # a bushing's sheds are the bushing's
    assert parts.part_of("column_1_insulator") == parts.part_of("chamber_2_insulator") == pid["insulator"]
    assert parts.part_of("base_tank") == parts.part_of("conservator") == parts.part_of("window_glass") == 0
    assert [c["id"] for c in parts.part_categories()] == list(range(1, len(parts.PARTS) + 1))
    assert {n for n, i in pid.items() if i in parts.GLASS} == {"gauge_glass", "sight_glass"}


def _gauge_frame():
    """A 6x8 frame: instance 3 with a pointer, a glass over part of its dial, and some of
    it no part; a glass pixel on the background."""
    ids = np.zeros((6, 8), np.uint16)
    p = np.zeros((6, 8), np.uint16)
    ids[1:5, 1:7] = 3
    p[1:3, 2:4] = parts.PART_ID["gauge_pointer"]
    p[3:5, 2:7] = parts.PART_ID["gauge_dial"]
    p[3:5, 5:7] = parts.PART_ID["gauge_glass"]
    p[0, 0] = parts.PART_ID["gauge_glass"]  # a part on the background is no one's
    return ids, p


def test_part_annotations_name_their_parent_instance():
    from pycocotools import mask as rle

    ids, p = _gauge_frame()
    anns = parts.part_annotations(ids, p, {3: "RE-A1"})
    pid = parts.PART_ID
    assert [(a["instance_id"], a["tag"], a["category_id"]) for a in anns] == [
        (3, "RE-A1", pid["gauge_pointer"]), (3, "RE-A1", pid["gauge_glass"]), (3, "RE-A1", pid["gauge_dial"])]
    assert anns[0]["bbox"] == [2, 1, 2, 2] and anns[0]["area"] == 4
    assert np.array_equal(rle.decode(anns[1]["segmentation"]).astype(bool), (ids == 3) & (p == pid["gauge_glass"]))
    assert anns[2]["area"] == 6 and all(a["behind_glass_px"] == 0 for a in anns)


def test_behind_the_glass_the_dial_is_labelled_and_the_glass_stays_glass():
    """The label pass's part code: a glass's pixels hold SEE_THROUGH x its part plus what
    the ray met behind it (the dial under its left column, the pointer under one pixel,
    nothing under the last). The glass keeps its own pixels, the dial's annotation takes
    those seen through the glass too."""
    from pycocotools import mask as rle

    from pipeline.render.cycles import SEE_THROUGH

    ids, p = _gauge_frame()
    pid = parts.PART_ID
    code = p.astype(np.uint32).copy()
    code[p == pid["gauge_glass"]] *= SEE_THROUGH
    code[3:5, 5] += pid["gauge_dial"]
    code[3, 6] += pid["gauge_pointer"]
    flat, behind = parts.split(code.astype(np.uint16))
    assert np.array_equal(flat, p) and flat.dtype == behind.dtype == np.uint16
    assert behind[3, 5] == behind[4, 5] == pid["gauge_dial"] and behind[3, 6] == pid["gauge_pointer"]
    assert behind[4, 6] == 0 and behind[0, 0] == 0  # nothing behind the glass there
    assert np.array_equal(behind[p != pid["gauge_glass"]], p[p != pid["gauge_glass"]])
    # a code that is no part, nor a glass's (Cycles on a glass's rim): no part in either image
    odd = code.copy()
    odd[2, 2], odd[2, 3] = 132, SEE_THROUGH * pid["bushing"] + pid["gauge_dial"]
    assert [int(a[2, c]) for a in parts.split(odd.astype(np.uint16)) for c in (2, 3)] == [0, 0, 0, 0]
    anns = {a["category_id"]: a for a in parts.part_annotations(ids, p, {3: "RE-A1"}, behind)}
    glass = (ids == 3) & (p == pid["gauge_glass"])
    assert np.array_equal(rle.decode(anns[pid["gauge_glass"]]["segmentation"]).astype(bool), glass)
    dial = rle.decode(anns[pid["gauge_dial"]]["segmentation"]).astype(bool)
    assert dial[3, 5] and dial[4, 5] and not dial[3, 6] and dial.sum() == 8
    assert anns[pid["gauge_dial"]]["behind_glass_px"] == 2 and anns[pid["gauge_pointer"]]["behind_glass_px"] == 1
    assert anns[pid["gauge_glass"]]["behind_glass_px"] == 0


def test_a_gauge_is_an_annotation_of_its_own_with_its_keypoints():
    from pycocotools import mask as rle

    ids, p = _gauge_frame()
    p[2, 6] = parts.PART_ID["bushing"]  # not a gauge's part
    kp = [4.0, 3.0, 2, 3.5, 1.5, 2, 0.0, 0.0, 0, 6.5, 4.5, 1]
    a = parts.gauge_annotation(ids, p, 3, "RE-A1", kp)
    expected = (ids == 3) & np.isin(p, parts.GAUGE)
    assert np.array_equal(rle.decode(a["segmentation"]).astype(bool), expected) and a["area"] == int(expected.sum())
    assert a["keypoints"] == kp and a["num_keypoints"] == 3 and a["instance_id"] == 3 and a["tag"] == "RE-A1"
    assert a["bbox"] == [2, 1, 5, 4]
    assert parts.gauge_annotation(ids, np.zeros_like(p), 3, "RE-A1", kp) is None  # no gauge pixel in the frame
    cat = parts.gauge_category([{"id": 1}, {"id": 4}], ("dial_centre", "pointer_tip", "scale_start", "scale_end"))
    assert cat["id"] == 5 and cat["name"] == "gauge" and cat["skeleton"] == [[1, 2], [1, 3], [1, 4]]
