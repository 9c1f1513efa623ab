"""Tables of your own objects: JSON and TOML files read into the built-in tables' structures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from hardware.sim.materials import TABLES, Material, Table, TactileObject
from hardware.sim.table_file import TableFileError, parse_table, read_table_file, table_document

PROJECT = Path(__file__).resolve().parents[2]

TOML = """
name = "kitchen"
description = "A mug, the same mug warm, and a cushion over a board"
action_std = 1.25

[materials.ceramic]
name = "glazed ceramic"
stiffness_n_per_mm = 70.0
friction = 0.5
stick_slip = 0.1
roughness_um = 1.5
texture_period_mm = 0.7
effusivity = 1600

[[objects]]
name = "warm_mug"
material = "ceramic"
temperature_c = 45.0
slot = 1

[[objects]]
name = "mug"
material = "ceramic"

[[objects]]
name = "cushion"
contact_angle_deg = 21.5

[objects.material]
stiffness_n_per_mm = 0.1
friction = 0.8
stick_slip = 0.25
roughness_um = 40.0
texture_period_mm = 1.0
effusivity = 80.0
insert_depth_mm = 5.5
insert_stiffness_n_per_mm = 20.0
"""

CERAMIC = {
    "name": "glazed ceramic",
    "stiffness_n_per_mm": 70.0,
    "friction": 0.5,
    "stick_slip": 0.1,
    "roughness_um": 1.5,
    "texture_period_mm": 0.7,
    "effusivity": 1600,
}


def kitchen() -> dict[str, Any]:
    """The TOML document above, written as JSON."""
    return {
        "name": "kitchen",
        "description": "A mug, the same mug warm, and a cushion over a board",
        "action_std": 1.25,
        "materials": {"ceramic": dict(CERAMIC)},
        "objects": [
            {"name": "warm_mug", "material": "ceramic", "temperature_c": 45.0, "slot": 1},
            {"name": "mug", "material": "ceramic"},
            {
                "name": "cushion",
                "contact_angle_deg": 21.5,
                "material": {
                    "stiffness_n_per_mm": 0.1,
                    "friction": 0.8,
                    "stick_slip": 0.25,
                    "roughness_um": 40.0,
                    "texture_period_mm": 1.0,
                    "effusivity": 80.0,
                    "insert_depth_mm": 5.5,
                    "insert_stiffness_n_per_mm": 20.0,
                },
            },
        ],
    }


def test_json_and_toml_give_the_same_table(tmp_path: Path) -> None:
    (tmp_path / "kitchen.toml").write_text(TOML)
    (tmp_path / "kitchen.json").write_text(json.dumps(kitchen()))
    from_toml = read_table_file(tmp_path / "kitchen.toml")
    assert from_toml == read_table_file(tmp_path / "kitchen.json")
    ceramic = Material("glazed ceramic", 70.0, 0.5, 0.1, 1.5, 0.7, 1600.0)
    foam = Material("cushion", 0.1, 0.8, 0.25, 40.0, 1.0, 80.0, None, 0.0, 5.5, 20.0)
    assert from_toml == Table(
        "kitchen",
        (
            TactileObject("mug", ceramic),  # no slot: the first free one
            TactileObject("warm_mug", ceramic, temperature_c=45.0),
            TactileObject("cushion", foam, contact_angle_deg=21.5),
        ),
        "A mug, the same mug warm, and a cushion over a board",
        1.25,
    )
    assert from_toml.objects == ("mug", "warm_mug", "cushion")


def test_the_name_defaults_to_the_file_stem(tmp_path: Path) -> None:
    document = kitchen()
    del document["name"], document["description"], document["action_std"]
    path = tmp_path / "my-shelf.json"
    path.write_text(json.dumps(document))
    table = read_table_file(path)
    assert (table.name, table.description, table.action_std) == ("my-shelf", "", 1.0)


@pytest.mark.parametrize("name", sorted(TABLES))
def test_a_built_in_table_written_as_a_file_reads_back_equal(name: str, tmp_path: Path) -> None:
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(table_document(TABLES[name])))
    assert read_table_file(path) == TABLES[name]


@pytest.mark.parametrize(
    "path", sorted((PROJECT / "examples").glob("*.toml")), ids=lambda p: p.name
)
def test_every_example_table_file_reads(path: Path) -> None:
    table = read_table_file(path)
    assert table.name
    assert len(table.slots) >= 2
    assert all(item.material.stiffness_n_per_mm > 0 for item in table.slots)


def edit(change: Any) -> dict[str, Any]:
    document = kitchen()
    change(document)
    return document


def cushion(document: dict[str, Any]) -> dict[str, Any]:
    material: dict[str, Any] = document["objects"][2]["material"]
    return material


BAD: list[tuple[str, Any, str | None, str, str]] = [
    # (case, change, object named, field named, words of the problem)
    (
        "unknown object property",
        lambda d: d["objects"][1].update(colour="red"),
        "mug",
        "colour",
        "unknown property",
    ),
    (
        "unknown material property",
        lambda d: cushion(d).update(hardness=3.0),
        "cushion",
        "material.hardness",
        "unknown property",
    ),
    (
        "unknown table property",
        lambda d: d.update(shelf=1),
        None,
        "shelf",
        "unknown property",
    ),
    (
        "negative stiffness",
        lambda d: cushion(d).update(stiffness_n_per_mm=-0.1),
        "cushion",
        "material.stiffness_n_per_mm",
        "must be > 0",
    ),
    (
        "negative stiffness of a shared material",
        lambda d: d["materials"]["ceramic"].update(stiffness_n_per_mm=-70.0),
        "materials.ceramic",
        "stiffness_n_per_mm",
        "must be > 0",
    ),
    (
        "insert deeper than the finger reaches",
        lambda d: cushion(d).update(insert_depth_mm=45.0),
        "cushion",
        "material.insert_depth_mm",
        "deeper than the fingertip can press",
    ),
    (
        "insert without its stiffness",
        lambda d: cushion(d).pop("insert_stiffness_n_per_mm"),
        "cushion",
        "material.insert_stiffness_n_per_mm",
        "missing",
    ),
    (
        "missing property",
        lambda d: cushion(d).pop("friction"),
        "cushion",
        "material.friction",
        "missing",
    ),
    (
        "wrong type",
        lambda d: cushion(d).update(friction="high"),
        "cushion",
        "material.friction",
        "expected a number",
    ),
    (
        "a boolean is not a number",
        lambda d: d["objects"][0].update(temperature_c=True),
        "warm_mug",
        "temperature_c",
        "expected a number",
    ),
    (
        "not finite",
        lambda d: cushion(d).update(effusivity=float("inf")),
        "cushion",
        "material.effusivity",
        "finite",
    ),
    (
        "below absolute zero",
        lambda d: d["objects"][0].update(temperature_c=-300.0),
        "warm_mug",
        "temperature_c",
        "must be >",
    ),
    (
        "contact beyond the finger's range",
        lambda d: d["objects"][1].update(contact_angle_deg=75.0),
        "mug",
        "contact_angle_deg",
        "FFJ3",
    ),
    (
        "duplicate names",
        lambda d: d["objects"][1].update(name="warm_mug"),
        "warm_mug",
        "name",
        "another object",
    ),
    (
        "duplicate slots",
        lambda d: d["objects"][1].update(slot=1),
        "mug",
        "slot",
        "already holds 'warm_mug'",
    ),
    (
        "a slot leaving a gap",
        lambda d: d["objects"][0].update(slot=7),
        "warm_mug",
        "slot",
        "leaves slot 2 empty",
    ),
    (
        "slot off the turntable",
        lambda d: d["objects"][0].update(slot=10),
        "warm_mug",
        "slot",
        "0..9",
    ),
    (
        "more objects than slots",
        lambda d: d.update(
            objects=[{"name": f"mug_{k}", "material": "ceramic"} for k in range(11)]
        ),
        None,
        "objects",
        "do not fit",
    ),
    (
        "no objects",
        lambda d: d.update(objects=[]),
        None,
        "objects",
        "non-empty list",
    ),
    (
        "unknown material key",
        lambda d: d["objects"][1].update(material="porcelain"),
        "mug",
        "material",
        "not a key of materials",
    ),
    (
        "an object without a name",
        lambda d: d["objects"][1].pop("name"),
        "objects[1]",
        "name",
        "missing",
    ),
    (
        "a zero action_std",
        lambda d: d.update(action_std=0),
        None,
        "action_std",
        "must be > 0",
    ),
]


@pytest.mark.parametrize(
    ("change", "owner", "field", "words"),
    [case[1:] for case in BAD],
    ids=[case[0] for case in BAD],
)
def test_bad_input_names_the_object_and_the_field(
    change: Any, owner: str | None, field: str, words: str
) -> None:
    with pytest.raises(TableFileError) as caught:
        parse_table(edit(change), source="kitchen.json")
    error = caught.value
    assert (error.object_name, error.field) == (owner, field)
    assert words in str(error)
    assert str(error).startswith("kitchen.json: ")
    if owner is not None and owner.startswith("materials."):
        assert f"{owner}.{field}: " in str(error)
    elif owner is not None:
        assert f"object {owner!r}, {field}: " in str(error)
    else:
        assert str(error).startswith(f"kitchen.json: {field}: ")


def test_unreadable_files_name_the_file(tmp_path: Path) -> None:
    broken = tmp_path / "broken.toml"
    broken.write_text("name = ")
    with pytest.raises(TableFileError, match="not valid TOML"):
        read_table_file(broken)
    with pytest.raises(TableFileError, match="cannot read it"):
        read_table_file(tmp_path / "missing.json")
    listed = tmp_path / "list.json"
    listed.write_text("[1, 2]")
    with pytest.raises(TableFileError, match="expected a table of keys"):
        read_table_file(listed)
