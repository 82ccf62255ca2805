"""The scenario fragments the conductor tests share: a conductor_thermal node `wire`
whose current comes from another node's port and whose temperature feeds the render
node's conductors (render.conductors.temperature), the input every renderer and the
runtime's conductor appliers read; and a `load` whose current rises with the clock."""

from __future__ import annotations

# a 30 mm conductor in 30 degC air, with the AC resistances of the ACSR tables
PARAMS = "diameter_m = 0.03, r25_ohm_per_km = 0.0728, r75_ohm_per_km = 0.0869, ambient_c = 30.0"


def thermal_wire(current_from: str, extra: str = "") -> str:
    """The `wire` node and its two edges, as TOML: its current from `current_from`
    (NODE.PORT), `extra` more params (e.g. a fixed irradiance)."""
    params = f"{PARAMS}, {extra}" if extra else PARAMS
    return f"""
[[nodes]]
id = "wire"
type = "conductor_thermal"
params = {{ {params} }}

[[edges]]
from = "{current_from}"
to = "wire.current"
type = "float"
unit = "A"

[[edges]]
from = "wire.temperature"
to = "render.conductors.temperature"
type = "float"
unit = "degC"
"""


def rising_load(gain: float, offset: float) -> str:
    """A `load` node (linear: offset + gain * t amperes, t the clock's seconds) and its
    edge from the clock, as TOML; its current is `load.y`."""
    return f"""
[[nodes]]
id = "load"
type = "linear"
params = {{ gain = {gain!r}, offset = {offset!r}, unit_in = "s", unit_out = "A" }}

[[edges]]
from = "clock.t"
to = "load.x"
type = "float"
unit = "s"
"""
