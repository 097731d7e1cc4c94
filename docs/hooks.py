"""MkDocs hooks of the so3jax site (registered in mkdocs.yml).

* ``<!-- keys: NAME [ARG] -->`` and ``<!-- options: COMMAND -->`` in a page are replaced by
  the tables ``schema_docs.render`` (docs/schema_docs.py) generates from the schema objects (the
  registrations, the parsers' checks, the default missions, the argparse parsers), so the
  pages list exactly what the code accepts; "model §N" in them links to the model page.
* A link ``[model §N.M](model.md)`` gets the anchor of that numbered section of
  ``docs/model.md``.
* The figures committed beside the recorded results (``sweeps/``, ``tuning/``,
  ``comparisons/``, ``benchmarks/results/``) are served at the same paths, so a page shows
  them without a copy in ``docs/``.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

import schema_docs  # docs/schema_docs.py: mkdocs puts this hook's folder on sys.path while it loads it
from mkdocs.structure.files import File

MODEL_LINK = re.compile(r"\[([Mm]odel §(\d+(?:\.\d+)*))\]\(([^)#\s]*model\.md)\)")
MODEL_HEADING = re.compile(r"^#{2,4}\s+((\d+(?:\.\d+)*)\.?\s.*?)\s*$", re.MULTILINE)
PLACEHOLDER = re.compile(r"^([ \t]*)<!--\s*(keys|options):\s*([\w\s.#-]+?)\s*-->", re.MULTILINE)
MODEL = re.compile(r"\bmodel §(\d+(?:\.\d+)*)")
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
    model = posixpath.relpath("model.md", posixpath.dirname(page.file.src_uri) or ".")
    sections = _sections(config)

    def table(match):  # indented as the placeholder (e.g. inside a list item)
        indent, what, args = match.groups()
        text = MODEL.sub(lambda m: f"[model §{m.group(1)}]({model})", schema_docs.render(what, tuple(args.split())))
        return "\n".join(indent + line if line else line for line in text.split("\n"))

    def anchored(match):  # [model §8.2](model.md) -> [model §8.2](model.md#82-sensors)
        label, number, target = match.groups()
        anchor = sections.get(number)
        return f"[{label}]({target}#{anchor})" if anchor else match.group(0)

    return MODEL_LINK.sub(anchored, PLACEHOLDER.sub(table, markdown))
