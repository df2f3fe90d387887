"""The README and docs/ stay a user guide whose references hold: the README's and every page's size
limits, every relative link and anchor resolves, every repository path the docs name exists, every
page is reachable from the README, no page reads as a diary (issue numbers, dates outside a table's
"Measured on" line, sessions), and the datasets' ``source_desc`` names files that exist and what
the expert does for each task kind."""

import ast
import re

import pytest
from conftest import ROOT

from embodied_envs.layout.task import KINDS

README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]
MAX_README_LINES = 200
MAX_LINE = 200  # characters, in the README and every docs page
MAX_DOC_LINES = 300  # lines per docs page: one reader's questions, answered in one read
# pages being rewritten now that still break the size or the diary rule: each leaves its list
# once it passes (test_known_exceptions_still_fail says when)
LONG_PAGES: set = set()
DIARY_PAGES: set = set()
# a link to a page the README names before it is written is allowed only while it does not exist
PENDING: set = set()  # pages linked before they are written
# repository folders whose paths, named whole in `backticks`, must exist
REPO_ROOTS = ("embodied_envs/", "tools/", "tests/", "layouts/", "assets/", ".ci/")

# what the docs say now, not when or in which round: history is git's
ISSUE = re.compile(r"\b(issues?|PRs?|pull requests?) #?\d+", re.I)
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
MEASURED_ON = re.compile(r"^\W*measured on\b", re.I)  # the one line a date may stand on
DIARY = re.compile(
    r"\b(last|this|another|previous|next|that) session|\bsession's|\btoday\b|\byesterday\b", re.I
)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CODE_SPAN = re.compile(r"`([^`\n]+)`")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def prose(text: str) -> str:
    """The text without fenced code blocks (commands there name outputs, not repository files)."""
    return FENCE.sub("", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a Markdown heading."""
    text = heading.strip().lower().replace("`", "")
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page) -> set[str]:
    text = prose(page.read_text(encoding="utf-8"))
    return {slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", text, re.M)}


def links(page) -> list[str]:
    text = CODE_SPAN.sub("", prose(page.read_text(encoding="utf-8")))
    return [t for t in LINK.findall(text) if not re.match(r"[a-z]+:", t)]


def test_the_readme_is_short_and_no_line_is_long():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines, the limit is 200"
    long = [
        f"{page.relative_to(ROOT)}:{i}: {len(line)} characters"
        for page in PAGES
        for i, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
        if len(line) > MAX_LINE
    ]
    assert not long, "lines over 200 characters:\n" + "\n".join(long)


def too_long(page) -> str | None:
    n = len(page.read_text(encoding="utf-8").splitlines())
    return f"{page.name}: {n} lines, the limit is {MAX_DOC_LINES}" if n > MAX_DOC_LINES else None


def diary_lines(page) -> list[str]:
    """Lines that date the text or tie it to a tracker or a work session, but a date on a
    table's "Measured on ..." line."""
    found = []
    for i, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        dated = DATE.search(line) and not MEASURED_ON.match(line)
        if ISSUE.search(line) or DIARY.search(line) or dated:
            found.append(f"{page.name}:{i}: {line.strip()[:120]}")
    return found


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_docs_page_is_within_its_size(page):
    if page.name not in LONG_PAGES:
        assert not too_long(page), too_long(page) + ": split it or cut what is history"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_page_reads_as_a_diary(page):
    if page.name not in DIARY_PAGES:
        found = diary_lines(page)
        assert not found, (
            "issue numbers, dates (but on a 'Measured on' line) or sessions; the docs say what the "
            "project is now and git keeps its history:\n" + "\n".join(found)
        )


def test_known_exceptions_still_fail():
    pages = {p.name: p for p in DOCS}
    passing = [f"{n} (LONG_PAGES)" for n in LONG_PAGES if n not in pages or not too_long(pages[n])]
    passing += [
        f"{n} (DIARY_PAGES)" for n in DIARY_PAGES if n not in pages or not diary_lines(pages[n])
    ]
    assert not passing, f"{passing} pass now: remove them from the list in tests/test_docs.py"


def test_the_diary_rule_finds_what_it_is_for(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "Measured on 2026-11-25, the 2-core machine.\n"  # allowed: a table's date
        "| seed | 2026 |\n"
        "Issue 35's 1.2x is met.\n"
        "Fixed on 2026-11-29 at last.\n"
        "Another session's tests ran beside it.\n",
        encoding="utf-8",
    )
    assert [line.split(":")[1] for line in diary_lines(page)] == ["3", "4", "5"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_resolves(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if file in PENDING and not file.exists():
            continue
        if not file.exists():
            broken.append(f"{target}: no file {file.relative_to(ROOT)}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            broken.append(f"{target}: no heading for #{anchor} in {file.relative_to(ROOT)}")
    assert not broken, f"{page.relative_to(ROOT)}: broken links:\n" + "\n".join(broken)


def test_pending_pages_leave_the_list_once_written():
    written = [str(p.relative_to(ROOT)) for p in PENDING if p.exists()]
    assert not written, f"{written} exist now: remove them from PENDING in tests/test_docs.py"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_repository_path_named_exists(page):
    named = [
        span
        for span in CODE_SPAN.findall(prose(page.read_text(encoding="utf-8")))
        if span.startswith(REPO_ROOTS) and " " not in span
    ]
    missing = [p for p in named if not (any(ROOT.glob(p)) if "*" in p else (ROOT / p).exists())]
    assert not missing, f"{page.relative_to(ROOT)} names paths that do not exist: {missing}"


def test_every_docs_page_is_linked_from_the_readme():
    linked = {(ROOT / t.partition("#")[0]).resolve() for t in links(README)}
    unlinked = [str(p.relative_to(ROOT)) for p in DOCS if p.resolve() not in linked]
    assert not unlinked, f"pages the README does not link to: {unlinked}"


def test_the_datasets_source_desc_names_files_that_exist_and_each_task_kind():
    found = []
    for module in sorted((ROOT / "embodied_envs").rglob("*.py")):
        for node in ast.walk(ast.parse(module.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Assign) and any(
                getattr(t, "id", None) == "SOURCE_DESC" for t in node.targets
            ):
                found.append(ast.literal_eval(node.value))
    assert len(found) == 1, f"expected one SOURCE_DESC in embodied_envs/, found {len(found)}"
    paths = re.findall(r"embodied_envs/[\w/]+\.py", found[0])
    assert paths, "SOURCE_DESC names no file of the expert"
    assert all((ROOT / p).is_file() for p in paths), f"SOURCE_DESC names missing files: {paths}"
    # what the expert does with each task kind a layout can name, a new kind failing here
    said = {"pick": "hold still (pick)", "place": "released (place, move)", "move": "(place, move)"}
    assert set(KINDS) == set(said), f"SOURCE_DESC: say what the expert does for {set(KINDS)}"
    assert all(words in found[0] for words in said.values()), found[0]
