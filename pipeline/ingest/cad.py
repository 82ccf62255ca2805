"""Reader for STEP files through cascadio (OpenCASCADE tessellation to GLB).

What cascadio gives (checked on a gmsh box written in millimetres at (10, 20, 30) mm):
the GLB is already in METRES (the STEP file declares its length unit and the glTF
conversion scales by it) and keeps the STEP file's axes (no glTF Y-up rotation).
So cfg.units is NOT applied again (it would shrink a mm model 1000x); the file's own
unit decides. cfg.up_axis IS applied (Y-up -> Z-up by +90 deg about X). cascadio's
tol_linear is in the file's length unit (a cylinder of r = 50 mm meshed with 0.1 has
chord deviations under 0.1 mm), so the metre tolerance is divided by the file unit.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from .. import ir
from ..errors import UserError
from .mesh import _load, asset_from_trimesh, check_size

TOL_ANGULAR_RAD = 0.5
_PREFIX = {"MILLI": 1e-3, "CENTI": 1e-2, "DECI": 1e-1, "KILO": 1e3, "MICRO": 1e-6}


def step_length_unit(path: Path, default: float) -> float:
    """Metres per file unit declared by the STEP header (SI_UNIT(.MILLI.,.METRE.),
    inch/foot conversion units); `default` when none is found."""
    text = Path(path).read_bytes()[:2_000_000].decode("latin-1", "replace").upper()
    if re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'INCH'", text):
        return 0.0254
    if re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'FOOT'", text):
        return 0.3048
    m = re.search(r"SI_UNIT\s*\(\s*(?:\.(\w+)\.|\$)\s*,\s*\.METRE\.\s*\)", text)
    if m:
        return _PREFIX.get(m.group(1) or "", 1.0)
    return default


def read_cad(cfg) -> ir.Asset:
    """Read cfg.source (.step/.stp) into an ir.Asset in metres, Z up.

    The tessellation tolerance (m) is recorded in Asset.metadata as
    ("tessellation_tolerance_m", ...), with the file unit found ("step_unit_m", ...).
    """
    import cascadio

    path = Path(cfg.source)
    check_size(path)
    if path.suffix.lower() not in (".step", ".stp"):
        raise UserError(path, None, f"not a STEP file: {path.suffix!r}")
    unit = step_length_unit(path, {"m": 1.0, "mm": 1e-3}[cfg.units])
    tol_m = float(cfg.tessellation_tolerance_m)
    with tempfile.TemporaryDirectory() as tmp:
        glb = Path(tmp) / "model.glb"
        try:
            status = cascadio.step_to_glb(str(path), str(glb), tol_linear=tol_m / unit, tol_angular=TOL_ANGULAR_RAD)
        except Exception as e:
            raise UserError(path, None, f"cannot read STEP file: {e}") from None
        if status != 0 or not glb.exists() or glb.stat().st_size == 0:
            raise UserError(path, None, "cannot read STEP file (OpenCASCADE found no shape)")
        loaded = _load(glb, "glb")
    metadata = (("tessellation_tolerance_m", repr(tol_m)), ("step_unit_m", repr(unit)))
    # cascadio already converted to metres: units "m" here on purpose (module docstring)
    asset = asset_from_trimesh(loaded, cfg, path, cfg.up_axis, "m", metadata)
    return asset
