"""The data attribute references an SCL file (SCD, ICD, CID: IEC 61850-6) declares.

A reference is `<IED name><LDevice inst>/<prefix><lnClass><inst>.<DO>[.<SDO>...].<DA>
[.<BDA>...]`, the form an MMS client reads, each with its functional constraint. The
data model comes from the IEDs' logical devices and the DataTypeTemplates their
logical nodes point at. The file is read with the project's hardened parser (no
entities, no DTD, no network): an SCD comes from a utility's engineering tool.
"""

from __future__ import annotations

from pathlib import Path

from .. import safe_xml
from ..errors import UserError

_MAX_DEPTH = 8  # nested DA types of a real model go 3-4 deep; a cycle stops here


def _local(tag) -> str:
    return tag.rpartition("}")[2] if isinstance(tag, str) else ""


def _children(element, name: str):
    return [c for c in element if _local(c.tag) == name]


def references(path: Path) -> dict[str, str]:
    """{reference: functional constraint} of every data attribute the file's IEDs hold."""
    path = Path(path)
    try:
        if safe_xml.declares_doctype(path):
            raise UserError(path, None, "an SCL file declares no DOCTYPE (refused: it can only declare entities)")
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
    root = safe_xml.parse(path).getroot()
    if _local(root.tag) != "SCL":
        raise UserError(path, None, f"not an SCL file (its root is <{_local(root.tag)}>)")
    templates = next(iter(_children(root, "DataTypeTemplates")), None)
    if templates is None:
        raise UserError(path, "DataTypeTemplates", "missing: the logical nodes' types are not declared")
    types = {kind: {t.get("id"): t for t in _children(templates, kind)} for kind in ("LNodeType", "DOType", "DAType")}
    out: dict[str, str] = {}
    for ied in _children(root, "IED"):
        for ap in _children(ied, "AccessPoint"):
            for server in _children(ap, "Server"):
                for ld in _children(server, "LDevice"):
                    domain = f"{ied.get('name', '')}{ld.get('inst', '')}"
                    for ln in _children(ld, "LN0") + _children(ld, "LN"):
                        name = f"{ln.get('prefix', '')}{ln.get('lnClass', '')}{ln.get('inst', '')}"
                        ln_type = types["LNodeType"].get(ln.get("lnType"))
                        if ln_type is None:
                            raise UserError(path, f"{domain}/{name}", f"lnType {ln.get('lnType')!r} is not declared")
                        for do in _children(ln_type, "DO"):
                            _data_object(types, do.get("type"), f"{domain}/{name}.{do.get('name')}", out, 0)
    return out


def _data_object(types: dict, type_id: str | None, prefix: str, out: dict[str, str], depth: int) -> None:
    do_type = types["DOType"].get(type_id)
    if do_type is None or depth > _MAX_DEPTH:
        return
    for element in do_type:
        kind = _local(element.tag)
        if kind == "SDO":
            _data_object(types, element.get("type"), f"{prefix}.{element.get('name')}", out, depth + 1)
        elif kind == "DA":
            _attribute(types, element, f"{prefix}.{element.get('name')}", element.get("fc", ""), out, depth + 1)


def _attribute(types: dict, element, ref: str, fc: str, out: dict[str, str], depth: int) -> None:
    out[ref] = fc
    if element.get("bType") == "Struct" and depth <= _MAX_DEPTH:
        da_type = types["DAType"].get(element.get("type"))
        for bda in _children(da_type, "BDA") if da_type is not None else ():
            _attribute(types, bda, f"{ref}.{bda.get('name')}", fc, out, depth + 1)
