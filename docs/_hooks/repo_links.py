"""MkDocs hook: links from the guides to repository files outside docs/ (notebooks, tests,
benchmarks) work when the Markdown is read in the repository; the site does not contain those
files, so there the link becomes its text. A link to a file that does not exist is left alone,
and the strict build reports it.
"""

import pathlib
import re

_LINK = re.compile(r"\[([^\]\n]+)\]\(((?:\.\./)+[^)#\s]+)(#[^)\s]*)?\)")


def on_page_markdown(markdown, page, config, **kwargs):
    docs = pathlib.Path(config["docs_dir"]).resolve()
    here = (docs / page.file.src_uri).parent

    def replace(match: re.Match) -> str:
        target = (here / match.group(2)).resolve()
        outside = docs not in target.parents and target != docs
        return match.group(1) if outside and target.exists() else match.group(0)

    return _LINK.sub(replace, markdown)
