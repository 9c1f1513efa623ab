"""Tables of your own objects: a JSON or TOML file read into a simulated rig's table.

A table file describes the objects on the simulated turntable with the same properties as the
built-in tables (docs/simulation.md, "Your own objects")::

    name = "kitchen"                      # optional: the file's stem
    description = "Two mugs and a cork"   # optional
    action_std = 1.0                      # optional: the random design's spread

    [materials.ceramic]                   # optional: materials several objects share
    stiffness_n_per_mm = 70.0
    friction = 0.5
    stick_slip = 0.1
    roughness_um = 1.5
    texture_period_mm = 0.7
    effusivity = 1600.0

    [[objects]]
    name = "mug"
    material = "ceramic"                  # a key of [materials], or the material itself
    slot = 0                              # optional: the file's order

    [[objects]]
    name = "warm_mug"
    material = "ceramic"
    temperature_c = 45.0

The material's keys are the fields of :class:`~hardware.sim.materials.Material`; an object's
are ``name``, ``material``, ``slot``, ``temperature_c`` and ``contact_angle_deg`` (those of
:class:`~hardware.sim.materials.TactileObject`). Anything missing, unknown, of the wrong type or
out of range raises :class:`TableFileError` naming the object and the field.
:func:`table_document` writes a table back as such a document (a built-in one too).
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from hardware.errors import ConfigurationError
from hardware.finger import default_joints
from hardware.sim.materials import Material, Table, TactileObject
from hardware.sim.world import FingerModel
from hardware.turntable import TurntableConfig

#: Suffixes read as TOML (anything else is read as JSON).
TOML_SUFFIXES = (".toml",)

_TABLE_KEYS = ("name", "description", "action_std", "materials", "objects")
_OBJECT_KEYS = ("name", "material", "slot", "temperature_c", "contact_angle_deg")
_MATERIAL_FIELDS = {f.name: f for f in fields(Material)}
_OBJECT_DEFAULTS: dict[str, float] = {
    f.name: float(f.default) for f in fields(TactileObject) if f.default is not MISSING
}

ABSOLUTE_ZERO_C = -273.15

#: How errors name a shared material (``materials.KEY``) in the place of an object.
SHARED = "materials."


class TableFileError(ConfigurationError):
    """A table file that cannot be read: what is wrong, where.

    Attributes:
        source: The file (or ``"table"`` for a document not read from a file).
        object_name: The object (or ``materials.KEY`` entry) at fault; ``None`` for the table's
            own fields.
        field: The field at fault (``material.insert_depth_mm``, ``slot``, ...).
    """

    def __init__(self, source: str, object_name: str | None, field: str, problem: str) -> None:
        self.source = source
        self.object_name = object_name
        self.field = field
        if object_name is None:
            where = ""
        elif object_name.startswith(SHARED):  # a shared material: materials.KEY.field
            where = f"{object_name}."
        else:
            where = f"object {object_name!r}, "
        super().__init__(f"{source}: {where}{field}: {problem}")


def read_table_file(path: str | Path) -> Table:
    """Read a table file (``.toml``, else JSON).

    Raises:
        TableFileError: The file cannot be read or parsed, or describes no valid table (the
            message names the object and the field).
    """
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TableFileError(source, None, "file", f"cannot read it ({exc}).") from None
    try:
        if path.suffix.lower() in TOML_SUFFIXES:
            document: Any = tomllib.loads(text)
        else:
            document = json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        kind = "TOML" if path.suffix.lower() in TOML_SUFFIXES else "JSON"
        raise TableFileError(source, None, "file", f"not valid {kind}: {exc}.") from None
    return parse_table(document, default_name=path.stem, source=source)


def parse_table(document: Any, default_name: str = "custom", source: str = "table") -> Table:
    """A table from its document (a JSON object or TOML table, already parsed).

    Args:
        document: The document (see the module's docstring).
        default_name: The table's name when the document gives none.
        source: Where the document came from (for the messages).

    Raises:
        TableFileError: Naming the object and the field that are wrong.
    """
    reader = _Reader(source)
    if not isinstance(document, Mapping):
        raise reader.error(None, "file", f"expected a table of keys, found {_kind(document)}.")
    reader.unknown_keys(document, _TABLE_KEYS, None, "")
    name = reader.text(document, "name", None, default=default_name)
    description = reader.text(document, "description", None, default="")
    action_std = reader.number(document, "action_std", None, default=1.0, above=0.0)
    materials = reader.materials(document.get("materials", {}))
    if "objects" not in document:
        raise reader.error(None, "objects", "missing: list the objects on the table.")
    entries = document["objects"]
    if not isinstance(entries, list) or not entries:
        raise reader.error(None, "objects", "expected a non-empty list of objects.")
    slot_count = TurntableConfig().slot_count
    if len(entries) > slot_count:
        raise reader.error(
            None,
            "objects",
            f"{len(entries)} objects do not fit on the turntable's {slot_count} slots.",
        )
    placed: dict[int, TactileObject] = {}
    unslotted: list[TactileObject] = []
    names: set[str] = set()
    for index, entry in enumerate(entries):
        label = f"objects[{index}]"
        if not isinstance(entry, Mapping):
            raise reader.error(label, "object", f"expected a table of keys, found {_kind(entry)}.")
        given_name = entry.get("name")
        if isinstance(given_name, str) and given_name.strip():
            label = given_name
        item, slot = reader.tactile_object(entry, label, materials, slot_count)
        if item.name in names:
            raise reader.error(item.name, "name", "another object has this name.")
        names.add(item.name)
        if slot is None:
            unslotted.append(item)
        elif slot in placed:
            raise reader.error(
                item.name, "slot", f"slot {slot} already holds {placed[slot].name!r}."
            )
        else:
            placed[slot] = item
    free = (s for s in range(slot_count) if s not in placed)
    for item in unslotted:
        placed[next(free)] = item
    for slot in range(len(placed)):
        if slot not in placed:
            beyond = min(s for s in placed if s > slot)
            raise reader.error(
                placed[beyond].name,
                "slot",
                f"slot {beyond} leaves slot {slot} empty; the simulated turntable is filled "
                f"from slot 0 (slots 0..{len(placed) - 1} for {len(placed)} objects).",
            )
    try:
        return Table(name, tuple(placed[s] for s in range(len(placed))), description, action_std)
    except ConfigurationError as exc:  # pragma: no cover - every case is checked above
        raise reader.error(None, "table", str(exc)) from None


def table_document(table: Table) -> dict[str, Any]:
    """A table as a document :func:`parse_table` reads back into an equal table.

    Every object carries its material in full and its slot; optional material fields appear
    only when set (a coating, an insert).
    """
    objects = []
    for slot, item in enumerate(table.slots):
        material: dict[str, Any] = {}
        for name, spec in _MATERIAL_FIELDS.items():
            value = getattr(item.material, name)
            if spec.default is MISSING or value != spec.default:
                material[name] = value
        objects.append(
            {
                "name": item.name,
                "slot": slot,
                "temperature_c": item.temperature_c,
                "contact_angle_deg": item.contact_angle_deg,
                "material": material,
            }
        )
    return {
        "name": table.name,
        "description": table.description,
        "action_std": table.action_std,
        "objects": objects,
    }


def _kind(value: object) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return f"the text {value!r}"
    if value is None:
        return "null"
    return f"{value!r}"


class _Reader:
    """The checks of one document, each naming where it found the fault."""

    def __init__(self, source: str) -> None:
        self.source = source
        joint = default_joints()[0]
        self.flexion_deg = (joint.lower_deg, joint.upper_deg)
        self.reach_mm = FingerModel().length_mm

    def error(self, owner: str | None, field: str, problem: str) -> TableFileError:
        return TableFileError(self.source, owner, field, problem)

    def unknown_keys(
        self, entry: Mapping[str, Any], allowed: tuple[str, ...], owner: str | None, prefix: str
    ) -> None:
        for key in entry:
            if key not in allowed:
                raise self.error(
                    owner,
                    f"{prefix}{key}",
                    f"unknown property; known: {', '.join(allowed)}.",
                )

    def text(self, entry: Mapping[str, Any], key: str, owner: str | None, *, default: str) -> str:
        if key not in entry:
            return default
        value = entry[key]
        if not isinstance(value, str) or (key == "name" and not value.strip()):
            raise self.error(owner, key, f"expected a non-empty text, found {_kind(value)}.")
        return value

    def number(
        self,
        entry: Mapping[str, Any],
        key: str,
        owner: str | None,
        *,
        default: float | None = None,
        above: float | None = None,
        at_least: float | None = None,
        prefix: str = "",
    ) -> float:
        field = f"{prefix}{key}"
        if key not in entry:
            if default is None:
                raise self.error(owner, field, "missing.")
            return default
        value = entry[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(owner, field, f"expected a number, found {_kind(value)}.")
        number = float(value)
        if not math.isfinite(number):
            raise self.error(owner, field, f"must be finite, received {value}.")
        if above is not None and not number > above:
            raise self.error(owner, field, f"must be > {above:g}, received {value}.")
        if at_least is not None and not number >= at_least:
            raise self.error(owner, field, f"must be ≥ {at_least:g}, received {value}.")
        return number

    def materials(self, section: Any) -> dict[str, Material]:
        if not isinstance(section, Mapping):
            raise self.error(
                None, "materials", f"expected a table of materials, found {_kind(section)}."
            )
        return {
            key: self.material(entry, f"{SHARED}{key}", key, "") for key, entry in section.items()
        }

    def material(self, entry: Any, owner: str, default_name: str, prefix: str) -> Material:
        if not isinstance(entry, Mapping):
            raise self.error(
                owner if prefix else None,
                prefix.rstrip(".") or owner,
                f"expected a table, found {_kind(entry)}.",
            )
        self.unknown_keys(entry, tuple(_MATERIAL_FIELDS), owner, prefix)
        name = self.text(entry, "name", owner, default=default_name)
        values: dict[str, Any] = {"name": name}
        for key in (
            "stiffness_n_per_mm",
            "friction",
            "roughness_um",
            "texture_period_mm",
            "effusivity",
        ):
            values[key] = self.number(entry, key, owner, above=0.0, prefix=prefix)
        values["stick_slip"] = self.number(entry, "stick_slip", owner, at_least=0.0, prefix=prefix)
        for first, second in (
            ("coating_effusivity", "coating_time_s"),
            ("insert_depth_mm", "insert_stiffness_n_per_mm"),
        ):
            given = [key for key in (first, second) if key in entry]
            if len(given) == 1:
                other = second if given[0] == first else first
                raise self.error(owner, f"{prefix}{other}", f"missing: {given[0]} needs it too.")
            if given:
                values[first] = self.number(entry, first, owner, above=0.0, prefix=prefix)
                values[second] = self.number(entry, second, owner, above=0.0, prefix=prefix)
        return Material(**values)

    def tactile_object(
        self,
        entry: Mapping[str, Any],
        label: str,
        materials: Mapping[str, Material],
        slot_count: int,
    ) -> tuple[TactileObject, int | None]:
        self.unknown_keys(entry, _OBJECT_KEYS, label, "")
        if "name" not in entry:
            raise self.error(label, "name", "missing.")
        name = self.text(entry, "name", label, default="")
        if "material" not in entry:
            raise self.error(name, "material", "missing: a key of [materials] or a material.")
        given = entry["material"]
        if isinstance(given, str):
            if given not in materials:
                known = ", ".join(materials) or "none"
                raise self.error(
                    name, "material", f"{given!r} is not a key of materials (known: {known})."
                )
            material = materials[given]
        else:
            material = self.material(given, name, name, "material.")
        slot: int | None = None
        if "slot" in entry:
            value = entry["slot"]
            if isinstance(value, bool) or not isinstance(value, int):
                raise self.error(name, "slot", f"expected an integer, found {_kind(value)}.")
            if not 0 <= value < slot_count:
                raise self.error(
                    name, "slot", f"must lie in 0..{slot_count - 1}, received {value}."
                )
            slot = value
        temperature = self.number(
            entry,
            "temperature_c",
            name,
            default=_OBJECT_DEFAULTS["temperature_c"],
            above=ABSOLUTE_ZERO_C,
        )
        low, high = self.flexion_deg
        angle = self.number(
            entry, "contact_angle_deg", name, default=_OBJECT_DEFAULTS["contact_angle_deg"]
        )
        if not low < angle < high:
            raise self.error(
                name,
                "contact_angle_deg",
                f"must lie inside FFJ3's range ({low:g}°, {high:g}°) for the fingertip to meet "
                f"the object, received {angle:g}.",
            )
        if material.insert_depth_mm is not None:
            deepest = self.reach_mm * (math.sin(math.radians(high)) - math.sin(math.radians(angle)))
            if material.insert_depth_mm >= deepest:
                field = (
                    f"materials.{given}.insert_depth_mm"
                    if isinstance(given, str)
                    else "material.insert_depth_mm"
                )
                raise self.error(
                    name,
                    field,
                    f"{material.insert_depth_mm:g} mm is deeper than the fingertip can press "
                    f"into this object ({deepest:.1f} mm: FFJ3 at its {high:g}° limit, contact "
                    f"at {angle:g}°).",
                )
        return TactileObject(name, material, temperature, angle), slot
