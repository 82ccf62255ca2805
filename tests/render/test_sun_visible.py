"""CyclesScene.sun_visible: what hides the sun from the lens is what the frame shows,
not every placement the scene holds (the veiling glare of a frame must not depend on
which other frames share its Blender process)."""

import numpy as np
import pytest

import live_scene


def test_only_a_shown_placement_hides_the_sun(tmp_path):
    pytest.importorskip("bpy")
    from pipeline.render.cycles import CyclesScene
    from pipeline.render.sensor import PhoneCamera
    from pipeline.runtime.site import load_site

    build, sources, _ = live_scene.make(tmp_path)
    site = load_site(build, sources)
    scene = CyclesScene(site, PhoneCamera(width=32, height=24, samples=1), 0)
    try:
        scene.load_many(["R-1", "R-2"])
        eye = np.array([0.6, -1.5, 0.5])  # between the two tanks (1 m cubes)

        def towards(tag):
            centre = (site.pose(site.placement(tag)) @ np.array([0.5, 0.5, 0.5, 1.0]))[:3]
            return (centre - eye) / np.linalg.norm(centre - eye)

        to_2, to_1 = towards("R-2"), towards("R-1")
        side = np.array([1.0, 0.0, 0.0])  # past both
        assert not scene.sun_visible(eye, to_2) and not scene.sun_visible(eye, to_1) and scene.sun_visible(eye, side)
        scene.show_only(["R-1"])
        assert scene.sun_visible(eye, to_2) and not scene.sun_visible(eye, to_1)
        scene.show_only(["R-2"])
        assert not scene.sun_visible(eye, to_2) and scene.sun_visible(eye, to_1)
        # the ray starts a centimetre out: a lens inside a tank sees its inside wall
        assert not scene.sun_visible(site.pose(site.placement("R-2"))[:3, 3] + [0.3, 0.3, 0.5], side)
    finally:
        scene.close()
