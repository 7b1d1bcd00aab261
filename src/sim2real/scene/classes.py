"""Object classes as data: each class has a label id, an a_ref colour and a palette colour.

A scene declares the classes of its objects; a :class:`ClassTable` says, for each, the value of
its pixels in label images (``label``, 0..254; 255 is the background), the flat albedo of the
reference rendering a_ref and the initial colour of its neural texture (``a_ref``, RGB in
[0, 1]) and the colour of label previews (``palette``, RGB 0..255).

:data:`DEFAULT_CLASSES` covers the paper's five classes with their fixed ids (0 liver, 1 fat,
2 ligament, 3 abdominal_wall, 4 gallbladder: these never change, so that old labels, scenes and
models keep their meaning) and common abdominal organs and instruments after them. A user's
class table file (JSON) adds classes or overrides colours::

    {"classes": {"tumour": {"a_ref": [0.6, 0.3, 0.3], "palette": [255, 0, 255]},
                 "kidney": {"a_ref": [0.5, 0.2, 0.15]}}}

An entry needs ``a_ref`` unless it only changes a default class; a new class without ``label``
gets the next free id after every id in use, in file order; one without ``palette`` gets a
colour derived from its name. A default class keeps its id (an entry that gives another one is
refused).

A scene stores the table of its own classes in ``scene.json`` (``classes``); a scene written
before classes were data has none and gets the defaults (:meth:`ClassTable.migrate`).
"""

from __future__ import annotations

import colorsys
import json
import os
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from sim2real.errors import UserError, reason

LABEL_BACKGROUND = 255
"""Value of background pixels in uint8 label images; other values are class label ids."""
BACKGROUND_PALETTE = (0, 0, 0)
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class ClassInfo:
    name: str
    label: int
    a_ref: tuple[float, float, float]
    palette: tuple[int, int, int]

    def to_json(self) -> dict:
        return {"label": self.label, "a_ref": list(self.a_ref), "palette": list(self.palette)}


def _info(name: str, label: int, a_ref, palette) -> ClassInfo:
    return ClassInfo(name, label, tuple(float(x) for x in a_ref), tuple(int(x) for x in palette))


DEFAULT_CLASSES: dict[str, ClassInfo] = {c.name: c for c in (
    # the paper's five: ids, albedos (the authors' a_ref constants) and palette as before
    _info("liver", 0, (0.34, 0.1, 0.1), (200, 40, 40)),
    _info("fat", 1, (0.85, 0.58, 0.36), (245, 200, 40)),
    _info("ligament", 2, (0.7, 0.56, 0.52), (70, 190, 230)),
    _info("abdominal_wall", 3, (0.62, 0.38, 0.42), (150, 80, 200)),
    _info("gallbladder", 4, (0.42, 0.48, 0.28), (40, 180, 60)),
    # common abdominal organs and instruments (flat albedos of their usual tint)
    _info("stomach", 5, (0.78, 0.52, 0.5), (230, 120, 160)),
    _info("duodenum", 6, (0.8, 0.6, 0.48), (240, 150, 90)),
    _info("pancreas", 7, (0.86, 0.7, 0.52), (250, 230, 140)),
    _info("spleen", 8, (0.4, 0.12, 0.2), (120, 20, 60)),
    _info("kidney", 9, (0.46, 0.16, 0.13), (160, 90, 40)),
    _info("colon", 10, (0.74, 0.54, 0.46), (110, 140, 60)),
    _info("small_bowel", 11, (0.82, 0.52, 0.47), (255, 170, 210)),
    _info("instrument", 12, (0.56, 0.58, 0.6), (200, 200, 200)),
    _info("vessel", 13, (0.5, 0.08, 0.1), (255, 0, 0)),
    _info("bladder", 14, (0.84, 0.72, 0.6), (0, 120, 120)),
    _info("diaphragm", 15, (0.64, 0.34, 0.35), (90, 60, 160)),
)}
"""Default classes; their ids never change (new defaults take new ids)."""

PAPER_CLASSES: tuple[str, ...] = ("liver", "fat", "ligament", "abdominal_wall", "gallbladder")
"""The paper's classes, ids 0..4: those of the procedural scenes."""


def _colour(value, n: int, lo: float, hi: float, integer: bool, what: str) -> tuple:
    if not (isinstance(value, (list, tuple)) and len(value) == n):
        raise UserError(f"{what} must be a list of {n} numbers in [{lo:g}, {hi:g}], got {value!r}")
    out = []
    for x in value:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x) or not lo <= x <= hi:
            raise UserError(f"{what} must be a list of {n} numbers in [{lo:g}, {hi:g}], got {value!r}")
        if integer and x != int(x):
            raise UserError(f"{what} must hold integers 0..255, got {value!r}")
        out.append(int(x) if integer else float(x))
    return tuple(out)


def name_palette(name: str) -> tuple[int, int, int]:
    """A bright colour derived from a class name (the same in every process)."""
    h = zlib.crc32(name.encode()) / 2**32
    return tuple(int(round(255 * c)) for c in colorsys.hsv_to_rgb(h, 0.75, 0.95))


def check_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise UserError(f"class name {name!r} must be lower case letters, digits and '_', starting with a letter")
    return name


class ClassTable(Mapping[str, ClassInfo]):
    """Classes by name (see the module docstring). Immutable."""

    def __init__(self, infos: Iterable[ClassInfo]):
        self._by_name: dict[str, ClassInfo] = {}
        labels: dict[int, str] = {}
        for c in infos:
            check_name(c.name)
            if not 0 <= c.label < LABEL_BACKGROUND:
                raise UserError(f"class '{c.name}' has label id {c.label}; ids are 0..{LABEL_BACKGROUND - 1}")
            if c.label in labels and labels[c.label] != c.name:
                raise UserError(f"classes '{labels[c.label]}' and '{c.name}' share label id {c.label}")
            if c.name in DEFAULT_CLASSES and DEFAULT_CLASSES[c.name].label != c.label:
                raise UserError(f"class '{c.name}' has the fixed label id {DEFAULT_CLASSES[c.name].label}, "
                                f"not {c.label}")
            labels[c.label] = c.name
            self._by_name[c.name] = c

    def __getitem__(self, name: str) -> ClassInfo:
        return self._by_name[name]

    def __iter__(self):
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self._by_name)

    def __eq__(self, other) -> bool:
        return isinstance(other, ClassTable) and self.to_json() == other.to_json()

    def __repr__(self) -> str:
        return f"ClassTable({', '.join(f'{c.name}={c.label}' for c in self.values())})"

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def defaults(cls) -> "ClassTable":
        return cls(DEFAULT_CLASSES.values())

    @classmethod
    def migrate(cls, names: Iterable[str]) -> "ClassTable":
        """The table of a scene written before classes were data: the defaults of its classes."""
        return cls.defaults().subset(names)

    def with_entries(self, entries: dict, where: str = "class table") -> "ClassTable":
        """This table with ``entries`` ({name: {a_ref, label, palette}}) added or overriding."""
        if not isinstance(entries, dict):
            raise UserError(f"{where}: 'classes' must be an object of class name -> entry")
        infos = dict(self._by_name)
        next_label = max([c.label for c in infos.values()] + [c.label for c in DEFAULT_CLASSES.values()] + [-1]) + 1
        for name, e in entries.items():
            check_name(name)
            if not isinstance(e, dict):
                raise UserError(f"{where}: entry of class '{name}' must be an object with a_ref, label, palette")
            unknown = set(e) - {"a_ref", "label", "palette"}
            if unknown:
                raise UserError(f"{where}: class '{name}' has unknown key '{sorted(unknown)[0]}' (a_ref, label, palette)")
            base = infos.get(name)
            if base is None and "a_ref" not in e:
                raise UserError(f"{where}: new class '{name}' needs an 'a_ref' colour (three numbers in [0, 1])")
            a_ref = _colour(e["a_ref"], 3, 0.0, 1.0, False, f"{where}: a_ref of class '{name}'") if "a_ref" in e else base.a_ref
            palette = (_colour(e["palette"], 3, 0, 255, True, f"{where}: palette of class '{name}'") if "palette" in e
                       else base.palette if base else name_palette(name))
            if "label" in e:
                label = e["label"]
                if isinstance(label, bool) or not isinstance(label, int):
                    raise UserError(f"{where}: label of class '{name}' must be an integer 0..254, got {label!r}")
            elif base is not None:
                label = base.label
            else:
                label, next_label = next_label, next_label + 1
            infos[name] = ClassInfo(name, int(label), a_ref, palette)
        return ClassTable(infos.values())

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> "ClassTable":
        """The defaults with a user's class table file applied."""
        path = Path(path)
        try:
            spec = json.loads(path.read_text())
        except OSError as e:
            raise UserError(f"cannot read class table {path}: {reason(e)}") from None
        except ValueError as e:
            raise UserError(f"class table {path} is not valid JSON ({e})") from None
        if not isinstance(spec, dict) or "classes" not in spec:
            raise UserError(f"class table {path} needs a top-level 'classes' object")
        return cls.defaults().with_entries(spec["classes"], f"class table {path}")

    @classmethod
    def from_json(cls, spec: dict, where: str = "class table") -> "ClassTable":
        """A table as :meth:`to_json` wrote it (every entry complete)."""
        if not isinstance(spec, dict):
            raise UserError(f"{where}: 'classes' must be an object of class name -> entry")
        infos = []
        for name, e in spec.items():
            if not isinstance(e, dict) or set(e) != {"a_ref", "label", "palette"}:
                raise UserError(f"{where}: class '{name}' needs exactly a_ref, label and palette")
            label = e["label"]
            if isinstance(label, bool) or not isinstance(label, int):
                raise UserError(f"{where}: label of class '{name}' must be an integer, got {label!r}")
            infos.append(ClassInfo(check_name(name), label, _colour(e["a_ref"], 3, 0.0, 1.0, False, f"{where}: a_ref of '{name}'"),
                                   _colour(e["palette"], 3, 0, 255, True, f"{where}: palette of '{name}'")))
        return cls(infos)

    def to_json(self) -> dict:
        return {c.name: c.to_json() for c in sorted(self.values(), key=lambda c: c.label)}

    def subset(self, names: Iterable[str]) -> "ClassTable":
        """The entries of ``names``; an unknown name is refused with the way to add it."""
        names = list(dict.fromkeys(names))
        missing = [n for n in names if n not in self._by_name]
        if missing:
            raise UserError(f"unknown class '{missing[0]}': give it an a_ref colour in a class table file "
                            f"(--class-table FILE; known: {', '.join(self)})")
        return ClassTable(self._by_name[n] for n in names)

    # --- lookups ------------------------------------------------------------------------------

    def albedo(self, classes: Iterable[str]) -> np.ndarray:
        """(O, 3) float32 a_ref albedo of each object (object classes in object-id order)."""
        return np.array([self[c].a_ref for c in classes], dtype=np.float32).reshape(-1, 3)

    def labels(self, classes: Iterable[str]) -> np.ndarray:
        """(O,) int16 label id of each object."""
        return np.array([self[c].label for c in classes], dtype=np.int16)

    def palette_lut(self) -> np.ndarray:
        """(256, 3) uint8: label id -> palette colour (black for unused ids and the background)."""
        lut = np.zeros((256, 3), np.uint8)
        for c in self.values():
            lut[c.label] = c.palette
        lut[LABEL_BACKGROUND] = BACKGROUND_PALETTE
        return lut

    def palette_json(self) -> dict:
        """{class: [r, g, b], 'background': [0, 0, 0]} in label order."""
        out = {c.name: list(c.palette) for c in sorted(self.values(), key=lambda c: c.label)}
        out["background"] = list(BACKGROUND_PALETTE)
        return out

    def merged(self, other: "ClassTable", where: str = "") -> "ClassTable":
        """Both tables' entries; the same class must mean the same in both."""
        infos = dict(self._by_name)
        for c in other.values():
            if c.name in infos and infos[c.name] != c:
                raise UserError(f"class '{c.name}' is defined differently in two scenes{where}")
            infos[c.name] = c
        return ClassTable(infos.values())
