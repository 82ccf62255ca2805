"""Reading XML that may be hostile: every XML file the pipeline reads comes through here.

A COLLADA mesh, a package's model.sdf or a world may come from anyone, so the parser
expands no entity (internal or external), loads no DTD and touches no network. A reader
of files it did not write refuses a DOCTYPE (`declares_doctype`) before libxml2 sees
the file: COLLADA and SDF need none, so one can only be there to declare entities, and
libxml2 still reads the declarations it does not resolve.
"""

from __future__ import annotations

import re
from pathlib import Path

from lxml import etree

from .errors import UserError

PROLOG_BYTES = 1 << 16
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)


def parser(*, remove_blank_text: bool = False, remove_comments: bool = False,
           huge_tree: bool = False) -> etree.XMLParser:
    """The hardened parser. `remove_blank_text` for a file rewritten with pretty_print,
    which indents only elements without whitespace of their own (the rewritten bytes
    depend on it); `remove_comments` for a reader that never looks at them; `huge_tree` for a
    mesh whose <float_array> text passes libxml2's limit on one text node (10 MB)."""
    return etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False,
                           huge_tree=huge_tree, remove_blank_text=remove_blank_text,
                           remove_comments=remove_comments)


def declares_doctype(path: str | Path) -> bool:
    """Whether the file's prolog (its first 64 KiB) holds a DOCTYPE. Raises OSError."""
    with open(path, "rb") as f:
        return _DOCTYPE.search(f.read(PROLOG_BYTES)) is not None


def has_doctype(tree: etree._ElementTree) -> bool:
    """Whether a parsed document declares a DOCTYPE: the check after the parse, for one
    that comes after more than the prolog's first 64 KiB."""
    info = tree.docinfo
    return bool(info.doctype) or info.internalDTD is not None or info.externalDTD is not None


def parse(path: str | Path, **options: bool) -> etree._ElementTree:
    """`path` parsed by parser(**options); an unreadable or ill-formed file is a
    UserError naming it."""
    try:
        with open(path, "rb") as f:  # opened here: lxml's own OSError gives no strerror
            return etree.parse(f, parser(**options))
    except etree.XMLSyntaxError as e:
        raise UserError(path, None, f"not well-formed XML: {e.msg}") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
