"""MkDocs hooks: the generated pages at the repository's root (RESULTS*.md,
BENCHMARKS.md, STABILITY.md and its figures, CHANGELOG.md) join the site as they are,
read in place, never copied into docs/; links written for GitHub (``../RESULTS.md`` from
docs/, ``docs/x.md`` from the root) are rewritten to the site's layout. A page holding
an ``INCLUDES`` marker gets the tables its generated page marks out, or a line saying
they are not yet measured while that page is absent (``RESULTS_priors.md`` into
``priors.md``)."""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File, Files

#: the root's pages that the site shows beside docs/
ROOT_PAGES = (
    "RESULTS.md",
    "RESULTS_fast.md",
    "RESULTS_traj.md",
    "RESULTS_positions.md",
    "RESULTS_priors.md",
    "BENCHMARKS.md",
    "STABILITY.md",
    "CHANGELOG.md",
)

#: marker in a docs page → (the root page whose marked tables replace it, the command
#: that writes that page); the tables lie between ``<!-- NAME:table -->`` and
#: ``<!-- /NAME:table -->``, NAME the page's stem after ``RESULTS_``
INCLUDES = {
    "<!-- include RESULTS_priors.md -->": (
        "RESULTS_priors.md",
        "hnn-pl reproduce --recipe priors --chunks 100 800 --seeds 5 --out RESULTS_priors.md",
    ),
}

_UP = re.compile(r"\]\(\.\./(" + "|".join(re.escape(p) for p in ROOT_PAGES) + r"|STABILITY/)")
_DOWN = re.compile(r"\]\(docs/")


def on_files(files: Files, config) -> Files:
    root = Path(config.config_file_path).parent
    names = [
        *ROOT_PAGES,
        *(f"STABILITY/{p.name}" for p in sorted((root / "STABILITY").glob("*.png"))),
    ]
    for name in names:
        if (root / name).is_file():
            files.append(File(name, str(root), config.site_dir, config.use_directory_urls))
    return files


def on_config(config):
    """The generated pages of :data:`INCLUDES` that exist join the nav's Results."""
    root = Path(config.config_file_path).parent
    for name, _ in INCLUDES.values():
        if not (root / name).is_file():
            continue
        for entry in config.nav or []:
            if isinstance(entry, dict) and "Results" in entry:
                pages = entry["Results"]
                last = max(k for k, p in enumerate(pages) if str(*p.values()).startswith("RESULTS"))
                pages.insert(last + 1, {"Choosing a prior": name})
    return config


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri in ROOT_PAGES:
        return _DOWN.sub("](", markdown)
    root = Path(config.config_file_path).parent
    for marker in INCLUDES:
        if marker in markdown:
            markdown = markdown.replace(marker, included(root, marker))
    return _UP.sub(r"](\1", markdown)


def included(root: Path, marker: str) -> str:
    """What replaces ``marker``: the tables of its root page (between the page's table
    markers) and a link to the whole page, or "not yet measured" and the command."""
    name, command = INCLUDES[marker]
    stem = name.removesuffix(".md").removeprefix("RESULTS_")
    path = root / name
    found = None
    if path.is_file():
        found = re.search(
            rf"<!-- {stem}:table -->\n(.*?)<!-- /{stem}:table -->", path.read_text(), re.S
        )
    if found is None:
        return f"*Not yet measured: `{command}` writes the table.*"
    return f"{found.group(1).strip()}\n\nEvery run, per seed: [{name}](../{name})."
