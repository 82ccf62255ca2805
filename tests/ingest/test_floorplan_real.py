"""Floor plans as drawn: a real third-party plan (../shared/corpus, copied into a tmp
dir) mapped as a user would map it, and generated hard cases (nesting, mirrors, half
turns, OCS, scaled blocks, every unit). Positions are checked against ezdxf's own
transforms (its virtual entities, followed down the handle chain) or worked out by
hand from the INSERT attributes."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import ezdxf
import ezdxf.units
import numpy as np
import pytest

from helpers import CORPUS, ROOT
from pipeline import config, ir
from pipeline.config import FloorplanOptions, load_site
from pipeline.errors import UserError
from pipeline.ingest.floorplan import (UNITS, read_floorplan, read_floorplan_memo,
                                       require_placements_and_platforms, scan_floorplan)

CORPUS_PLAN = CORPUS / "dxf" / "architectural_plan_mm.dxf"

SITE = """
[site]
name = "real"
timezone = "UTC"
floorplan = "floorplan/plan.dxf"
[plan]
crs = "EPSG:31984"
grid_origin = [576000.0, 8595900.0]
{plan}
[[levels]]
name = "L1"
elevation = 10.0
[[levels]]
name = "L2"
elevation = 12.0
{floorplan}
"""

# What a user writes for the corpus plan: its blocks have CAD names, its one attribute
# tag is "A" (all empty), it has no level attribute.
CORPUS_FLOORPLAN = """
[floorplan]
default_level = "L1"
attributes = { tag = "A" }
[floorplan.blocks]
"M_*" = "cabinet"          # the five (-s, -s, s) half turns are M_ blocks
"304070958*" = "cabinet"
"EQ-F" = "panel"           # OCS: extrusion (0, 0, -1)
"EQ-P" = "panel"
"ID8" = "lamp"             # nested 2 and 3 deep, OCS
"A$C67443EF0" = "lamp"     # 3 deep
"A$C63C96F4B" = "door"     # in modelspace and nested in A$C2497704E
"sczn1" = "seat"           # scales like 1.26 with 1e-11 of noise
"""
CORPUS_ASSETS = {"cabinet", "panel", "lamp", "door", "seat"}


def corpus_mapped(name: str) -> bool:
    """The mapping above, written out without patterns."""
    return name.startswith(("M_", "304070958")) or name in {"EQ-F", "EQ-P", "ID8", "A$C67443EF0", "A$C63C96F4B", "sczn1"}


def write_site(root: Path, plan: str = "", floorplan: str = "") -> Path:
    (root / "floorplan").mkdir(parents=True, exist_ok=True)
    (root / "site.toml").write_text(textwrap.dedent(SITE.format(plan=plan, floorplan=floorplan)))
    return root / "site.toml"


def ezdxf_pose(doc, chain) -> tuple[np.ndarray, float, np.ndarray]:
    """(origin in drawing units, heading in degrees, (3, 3) linear part) of the block
    at the end of a handle chain, as ezdxf itself transforms it: the modelspace
    INSERT's virtual entities followed down the chain."""
    ref = doc.entitydb[chain[0]]
    for handle in chain[1:]:
        ref = next(v for v in ref.virtual_entities()
                   if v.dxftype() == "INSERT" and v.source_of_copy.dxf.handle == handle)
    m = ref.matrix44()
    x = m.transform_direction((1, 0, 0))
    linear = np.array([m.transform_direction(a) for a in ((1, 0, 0), (0, 1, 0), (0, 0, 1))])
    return np.array(m.transform((0, 0, 0))), math.degrees(math.atan2(x.y, x.x)), linear


def mapped_chains(doc, mapped) -> list[tuple[str, ...]]:
    """Every handle chain from a modelspace INSERT to an INSERT of a mapped block,
    through unmapped blocks, found with ezdxf's virtual entities."""
    out = []

    def walk(ref, chain):
        chain = (*chain, (ref.source_of_copy or ref).dxf.handle)
        if mapped(ref.dxf.name):
            out.append(chain)
            return
        for v in ref.virtual_entities():
            if v.dxftype() == "INSERT":
                walk(v, chain)

    for e in doc.modelspace().query("INSERT"):
        walk(e, ())
    return out


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


# --- the corpus plan -------------------------------------------------------------------


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    if not CORPUS_PLAN.is_file():
        pytest.skip(f"no corpus at {CORPUS_PLAN}")
    root = tmp_path_factory.mktemp("corpus")
    site_toml = write_site(root, floorplan=CORPUS_FLOORPLAN)
    shutil.copy(CORPUS_PLAN, root / "floorplan" / "plan.dxf")
    site = load_site(site_toml)
    path = site.root / site.floorplan
    fp, problems = scan_floorplan(path, CORPUS_ASSETS, set(site.level_names), site.floorplan_options)
    return site, path, ezdxf.readfile(path), fp, problems


def test_corpus_every_mapped_insert_is_placed_or_reported_by_handle(corpus):
    """Each chain ezdxf leads to a mapped block is a placement, or a problem naming its
    handles when the chain's linear part is mirrored (negative determinant) or
    non-uniform (singular values apart), and nothing else."""
    site, path, doc, fp, problems = corpus
    chains = mapped_chains(doc, corpus_mapped)
    bad = {}
    for chain in chains:
        _, _, linear = ezdxf_pose(doc, chain)
        sv = np.linalg.svd(linear, compute_uv=False)
        if np.linalg.det(linear) < 0 or sv[0] - sv[-1] > 1e-6 * sv[0]:
            bad[chain] = ("mirrored" if np.linalg.det(linear) < 0 else "non-uniform")
    placed = {p.dxf_handles for p in fp.placements}
    assert placed == set(chains) - set(bad)
    assert len(problems) == len(bad) > 0
    for chain, what in bad.items():
        name = " > ".join(f"#{h}" for h in chain)
        (problem,) = [p for p in problems if p.obj == f"INSERT {name}"]
        assert what in problem.message and problem.file == str(path)
    assert {len(c) for c in placed} == {1, 2, 3}  # nested 3 deep
    # every INSERT of a mapped block met is accounted for
    assert sum(n for b, n in fp.inserts if corpus_mapped(b)) == len(chains)


def test_corpus_positions_and_headings_match_ezdxf(corpus):
    site, path, doc, fp, problems = corpus
    worst_m, worst_deg = 0.0, 0.0
    for p in fp.placements:
        origin, heading, _ = ezdxf_pose(doc, p.dxf_handles)
        worst_m = max(worst_m, float(np.abs(np.array([p.x, p.y, p.z]) - origin * 0.001).max()))
        worst_deg = max(worst_deg, angle_diff(p.heading_deg, heading))
        assert p.handle == p.dxf_handles[-1] and p.level == "L1" and p.scale == 1.0
    assert worst_m < 1e-6 and worst_deg < 1e-6
    assert sum(len(p.dxf_handles) > 1 for p in fp.placements) > 50


def test_corpus_half_turns_and_ocs_inserts_are_placed(corpus):
    site, path, doc, fp, problems = corpus
    by_handle = {p.handle: p for p in fp.placements}
    half_turns = [e for e in doc.modelspace().query("INSERT") if e.dxf.xscale < 0 and e.dxf.yscale < 0 < e.dxf.zscale]
    assert len(half_turns) == 5
    for e in half_turns:  # (-s, -s, s): a plain 180 degree turn, never a mirror
        assert angle_diff(by_handle[e.dxf.handle].heading_deg, e.dxf.rotation + 180.0) < 1e-9
    ocs = [e for e in doc.entitydb.values() if e.dxftype() == "INSERT" and tuple(e.dxf.extrusion) == (0, 0, -1)]
    upright = [e for e in ocs if e.dxf.xscale * e.dxf.zscale > 0]  # x and z flipped back: a turn
    assert upright and all(e.dxf.handle in by_handle for e in upright if e.dxf.name.startswith("EQ-"))
    placed_ocs = [p for p in fp.placements if p.handle in {e.dxf.handle for e in ocs}]
    assert len(placed_ocs) >= 5 and any(len(p.dxf_handles) == 1 for p in placed_ocs)
    # the mirrored ones among them are reported, not placed
    mirrored = [e for e in ocs if e.dxf.xscale * e.dxf.zscale < 0 and e.dxf.name.startswith("EQ-")]
    assert mirrored and all(any(f"#{e.dxf.handle}" in p.obj and "mirrored" in p.message for p in problems)
                            for e in mirrored)


def test_corpus_tags_derived_and_warnings(corpus):
    site, path, doc, fp, problems = corpus
    assert all(p.tag == "insert_" + "_".join(p.dxf_handles) for p in fp.placements)  # every "A" is empty
    (left_out,) = [w for w in fp.warnings if "left out" in w]
    assert "A$C10FB1B64 x116" in left_out and "_WBLK x44" in left_out
    (no_platforms,) = [w for w in fp.warnings if w.startswith("no platforms")]
    assert "PLATFORM_L1, PLATFORM_L2" in no_platforms and "WINDOW x40" in no_platforms
    assert not any(w.startswith("no placements") for w in fp.warnings)
    assert dict(fp.ignored) == {"ARC": 68, "CIRCLE": 49, "LINE": 1248, "LWPOLYLINE": 477, "TEXT": 340}


def test_corpus_read_raises_every_problem_at_once(corpus):
    site, path, doc, fp, problems = corpus
    with pytest.raises(UserError) as e:
        read_floorplan(path, CORPUS_ASSETS, set(site.level_names), site.floorplan_options)
    assert e.value.file == str(path) and e.value.obj == f"{len(problems)} problems"
    lines = e.value.message.splitlines()[1:]
    assert lines == [f"  {p.obj}: {p.message}" for p in problems]


def test_corpus_unmapped_says_what_it_holds(corpus, tmp_path):
    site, path, doc, fp, problems = corpus
    empty, _ = scan_floorplan(path, CORPUS_ASSETS, set(site.level_names), FloorplanOptions(units="mm"))
    assert empty.placements == ()
    (no_placements,) = [w for w in empty.warnings if w.startswith("no placements")]
    assert "631 INSERTs of 34 blocks" in no_placements and "sczn1 x141" in no_placements
    with pytest.raises(UserError) as e:
        require_placements_and_platforms(empty)
    assert e.value.file == str(path) and "no placements" in e.value.message and "no platforms" in e.value.message


# --- generated hard cases --------------------------------------------------------------


def new_doc(units: int = 6):
    doc = ezdxf.new("R2018", setup=False)
    doc.header["$INSUNITS"] = units
    doc.blocks.new("breaker").add_line((0, 0), (1, 0))
    return doc


def tagged(ref, tag=None, level="L1"):
    for name, value in (("TAG", tag), ("LEVEL", level)):
        if value is not None:
            ref.add_attrib(name, value, (0, 0))
    return ref


def rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def read(doc, tmp_path, name="plan.dxf", **options) -> tuple[ir.FloorPlan, list[UserError]]:
    doc.saveas(tmp_path / name)
    return scan_floorplan(tmp_path / name, {"breaker"}, {"L1", "L2"}, FloorplanOptions(**options))


def nested_plan(bay_xscale: float = 1.0, row_xscale: float = 1.0):
    """ROW (base point (1, 2, 0)) holds two BAYs; a BAY holds one breaker. Returns the
    document and, per breaker, its expected position and heading worked out by hand."""
    doc = new_doc()
    bay = doc.blocks.new("BAY")
    bay.add_blockref("breaker", (3.0, 0.5, 0.25), dxfattribs={"rotation": 30.0})
    row = doc.blocks.new("ROW", base_point=(1.0, 2.0, 0.0))
    row.add_blockref("BAY", (10.0, 0.0), dxfattribs={"xscale": bay_xscale})
    row.add_blockref("BAY", (20.0, 0.0), dxfattribs={"rotation": 90.0, "xscale": bay_xscale})
    tagged(doc.modelspace().add_blockref("ROW", (100.0, 50.0, 2.0), dxfattribs={"rotation": 45.0, "xscale": row_xscale}),
           level="L2")
    expected = []
    inner = np.array([3.0, 0.5, 0.25])
    for at, turn in (((10.0, 0.0, 0.0), 90.0 * 0), ((20.0, 0.0, 0.0), 90.0)):
        in_row = rot_z(turn) @ (np.diag([bay_xscale, 1, 1]) @ inner) + at - (1.0, 2.0, 0.0)
        world = rot_z(45.0) @ (np.diag([row_xscale, 1, 1]) @ in_row) + (100.0, 50.0, 2.0)
        expected.append((world, (45.0 + turn + 30.0) % 360.0))
    return doc, expected


def test_nested_inserts_placed_with_the_composed_transform(tmp_path):
    doc, expected = nested_plan()
    fp, problems = read(doc, tmp_path)
    assert problems == [] and len(fp.placements) == 2
    got = sorted(fp.placements, key=lambda p: p.x)
    want = sorted(expected, key=lambda e: e[0][0])
    for p, (pos, heading) in zip(got, want):
        assert np.abs(np.array([p.x, p.y, p.z]) - pos).max() < 1e-12
        assert angle_diff(p.heading_deg, heading) < 1e-9
        assert len(p.dxf_handles) == 3 and p.level == "L2"  # the level of the ROW INSERT around it
        assert p.tag == "insert_" + "_".join(p.dxf_handles)
    again, _ = read(ezdxf.readfile(tmp_path / "plan.dxf"), tmp_path, "again.dxf")  # saved once more
    assert [p.tag for p in again.placements] == [p.tag for p in fp.placements]


def test_mirrored_nested_inserts_are_all_reported_and_a_double_mirror_is_a_turn(tmp_path):
    doc, _ = nested_plan(bay_xscale=-1.0)
    fp, problems = read(doc, tmp_path)
    assert fp.placements == () and len(problems) == 2
    for p in problems:
        assert p.obj.startswith("INSERT #") and p.obj.count(" > ") == 2 and "mirrored" in p.message
    with pytest.raises(UserError) as e:
        read_floorplan(tmp_path / "plan.dxf", {"breaker"}, {"L1", "L2"})
    assert e.value.obj == "2 problems" and all(p.obj in e.value.message for p in problems)
    doc, expected = nested_plan(bay_xscale=-1.0, row_xscale=-1.0)
    fp, problems = read(doc, tmp_path, "twice.dxf")
    assert problems == [] and len(fp.placements) == 2
    for p in fp.placements:
        pos, heading = min(expected, key=lambda e: np.abs(e[0] - (p.x, p.y, p.z)).max())
        assert np.abs(np.array([p.x, p.y, p.z]) - pos).max() < 1e-12
        # two mirrors in x: the breaker's x axis runs where the mirrored chain sends it
        assert p.heading_deg == pytest.approx(ezdxf_pose(ezdxf.readfile(tmp_path / "twice.dxf"), p.dxf_handles)[1] % 360.0, abs=1e-9)


def test_half_turn_scale_is_a_rotation_and_non_uniform_is_reported(tmp_path):
    doc = new_doc()
    msp = doc.modelspace()
    tagged(msp.add_blockref("breaker", (5, 5), dxfattribs={"xscale": -2, "yscale": -2, "zscale": 2, "rotation": 10}), "HALF")
    tagged(msp.add_blockref("breaker", (6, 5), dxfattribs={"xscale": 1, "yscale": 1 + 2e-7, "zscale": 1}), "NEAR")
    tagged(msp.add_blockref("breaker", (7, 5), dxfattribs={"xscale": 1, "yscale": 1 + 2e-6, "zscale": 1}), "FAR")
    tagged(msp.add_blockref("breaker", (8, 5), dxfattribs={"xscale": 1, "yscale": 1, "zscale": -1}), "ZFLIP")
    tagged(msp.add_blockref("breaker", (9, 5), dxfattribs={"xscale": -1, "yscale": 1, "zscale": -1}), "UPSIDE")
    fp, problems = read(doc, tmp_path)
    by_tag = {p.tag: p for p in fp.placements}
    assert set(by_tag) == {"HALF", "NEAR"}
    assert by_tag["HALF"].heading_deg == pytest.approx(190.0, abs=1e-9)
    assert by_tag["NEAR"].heading_deg == 0.0 and by_tag["NEAR"].scale == 1.0
    messages = {p.obj.split()[1]: p.message for p in problems}
    assert "non-uniform" in messages["FAR"] and "mirrored" not in messages["FAR"]
    assert "mirrored" in messages["ZFLIP"]
    assert "z axis" in messages["UPSIDE"] and "mirrored" not in messages["UPSIDE"]  # a turn about x, upside down


def test_ocs_inserts(tmp_path):
    """Extrusion (0, 0, -1): OCS x is WCS -x, OCS z is WCS -z. With x and z scales
    negative the block stands upright, turned by minus its rotation."""
    doc = new_doc()
    msp = doc.modelspace()
    tagged(msp.add_blockref("breaker", (10, 5, -2), dxfattribs={
        "extrusion": (0, 0, -1), "xscale": -1, "yscale": 1, "zscale": -1, "rotation": 30}), "OCS-UP")
    tagged(msp.add_blockref("breaker", (10, 5, -2), dxfattribs={"extrusion": (0, 0, -1), "rotation": 30}), "OCS-DOWN")
    fp, problems = read(doc, tmp_path)
    (p,) = fp.placements
    assert (p.tag, p.x, p.y, p.z) == ("OCS-UP", -10.0, 5.0, 2.0)
    assert p.heading_deg == pytest.approx(330.0, abs=1e-9)
    (down,) = problems
    assert "OCS-DOWN" in down.obj and "z axis" in down.message


def test_scaled_block_with_base_point(tmp_path):
    doc = new_doc()
    doc.blocks.new("SYMBOL", base_point=(1.0, 1.0, 0.0)).add_blockref("breaker", (0, 0))
    tagged(doc.modelspace().add_blockref("SYMBOL", (20, 10), dxfattribs={"xscale": 2.5, "yscale": 2.5, "zscale": 2.5,
                                                                        "rotation": 90}), "S-1")
    for mode, scale in (("ignore", 1.0), ("apply", 2.5)):
        fp, problems = read(doc, tmp_path, f"{mode}.dxf", insert_scale=mode)
        (p,) = fp.placements
        assert problems == [] and p.level == "L1"  # the level of the SYMBOL INSERT around it
        assert (p.x, p.y) == pytest.approx((20 + 2.5, 10 - 2.5), abs=1e-12)  # -2.5 * R90 (1, 1)
        assert p.heading_deg == 90.0 and p.scale == pytest.approx(scale, rel=1e-12)


@pytest.mark.parametrize("code", sorted(UNITS))
def test_every_unit_for_x_y_and_z(tmp_path, code):
    name, metres = UNITS[code]
    doc = new_doc(units=code)
    at = np.array([12.5, -7.25, 1.5])
    tagged(doc.modelspace().add_blockref("breaker", tuple(at / metres)), "U-1")
    doc.modelspace().add_lwpolyline([(v / metres, w / metres) for v, w in ((0, 0), (30, 0), (30, 20))], close=True,
                                    dxfattribs={"layer": "PLATFORM_L1"})
    fp, problems = read(doc, tmp_path)
    (p,) = fp.placements
    assert fp.units == name and problems == []
    assert np.allclose((p.x, p.y, p.z), at, rtol=1e-14, atol=0)
    assert np.allclose(fp.platforms[0].outline[1], (30, 0), rtol=1e-14, atol=1e-14)
    try:
        theirs = ezdxf.units.conversion_factor(code, 6)
    except (TypeError, ValueError, IndexError):
        theirs = None  # ezdxf has no factor for survey units, mils, microinches
    if theirs is not None and name not in ("ly", "pc"):  # ezdxf rounds these to three digits
        assert metres == pytest.approx(theirs, rel=1e-8)  # and miles to eleven


def test_unitless_drawing_and_plan_units(tmp_path):
    doc = new_doc(units=0)
    tagged(doc.modelspace().add_blockref("breaker", (10, 20, 1)), "U-1")
    with pytest.raises(UserError) as e:
        read(doc, tmp_path)
    assert e.value.obj == "$INSUNITS" and "[plan] units" in e.value.message
    fp, _ = read(doc, tmp_path, units="ft")
    assert fp.units == "ft" and (fp.placements[0].x, fp.placements[0].z) == pytest.approx((3.048, 0.3048), rel=1e-15)
    metres = new_doc(units=6)
    tagged(metres.modelspace().add_blockref("breaker", (10, 20, 1)), "U-1")
    fp, _ = read(metres, tmp_path, "m.dxf", units="cm")  # site.toml overrides, and says so
    assert fp.units == "cm ([plan] units; $INSUNITS says m)" and fp.placements[0].x == pytest.approx(0.1)


def test_insertion_z_takes_the_drawing_unit_only(tmp_path):
    doc = new_doc(units=4)
    tagged(doc.modelspace().add_blockref("breaker", (10_000, 20_000, 62_500)), "Z-1")
    fp, _ = read(doc, tmp_path)
    (p,) = fp.placements
    assert (p.x, p.y) == (10.0, 20.0)  # georef applies grid_scale to x and y only
    assert p.z == 62.5  # a height is the drawing unit's: grid_scale is horizontal


def test_missing_tag_and_level_and_renamed_attributes(tmp_path):
    doc = new_doc()
    msp = doc.modelspace()
    tagged(msp.add_blockref("breaker", (1, 0)), None, None)
    ref = msp.add_blockref("breaker", (2, 0))
    ref.add_attrib("KKS", "52-1A", (0, 0))
    ref.add_attrib("NIVEL", "L2", (0, 0))
    ref.add_attrib("TAG", "ignored", (0, 0))
    fp, problems = read(doc, tmp_path)
    assert len(problems) == 2 and all("no LEVEL attribute" in p.message and "default_level" in p.message for p in problems)
    assert "INSERT ignored (#" in problems[1].obj  # read as TAG until site.toml names KKS
    fp, problems = read(doc, tmp_path, "renamed.dxf", default_level="L1", tag_attribute="kks", level_attribute="NIVEL")
    assert problems == []
    first, second = sorted(fp.placements, key=lambda p: p.x)
    assert (first.tag, first.level) == (f"insert_{first.handle}", "L1")
    assert (second.tag, second.level) == ("52-1A", "L2")


def test_block_mapping_patterns_and_asset_names(tmp_path):
    doc = new_doc()
    for name in ("A$C10FB1B64", "CB-500kV", "变压器", "Other"):
        doc.blocks.new(name).add_line((0, 0), (1, 0))
    msp = doc.modelspace()
    for i, name in enumerate(("A$C10FB1B64", "CB-500kV", "cb-500KV", "变压器", "breaker", "Other", "Other")):
        tagged(msp.add_blockref(name, (i, 0)), f"T-{i}" if name != "Other" else None)
    blocks = (("CB-*", "breaker"), ("a$c10fb1b64", "breaker"), ("变压器", "transformer"), ("*kV", "nothing"))
    doc.saveas(tmp_path / "plan.dxf")
    fp, problems = scan_floorplan(tmp_path / "plan.dxf", {"breaker", "transformer"}, {"L1"},
                                  FloorplanOptions(blocks=blocks))
    assert {p.tag: p.asset_id for p in fp.placements} == {
        "T-0": "breaker", "T-1": "breaker", "T-2": "breaker", "T-3": "transformer", "T-4": "breaker"}
    assert problems == []
    (left_out,) = [w for w in fp.warnings if "left out" in w]
    assert left_out.startswith("2 INSERTs of 1 blocks place nothing") and "Other x2" in left_out
    fp, problems = scan_floorplan(tmp_path / "plan.dxf", {"breaker"}, {"L1"},
                                  FloorplanOptions(blocks=(("变压器", "transfomer"),)))
    assert sorted(q.obj.split()[1] for q in problems) == ["T-0", "T-1", "T-2", "T-3"]  # tagged, none mapped
    (p,) = [q for q in problems if "T-3" in q.obj]
    assert "'transfomer'" in p.message and "site.toml [floorplan] blocks" in p.message and "T-3" in p.obj


def test_tagged_insert_of_no_asset_is_an_error(tmp_path):
    """A tagged INSERT is equipment: an unknown block is an error, not a warning, and
    the hint is one a user can follow."""
    doc = new_doc()
    for name in ("变压器", "breakr"):
        doc.blocks.new(name).add_line((0, 0), (1, 0))
        tagged(doc.modelspace().add_blockref(name, (0, 0)), f"T-{name}")
    fp, problems = read(doc, tmp_path)
    cjk, typo = sorted(problems, key=lambda p: "变压器" not in p.message)
    assert "'变压器' is not an asset and site.toml [floorplan] blocks maps it to none" in cjk.message
    assert "sources/assets" not in cjk.message  # no such folder name can exist
    assert "(no sources/assets/breakr/)" in typo.message and "did you mean asset 'breaker'?" in typo.message
    assert not [w for w in fp.warnings if "left out" in w]


def test_duplicate_tags_of_nested_inserts_name_both_chains(tmp_path):
    doc = new_doc()
    tagged(doc.blocks.new("BAY").add_blockref("breaker", (0, 0)), "52-1")
    for x in (0, 10):
        doc.modelspace().add_blockref("BAY", (x, 0))
    fp, problems = read(doc, tmp_path)
    (p,) = problems
    assert "duplicate TAG" in p.message and p.obj.count(" > ") == 1 and p.message.count(" > ") == 1


def test_memo_keeps_handles_and_follows_the_options(tmp_path):
    doc, _ = nested_plan()
    doc.saveas(tmp_path / "plan.dxf")
    memo = tmp_path / "memo.json"
    first = read_floorplan_memo(tmp_path / "plan.dxf", {"breaker"}, {"L1", "L2"}, memo)
    again = read_floorplan_memo(tmp_path / "plan.dxf", {"breaker"}, {"L1", "L2"}, memo)
    assert again == first and all(isinstance(p.dxf_handles, tuple) for p in again.placements)
    scaled = read_floorplan_memo(tmp_path / "plan.dxf", {"breaker"}, {"L1", "L2"}, memo,
                                 FloorplanOptions(units="cm"))  # the options enter the memo's key
    assert [p.z for p in scaled.placements] == pytest.approx([p.z / 100 for p in first.placements], rel=1e-15)


def test_site_toml_floorplan_and_units(tmp_path):
    site = load_site(write_site(tmp_path, plan='units = "ft"\ngrid_scale = 0.9996', floorplan=textwrap.dedent("""
        [floorplan]
        default_level = "L2"
        insert_scale = "apply"
        attributes = { tag = "KKS" }
        [floorplan.blocks]
        "CB*" = "breaker"
        "A$C1" = "breaker"
        """)))
    o = site.floorplan_options
    assert o.blocks == (("CB*", "breaker"), ("A$C1", "breaker"))
    assert (o.tag_attribute, o.level_attribute, o.state_attribute) == ("KKS", "LEVEL", "STATE")
    assert (o.default_level, o.insert_scale, o.units) == ("L2", "apply", "ft")
    assert load_site(write_site(tmp_path / "plain")).floorplan_options == FloorplanOptions()
    for plan, floorplan, key in (("", '[floorplan]\ndefault_level = "L9"', "floorplan.default_level"),
                                 ('units = "furlong"', "", "plan.units"),
                                 ("", '[floorplan]\nblocks = { "X" = "Not An Id" }', "floorplan.blocks.X"),
                                 ("", '[floorplan]\ninsert_scale = "stretch"', "floorplan.insert_scale")):
        with pytest.raises(UserError) as e:
            load_site(write_site(tmp_path / "bad", plan=plan, floorplan=floorplan))
        assert e.value.obj == key


def test_schema_units_are_the_readers():
    names = config.schema("site")["properties"]["plan"]["properties"]["units"]["enum"]
    assert sorted(names) == sorted(name for name, _ in UNITS.values())


def test_placements_json_records_the_handles():
    from pipeline.scene.assemble import _placements_record
    from pipeline.scene.placements import Placed

    site = load_site(ROOT / "sources" / "site.toml")
    plain = ir.Placement("52-1A", "circuit_breaker", "L1", 1.0, 2.0, handle="2F", dxf_handles=("1A", "2F"))
    scaled = ir.Placement("52-1B", "circuit_breaker", "L1", 1.0, 2.0, handle="30", dxf_handles=("30",), scale=2.5)
    placed = [Placed(p, np.eye(4), 0.0) for p in (plain, scaled)]
    fp = ir.FloorPlan("plan.dxf", "m", (plain, scaled), ())
    record = _placements_record(site, fp, placed, (0.0, 0.0, 0.0), {}, "t", {}, [])
    json.dumps(record)
    first, second = record["placements"]
    assert first["dxf_handles"] == ["1A", "2F"] and "scale" not in first
    assert second["dxf_handles"] == ["30"] and second["scale"] == 2.5


def test_corpus_plan_builds_a_scene_with_its_handles(corpus, tmp_path):
    """The corpus plan in a sources tree, as a user gets it to build: two mini assets
    mapped to CAD blocks (half turns, OCS, 3 deep), the mirrored INSERTs the first
    build lists deleted in CAD, a terrace drawn around everything."""
    import ezdxf.bbox

    import mini_sources
    from pipeline.builder.run import build

    root = mini_sources.make(tmp_path / "sources")
    floorplan = '[floorplan]\ndefault_level = "L1"\nattributes = { tag = "A" }\n[floorplan.blocks]\n' \
                '"M_A2ZXL" = "kiosk"\n"A$C67443EF0" = "pole"\n"EQ-*" = "pole"\n'
    (root / "site.toml").write_text((root / "site.toml").read_text() + floorplan)
    plan = root / "floorplan" / "plan.dxf"
    shutil.copy(CORPUS_PLAN, plan)
    site = load_site(root / "site.toml")
    with pytest.raises(UserError) as e:
        build(root, tmp_path / "build", quiet=True)
    doc = ezdxf.readfile(plan)
    msp = doc.modelspace()
    listed = [line.split("#")[1].split(":")[0] for line in e.value.message.splitlines()[1:]]
    assert len(listed) == 3 and "no platforms" not in e.value.message  # the INSERTs come first
    for handle in listed:
        msp.delete_entity(doc.entitydb[handle])
    (x0, y0, _), (x1, y1, _) = ezdxf.bbox.extents(msp, fast=True).extmin, ezdxf.bbox.extents(msp, fast=True).extmax
    msp.add_lwpolyline([(x0 - 1e3, y0 - 1e3), (x1 + 1e3, y0 - 1e3), (x1 + 1e3, y1 + 1e3), (x0 - 1e3, y1 + 1e3)],
                       close=True, dxfattribs={"layer": "PLATFORM_L1"})
    doc.saveas(plan)
    report = build(root, tmp_path / "build", quiet=True)
    assert not report.failed
    record = json.loads((tmp_path / "build" / "scene" / "placements.json").read_text())
    chains = [tuple(p["dxf_handles"]) for p in record["placements"]]
    assert sorted(chains) == sorted(mapped_chains(doc, lambda b: b in ("M_A2ZXL", "A$C67443EF0") or b.startswith("EQ-")))
    assert max(map(len, chains)) == 3 and site.floorplan_options.default_level == "L1"
    for p in record["placements"]:
        origin, heading, _ = ezdxf_pose(doc, p["dxf_handles"])
        assert np.abs(np.array(p["plan"]) - origin * 0.001).max() < 1e-6
        assert angle_diff(p["heading_deg"], heading) < 1e-6
        assert p["tag"] == "insert_" + "_".join(p["dxf_handles"])


def test_scaled_inserts_are_one_warning_under_ignore(tmp_path):
    doc = new_doc()
    msp = doc.modelspace()
    for i, s in enumerate((2.0, 2.0, 1.5, 1.0, -1.0)):  # -1 in x and y: a half turn, not a scale
        tagged(msp.add_blockref("breaker", (i, 0), dxfattribs={"xscale": s, "yscale": s, "zscale": abs(s)}), f"S-{i}")
    fp, problems = read(doc, tmp_path)
    assert problems == [] and all(p.scale == 1.0 for p in fp.placements)
    (warning,) = [w for w in fp.warnings if "scaled" in w]
    assert warning.startswith("3 INSERTs are drawn scaled (2 x2, 1.5 x1)") and 'insert_scale = "ignore"' in warning
    fp, _ = read(doc, tmp_path, "apply.dxf", insert_scale="apply")
    assert [p.scale for p in fp.placements] == pytest.approx([2.0, 2.0, 1.5, 1.0, 1.0], rel=1e-12)
    assert not [w for w in fp.warnings if "scaled" in w]


def test_inserts_absorbed_by_a_mapped_container_are_counted(tmp_path):
    doc, _ = nested_plan()  # ROW > 2 BAY > 1 breaker each
    fp, problems = read(doc, tmp_path)
    assert problems == [] and fp.absorbed == ()  # exploded: nothing absorbed
    tagged(doc.modelspace().add_blockref("ROW", (300.0, 50.0)), "ROW-2", level="L1")
    fp, problems = read(doc, tmp_path, "mapped.dxf", blocks=(("ROW", "breaker"),))
    assert problems == [] and len(fp.placements) == 2
    assert fp.absorbed == (("ROW", 8),)  # per ROW placement: 2 BAYs and the breaker in each


def test_twin_info_counts_the_absorbed_inserts(tmp_path):
    import mini_sources

    def bolts(msp):  # three INSERTs inside every kiosk: four kiosks absorb twelve
        msp.doc.blocks.new("BOLT").add_circle((0, 0), 0.01)
        for i in range(3):
            msp.doc.blocks.get("kiosk").add_blockref("BOLT", (0.1 * i, 0))

    sources = mini_sources.make(tmp_path / "sources")
    mini_sources.write_plan(sources / "floorplan" / "plan.dxf", extra=bolts)
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "info", "--sources", str(sources)],
                          capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "INSERTs absorbed by mapped blocks (their models stand for them): 12 in kiosk x12" in proc.stdout
