"""A griffe extension (mkdocs.yml, mkdocstrings' ``extensions``): so3jax's docstrings are
plain prose with reST roles, rendered here as Markdown without misreading them.

* ``[0, pi] [rad]``, ``table[a][b]``: a bracket after a bracket is escaped, so Markdown
  does not take the pair for a reference link;
* ``(3, *b)``, ``**options``: an asterisk before a name is escaped (no emphasis);
* a line that starts with ``+ `` continues an equation (no list item);
* ``:func:`so3jax.x```: reST roles become inline code.
"""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc|const):`~?([^`]+)`")
_PAIRED_BRACKET = re.compile(r"\](\s*)\[")
_STAR = re.compile(r"(?<=[\s(,\[*])\*(?=[\w*])")
_PLUS = re.compile(r"^(\s*)\+ ", re.MULTILINE)


_CODE = re.compile(r"(``.+?``|`[^`\n]+`)", re.DOTALL)


def prose(text: str) -> str:
    """The docstring with the escapes above, outside its code spans."""
    parts = _CODE.split(_ROLE.sub(r"`\1`", text))
    for i in range(0, len(parts), 2):  # the even parts are outside code spans
        part = _PAIRED_BRACKET.sub(r"]\1\\[", parts[i])
        part = _PLUS.sub(r"\1\\+ ", part)
        parts[i] = _STAR.sub(r"\\*", part)
    return "".join(parts)


class PlainDocstrings(griffe.Extension):
    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = prose(obj.docstring.value)
