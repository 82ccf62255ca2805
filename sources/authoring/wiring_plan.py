"""The sample's conductors, drawn on the floor plan's conductor layers (floorplan.py
writes them): every span a LINE from one terminal to another, its ends exactly on the
terminals' plan points (asset.toml [[terminals]] and a .blend's `terminal.<name>`
empties, turned by the INSERT heading).

- 500 kV diameters, per phase: the bus B tap strung up to the bay gantry, a dropper
  to the first disconnector, the breaker positions (disconnector, CT, breaker,
  disconnector) joined by jumpers, the post insulators between positions, the last
  disconnector up to the north gantry and down to bus A; the line gantries strung to
  the bay gantries over the buses; line exits (gantry, arrester, CVT, line
  disconnector) joined by droppers and jumpers; the reactor banks' HV bushings from
  the north line arresters.
- 230 kV bays, per phase: CT, breaker, the two bus selectors to the double bus; the
  feeders' line exits; the transformer bay's arrester and gantry.
The transformer bushings are connected in site.toml [[conductors]] (the other way to
write spans).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent
ASSETS = HERE.parent / "assets"

LAYER_500_STRAIN = "CONDUCTOR_500_STRAIN"  # strung spans: tension in site.toml
LAYER_500_DROP = "CONDUCTOR_500_DROP"  # droppers and jumpers: a sag ratio
LAYER_230_DROP = "CONDUCTOR_230_DROP"
LAYERS = (LAYER_500_STRAIN, LAYER_500_DROP, LAYER_230_DROP)


def terminals(asset: str) -> dict[str, tuple[float, float, float]]:
    """An asset's terminals as the pipeline reads them: asset.toml [[terminals]] and,
    for a .blend, its `terminal.<name>` empties (to the micrometre, as the manifest)."""
    data = tomllib.loads((ASSETS / asset / "asset.toml").read_text())
    out = {t["name"]: tuple(t["position"]) for t in data.get("terminals", [])}
    source = ASSETS / asset / data["source"]
    if source.suffix == ".blend":
        out |= blend_terminals(source)
    return out


def blend_terminals(path: Path) -> dict[str, tuple[float, float, float]]:
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False, use_scripts=False)
    return {ob.name.removeprefix("terminal."): tuple(round(v, 6) + 0.0 for v in ob.matrix_world.translation)
            for ob in bpy.data.objects if ob.type == "EMPTY" and ob.name.startswith("terminal.")}


class Wiring:
    """Spans between the plan's items: (layer, (x0, y0), (x1, y1), ends) in order."""

    def __init__(self, items):
        self.by_tag = {i.tag: i for i in items}
        self.items = items
        self.spans: list[tuple[str, tuple[float, float], tuple[float, float], str]] = []
        self._terminals = {}

    def point(self, tag: str, name: str) -> tuple[float, float]:
        item = self.by_tag[tag]
        if item.asset not in self._terminals:
            self._terminals[item.asset] = terminals(item.asset)
        x, y, _ = self._terminals[item.asset][name]
        a = math.radians(item.heading)
        return (round(item.x + x * math.cos(a) - y * math.sin(a), 6), round(item.y + x * math.sin(a) + y * math.cos(a), 6))

    def nearest(self, tag: str, towards: tuple[float, float]) -> str:
        """The terminal of `tag` nearest to a plan point."""
        item = self.by_tag[tag]
        if item.asset not in self._terminals:
            self._terminals[item.asset] = terminals(item.asset)
        return min(sorted(self._terminals[item.asset]), key=lambda n: math.dist(self.point(tag, n), towards))

    def span(self, layer: str, a: str, b: str) -> None:
        """A span between items a and b, each end on the terminal nearest the other
        item (a's chosen first, towards b's centre)."""
        ta = self.nearest(a, (self.by_tag[b].x, self.by_tag[b].y))
        tb = self.nearest(b, self.point(a, ta))
        self.span_at(layer, (a, ta), (b, tb))

    def span_at(self, layer: str, a: tuple[str, str], b: tuple[str, str]) -> None:
        self.spans.append((layer, self.point(*a), self.point(*b), f"{a[0]}.{a[1]}~{b[0]}.{b[1]}"))

    def bus_tap(self, prefix: str, bus: str, phase: str, x: float) -> tuple[str, str]:
        """The terminal on bus `bus` phase `phase` at plan x: a busbar tap, or the
        support's clamp where two busbars meet."""
        for item in self.items:
            if item.asset == "busbar_support" and item.tag.startswith(f"SB-{prefix}{bus}{phase}-") and abs(item.x - x) < 1e-6:
                return item.tag, "clamp"
        for item in self.items:
            if item.asset == "rigid_busbar" and item.tag.startswith(f"BR-{prefix}{bus}{phase}-") and abs(item.x - x) < 6.0:
                k = round(x - item.x)
                return item.tag, "at_0" if k == 0 else f"at_{'m' if k < 0 else 'p'}{abs(k)}"
        raise ValueError(f"no bus {prefix}{bus}{phase} at x = {x}")


def yard_500(w: Wiring, d_centres, p500, reactor_banks) -> None:
    for d, xc in enumerate(d_centres):
        south, north = 2 * d + 1, 2 * d + 2
        gantry_s, gantry_n = f"PO-D{d + 1}S", f"PO-D{d + 1}N"
        for i, ph in enumerate("ABC"):
            x = xc + (i - 1) * p500
            b1, b3 = 3 * d + 1, 3 * d + 3
            # bus B up to the bay gantry, and down to the first disconnector
            w.span_at(LAYER_500_STRAIN, w.bus_tap("5", "B", ph, x), (gantry_s, w.nearest(gantry_s, (x, 53.0))))
            w.span(LAYER_500_DROP, gantry_s, f"89-{b1}1{ph}")
            for b in range(b1, b3 + 1):
                w.span(LAYER_500_DROP, f"89-{b}1{ph}", f"TC-{b}{ph}")
                w.span(LAYER_500_DROP, f"TC-{b}{ph}", f"52-{b}{ph}")
                w.span(LAYER_500_DROP, f"52-{b}{ph}", f"89-{b}2{ph}")
                if b < b3:
                    w.span(LAYER_500_DROP, f"89-{b}2{ph}", f"IP-{b}{ph}")
                    w.span(LAYER_500_DROP, f"IP-{b}{ph}", f"89-{b + 1}1{ph}")
            w.span(LAYER_500_DROP, f"89-{b3}2{ph}", gantry_n)
            w.span_at(LAYER_500_STRAIN, (gantry_n, w.nearest(gantry_n, (x, 141.0))), w.bus_tap("5", "A", ph, x))
            # line gantries strung to the bay gantries over the buses
            for line_gantry, bay_gantry in ((f"PO-L{south}", gantry_s), (f"PO-L{north}", gantry_n)):
                bay = w.nearest(bay_gantry, (x, w.by_tag[bay_gantry].y))
                w.span_at(LAYER_500_STRAIN, (bay_gantry, bay), (line_gantry, w.nearest(line_gantry, w.point(bay_gantry, bay))))
            # line exits: gantry, arrester, CVT, line disconnector
            for line in (south, north):
                w.span(LAYER_500_DROP, f"PO-L{line}", f"PR-{line}{ph}")
                w.span(LAYER_500_DROP, f"PR-{line}{ph}", f"TP-{line}{ph}")
                w.span(LAYER_500_DROP, f"TP-{line}{ph}", f"89-L{line}{ph}")
            if d in reactor_banks:
                bank = reactor_banks[d]
                w.span_at(LAYER_500_DROP, (f"PR-{north}{ph}", "line"), (f"RE-{bank}{i + 1}", "hv"))


def yard_230(w: Wiring, b_centres, p230) -> None:
    kinds = ("feeder", "feeder", "coupler", "transformer")
    for j, (xc, kind) in enumerate(zip(b_centres, kinds)):
        b, line = 21 + j, 7 + j
        for i, ph in enumerate("ABC"):
            x = xc + (i - 1) * p230
            if kind == "feeder":
                w.span(LAYER_230_DROP, f"PO-L{line}", f"PR-{line}{ph}")
                w.span(LAYER_230_DROP, f"PR-{line}{ph}", f"TP-{line}{ph}")
                w.span(LAYER_230_DROP, f"TP-{line}{ph}", f"89-L{line}{ph}")
                w.span(LAYER_230_DROP, f"89-L{line}{ph}", f"TC-{b}{ph}")
            w.span(LAYER_230_DROP, f"TC-{b}{ph}", f"52-{b}{ph}")
            w.span(LAYER_230_DROP, f"52-{b}{ph}", f"89-{b}1{ph}")
            # the two selectors: bus 1 through the first, bus 1 to bus 2 through the second
            sel1, sel2 = f"89-{b}1{ph}", f"89-{b}2{ph}"
            bus1, bus2 = w.bus_tap("2", "1", ph, x), w.bus_tap("2", "2", ph, x)
            w.span_at(LAYER_230_DROP, (sel1, w.nearest(sel1, (x, 60.0))), bus1)
            w.span_at(LAYER_230_DROP, bus1, (sel2, w.nearest(sel2, (x, 40.0))))
            w.span_at(LAYER_230_DROP, (sel2, w.nearest(sel2, (x, 80.0))), bus2)
            if kind == "transformer":
                w.span_at(LAYER_230_DROP, bus2, (f"PR-T{ph}", "line"))
                gantry = f"PO-{b}N"
                w.span_at(LAYER_230_DROP, (f"PR-T{ph}", "line"), (gantry, w.nearest(gantry, w.point(f"PR-T{ph}", "line"))))


def build(items, d_centres, p500, reactor_banks, b_centres, p230) -> Wiring:
    w = Wiring(items)
    yard_500(w, d_centres, p500, reactor_banks)
    yard_230(w, b_centres, p230)
    ends = [s[3] for s in w.spans]
    assert len(set(ends)) == len(ends), "a span drawn twice"
    return w


def draw(msp, w: Wiring) -> None:
    for layer, a, b, _ in w.spans:
        msp.add_line((*a, 0.0), (*b, 0.0), dxfattribs={"layer": layer})
