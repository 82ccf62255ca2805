"""One hand-made asset per geometry and hierarchy rule; each yields exactly its code.

`FIXTURES[code]()` returns (asset, check_asset keyword arguments). Every fixture starts
from `base()`, a one-link asset that is clean, and breaks one thing.
"""

from __future__ import annotations

import numpy as np

from fixtures_assets import box_mesh
from pipeline import ir


def base(visual: ir.Mesh | None = None, collision: ir.Mesh | None = None, **changes) -> ir.Asset:
    """A 1 m crate: link `body`, visual `shell` and collision `hull`, both closed boxes."""
    link = ir.Link("body", visuals=(ir.Visual("shell", "paint", (visual or box_mesh(center=(0, 0, 0.5)),)),),
                   collisions=(ir.Collision("hull", collision or box_mesh(center=(0, 0, 0.5))),))
    asset = ir.Asset(id="crate", category="test", links=(link,), materials=(ir.Material("paint"),))
    return asset.with_(**changes) if changes else asset


def two_links(joint: ir.Joint | None = None, **joint_changes) -> ir.Asset:
    """base() plus a link `lid` above it on a revolute joint `hinge` (clean as given)."""
    lid = ir.Link("lid", pose=ir.pose(_at(0, 0, 1.0)),
                  visuals=(ir.Visual("lid_shell", "paint", (box_mesh((1.0, 1.0, 0.1), (0, 0, 0.05)),)),))
    kw = dict(name="hinge", type="revolute", parent="body", child="lid", pose=_at(0, 0, 1.0),
              axis=(1.0, 0.0, 0.0), lower=0.0, upper=1.5)
    kw.update(joint_changes)
    a = base()
    return a.with_(links=(*a.links, lid), joints=(joint or ir.Joint(**kw),))


def _at(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _box():
    return box_mesh(center=(0, 0, 0.5))


def _flip(mesh: ir.Mesh, rows) -> ir.Mesh:
    f = np.array(mesh.faces)
    f[rows] = f[rows][:, ::-1]
    return ir.Mesh(mesh.vertices, f)


def _link(name: str, z: float = 0.0) -> ir.Link:
    return ir.Link(name, visuals=(ir.Visual(f"{name}_v", "paint", (box_mesh(center=(0, 0, z)),)),))


def geom001():
    v = np.array(_box().vertices)
    v[3, 1] = np.nan
    return base(visual=ir.Mesh(v, _box().faces)), {}


def geom002():
    # an open quad and a separate triangle with three collinear corners
    v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]]
    return base(visual=ir.Mesh(v, [[0, 1, 2], [0, 2, 3], [4, 5, 6]])), {}


def geom003():
    # three fins on one edge
    v = [[0, 0, 0], [0, 0, 1], [1, 0, 0.5], [-1, 0, 0.5], [0, 1, 0.5]]
    return base(visual=ir.Mesh(v, [[0, 1, 2], [1, 0, 3], [0, 1, 4]])), {}


def geom004():
    return base(visual=_flip(_box(), [5])), {}


def geom005():
    return base(visual=_flip(_box(), slice(None))), {}


def geom006():
    b = _box()
    return base(collision=ir.Mesh(b.vertices, b.faces[:-2])), {}


def geom007():
    # a triangle with both sides: closed, consistently wound, and flat
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    return base(visual=ir.Mesh(v, [[0, 1, 2], [0, 2, 1]])), {}


def geom008():
    return base(), {"budget_triangles": 10}


def geom009():
    return base(lods=(ir.LodInfo(1, budget_m=0.01, error_m=0.05, triangles=4),)), {}


def geom010():
    # a 1 m crate read from millimetres as metres: 1000 m
    big = box_mesh((1000.0, 1000.0, 1000.0), (0, 0, 500.0))
    return base(visual=big, collision=big), {}


def geom011():
    return base(visual=ir.Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32))), {}


def geom012():
    f = np.array(_box().faces)
    f[0, 0] = 99
    return base(visual=ir.Mesh(_box().vertices, f)), {}


def hier001():
    a = base()
    return a.with_(links=(*a.links, _link("spare", 0.5))), {}


def hier002():
    # body -> a -> b -> a: link a has two parents, a closed loop
    a = base()
    j = [ir.Joint("j1", "fixed", "body", "a"), ir.Joint("j2", "fixed", "a", "b"), ir.Joint("j3", "fixed", "b", "a")]
    return a.with_(links=(*a.links, _link("a", 0.5), _link("b", 0.5)), joints=tuple(j)), {}


def hier003():
    a = base()
    return a.with_(links=(*a.links, _link("a", 0.5)), joints=(ir.Joint("j1", "fixed", "ghost", "a"),)), {}


def hier004():
    shell = ir.Visual("shell", "paint", (_box(),))
    a = base()
    return a.with_(links=(ir.Link("body", visuals=(shell, shell), collisions=a.links[0].collisions),)), {}


def hier005():
    link = base().links[0]
    return base(links=(ir.Link("body", visuals=(ir.Visual("shell.001", "paint", (_box(),)),),
                               collisions=link.collisions),)), {}


def hier006():
    return two_links(axis=(0.0, 0.0, 1e-9)), {}


def hier007():
    return two_links(lower=1.0, upper=-1.0), {}


def hier008():
    return two_links(pose=_at(50.0, 0.0, 1.0)), {}


def hier009():
    return base(bindings=(ir.StateBinding("oil_level", "rotate", "needle", domain=(0.0, 1.0)),)), {}


def hier010():
    return base(bindings=(ir.StateBinding("oil_level", "rotate", "shell", domain=(1.0, 1.0)),)), {}


def hier011():
    mats = (ir.Material("paint"), ir.Material("alarm"))
    b = ir.StateBinding("alarm", "material", "shell", domain=(0.0, 1.0), materials=("paint", "alarm"))
    return base(materials=mats, bindings=(b,)), {}


def hier012():
    link = base().links[0]
    return base(links=(ir.Link("../evil", visuals=link.visuals, collisions=link.collisions),)), {}


def hier013():
    # an armature the reader read at rest, as ingest.blend says it
    return base().with_(metadata=(("warning.armature", "armatures are not carried: Rig (3 bones)"),)), {}


FIXTURES = {name.upper(): fn for name, fn in sorted(globals().items())
            if name[:4] in ("geom", "hier") and name[4:].isdigit()}
