"""The documentation: the package map (docs/architecture.md) names every package and module of the
tree, and every link and image of README.md and docs/*.md points at something in the repository."""

from __future__ import annotations

import re
from pathlib import Path

import sim2real

SRC = Path(sim2real.__file__).resolve().parent
ROOT = SRC.parents[1]
README = ROOT / "README.md"
ARCHITECTURE = ROOT / "docs" / "architecture.md"

# [text](target) and ![alt](target); a target ends at whitespace or ')' (an optional "title" follows)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
CODE = re.compile(r"`[^`\n]*`")


def _package_map() -> str:
    text = ARCHITECTURE.read_text()
    start = text.index("# Package map")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def test_the_package_map_matches_the_tree():
    """Every package has its row (``src/sim2real/NAME/``) naming each of its modules (the CLI's
    row says 'one module per command' instead), and every top-level module is named."""
    section = _package_map()
    rows = {line.split("`")[1]: line for line in section.splitlines() if line.startswith("| `src/sim2real/")}
    missing = []
    for package in sorted(p for p in SRC.iterdir() if (p / "__init__.py").is_file()):
        row = rows.get(f"src/sim2real/{package.name}/")
        if row is None:
            missing.append(f"{package.name}/")
            continue
        if package.name == "cli":
            assert "one module per command" in row
            continue
        missing += [f"{package.name}/{m.name}" for m in sorted(package.glob("*.py"))
                    if m.name not in ("__init__.py", "__main__.py") and f"`{m.name}`" not in row]
    missing += [m.name for m in sorted(SRC.glob("*.py"))
                if m.name != "__init__.py" and f"`{m.name}`" not in section and f"src/sim2real/{m.name}" not in section]
    assert missing == []
    listed = {key.split("/")[2] for key in rows if key.endswith("/")}
    assert listed <= {p.name for p in SRC.iterdir() if p.is_dir()}, "a row names a package that no longer exists"


def test_the_readme_links_the_package_map():
    assert "](docs/architecture.md)" in README.read_text()


def links(text: str) -> list[str]:
    """The targets of the Markdown links and images of ``text``, outside code blocks and code spans."""
    return LINK.findall(CODE.sub("", FENCE.sub("", text)))


def anchors(text: str) -> set[str]:
    """The anchors of ``text``'s headings, as GitHub makes them: lower case, punctuation but '-'
    and '_' dropped, each space a '-'."""
    out = set()
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*$", FENCE.sub("", text), re.M):
        out.add(re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-"))
    return out


def test_links_finds_links_and_images_but_not_code():
    """The parser itself, on a hand-written text: two links and an image, none from code."""
    text = ("See [a](docs/a.md#x) and ![b](b.png \"t\").\n`[c](c.md)` [d](<e f.md>)\n"
            "```\n[g](g.md)\n```\n[h](https://h.example)\n")
    assert links(text) == ["docs/a.md#x", "b.png", "https://h.example"]
    assert anchors("# Starting from a trained run (`--init-from`)\n## A, b: c\n") == {
        "starting-from-a-trained-run---init-from", "a-b-c"}


def test_every_link_and_image_resolves_inside_the_repository():
    """Each link and image of README.md and docs/*.md names a file or folder of the repository
    (relative to the page), and an anchor names a heading of its page; no link leaves the
    repository."""
    pages = [README, *sorted((ROOT / "docs").glob("*.md"))]
    bad = []
    for page in pages:
        text = page.read_text()
        for target in links(text):
            where = f"{page.relative_to(ROOT)}: {target}"
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
                bad.append(f"{where} (outside the repository)")
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists() or ROOT.resolve() not in (file, *file.parents):
                bad.append(f"{where} (no such file in the repository)")
            elif anchor and file.suffix == ".md" and anchor not in anchors(file.read_text()):
                bad.append(f"{where} (no such heading)")
    assert bad == []


def test_every_figure_and_data_file_of_docs_is_used_by_a_page():
    """No stale picture or rows file lies in docs/ unreferenced: each docs/*.png is shown by
    README.md or a docs page, and each docs/*.jsonl is named by a docs page."""
    pages = [README, *sorted((ROOT / "docs").glob("*.md"))]
    shown = {(page.parent / t.partition("#")[0]).resolve() for page in pages for t in links(page.read_text())}
    named = "\n".join(p.read_text() for p in pages)
    unused = [p.name for p in sorted((ROOT / "docs").glob("*.png")) if p.resolve() not in shown]
    unused += [p.name for p in sorted((ROOT / "docs").glob("*.jsonl")) if f"docs/{p.name}" not in named]
    assert unused == []
