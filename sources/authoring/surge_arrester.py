"""Author sources/assets/surge_arrester/surge_arrester.step: a metal-oxide surge arrester
as vendor CAD delivers it (ASSETS.md): millimetres, Y up, a bag of separate solids.

Built with gmsh's OpenCASCADE kernel. The vertical axis is model Y, ground at Y = 0 and
the foundation centre on the axis. Parts: base plate, insulating base, flanges, a
silicone housing with 40 alternating sheds, a top cap with a line terminal and a grading
ring held by three arms.

The STEP writer stamps the write time into the header; `write_step` pins it so a rerun
writes the same bytes. post_insulator.py and junction_box.py reuse the helpers here.

    .venv/bin/python sources/authoring/surge_arrester.py [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import re
import tempfile
from pathlib import Path

ASSETS = Path(__file__).resolve().parent.parent / "assets"
ASSET_ID = "surge_arrester"

# A fixed header date: the STEP file's content is what the build hashes.
STEP_DATE = "2025-01-01T00:00:00"
# Linear deflection the pipeline tessellates this CAD with (metres).
TESSELLATION_M = 0.0005

# Dimensions in millimetres (heights along Y).
BASE_PLATE = 500.0, 25.0           # square side, thickness
BASE_INSULATOR = 110.0, 125.0      # radius, height
FLANGE = 130.0, 40.0               # radius, thickness
HOUSING_CORE_R = 62.0
HOUSING_TOP = 4550.0
SHED_COUNT = 40
SHED_RADII = 150.0, 122.0          # big, small (alternating)
SHED_HEIGHT = 34.0                 # sloped top, rim to core
SHED_RIM = 6.0                     # vertical drip rim under each shed
CAP = 45.0, 160.0                  # radius, height above the top flange
TERMINAL = 20.0, 5000.0            # radius, top of the stud (overall height)
RING = 320.0, 30.0, 4300.0         # ring radius, tube radius, height (outer dia. 700)
RING_ARMS = 3
ARM_R = 12.0


def parse_out() -> Path:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ASSETS, help="assets folder to write into")
    return p.parse_args().out


def start_gmsh(model: str):
    """A fresh gmsh session that prints nothing; returns the OpenCASCADE kernel."""
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add(model)
    return gmsh.model.occ


def y_cylinder(occ, y0: float, height: float, radius: float) -> int:
    """A solid cylinder on the Y axis from y0 up by `height`."""
    return occ.addCylinder(0, y0, 0, 0, height, 0, radius)


def shed(occ, y_rim: float, radius: float) -> None:
    """One housing shed: a drip rim below `y_rim` and a cone sloping up to the core."""
    y_cylinder(occ, y_rim - SHED_RIM, SHED_RIM, radius)
    occ.addCone(0, y_rim, 0, 0, SHED_HEIGHT, 0, radius, HOUSING_CORE_R + 4.0)


def housing(occ, y_bottom: float) -> None:
    """Core tube and 40 sheds, big and small in turn, evenly over the core."""
    y_cylinder(occ, y_bottom, HOUSING_TOP - y_bottom, HOUSING_CORE_R)
    pitch = (HOUSING_TOP - y_bottom - 60.0) / SHED_COUNT
    for i in range(SHED_COUNT):
        y_rim = y_bottom + 40.0 + pitch * i
        shed(occ, y_rim, SHED_RADII[i % 2])


def grading_ring(occ, y_top_flange: float) -> None:
    """Torus about the Y axis and straight arms from the top flange out to it."""
    ring_r, tube_r, ring_y = RING
    occ.addTorus(0, ring_y, 0, ring_r, tube_r, zAxis=[0, 1, 0])
    flange_r = FLANGE[0]
    for k in range(RING_ARMS):
        a = math.pi / 2 + 2 * math.pi * k / RING_ARMS
        cx, cz = math.cos(a), math.sin(a)
        start = (flange_r * 0.8 * cx, y_top_flange + FLANGE[1] / 2, flange_r * 0.8 * cz)
        end = (ring_r * cx, ring_y, ring_r * cz)
        occ.addCylinder(*start, *(e - s for s, e in zip(start, end)), ARM_R)


def build(occ) -> None:
    side, plate_t = BASE_PLATE
    occ.addBox(-side / 2, 0, -side / 2, side, plate_t, side)
    ins_r, ins_h = BASE_INSULATOR
    y_cylinder(occ, plate_t, ins_h, ins_r)
    flange_r, flange_t = FLANGE
    y_bottom_flange = plate_t + ins_h
    y_cylinder(occ, y_bottom_flange, flange_t, flange_r)
    housing(occ, y_bottom_flange + flange_t)
    y_cylinder(occ, HOUSING_TOP, flange_t, flange_r)
    cap_r, cap_h = CAP
    y_cap = HOUSING_TOP + flange_t
    y_cylinder(occ, y_cap, cap_h, cap_r)
    stud_r, top = TERMINAL
    y_cylinder(occ, y_cap + cap_h, top - y_cap - cap_h, stud_r)
    grading_ring(occ, HOUSING_TOP)


# --- writing ---------------------------------------------------------------------------


def pin_header(text: str, file_name: str) -> str:
    """The STEP text with the FILE_NAME entry's name and time stamp fixed."""
    head, sep, body = text.partition("ENDSEC;")
    head = re.sub(r"FILE_NAME\('[^']*','[^']*'", f"FILE_NAME('{file_name}','{STEP_DATE}'", head, count=1)
    if f"'{STEP_DATE}'" not in head:
        raise RuntimeError("STEP header has no FILE_NAME entry to pin")
    return head + sep + body


def write_step(path: Path) -> Path:
    """Write the current gmsh model to `path` as STEP with a reproducible header."""
    import gmsh

    gmsh.model.occ.synchronize()
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / path.name
        gmsh.write(str(raw))
        text = raw.read_text(encoding="ascii")
    path.write_text(pin_header(text, path.name), encoding="ascii", newline="\n")
    return path


def write_asset_toml(folder: Path, fields: dict, lod_budgets, collision: str, terminals=()) -> Path:
    """asset.toml (schemas/asset.schema.json) from flat `fields`, in the given order;
    `terminals`: (name, (x, y, z)) conductor attachment points, metres, Z up."""
    lines = [f"{key} = {toml_value(value)}" for key, value in fields.items()]
    lines += ["", "[lod]", f"budgets_m = {toml_value(list(lod_budgets))}",
              "", "[collision]", f'mode = "{collision}"', ""]
    for name, xyz in terminals:
        lines += ["[[terminals]]", f'name = "{name}"',
                  "position = [" + ", ".join(repr(round(float(v), 6) + 0.0) for v in xyz) + "]", ""]
    path = folder / "asset.toml"
    path.write_text("\n".join(lines), encoding="utf-8", newline="\n")
    return path


def toml_value(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return str(value)


def main() -> None:
    import gmsh

    out = parse_out()
    occ = start_gmsh(ASSET_ID)
    try:
        build(occ)
        folder = out / ASSET_ID
        write_step(folder / f"{ASSET_ID}.step")
    finally:
        gmsh.finalize()
    write_asset_toml(folder, {
        "category": "surge_arrester",
        "description": "Metal-oxide surge arrester, silicone housing with 40 sheds and a grading ring (vendor STEP, mm, Y up)",
        "source": f"{ASSET_ID}.step",
        "units": "mm",
        "up_axis": "Y",
        "tessellation_tolerance_m": TESSELLATION_M,
        "triangle_budget": 100000,
        "mass_kg": 180.0,
    }, [0.003, 0.015, 0.06], "hull_per_link", terminals=[("line", (0.0, 0.0, TERMINAL[1] / 1000.0))])


if __name__ == "__main__":
    main()
