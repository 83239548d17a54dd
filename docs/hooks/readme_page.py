"""The project README as a page of the docs site: an mkdocs hook (mkdocs.yml `hooks:`).

README.md lives at the repository's root, above docs/, and its links are written for a reader of the repository:
into docs/ (`docs/results.md#contact-tasks`, `docs/figures/demo_force.png`) and to files the site does not hold
(`hardware/README.md`, `LICENSE`). Included as it is, every one of them would be a broken link, which
`mkdocs build --strict` refuses. So the hook adds the README to the site as the generated page `PAGE`, its links
rewritten by `site_target` (a path under docs/ becomes that path on the site; the README itself becomes `PAGE`; any
other file of the repository is no page of the site, so its link becomes its text), and gives the docs pages the same
rewrite for their links that leave docs/ (`../README.md` → `PAGE`), so both read right on GitHub and on the site.

Assumptions, true of the project's pages: links are inline, `[text](target)` or `![alt](target)`, with no space or
parenthesis in the target and no `]` in the text; a target is a URL, an anchor of the same page, or a path relative
to the page; the docs pages sit directly in docs/ or below it.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

README = "README.md"  # at the repository's root, beside mkdocs.yml
DOCS = "docs"  # the repository's docs folder, the site's docs_dir
PAGE = "project-readme.md"  # the README's page on the site (mkdocs.yml nav)
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")
EXTERNAL = re.compile(r"^([a-z][a-z0-9+.-]*:|#)", re.I)  # a URL (https:, mailto:) or an anchor of the same page


def site_target(path: str) -> str | None:
    """The site's path (relative to docs_dir) of the file `path` (normalised, relative to the repository's root):
    docs/X → X, README.md → PAGE; None for a file outside docs/ (module docstring)."""
    if path == README:
        return PAGE
    if path.startswith(DOCS + "/"):
        return path.removeprefix(DOCS + "/")
    return None


def rewrite_links(markdown: str, page_dir: str) -> str:
    """`markdown` of a page in the folder `page_dir` (relative to the repository's root: "" for the README, "docs"
    or below for a docs page) with its links re-aimed for the site (module docstring). A docs page's links that stay
    inside docs/ are kept as written: mkdocs resolves them."""
    site_dir = posixpath.relpath(page_dir, DOCS) if page_dir else "."  # the page's folder on the site

    def replace(match: re.Match[str]) -> str:
        bang, text, target = match.groups()
        if EXTERNAL.match(target):
            return match.group(0)
        file, hash_, anchor = target.partition("#")
        path = posixpath.normpath(posixpath.join(page_dir, file))
        if page_dir and path.startswith(DOCS + "/"):
            return match.group(0)
        aim = site_target(path)
        if aim is None:
            return text  # a file the site does not hold: its name, as the README writes it
        return f"{bang}[{text}]({posixpath.relpath(aim, site_dir)}{hash_}{anchor})"

    return LINK.sub(replace, markdown)


def readme_markdown(root: Path) -> str:
    """The README's page: README.md with its links re-aimed for the site."""
    return rewrite_links((root / README).read_text(encoding="utf-8"), "")


def root_of(config) -> Path:
    return Path(config.config_file_path).resolve().parent


def on_files(files, config):
    """Add the README's page (generated: nothing is written into docs/)."""
    files.append(File.generated(config, PAGE, content=readme_markdown(root_of(config))))
    return files


def on_page_markdown(markdown, page, config, files):
    """A docs page's links out of docs/ (`../README.md`) re-aimed for the site."""
    if page.file.src_uri == PAGE:
        return markdown
    return rewrite_links(markdown, posixpath.join(DOCS, posixpath.dirname(page.file.src_uri)).rstrip("/"))


def on_serve(server, config, builder):
    """`mkdocs serve` rebuilds when README.md changes."""
    server.watch(str(root_of(config) / README))
    return server
