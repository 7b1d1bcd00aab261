"""The README's package map names every package and module of the tree."""

from __future__ import annotations

from pathlib import Path

import sim2real

SRC = Path(sim2real.__file__).resolve().parent
README = SRC.parents[1] / "README.md"


def _package_map() -> str:
    text = README.read_text()
    start = text.index("## Package map")
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
