"""XML that stays XML whatever text it carries, for every writer of JUnit reports (`redline ci
wait`, the server's verdicts, `redline compare`): ElementTree and ``quoteattr`` write a control
character as it is, and a job's reason holding a build's coloured output (``\\x1b[31m``), or a
case named with ``\\x01``, made a report no CI could parse (an audit)."""

from __future__ import annotations

import re
from xml.etree import ElementTree

#: what XML 1.0 cannot hold, even escaped
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def xml_safe(text: str) -> str:
    """``text`` with each character XML cannot hold written as its escape (``\\x1b``)."""
    return _NOT_XML.sub(lambda found: found[0].encode("unicode_escape").decode(), text)


def xml_document(root: ElementTree.Element) -> str:
    """``root`` as an XML document with its declaration, every text in it `xml_safe`."""
    return xml_safe(ElementTree.tostring(root, encoding="unicode", xml_declaration=True))
