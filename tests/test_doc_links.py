"""The documentation's links (issue 32): every relative link in README.md and docs/*.md — Markdown links
``[text](path)`` and the plain ``docs/NAME.md`` mentions the pages use in running text — names a file
that exists, and the README's documentation list names every page of docs/ (a family's page, docs/<name>.md,
by the one line that says so). No rendering; fast."""

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


def unlisted_pages(root: Path, families) -> list[str]:
    """The pages of ``root``/docs/ that the README neither links nor covers by its family-page line: a
    family's page is ``docs/<name>.md`` for each name of ``families`` (`rtfit list`), so a family added
    links no new line here (issue 30: adding a family edits no shared list)."""
    readme = (root / "README.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"\]\((docs/[\w.-]+\.md)\)", readme)) | {f"docs/{n}.md" for n in families}
    return sorted({f"docs/{p.name}" for p in (root / "docs").glob("*.md")} - listed)


def families_without_a_page(root: Path, families) -> list[str]:
    """The families (names as `rtfit list` gives them) with no page ``docs/<name>.md`` under ``root``."""
    return [n for n in families if not (root / "docs" / f"{n}.md").is_file()]


README_FAMILY_WORDS = ("`rtfit list` names every family", "each family's page is `docs/<name>.md`")
"""What the README says about the families instead of listing them: where their names and their pages are."""


def test_readme_lists_every_page_of_docs():
    from rtfit.experiments.families import FAMILIES

    assert unlisted_pages(ROOT, FAMILIES) == []


def test_every_family_has_its_page():
    """Each family of the registry (`rtfit list`) has its page docs/<name>.md, which the README's family
    line points to; the README names no family list or count to keep in step."""
    from rtfit.experiments.families import FAMILIES

    assert families_without_a_page(ROOT, FAMILIES) == []
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert all(words in readme for words in README_FAMILY_WORDS), README_FAMILY_WORDS
