"""Collision cells: corners that Gazebo's loader would take for one are written as one."""

import numpy as np

from pipeline.scene.world_collisions import WELD_M, weld


def test_corners_closer_than_the_weld_are_one_vertex_and_flat_faces_go():
    # two triangles meeting at a corner 20 um apart (piled devices' boxes), and a sliver
    # whose two corners are 30 um apart: after the weld it has no area and is dropped
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                         [2e-5, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0],
                         [5.0, 5.0, 0.0], [5.0, 5.0 + 3e-5, 0.0], [6.0, 5.0, 0.0]])
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    welded, kept = weld(vertices, faces)
    assert len(welded) == 7 and len(kept) == 2
    assert kept[0][0] == kept[1][0]  # the shared corner
    assert np.allclose(welded[kept], vertices[faces[:2]], atol=WELD_M)
    # corners further apart than the weld stay apart
    apart, kept_apart = weld(vertices * 10.0, faces)
    assert len(apart) == 9 and len(kept_apart) == 3
