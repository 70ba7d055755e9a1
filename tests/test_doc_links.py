"""The documentation's links (issue 32): every relative link in README.md and docs/*.md — Markdown links
``[text](path)`` and the plain ``docs/NAME.md`` mentions the pages use in running text — names a file
that exists, and the README's documentation list names every page of docs/. No rendering; fast."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")  # [text](target) or [text](target "title")
MENTION = re.compile(r"(?<![\w/.-])(docs/[\w.-]+\.(?:md|json))")  # a page named in running text
FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)  # code blocks: commands and output, not links
CODE = re.compile(r"``.*?``|`[^`\n]*`")  # inline code: `[links](url)` is syntax shown, not a link


def _targets(page: Path) -> list[tuple[str, Path]]:
    """(as written, resolved path) of every relative link and docs/ mention in ``page``."""
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    out = []
    for target in LINK.findall(CODE.sub("", text)):
        if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:|^#|^/", target):  # a URL, an anchor, a site path
            continue
        out.append((target, (page.parent / target.split("#", 1)[0]).resolve()))
    out += [(m, (ROOT / m).resolve()) for m in MENTION.findall(text)]  # mentions are from the repo root
    return out


@pytest.mark.parametrize("page", PAGES, ids=[p.relative_to(ROOT).as_posix() for p in PAGES])
def test_relative_links_point_to_existing_files(page):
    broken = [written for written, path in _targets(page) if not path.exists()]
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def test_readme_lists_every_page_of_docs():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"\]\((docs/[\w.-]+\.md)\)", readme))
    pages = {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}
    assert sorted(pages - listed) == []


def test_readme_names_every_experiment_and_their_count():
    """The README's experiment paragraph names each registered experiment (`rtfit list`) in backticks and
    says how many there are: a family added to `experiments.families.FAMILIES` without its README line, or
    a count left behind, fails here (issue 30: the lists naming the families had drifted apart)."""
    from rtfit.experiments.families import FAMILIES

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    start = readme.index("Experiments (`rtfit list`")
    paragraph = readme[start : readme.index("\n\n", start)]
    missing = [name for name in FAMILIES if f"`{name}`" not in paragraph]
    assert not missing, f"README.md's experiment list lacks {missing}"
    count = re.search(r"(\d+) experiments", paragraph)
    assert count and int(count.group(1)) == len(FAMILIES), (count and count.group(0), len(FAMILIES))
