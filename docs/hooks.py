"""MkDocs hooks of the so3jax site (registered in mkdocs.yml).

* The generated blocks of a page (``<!-- keys: NAME [ARG] -->``, ``<!-- options: COMMAND -->``,
  ``<!-- api: MODULE -->`` up to ``<!-- end: ... -->``) are generated anew by
  ``generated.expand`` (docs/generated.py, which also writes them into the committed pages):
  the tables ``schema_docs.render`` (docs/schema_docs.py) generates from the schema objects
  (the registrations, the parsers' checks, the default missions, the argparse parsers), so
  the pages list exactly what the code accepts, and mkdocstrings' ``::: MODULE`` directives.
* A link ``[model §N.M](model.md)`` gets the anchor of that numbered section of
  ``docs/model.md``.
* The formulas (``pymdownx.arithmatex``, generic mode: ``\\(...\\)`` in a
  ``<span class="arithmatex">``, ``\\[...\\]`` in a ``<div class="arithmatex">``) become MathML
  when the site is built (``latex2mathml``), which browsers render natively: the site needs
  no script and no network to show them. ``\\tag{N}`` becomes a right-aligned label "(N)".
  A formula the converter does not take (an unknown command comes back verbatim) fails the
  build, naming the page and the formula.
* The figures committed beside the recorded results (``sweeps/``, ``tuning/``,
  ``comparisons/``, ``benchmarks/results/``) are served at the same paths, so a page shows
  them without a copy in ``docs/``.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

import generated  # docs/generated.py: mkdocs puts this hook's folder on sys.path while it loads it
from latex2mathml.commands import MATRICES
from latex2mathml.converter import convert
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

MODEL_LINK = re.compile(r"\[([Mm]odel §(\d+(?:\.\d+)*))\]\(([^)#\s]*model\.md)\)")
MODEL_HEADING = re.compile(r"^#{2,4}\s+((\d+(?:\.\d+)*)\.?\s.*?)\s*$", re.MULTILINE)
ARITHMATEX = re.compile(r'<(span|div) class="arithmatex">(.*?)</\1>', re.DOTALL)
DELIMITED = re.compile(r"^\\([(\[])(.*)\\[)\]]$", re.DOTALL)
TAG = re.compile(r"\\tag(\*?)\{([^{}]*)\}")
CONTROL_SPACE = re.compile(r"\\(\\|\n)")  # "\\" (a line break) or a backslash ending a line (a space)
OPERATORS = re.compile(r"\\(arg)(?![A-Za-z])")  # operator names latex2mathml lacks
ALIGNED = re.compile(r"\\(begin|end)\{aligned\}")  # latex2mathml's align* is the same table
ENVIRONMENT = re.compile(r"\\begin\{([^{}]*)\}")
ENVIRONMENTS = {name.lstrip("\\") for name in MATRICES}  # the environments latex2mathml lays out
BRACE = re.compile(r"\\.|[{}]", re.DOTALL)
# what latex2mathml passes through silently where it does not understand the TeX: a command
# verbatim, an alignment "&" or a line break "\\\\" outside a table
UNCONVERTED = re.compile(r'>[^<]*(?:\\|&(?!#x[0-9A-Fa-f]+;|[a-z]+;))[^<]*<|linebreak="newline"')
RESULT_FOLDERS = ("sweeps", "tuning", "comparisons", "benchmarks/results")


def on_files(files, config):
    root = Path(config["config_file_path"]).parent
    for folder in RESULT_FOLDERS:
        for path in sorted((root / folder).rglob("*.png")):
            uri = path.relative_to(root).as_posix()
            if files.get_file_from_path(uri) is None:
                files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files


def _sections(config) -> dict:
    """{section number: anchor} of docs/model.md's numbered headings ("## 8. The flight
    loop", "### 8.2 Sensors"), slugged as the toc extension slugs them."""
    from markdown.extensions.toc import slugify

    path = Path(config["docs_dir"]) / "model.md"
    text = path.read_text() if path.exists() else ""
    return {m.group(2): slugify(m.group(1), "-") for m in MODEL_HEADING.finditer(text)}


def on_page_markdown(markdown, page, config, files):
    sections = _sections(config)

    def anchored(match):  # [model §8.2](model.md) -> [model §8.2](model.md#82-sensors)
        label, number, target = match.groups()
        anchor = sections.get(number)
        return f"[{label}]({target}#{anchor})" if anchor else match.group(0)

    return MODEL_LINK.sub(anchored, generated.expand(markdown, page.file.src_uri, markers=False))


def mathml(tex: str, display: bool) -> str:
    """The MathML of one formula (without its delimiters); a display formula's ``\\tag{N}``
    as a label "(N)" beside it. ValueError where the converter does not take it."""
    tags = TAG.findall(tex)
    if len(tags) > (1 if display else 0):
        raise ValueError("more than one \\tag" if display else "a \\tag in an inline formula")
    depth = 0
    for token in BRACE.findall(tex):
        depth += {"{": 1, "}": -1}.get(token, 0)
        if depth < 0:
            break
    if depth:
        raise ValueError("unbalanced braces")
    tex = ALIGNED.sub(r"\\\1{align*}", TAG.sub("", tex))
    unknown = sorted(set(ENVIRONMENT.findall(tex)) - ENVIRONMENTS)
    if unknown:
        raise ValueError(f"unknown environment {', '.join(unknown)}")
    tex = CONTROL_SPACE.sub(lambda m: m.group(0) if m.group(1) == "\\" else "\\ ", tex)
    tex = OPERATORS.sub(r"\\operatorname{\1}", tex)
    try:
        math = convert(tex.strip(), display="block" if display else "inline")
    except Exception as error:  # the converter's own errors (a missing argument, \left without \right)
        raise ValueError(f"{type(error).__name__}: {error}") from error
    unconverted = UNCONVERTED.search(math)
    if unconverted:
        raise ValueError(f"not converted: {html.unescape(unconverted.group(0).strip('<>')).strip()!r}")
    if not display:
        return math
    label = ""
    if tags:
        star, number = tags[0]
        label = f'<span class="math-tag">{html.escape(number if star else f"({number})", quote=False)}</span>'
    return f'<div class="math-display">{math}{label}</div>'


def on_page_content(content, page, config, files):
    def convert_formula(match):
        element, body = match.groups()
        tex = html.unescape(body).strip()
        delimited = DELIMITED.match(tex)
        display = element == "div" if delimited is None else delimited.group(1) == "["
        try:
            return mathml(delimited.group(2) if delimited else tex, display)
        except ValueError as error:
            raise PluginError(f"{page.file.src_uri}: cannot convert the formula {tex!r} to MathML ({error})") from error

    return ARITHMATEX.sub(convert_formula, content)
