"""The lower-bounds check (``.ci/floors``) pins every direct dependency of pyproject.toml, the test
extras too, at the release its ``>=`` names: a dependency without a plain lower bound would be
left for pip to choose there, and the check would no longer say what it claims."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, which pytest itself requires there
    tomllib = pytest.importorskip("tomli")
Requirement = pytest.importorskip("packaging.requirements").Requirement

ROOT = Path(__file__).resolve().parents[1]


def test_the_floors_check_pins_every_dependency_at_its_lower_bound():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = project["dependencies"] + [d for extra in project["optional-dependencies"].values() for d in extra]
    expected = {}
    for text in declared:
        req = Requirement(text)
        lower = [s.version for s in req.specifier if s.operator == ">="]
        assert len(lower) == 1, f"{text}: one '>=' lower bound expected"
        expected[req.name] = lower[0]
    out = subprocess.run(["bash", str(ROOT / ".ci" / "floors"), "--constraints"], capture_output=True, text=True,
                         check=True, timeout=60).stdout
    pins = dict(line.split("==") for line in out.split())
    assert pins == expected
    assert len(pins) == len(declared)  # no name twice
