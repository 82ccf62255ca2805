"""Authors the sample floor plan, sources/floorplan/substation.dxf ($INSUNITS = 6, metres).

A fictional 500/230 kV substation on three terraces (plant grid: x along the yard,
y across it; sizes from ASSETS.md, spacing from real phase clearances):

- L1, 500 kV breaker-and-a-half yard: 3 diameters x 3 breakers, each breaker position
  with a circuit breaker, a current transformer and two centre-break disconnectors per
  phase; two tubular main buses on supports; 6 line exits (line disconnector, CVT,
  surge arrester, gantry), two of them with a bank of 3 single-phase shunt reactors.
- L2, 230 kV double-bus yard: 2 feeder bays, a bus coupler and a transformer bay with
  vertical-break disconnectors.
- L3, the autotransformer bank (3 single-phase units), the control house, kiosks.
- Lightning masts, lighting poles and PTZ camera masts on every level, and a fence of
  3 m panels around the whole site (panels that cross a slope between terraces sit on
  the lower terrace, lifted to the slope's height at their centre).

The output is byte-deterministic: ezdxf's creation/update dates, GUIDs and version
stamps are fixed, the CLASSES section is sorted (ezdxf fills it from a set), handles
are sequential, and every number is computed, not random.

    .venv/bin/python sources/authoring/floorplan.py [--out PATH]

PATH is a .dxf file or a folder; make_all.py passes the assets folder to every
authoring script, so a folder named `assets` means its sibling `floorplan/`.
"""

from __future__ import annotations

import argparse
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import ezdxf

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE.parent / "floorplan" / "substation.dxf"

# Footprint (x, y) in the model frame, from ASSETS.md.
FOOTPRINT = {
    "shunt_reactor": (8.0, 5.0),
    "disconnect_switch_cb": (5.6, 0.8),
    "disconnect_switch_vb": (5.0, 0.8),
    "ptz_camera_mast": (0.6, 0.6),
    "circuit_breaker": (3.5, 1.2),
    "current_transformer": (1.2, 1.2),
    "potential_transformer": (1.2, 1.2),
    "power_transformer": (11.0, 7.0),
    "surge_arrester": (0.7, 0.7),
    "post_insulator": (0.4, 0.4),
    "junction_box": (0.9, 0.6),
    "busbar_support": (1.0, 1.0),
    "equipment_support": (1.1, 1.1),
    "rigid_busbar": (12.0, 0.25),
    "gantry": (21.0, 1.6),
    "lightning_mast": (1.6, 1.6),
    "lighting_pole": (1.2, 0.5),
    "control_house": (20.0, 10.0),
    "fence_segment": (3.0, 0.1),
}
SUPPORT_HEIGHT = 8.0  # busbar_support top: the busbars ride on it
PEDESTAL_HEIGHT = 2.5  # equipment_support top: 500 kV CTs, arresters and post insulators stand on it
PHASES = "ABC"

# Terraces: (level, elevation, x0, y0, x1, y1). The gaps between them are exactly the
# slope run (height difference x slope_ratio 1.5 of site.toml).
LEVELS = {"L1": 48.0, "L2": 52.5, "L3": 56.0}
SLOPE_RATIO = 1.5
L1_BOX = (0.0, 0.0, 104.0, 206.0)
L2_BOX = (104.0 + 4.5 * SLOPE_RATIO, 0.0, 212.75, 84.0)
L3_BOX = (104.0 + 8.0 * SLOPE_RATIO, 84.0 + 3.5 * SLOPE_RATIO, 212.75, 206.0)
PLATFORMS = {"L1": L1_BOX, "L2": L2_BOX, "L3": L3_BOX}
FENCE = (2.0, 2.0, 209.0, 203.0)  # panel lines, sides multiples of 3 m


@dataclass(frozen=True)
class Item:
    asset: str
    tag: str
    level: str
    x: float
    y: float
    heading: float = 0.0
    z: float = 0.0
    state: str | None = None


class Plan:
    def __init__(self):
        self.items: list[Item] = []

    def put(self, asset, tag, level, x, y, heading=0.0, z=0.0, state=None):
        self.items.append(Item(asset, tag, level, round(x, 3), round(y, 3), heading, z, state))

    def put_raised(self, asset, tag, level, x, y, heading=0.0):
        """500 kV equipment on an equipment_support (tagged SE-<tag>), its live parts
        clear of the 5.4 m ground clearance of sources/clearances.toml."""
        self.put("equipment_support", f"SE-{tag}", level, x, y, heading)
        self.put(asset, tag, level, x, y, heading, z=PEDESTAL_HEIGHT)


# --- L1: 500 kV breaker-and-a-half ------------------------------------------------

D_CENTRES = (22.0, 52.0, 82.0)  # diameter centres, 30 m pitch
P500 = 9.0  # phase spacing
BUS_B_Y = (32.0, 40.0, 48.0)
BUS_A_Y = (146.0, 154.0, 162.0)
REACTOR_BANKS = {0: "A", 2: "B"}  # diameter index -> bank letter (north line exits)
REACTOR_Y = 194.0
# Bank B turns 90 degrees: its gauges face plant +x (azimuth ~67 deg, ENE), so a reader
# in front of them looks WSW, into the late-afternoon sun (the study's glare case).
# Its row sits west of the diameter's exit (x 57..77, 10 m pitch) so that 25 m of flat
# L1 ground (to x = 104) lies in front of RE-B3's gauge: the study's 45x close-up.
REACTOR_B_X = (57.0, 67.0, 77.0)
REACTOR_HEADING = {"A": 180.0, "B": 90.0}


def reactor_gauge_point(x, y, heading_deg):
    """Plant-grid point 4 m in front of a reactor's main tank gauge, 1.6 m above the
    level: model (0, -5.8, 1.6) rotated by the INSERT heading and translated."""
    a = math.radians(heading_deg)
    mx, my = 0.0, -5.8
    return (round(x + mx * math.cos(a) - my * math.sin(a), 3), round(y + mx * math.sin(a) + my * math.cos(a), 3), 1.6)


def yard_500(plan: Plan) -> None:
    for d, xc in enumerate(D_CENTRES):
        phases = [(ph, xc + (i - 1) * P500) for i, ph in enumerate(PHASES)]
        for k in range(3):  # breaker positions, south to north
            b = 3 * d + k + 1  # breaker number 1..9
            y0 = 56.0 + 28.0 * k
            for ph, x in phases:
                # Conductors run along y: the switches' blades and the breaker's
                # interrupter turn to 90 degrees.
                plan.put("disconnect_switch_cb", f"89-{b}1{ph}", "L1", x, y0 + 2.8, 90.0, state=f"89-{b}1{ph}")
                plan.put_raised("current_transformer", f"TC-{b}{ph}", "L1", x, y0 + 9.0)
                plan.put("circuit_breaker", f"52-{b}{ph}", "L1", x, y0 + 14.0, 90.0)
                plan.put("disconnect_switch_cb", f"89-{b}2{ph}", "L1", x, y0 + 21.0, 90.0, state=f"89-{b}2{ph}")
                if k < 2:  # the circuit takes off between two breakers
                    plan.put_raised("post_insulator", f"IP-{b}{ph}", "L1", x, y0 + 26.0)
        # Bay-end strain gantries beside the main buses.
        plan.put("gantry", f"PO-D{d + 1}S", "L1", xc, 53.0)
        plan.put("gantry", f"PO-D{d + 1}N", "L1", xc, 141.0)
        # Line exits: south (facing the other way: 180/270 degrees) and north.
        south, north = 2 * d + 1, 2 * d + 2
        for ph, x in phases:
            plan.put("disconnect_switch_cb", f"89-L{south}{ph}", "L1", x, 23.5, 270.0, state=f"89-L{south}{ph}")
            plan.put("potential_transformer", f"TP-{south}{ph}", "L1", x, 17.0, 180.0)
            plan.put_raised("surge_arrester", f"PR-{south}{ph}", "L1", x, 13.0, 180.0)
            plan.put("disconnect_switch_cb", f"89-L{north}{ph}", "L1", x, 170.5, 90.0, state=f"89-L{north}{ph}")
            plan.put("potential_transformer", f"TP-{north}{ph}", "L1", x, 177.0)
            plan.put_raised("surge_arrester", f"PR-{north}{ph}", "L1", x, 181.0)
        plan.put("gantry", f"PO-L{south}", "L1", xc, 8.0, 180.0)
        plan.put("gantry", f"PO-L{north}", "L1", xc, 186.0)
        if d in REACTOR_BANKS:
            bank = REACTOR_BANKS[d]
            for i in range(3):
                # Bank A's gauges face the access road along the north fence (heading
                # 180); bank B's face east (heading 90).
                tag = f"RE-{bank}{i + 1}"
                x = REACTOR_B_X[i] if bank == "B" else xc + (i - 1) * 10.0
                plan.put("shunt_reactor", tag, "L1", x, REACTOR_Y, REACTOR_HEADING[bank], state=f"reactor_{bank}{i + 1}")
        plan.put("junction_box", f"CJ-D{d + 1}", "L1", xc + 15.0, 84.0, 90.0)
    buses(plan, "L1", {"B": BUS_B_Y, "A": BUS_A_Y}, x0=10.0, count=7, prefix="5")
    for i, (x, y) in enumerate([(6, 12), (37, 12), (67, 12), (98, 12), (37, 98), (67, 98), (6, 120), (98, 120), (6, 190), (98, 200), (62, 201)]):
        plan.put("lightning_mast", f"SPDA-1{i + 1:02d}", "L1", x, y)
    for i, (x, y) in enumerate([(37, 28), (67, 28), (37, 70), (67, 126), (37, 165), (67, 165), (6, 60), (98, 90)]):
        plan.put("lighting_pole", f"IL-1{i + 1:02d}", "L1", x, y, 90.0 if i % 2 else 0.0)
    plan.put("ptz_camera_mast", "CAM-1", "L1", 37.0, 199.0, state="ptz_1")


def buses(plan: Plan, level, rows, x0, count, prefix) -> None:
    """Tubular buses along x: `count` 12 m busbars per phase riding on supports."""
    for bus, ys in rows.items():
        for ph, y in zip(PHASES, ys):
            for k in range(count + 1):
                plan.put("busbar_support", f"SB-{prefix}{bus}{ph}-{k + 1:02d}", level, x0 + 12.0 * k, y)
            for k in range(count):
                plan.put("rigid_busbar", f"BR-{prefix}{bus}{ph}-{k + 1:02d}", level, x0 + 6.0 + 12.0 * k, y, z=SUPPORT_HEIGHT)


# --- L2: 230 kV double bus ----------------------------------------------------------

B_CENTRES = tuple(L2_BOX[0] + 14.0 + 22.0 * j for j in range(4))  # 22 m bays: gantry spans
P230 = 6.0


def yard_230(plan: Plan) -> None:
    kinds = ("feeder", "feeder", "coupler", "transformer")
    for j, (xc, kind) in enumerate(zip(B_CENTRES, kinds)):
        b = 21 + j  # 230 kV breaker numbers
        line = 7 + j
        for i, ph in enumerate(PHASES):
            x = xc + (i - 1) * P230
            plan.put("current_transformer", f"TC-{b}{ph}", "L2", x, 26.0)
            plan.put("circuit_breaker", f"52-{b}{ph}", "L2", x, 31.0, 90.0)
            plan.put("disconnect_switch_vb", f"89-{b}1{ph}", "L2", x, 37.5, 90.0, state=f"89-{b}1{ph}")
            plan.put("disconnect_switch_vb", f"89-{b}2{ph}", "L2", x, 58.0, 90.0, state=f"89-{b}2{ph}")
            if kind == "feeder":
                plan.put("disconnect_switch_vb", f"89-L{line}{ph}", "L2", x, 20.0, 270.0, state=f"89-L{line}{ph}")
                plan.put("potential_transformer", f"TP-{line}{ph}", "L2", x, 14.5, 180.0)
                plan.put("surge_arrester", f"PR-{line}{ph}", "L2", x, 11.5, 180.0)
            elif kind == "transformer":
                plan.put("surge_arrester", f"PR-T{ph}", "L2", x, 77.0)
        if kind == "feeder":
            plan.put("gantry", f"PO-L{line}", "L2", xc, 7.0, 180.0)
        if kind != "coupler":
            plan.put("gantry", f"PO-{b}N", "L2", xc, 80.0)
        plan.put("junction_box", f"CJ-{b}", "L2", xc + 11.0, 26.0, 90.0)
    buses(plan, "L2", {"1": (44.0, 49.0, 54.0), "2": (64.0, 69.0, 74.0)}, x0=B_CENTRES[0] - 8.0, count=7, prefix="2")
    for i, (x, y) in enumerate([(135.75, 20), (179.75, 20), (135.75, 66), (179.75, 66), (206, 40)]):
        plan.put("lightning_mast", f"SPDA-2{i + 1:02d}", "L2", x, y)
    for i, (x, y) in enumerate([(157.75, 31), (201.75, 31), (157.75, 60), (116, 60)]):
        plan.put("lighting_pole", f"IL-2{i + 1:02d}", "L2", x, y, 90.0)
    plan.put("ptz_camera_mast", "CAM-2", "L2", 201.75, 14.0, state="ptz_2")


# --- L3: transformers and control -----------------------------------------------------


def platform_3(plan: Plan) -> None:
    for i, (ph, x) in enumerate(zip(PHASES, (140.0, 158.0, 176.0))):
        plan.put("power_transformer", f"AT-1{ph}", "L3", x, 110.0, state=f"trafo_T1{ph}")
        plan.put("surge_arrester", f"PR-AT1{ph}", "L3", x - 3.0, 101.0)
        plan.put_raised("surge_arrester", f"PR-AT5{ph}", "L3", x - 3.0, 119.0)  # the 500 kV side
        plan.put("post_insulator", f"IP-AT{ph}", "L3", x + 3.0, 119.0)
        plan.put("junction_box", f"CJ-AT{ph}", "L3", x + 7.5, 104.0, 90.0)
    plan.put("control_house", "CASA-1", "L3", 190.0, 180.0, 90.0)
    plan.put("junction_box", "CJ-CASA", "L3", 178.0, 172.0, 180.0)
    for i, (x, y) in enumerate([(125, 100), (205, 100), (125, 200), (205, 200)]):
        plan.put("lightning_mast", f"SPDA-3{i + 1:02d}", "L3", x, y)
    for i, (x, y) in enumerate([(150, 140), (180, 140), (150, 190)]):
        plan.put("lighting_pole", f"IL-3{i + 1:02d}", "L3", x, y)
    plan.put("ptz_camera_mast", "CAM-3", "L3", 200.0, 125.0, state="ptz_3")
    plan.put("ptz_camera_mast", "CAM-4", "L3", 130.0, 150.0, state="ptz_4")


# --- fence ---------------------------------------------------------------------------


def _level_at(x, y):
    """(level, z) of ground at a plan point: a terrace, or the slope between two."""
    for lv, (x0, y0, x1, y1) in PLATFORMS.items():
        if x0 <= x <= x1 and y0 <= y <= y1:
            return lv, 0.0
    # Slopes: linear between the lower terrace's edge and the upper one's.
    if y < L2_BOX[3] and L1_BOX[2] < x < L2_BOX[0]:
        return "L1", (LEVELS["L2"] - LEVELS["L1"]) * (x - L1_BOX[2]) / (L2_BOX[0] - L1_BOX[2])
    if y > L3_BOX[1] and L1_BOX[2] < x < L3_BOX[0]:
        return "L1", (LEVELS["L3"] - LEVELS["L1"]) * (x - L1_BOX[2]) / (L3_BOX[0] - L1_BOX[2])
    if x > L3_BOX[0] and L2_BOX[3] < y < L3_BOX[1]:
        return "L2", (LEVELS["L3"] - LEVELS["L2"]) * (y - L2_BOX[3]) / (L3_BOX[1] - L2_BOX[3])
    raise ValueError(f"fence point ({x}, {y}) is on no terrace or slope")


def fence(plan: Plan) -> None:
    x0, y0, x1, y1 = FENCE
    n = 0
    runs = [  # start, direction, panels; counter-clockwise around the site
        ((x0, y0), (1, 0), round((x1 - x0) / 3)),
        ((x1, y0), (0, 1), round((y1 - y0) / 3)),
        ((x1, y1), (-1, 0), round((x1 - x0) / 3)),
        ((x0, y1), (0, -1), round((y1 - y0) / 3)),
    ]
    for (sx, sy), (dx, dy), count in runs:
        heading = math.degrees(math.atan2(dy, dx)) % 360.0
        for k in range(count):
            x, y = sx + dx * (1.5 + 3.0 * k), sy + dy * (1.5 + 3.0 * k)
            level, z = _level_at(x, y)
            n += 1
            plan.put("fence_segment", f"CERCA-{n:03d}", level, x, y, heading, round(z, 3))


# --- checks and output ----------------------------------------------------------------


def corners(item: Item):
    """(4, 2) corners of an item's footprint rectangle in the plan."""
    sx, sy = FOOTPRINT[item.asset]
    a = math.radians(item.heading)
    c, s = math.cos(a), math.sin(a)
    return [(item.x + u * c - v * s, item.y + u * s + v * c) for u, v in ((-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2))]


def overlaps(a: Item, b: Item) -> bool:
    """Separating-axis test of two footprint rectangles (touching is not overlapping)."""
    ca, cb = corners(a), corners(b)
    for poly in (ca, cb):
        for i in range(4):
            (px, py), (qx, qy) = poly[i], poly[(i + 1) % 4]
            nx, ny = qy - py, px - qx
            pa = [nx * x + ny * y for x, y in ca]
            pb = [nx * x + ny * y for x, y in cb]
            if max(pa) <= min(pb) + 1e-6 or max(pb) <= min(pa) + 1e-6:
                return False
    return True


def exempt(a: Item, b: Item) -> bool:
    """Pairs meant to share ground: busbars ride on supports; 500 kV equipment stands on
    its pedestal; fence panels chain."""
    kinds = {a.asset, b.asset}
    on_its_pedestal = "equipment_support" in kinds and {a.tag, b.tag} == {"SE-" + a.tag.removeprefix("SE-"),
                                                                           a.tag.removeprefix("SE-")}
    return kinds == {"rigid_busbar", "busbar_support"} or kinds == {"fence_segment"} or on_its_pedestal


def check(plan: Plan) -> None:
    tags = [i.tag for i in plan.items]
    dup = sorted({t for t in tags if tags.count(t) > 1})
    assert not dup, f"duplicate tags {dup}"
    items = plan.items
    for i, a in enumerate(items):
        ra = math.hypot(*FOOTPRINT[a.asset]) / 2
        for b in items[i + 1 :]:
            if math.hypot(a.x - b.x, a.y - b.y) > ra + math.hypot(*FOOTPRINT[b.asset]) / 2 or exempt(a, b):
                continue
            assert not overlaps(a, b), f"{a.tag} overlaps {b.tag}"


def build() -> Plan:
    plan = Plan()
    yard_500(plan)
    yard_230(plan)
    platform_3(plan)
    fence(plan)
    check(plan)
    return plan


def write(plan: Plan, out: Path) -> None:
    # Fixed dates and GUIDs and a fixed ezdxf version stamp, so two runs give the
    # same bytes (ezdxf's documented switch for reproducible output).
    previous = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True
    try:
        doc = ezdxf.new("R2010", setup=False)
        doc.header["$INSUNITS"] = 6
        doc.header["$MEASUREMENT"] = 1
        for name in (*(f"PLATFORM_{lv}" for lv in PLATFORMS), "ANNOTATION", "EQUIPMENT", *_sibling("wiring_plan").LAYERS):
            doc.layers.add(name)
        for asset in sorted(FOOTPRINT):
            # The block is a symbol: the footprint rectangle and attribute definitions.
            blk = doc.blocks.new(asset)
            sx, sy = FOOTPRINT[asset]
            blk.add_lwpolyline([(-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2)], close=True)
            for k, name in enumerate(("TAG", "LEVEL", "STATE")):
                blk.add_attdef(name, (0.0, -0.3 * k), dxfattribs={"height": 0.25})
        msp = doc.modelspace()
        for lv, (x0, y0, x1, y1) in PLATFORMS.items():
            msp.add_lwpolyline([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], close=True, dxfattribs={"layer": f"PLATFORM_{lv}"})
        for item in plan.items:
            ref = msp.add_blockref(item.asset, (item.x, item.y, item.z), dxfattribs={"rotation": item.heading, "layer": "EQUIPMENT"})
            attrs = {"TAG": item.tag, "LEVEL": item.level}
            if item.state:
                attrs["STATE"] = item.state
            for k, (name, value) in enumerate(attrs.items()):
                ref.add_attrib(name, value, (item.x, item.y - 0.3 * k), dxfattribs={"height": 0.25})
        wiring_plan = _sibling("wiring_plan")
        wiring_plan.draw(msp, wiring_plan.build(plan.items, D_CENTRES, P500, REACTOR_BANKS, B_CENTRES, P230))
        annotate(msp)
        fix_class_order(doc)
        out.parent.mkdir(parents=True, exist_ok=True)
        doc.saveas(out)
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = previous


def _sibling(name: str):
    """A module beside this script, also when this one is loaded by its path."""
    import importlib.util
    import sys

    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def fix_class_order(doc) -> None:
    """ezdxf registers the CLASSES of the entity types in use by iterating a set, whose
    order changes with Python's hash seed: register them now and sort the new ones."""
    before = list(doc.classes.classes)
    doc.classes.add_required_classes(doc.dxfversion)
    added = sorted(k for k in doc.classes.classes if k not in before)
    doc.classes.classes = OrderedDict((k, doc.classes.classes[k]) for k in before + added)


def annotate(msp) -> None:
    """Drawing notes that the reader must ignore (and count)."""
    a = {"layer": "ANNOTATION"}
    msp.add_text("SE SAMPLE 500/230 kV - PLANTA GERAL", height=3.0, dxfattribs=a).set_placement((0.0, 212.0))
    for lv, (x0, y0, x1, y1) in PLATFORMS.items():
        msp.add_text(f"PLATO {lv} EL. {LEVELS[lv]:.1f} m", height=2.0, dxfattribs=a).set_placement(((x0 + x1) / 2, y1 - 6.0))
    msp.add_line((0.0, -4.0), (104.0, -4.0), dxfattribs=a)
    msp.add_line((0.0, -6.0), (0.0, -2.0), dxfattribs=a)
    msp.add_line((104.0, -6.0), (104.0, -2.0), dxfattribs=a)
    dim = msp.add_linear_dim(base=(0.0, -8.0), p1=(0.0, 0.0), p2=(104.0, 0.0), dxfattribs=a)
    dim.render()


def resolve_out(arg: Path | None) -> Path:
    if arg is None:
        return DEFAULT_OUT
    if arg.suffix.lower() == ".dxf":
        return arg
    if arg.name == "assets":
        return arg.parent / "floorplan" / "substation.dxf"
    return arg / "substation.dxf"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=None, help="output .dxf file or folder")
    out = resolve_out(p.parse_args(argv).out)
    plan = build()
    write(plan, out)
    print(f"{out}: {len(plan.items)} INSERTs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
