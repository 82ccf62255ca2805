"""Equipment that looks used, and skies other than clear, in a CyclesScene (issue 38
item 5): what a dataset config's [appearance] draws per frame (datasets/plan.py
appearance) applied to the scene.

`prepare` adds, once, to every imported material with a Principled BSDF: the base
colour times a per-object tint, weathered (less saturated, lighter), then dirt, rust
and oil stains over it where procedural noise in the object's own coordinates passes a
threshold set by the object's amount of each (no stain at amount 0); roughness offset
per object and pulled towards each stain's own. The amounts are object custom
properties read by Attribute nodes, set for every object of every placement each
frame (`apply`), so a frame's look never depends on the frames before it. A scene
without [appearance] is never prepared: its materials stay as imported.
"""

from __future__ import annotations

import numpy as np

# name -> (colour (linear RGB), roughness, noise scale): what each stain looks like
STAINS = {"dirt": ((0.16, 0.13, 0.09), 0.95, 2.5), "rust": ((0.28, 0.09, 0.03), 0.85, 9.0),
          "oil_stains": ((0.025, 0.022, 0.018), 0.25, 4.0)}
PROPS = ("twin_tint", "twin_roughness", "twin_weathering", "twin_offset") + tuple(f"twin_{k}" for k in STAINS)
NEUTRAL = {"tint": [1.0, 1.0, 1.0], "roughness": 0.0, "weathering": 0.0, "offset": [0.0, 0.0, 0.0],
           **{k: 0.0 for k in STAINS}}
OVERCAST_SUN = 0.1  # the direct sun's share left behind cloud
HAZY_SUN, HAZY_AEROSOL = 0.6, 3.0  # a hazy sky: dimmer sun, three times the dust


def prepare(bl) -> int:
    """Add the appearance nodes to the scene's materials (once each); returns how many."""
    done = 0
    for mat in bl.bpy.data.materials:
        if mat.node_tree is None or mat.get("twin_look") or mat.name.startswith("__"):
            continue
        bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is None:
            continue
        _Graph(mat.node_tree).build(bsdf)
        mat["twin_look"] = 1
        done += 1
    return done


def apply(bl, look: dict | None, aerosol: float) -> None:
    """The frame's look on every placement's objects (neutral for a placement the draw
    does not name), and its sky (after set_shot, which sets the clear sky)."""
    instances = (look or {}).get("instances", {})
    for tag, objs in bl.objects.items():
        values = {**NEUTRAL, **instances.get(tag, {})}
        for ob in objs.values():
            ob["twin_tint"] = [float(v) for v in values["tint"]]
            ob["twin_offset"] = [float(v) for v in values["offset"]]
            for k in ("roughness", "weathering", *STAINS):
                ob[f"twin_{k}"] = float(values[k])
    sky = (look or {}).get("sky", "clear")
    if sky == "overcast":
        bl.sun.data.energy *= OVERCAST_SUN
    elif sky == "hazy":
        bl.sun.data.energy *= HAZY_SUN
        bl.sky.aerosol_density = float(aerosol) * HAZY_AEROSOL
    # an overcast sky is a milky, greyer one: more air scatters more of the blue out
    bl.sky.air_density = 4.0 if sky == "overcast" else 1.0


def vignette(linear: np.ndarray, strength: float) -> np.ndarray:
    """The lens's vignetting on a linear render: the light falls off as 1 - strength r^2,
    r the distance from the centre over the half diagonal."""
    if strength <= 0:
        return linear
    h, w = linear.shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x + 0.5 - w / 2.0) ** 2 + (y + 0.5 - h / 2.0) ** 2) / ((w / 2.0) ** 2 + (h / 2.0) ** 2)
    return (linear * (1.0 - strength * r2)[..., None]).astype(linear.dtype)


class _Graph:
    """Node building on one material's tree."""

    def __init__(self, nt):
        self.nt = nt

    def node(self, kind: str, **settings):
        n = self.nt.nodes.new(kind)
        for k, v in settings.items():
            setattr(n, k, v)
        return n

    def attr(self, name: str, output: str = "Factor"):
        return self.node("ShaderNodeAttribute", attribute_type="OBJECT", attribute_name=name).outputs[output]

    def math(self, op: str, a, b, clamp: bool = False):
        n = self.node("ShaderNodeMath", operation=op, use_clamp=clamp)
        self._in(n.inputs[0], a)
        self._in(n.inputs[1], b)
        return n.outputs[0]

    def mix(self, data_type: str, fac, a, b, blend: str = "MIX"):
        n = self.node("ShaderNodeMix", data_type=data_type, blend_type=blend)
        ins = [s for s in n.inputs if s.enabled]
        outs = [s for s in n.outputs if s.enabled]
        for sock, value in zip(ins[:3], (fac, a, b)):
            self._in(sock, value)
        return outs[0]

    def _in(self, sock, value):
        if hasattr(value, "links") or hasattr(value, "is_output"):
            self.nt.links.new(value, sock)
        else:
            sock.default_value = value

    def source(self, sock):
        """What feeds `sock`: its link's output, or its value."""
        link = next((lk for lk in self.nt.links if lk.to_socket == sock), None)
        if link is not None:
            return link.from_socket
        v = sock.default_value
        return tuple(v) if hasattr(v, "__len__") else float(v)

    def mask(self, name: str, scale: float, coords):
        """0..1 where noise passes the object's amount of stain `name` (none at 0)."""
        noise = self.node("ShaderNodeTexNoise", noise_dimensions="3D")
        noise.inputs["Scale"].default_value = scale
        noise.inputs["Detail"].default_value = 4.0
        self.nt.links.new(coords, noise.inputs["Vector"])
        amount = self.attr(f"twin_{name}")
        threshold = self.math("SUBTRACT", 0.72, self.math("MULTIPLY", amount, 0.45))
        ramp = self.node("ShaderNodeMapRange", clamp=True)
        self.nt.links.new(noise.outputs["Fac"], ramp.inputs["Value"])
        self.nt.links.new(threshold, ramp.inputs["From Min"])
        self.nt.links.new(self.math("ADD", threshold, 0.08), ramp.inputs["From Max"])
        on = self.math("MULTIPLY", amount, 20.0, clamp=True)
        return self.math("MULTIPLY", ramp.outputs["Result"], on)

    def build(self, bsdf) -> None:
        colour_in, rough_in = bsdf.inputs["Base Color"], bsdf.inputs["Roughness"]
        colour, rough = self.source(colour_in), self.source(rough_in)
        if not hasattr(colour, "is_output"):
            rgb = self.node("ShaderNodeRGB")
            rgb.outputs[0].default_value = colour
            colour = rgb.outputs[0]
        tinted = self.mix("RGBA", 1.0, colour, self.attr("twin_tint", "Color"), "MULTIPLY")
        weathering = self.attr("twin_weathering")
        hsv = self.node("ShaderNodeHueSaturation")
        self.nt.links.new(tinted, hsv.inputs["Color"])
        self.nt.links.new(self.math("SUBTRACT", 1.0, self.math("MULTIPLY", weathering, 0.7)), hsv.inputs["Saturation"])
        self.nt.links.new(self.math("ADD", 1.0, self.math("MULTIPLY", weathering, 0.3)), hsv.inputs["Value"])
        coords = self.node("ShaderNodeTexCoord").outputs["Object"]
        shift = self.node("ShaderNodeVectorMath", operation="ADD")
        self.nt.links.new(coords, shift.inputs[0])
        self.nt.links.new(self.attr("twin_offset", "Vector"), shift.inputs[1])
        colour, rough = hsv.outputs["Color"], self.math("ADD", rough, self.attr("twin_roughness"), clamp=True)
        for name, (stain, stain_rough, scale) in STAINS.items():
            m = self.mask(name, scale, shift.outputs[0])
            colour = self.mix("RGBA", m, colour, (*stain, 1.0))
            rough = self.mix("FLOAT", m, rough, stain_rough)
        self.nt.links.new(colour, colour_in)
        self.nt.links.new(rough, rough_in)
