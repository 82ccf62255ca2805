"""SDF applier (Gazebo): what a classic simulator can swap at run time.

- sun.jsonl: per step the sun's `<light type="directional">` fragment (direction of
  travel = -towards-sun, ENU; diffuse scaled by irradiance / G0) and the same values as
  JSON fields, for a plugin or a bridge to push to the running world.
- models/<asset>__state_<hash>/: per-state variants of a package, built ahead of time
  at a quantisation of `quantum` x each binding's domain span (default 10 % steps): a
  copy of the package's model.sdf edited with lxml (hardened parser) to set the bound
  visual's pose and material. Meshes stay model://<asset>/meshes/..., so a variant is
  two small files. Shape bindings have no SDF equivalent (no morph targets): they are
  listed under "not_applied".
- variants.jsonl: per step, which variant URI each stateful placement uses; a world
  swaps the <include> URI when it changes. With conductor temperatures, the step's
  "conductors": the sag variant the scene built nearest that temperature
  (scene/conductor_variants/, apply_conductors.sdf_choices), or null for the world's
  own as-built `conductors` model.
Only the quantised states that the run visits are built.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
from lxml import etree

from .. import ir
from ..export import names, sdf
from .. import safe_xml
from ..files import atomic_write
from ..geometry.transform import matrix_to_xyz_rpy
from . import nodes
from .. import sun as sunmod


def _f(v: float) -> str:
    return names.fmt(round(float(v), 9))


def _pose_text(m: np.ndarray) -> str:
    xyz, rpy = matrix_to_xyz_rpy(m)
    return " ".join(_f(v) for v in (*xyz, *rpy))


def sun_fragment(elev: float, az: float, irr: float, g0: float = sunmod.G0) -> dict:
    d = -sunmod.direction_enu(elev, az)
    level = max(0.0, min(1.0, irr / g0))
    diffuse = " ".join(_f(c) for c in (level, level, level, 1.0))
    xml = (f'<light name="sun" type="directional"><cast_shadows>true</cast_shadows>'
           f'<diffuse>{diffuse}</diffuse><direction>{" ".join(_f(c) for c in d)}</direction>'
           f'<intensity>{_f(level)}</intensity></light>')
    return {"direction": [float(_f(c)) for c in d], "intensity": float(_f(level)),
            "irradiance": float(_f(irr)), "sdf": xml}


def quantise(value: float, domain, quantum: float) -> float:
    d0, d1 = float(domain[0]), float(domain[1])
    lo, hi = min(d0, d1), max(d0, d1)
    q = quantum * (hi - lo)
    if q <= 0:
        return float(value)
    v = lo + round((min(hi, max(lo, float(value))) - lo) / q) * q
    return float(_f(min(hi, v)))


def _material(visual_el, record: dict) -> None:
    m = ir.Material(record["name"], tuple(record["base_color"]), record["metallic"], record["roughness"],
                    tuple(record["emission"]))
    sdf.material_element(visual_el, m)


def build_variant(model_sdf: bytes, name: str, states: list[nodes.VisualState], materials: dict) -> bytes:
    """A copy of model.sdf renamed `name`, each state's visual posed and dressed."""
    root = etree.fromstring(model_sdf, safe_xml.parser(remove_blank_text=True))
    model = root.find("model")
    model.set("name", name)
    for vs in states:
        visual = model.find(f"link[@name='{vs.link}']/visual[@name='{vs.visual}']")
        if visual is None:
            raise KeyError(f"{vs.link}/{vs.visual}")
        pose = visual.find("pose")
        if pose is None:
            pose = etree.Element("pose")
            visual.insert(0, pose)
        pose.text = _pose_text(vs.transform)
        if vs.material is not None and vs.material in materials:
            _material(visual, materials[vs.material])
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _config(name: str, asset: str) -> bytes:
    root = etree.Element("model")
    etree.SubElement(root, "name").text = name
    etree.SubElement(root, "version").text = "1.0"
    etree.SubElement(root, "sdf", version="1.9").text = "model.sdf"
    etree.SubElement(root, "description").text = f"state variant of {asset} (substation-twin runtime)"
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def write(run, out_dir: Path, quantum: float = 0.1, conductors: list[str | None] | None = None) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary: dict = {"files": [], "variants": [], "not_applied": []}
    if run.sun is not None:
        lines = [json.dumps({"k": k, "t": float(_f(t)), **sun_fragment(*s)}, sort_keys=True)
                 for k, (t, s) in enumerate(zip(run.times, run.sun))]
        atomic_write(out_dir / "sun.jsonl", ("\n".join(lines) + "\n").encode())
        summary["files"].append(str(out_dir / "sun.jsonl"))
    table = [dict() for _ in run.times]
    built: set[str] = set()
    for ob in sorted(run.observed, key=lambda o: o.tag):
        src = Path(ob.package or "") / "model.sdf"
        if not src.is_file():
            summary["not_applied"].append(f"{ob.tag}: no model.sdf in the package")
            continue
        sdf_bytes = src.read_bytes()
        materials = {m["name"]: m for m in ob.manifest.get("materials", [])}
        if any(r["effect"] == "shape" for r in ob.manifest.get("bindings", [])):
            summary["not_applied"].append(f"{ob.tag}: shape bindings have no SDF variant (no morph targets)")
        domains = {r["variable"]: r["domain"] for r in ob.manifest.get("bindings", [])}
        for k, frame in enumerate(run.frames):
            values = {bo.binding["variable"]: bo.value for vs in frame if vs.tag == ob.tag for bo in vs.outputs}
            if not values:
                continue
            q = {var: quantise(v, domains[var], quantum) for var, v in sorted(values.items())}
            key = json.dumps([ob.asset, q], sort_keys=True)
            name = f"{ob.asset}__state_{hashlib.sha256(key.encode()).hexdigest()[:10]}"
            if name not in built:
                states = nodes.visual_states({ob.state: q}, [ob])
                try:
                    data = build_variant(sdf_bytes, name, states, materials)
                except (KeyError, etree.XMLSyntaxError) as e:
                    summary["not_applied"].append(f"{ob.tag}: cannot edit {src}: {e}")
                    break
                atomic_write(out_dir / "models" / name / "model.sdf", data)
                atomic_write(out_dir / "models" / name / "model.config", _config(name, ob.asset))
                built.add(name)
                summary["variants"].append({"name": name, "asset": ob.asset, "state": q})
            table[k][ob.tag] = f"model://{name}"
    wires = {} if conductors is None else {"conductors": conductors}
    lines = [json.dumps({"k": k, "t": float(_f(t)), "placements": table[k],
                         **{key: v[k] for key, v in wires.items()}}, sort_keys=True)
             for k, t in enumerate(run.times)]
    atomic_write(out_dir / "variants.jsonl", ("\n".join(lines) + "\n").encode())
    summary["files"].append(str(out_dir / "variants.jsonl"))
    summary["variant_count"] = len(built)
    return summary
