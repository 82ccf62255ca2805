"""safe_xml: the one parser every XML reader of the pipeline uses expands no entity,
loads no DTD, fetches nothing, and names the file when it cannot parse it."""

from __future__ import annotations

import http.server
import threading

import pytest
from lxml import etree

from pipeline import safe_xml
from pipeline.errors import UserError

SECRET = "TOP-SECRET-5e1d"


def _text(tree) -> str:
    root = tree.getroot() if hasattr(tree, "getroot") else tree
    return etree.tostring(root, encoding="unicode")


@pytest.fixture
def secret(tmp_path):
    path = tmp_path / "secret.txt"
    path.write_text(SECRET)
    return path


def test_an_external_entity_is_not_resolved(tmp_path, secret):
    doc = tmp_path / "xxe.sdf"
    doc.write_text(f'<!DOCTYPE sdf [<!ENTITY xxe SYSTEM "{secret.as_uri()}">]>\n<sdf><name>&xxe;</name></sdf>')
    resolving = etree.parse(str(doc), etree.XMLParser(resolve_entities=True, load_dtd=True))
    assert SECRET in _text(resolving)  # the control: the entity does reach the file
    for tree in (safe_xml.parse(doc), etree.parse(str(doc), safe_xml.parser(huge_tree=True)),
                 etree.fromstring(doc.read_bytes(), safe_xml.parser(remove_blank_text=True))):
        assert SECRET not in _text(tree)
        name = tree.find(".//name") if hasattr(tree, "getroot") else tree.find("name")
        assert name.text is None  # &xxe; stays a reference
    assert safe_xml.declares_doctype(doc)


def test_a_dtd_declared_entity_is_not_expanded(tmp_path):
    doc = tmp_path / "internal.dae"
    doc.write_text('<!DOCTYPE C [<!ENTITY up "Z_UP">]>\n<C><up_axis>&up;</up_axis></C>')
    tree = safe_xml.parse(doc, remove_comments=True)
    assert tree.getroot().find("up_axis").text is None
    assert "Z_UP" not in _text(tree)
    assert safe_xml.declares_doctype(doc)


def test_billion_laughs_expands_nothing(tmp_path):
    lol = '<!ENTITY lol0 "lol">' + "".join(
        f'<!ENTITY lol{k} "{("&lol" + str(k - 1) + ";") * 10}">' for k in range(1, 10))
    doc = tmp_path / "laughs.sdf"
    doc.write_text(f"<!DOCTYPE sdf [{lol}]>\n<sdf>&lol9;</sdf>")
    try:
        assert _text(safe_xml.parse(doc)) == "<sdf>&lol9;</sdf>"
    except UserError as e:  # libxml2 2.12 and later refuse the declarations outright
        assert "laughs.sdf: not well-formed XML: Maximum entity amplification" in str(e)


def test_no_dtd_or_entity_is_fetched_over_the_network(tmp_path):
    hits = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            hits.append(self.path)
            self.send_response(200)
            self.end_headers()
            self.wfile.write(b'<!ENTITY leak "LEAKED">')

        def log_message(self, *args):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_port}"
        doc = tmp_path / "remote.sdf"
        doc.write_text(f'<!DOCTYPE sdf SYSTEM "{url}/dtd" [<!ENTITY ext SYSTEM "{url}/entity">]>\n'
                       f"<sdf>&ext;&leak;</sdf>")
        assert "LEAKED" not in _text(safe_xml.parse(doc))
    finally:
        server.shutdown()
        server.server_close()
    assert hits == []


def test_a_doctype_is_seen_in_the_prolog_only(tmp_path):
    plain = tmp_path / "plain.sdf"
    plain.write_text('<?xml version="1.0"?>\n<sdf version="1.9"/>')
    assert not safe_xml.declares_doctype(plain)
    lower = tmp_path / "lower.sdf"
    lower.write_text("<!doctype sdf>\n<sdf/>")
    assert safe_xml.declares_doctype(lower)
    late = tmp_path / "late.sdf"
    late.write_text("<sdf><!--" + " " * safe_xml.PROLOG_BYTES + "--></sdf><!DOCTYPE")
    assert not safe_xml.declares_doctype(late)
    with pytest.raises(OSError):
        safe_xml.declares_doctype(tmp_path / "missing.sdf")


def test_a_file_that_cannot_be_parsed_is_a_user_error_naming_it(tmp_path):
    bad = tmp_path / "bad.sdf"
    bad.write_text("<sdf><model></sdf>")
    with pytest.raises(UserError, match=r"bad\.sdf: not well-formed XML: Opening and ending tag mismatch"):
        safe_xml.parse(bad)
    with pytest.raises(UserError, match=r"missing\.sdf: cannot read: No such file or directory"):
        safe_xml.parse(tmp_path / "missing.sdf")


def test_the_options_that_differ_between_readers(tmp_path):
    doc = tmp_path / "model.sdf"
    doc.write_text("<sdf>\n  <model><!-- note --><pose>0 0 0 0 0 0</pose></model>\n</sdf>")
    kept = safe_xml.parse(doc)
    assert kept.getroot().text == "\n  " and kept.getroot().find("model")[0].tag is etree.Comment
    stripped = safe_xml.parse(doc, remove_blank_text=True, remove_comments=True)
    assert stripped.getroot().text is None and stripped.getroot().find("model")[0].tag == "pose"
    big = tmp_path / "big.dae"
    big.write_bytes(b"<C><float_array>" + b"0.5 " * 3_000_000 + b"</float_array></C>")
    with pytest.raises(UserError, match="not well-formed XML"):
        safe_xml.parse(big)
    assert len(safe_xml.parse(big, huge_tree=True).getroot().findtext("float_array")) == 12_000_000


def test_a_doctype_past_the_prolog_check_is_seen_after_the_parse(tmp_path):
    late = tmp_path / "late.dae"
    late.write_text('<?xml version="1.0"?>\n<!--' + "x" * safe_xml.PROLOG_BYTES + '-->\n'
                    '<!DOCTYPE COLLADA [<!ENTITY up "Y_UP">]>\n<COLLADA><asset><up_axis>&up;</up_axis></asset></COLLADA>')
    assert not safe_xml.declares_doctype(late)
    assert safe_xml.has_doctype(safe_xml.parse(late))
    bare = tmp_path / "bare.sdf"
    bare.write_text("<!DOCTYPE sdf>\n<sdf/>")
    assert safe_xml.has_doctype(safe_xml.parse(bare))
    plain = tmp_path / "plain.sdf"
    plain.write_text("<sdf/>")
    assert not safe_xml.has_doctype(safe_xml.parse(plain))


def test_collada_facts_refuse_a_late_doctype(tmp_path):
    """pycollada, which trimesh reads COLLADA with, expands entities: a DOCTYPE the
    prolog check misses is refused after the safe parse."""
    from pipeline.ingest.mesh import collada_facts

    late = tmp_path / "late.dae"
    late.write_text('<?xml version="1.0"?>\n<!--' + "x" * safe_xml.PROLOG_BYTES + '-->\n'
                    '<!DOCTYPE COLLADA [<!ENTITY up "Y_UP">]>\n'
                    '<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">'
                    "<asset><up_axis>&up;</up_axis></asset></COLLADA>")
    with pytest.raises(UserError, match=r"late\.dae: COLLADA file declares a DOCTYPE"):
        collada_facts(late)
