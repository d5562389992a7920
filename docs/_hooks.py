"""MkDocs hooks: the generated pages at the repository's root (RESULTS*.md,
BENCHMARKS.md, STABILITY.md and its figures, CHANGELOG.md) join the site as they are,
read in place, never copied into docs/; links written for GitHub (``../RESULTS.md`` from
docs/, ``docs/x.md`` from the root) are rewritten to the site's layout."""

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
    "BENCHMARKS.md",
    "STABILITY.md",
    "CHANGELOG.md",
)

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


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri in ROOT_PAGES:
        return _DOWN.sub("](", markdown)
    return _UP.sub(r"](\1", markdown)
