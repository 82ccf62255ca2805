"""`twin run SCENARIO`: step the scenario's graph, map the render node's values through
the placements' manifests, write states.jsonl and apply the result to every format the
build produced (USD layer, animated glTF copies, SDF variants and sun fragments).

The runtime reads the build only through files meant for it: build/scene/placements.json
(TAG, asset, STATE of every placement, the site's time zone), build/models/<asset>/manifest.json, and the
packages' model files named there; never the build internals.
"""

from __future__ import annotations

import datetime as dt
import json
import time
from dataclasses import dataclass
from pathlib import Path

from .. import config
from ..errors import UserError
from ..export import manifest as manifest_io
from ..files import atomic_write
from . import graph, nodes


@dataclass
class RunData:
    """Everything an applier needs. frames[k]: VisualStates at times[k]; sun[k]:
    (elevation rad, azimuth rad, irradiance W/m2) or sun None without a sun node."""

    scenario: graph.Scenario
    times: list[float]
    frames: list[list[nodes.VisualState]]
    sun: list[tuple[float, float, float]] | None
    observed: list[nodes.Observed]
    sun_intensity_scale: float = 1.0
    conductor_temperature: list[float | None] | None = None  # render.conductors.temperature per step


def _scene_index(build_dir: Path) -> dict:
    index = Path(build_dir) / "scene" / "placements.json"
    if not index.is_file():
        raise UserError(index, None, "no built scene: run `twin build` first")
    try:
        data = json.loads(index.read_text())
        data["placements"]
    except (ValueError, KeyError, TypeError) as e:
        raise UserError(index, None, f"unreadable placement index: {e}") from None
    return data


def scene_zone(build_dir: Path) -> dt.tzinfo | None:
    """The built site's time zone (site.toml [site] timezone); None for a scene built
    before placements.json recorded it."""
    name = _scene_index(build_dir).get("timezone")
    return None if name is None else config.time_zone(name, Path(build_dir) / "scene" / "placements.json", "timezone")


def load_observed(build_dir: Path) -> list[nodes.Observed]:
    """Stateful placements (STATE set) of the built scene, with their manifests."""
    build_dir = Path(build_dir)
    placements = _scene_index(build_dir)["placements"]
    out = []
    for p in placements:
        if not p.get("state"):
            continue
        package = build_dir / "models" / p["asset"]
        try:
            m = manifest_io.read(package)
        except FileNotFoundError:
            raise UserError(package / manifest_io.MANIFEST, p["tag"], "manifest missing: rebuild the asset") from None
        out.append(nodes.Observed(p["tag"], p["state"], p["asset"], m, package))
    return out


def simulate(scenario: graph.Scenario, observed: list[nodes.Observed]) -> tuple[RunData, list[dict]]:
    """Step the graph over the scenario; returns the applier data and states records."""
    g = graph.Graph(scenario)
    renders = [n for n in g.order if g.nodes[n].type_name == "render"]
    suns = sorted(n for n in g.nodes if g.nodes[n].type_name == "sun")
    render = g.nodes[renders[0]] if renders else None
    sun_id = (render.p["sun"] if render is not None and render.p["sun"] else (suns[0] if len(suns) == 1 else None))
    if sun_id is not None and sun_id not in suns:
        raise UserError(scenario.path, f"node {render.id}", f"param sun = {sun_id!r} is not a sun node")
    if render is not None:
        ports = [e.dst[1] for e in g.feeds[render.id]]
        bad = nodes.unbound_inputs(ports, observed)
        if bad:
            raise UserError(scenario.path, f"node {render.id}",
                            f"no placement in the built scene binds {', '.join(bad)} (STATE.variable)")
    engine = graph.Engine(g)
    mapper = nodes.VisualMapper(observed)
    times, frames, sun, records, wires = [], [], [] if sun_id else None, [], []
    for report in engine.run():
        times.append(report.t)
        wires.append(render.values.get(nodes.CONDUCTORS_STATE, {}).get("temperature") if render is not None else None)
        frames.append(mapper.states(render.values) if render is not None else [])
        if sun_id:
            v = engine.values
            sun.append((v[(sun_id, "elevation")], v[(sun_id, "azimuth")], v[(sun_id, "irradiance")]))
        records.append({"k": report.k, "t": report.t, "ran": report.count,
                        "outputs": {f"{n}.{p}": v for (n, p), v in sorted(engine.values.items())}})
    scale = float(render.p["sun_intensity_scale"]) if render is not None else 1.0
    wired = any(v is not None for v in wires)
    return RunData(scenario, times, frames, sun, observed, scale, wires if wired else None), records


def _num(v):
    # Fixed float text: 12 significant digits, so files compare across platforms.
    if isinstance(v, bool) or not isinstance(v, float):
        return v
    return float(f"{v:.12g}")


def write_states(records: list[dict], path: Path) -> None:
    lines = [json.dumps({**r, "t": _num(r["t"]), "outputs": {k: _num(v) for k, v in r["outputs"].items()}},
                        sort_keys=True, separators=(",", ":")) for r in records]
    atomic_write(path, "\n".join(lines) + "\n")


def run_scenario(scenario_path: Path, build_dir: Path, out_dir: Path | None = None, *,
                 formats: tuple[str, ...] = ("usd", "gltf", "sdf"), sdf_quantum: float = 0.1,
                 progress=None) -> dict:
    """Run a scenario against a built scene; outputs in out_dir (default
    build/runs/<scenario name>/). Returns a summary dict. `progress`: a progress.Bar
    that the simulation and each applier advance."""
    t0 = time.perf_counter()
    step = progress.step if progress is not None else (lambda what=None: None)
    build_dir = Path(build_dir)
    scenario = graph.load_scenario(scenario_path, scene_zone(build_dir))
    observed = load_observed(build_dir)
    missing = sorted(set(scenario.assets) - {o.asset for o in observed} - {
        p.name for p in (build_dir / "models").glob("*") if (p / manifest_io.MANIFEST).is_file()})
    if missing:
        raise UserError(scenario.path, "scenario.assets", f"not built: {', '.join(missing)}")
    out = Path(out_dir) if out_dir is not None else build_dir / "runs" / scenario.name
    out.mkdir(parents=True, exist_ok=True)
    if progress is not None:
        progress.add(1 + len(formats))
    data, records = simulate(scenario, observed)
    step("simulate")
    t_sim = time.perf_counter() - t0
    write_states(records, out / "states.jsonl")
    summary = {"scenario": scenario.name, "steps": len(records), "nodes": len(scenario.nodes),
               "node_runs": sum(r["ran"] for r in records), "placements": sorted(o.tag for o in observed),
               "out": str(out), "simulate_s": round(t_sim, 4), "appliers": {}}
    if "usd" in formats:
        scenes = sorted((build_dir / "scene").glob("*.usda"))
        if len(scenes) == 1:
            from . import apply_usd

            summary["appliers"]["usd"] = apply_usd.write(data, scenes[0], out / "states.usda")
            wires = build_dir / "scene" / "conductors.json"
            if data.conductor_temperature is not None and wires.is_file():
                from . import apply_conductors

                summary["appliers"]["conductors_usd"] = apply_conductors.write(
                    wires, scenes[0], out / "conductors.usda", data.times, data.conductor_temperature,
                    scenario.step_s)
        step("usd")  # done, or nothing to apply to
    if "gltf" in formats:
        from . import apply_gltf

        summary["appliers"]["gltf"] = apply_gltf.write(data, out / "gltf")
        wires = build_dir / "scene" / "conductors.json"
        if data.conductor_temperature is not None and wires.is_file():
            from . import apply_conductors

            summary["appliers"]["conductors_gltf"] = apply_conductors.write_gltf(
                wires, out / "gltf" / "conductors.glb", data.times, data.conductor_temperature)
        step("gltf")
    if "sdf" in formats:
        from . import apply_sdf

        wires, choices = build_dir / "scene" / "conductors.json", None
        if data.conductor_temperature is not None and wires.is_file():
            from . import apply_conductors

            choices = apply_conductors.sdf_choices(wires, data.conductor_temperature)
        summary["appliers"]["sdf"] = apply_sdf.write(data, out / "sdf", quantum=sdf_quantum, conductors=choices)
        step("sdf")
    summary["total_s"] = round(time.perf_counter() - t0, 4)
    return summary
