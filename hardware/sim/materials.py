"""Materials and objects of the simulated tactile world.

Property values are order-of-magnitude figures for the materials named (thermal effusivity
e = sqrt(k ρ c) from handbook conductivities, densities and heat capacities; wall stiffness of a
thin cup is low, a thick glass or steel wall is effectively rigid against a fingertip pad of
~1 N/mm). They are meant to make the four cups of the paper differ the way the paper reports:
the stainless cup stands apart by its heat flux, the paper and clear plastic cups are close
(similar hardness), the bumpy glass vibrates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from hardware.errors import ConfigurationError
from hardware.sim.electrodes import TWINS


@dataclass(frozen=True)
class Material:
    """What the fingertip feels of a surface.

    Attributes:
        name: Material name.
        stiffness_n_per_mm: Contact stiffness of the surface (thin walls give way).
        friction: Kinetic friction coefficient against the fingertip skin.
        stick_slip: Excess of static over kinetic friction; drives stick-slip vibration.
        roughness_um: Texture amplitude.
        texture_period_mm: Spatial period of the texture (sets the vibration frequency
            v / period when sliding at speed v).
        effusivity: Thermal effusivity sqrt(k ρ c) in W s^0.5 m^-2 K^-1 (how fast the surface
            draws heat from a warm fingertip). For a coated body, the effusivity of the body
            under the coating.
        coating_effusivity: Effusivity of a thin surface layer (lacquer, paint), or ``None``.
        coating_time_s: Thermal time of that layer, d² / α (thickness d, diffusivity α): the
            fingertip feels the coating for contacts much shorter than it and the body under it
            for contacts much longer (see :meth:`effusivity_at`).
        insert_depth_mm: Depth under the surface of a stiffer insert (a board or sheet inside a
            soft cushion), or ``None``. Pressed less deep, the fingertip feels only the soft
            surface material; pressed deeper, the insert's stiffness adds (see
            :func:`hardware.sim.world.contact`).
        insert_stiffness_n_per_mm: Extra stiffness once the insert is reached (≥ 0).
    """

    name: str
    stiffness_n_per_mm: float
    friction: float
    stick_slip: float
    roughness_um: float
    texture_period_mm: float
    effusivity: float
    coating_effusivity: float | None = None
    coating_time_s: float = 0.0
    insert_depth_mm: float | None = None
    insert_stiffness_n_per_mm: float = 0.0

    def effusivity_at(self, contact_time_s: float) -> float:
        """Effusivity felt after ``contact_time_s`` of contact.

        A coated body: the surface heat flux of a layer (effusivity e_c, thermal time
        τ = d²/α) on a semi-infinite body (e_b) brought to a step in surface temperature is,
        by the method of images, that of a half-space of effusivity

            e(t) = e_c [1 + 2 Σ_{n≥1} (−Γ)ⁿ exp(−n² τ / t)],  Γ = (e_c − e_b) / (e_c + e_b),

        which is e_c for t ≪ τ and e_b for t ≫ τ (30 terms; the series converges
        geometrically, |Γ| < 1).
        """
        if self.coating_effusivity is None or self.coating_time_s <= 0:
            return self.effusivity
        if contact_time_s <= 0:
            return self.coating_effusivity
        coat, body = self.coating_effusivity, self.effusivity
        reflection = (coat - body) / (coat + body)
        ratio = self.coating_time_s / contact_time_s
        series = sum(
            (-reflection) ** n * math.exp(-n * n * ratio)
            for n in range(1, 31)
            if n * n * ratio < 700
        )
        return coat * (1.0 + 2.0 * series)

    def __post_init__(self) -> None:
        for field_name in (
            "stiffness_n_per_mm",
            "friction",
            "roughness_um",
            "texture_period_mm",
            "effusivity",
        ):
            value = float(getattr(self, field_name))
            if not value > 0:
                raise ConfigurationError(
                    f"Material {self.name!r}: {field_name} must be positive, received {value}."
                )
        if self.coating_effusivity is not None and not (
            self.coating_effusivity > 0 and self.coating_time_s > 0
        ):
            raise ConfigurationError(
                f"Material {self.name!r}: a coating needs a positive effusivity and time, "
                f"received {self.coating_effusivity} and {self.coating_time_s}."
            )
        if self.insert_depth_mm is not None and not (
            self.insert_depth_mm > 0 and self.insert_stiffness_n_per_mm > 0
        ):
            raise ConfigurationError(
                f"Material {self.name!r}: an insert needs a positive depth and stiffness, "
                f"received {self.insert_depth_mm} mm and {self.insert_stiffness_n_per_mm} N/mm."
            )
        if self.stick_slip < 0:
            raise ConfigurationError(
                f"Material {self.name!r}: stick_slip must be >= 0, received {self.stick_slip}."
            )


@dataclass(frozen=True)
class TactileObject:
    """An object standing on the turntable.

    Attributes:
        name: Object name.
        material: Its surface material.
        temperature_c: Its temperature.
        contact_angle_deg: FFJ3 flexion at which the fingertip first meets its surface (larger
            objects are met earlier).
    """

    name: str
    material: Material
    temperature_c: float = 22.0
    contact_angle_deg: float = 20.0

    def properties(self) -> dict[str, float | str]:
        """What is known of the object, as a flat record with units in the keys.

        Keys: ``material``, ``stiffness_n_per_mm``, ``friction``, ``stick_slip``,
        ``roughness_um``, ``texture_period_mm``, ``thermal_effusivity_w_s05_per_m2_k``,
        ``temperature_c``, ``contact_angle_deg``; for a coated surface also
        ``coating_effusivity_w_s05_per_m2_k`` and ``coating_time_s``; with an insert
        ``insert_depth_mm`` and ``insert_stiffness_n_per_mm``.
        """
        m = self.material
        coating: dict[str, float | str] = (
            {}
            if m.coating_effusivity is None
            else {
                "coating_effusivity_w_s05_per_m2_k": m.coating_effusivity,
                "coating_time_s": m.coating_time_s,
            }
        )
        insert: dict[str, float | str] = (
            {}
            if m.insert_depth_mm is None
            else {
                "insert_depth_mm": m.insert_depth_mm,
                "insert_stiffness_n_per_mm": m.insert_stiffness_n_per_mm,
            }
        )
        return {
            "material": m.name,
            "stiffness_n_per_mm": m.stiffness_n_per_mm,
            "friction": m.friction,
            "stick_slip": m.stick_slip,
            "roughness_um": m.roughness_um,
            "texture_period_mm": m.texture_period_mm,
            "thermal_effusivity_w_s05_per_m2_k": m.effusivity,
            "temperature_c": self.temperature_c,
            "contact_angle_deg": self.contact_angle_deg,
            **coating,
            **insert,
        }


PAPER = Material("paper (coated board)", 0.35, 0.55, 0.15, 6.0, 0.4, 450.0)
GLASS_BUMPY = Material("glass, moulded bumps", 60.0, 0.70, 0.25, 80.0, 3.0, 1450.0)
PET = Material("PET (clear plastic)", 0.60, 0.45, 0.20, 0.8, 1.0, 560.0)
STAINLESS = Material("stainless steel", 80.0, 0.30, 0.05, 0.4, 0.5, 7600.0)
CERAMIC = Material("glazed ceramic", 70.0, 0.50, 0.10, 1.5, 0.7, 1600.0)
WOOD = Material("pine wood", 20.0, 0.45, 0.12, 20.0, 0.8, 450.0)
FOAM = Material("polyurethane foam", 0.08, 0.90, 0.30, 150.0, 1.5, 60.0)
RUBBER = Material("natural rubber", 0.50, 1.10, 0.40, 3.0, 0.5, 600.0)
ALUMINIUM = Material("aluminium (thin can)", 1.5, 0.35, 0.08, 0.6, 0.5, 24000.0)
CORK = Material("cork", 2.0, 0.60, 0.15, 30.0, 0.6, 140.0)

# Look-alikes (docs/simulation.md, "Tables"): one cup, changed in one property each.
PET_STIFF = replace(PET, name="PET, thicker wall", stiffness_n_per_mm=0.68)
PET_WAXED = replace(PET, name="PET, wax film", friction=0.40, stick_slip=0.16)
# A 1.1 mm PET wall (α ≈ 1.2e-7 m²/s: d²/α ≈ 10 s) with water (e ≈ 1580) behind it.
PET_ON_WATER = replace(
    PET, name="PET wall on water", effusivity=1580.0, coating_effusivity=560.0, coating_time_s=10.0
)
# Micro-textured steel plates: one relief depth, four pitches (sliding at v excites v / pitch).
MICRO_TEXTURE = Material("micro-textured steel", 80.0, 0.35, 0.10, 20.0, 0.03, 7600.0)

# Cushions (docs/simulation.md, "Tables"): one upholstery foam cover, with or without a stiffer
# insert under 5.5 mm of foam. Only a press that compresses the foam down to the insert feels it.
CUSHION_FOAM = Material("upholstery foam", 0.10, 0.80, 0.25, 40.0, 1.0, 80.0)
CUSHION_INSERTS: dict[str, tuple[str, float]] = {
    "cushion_rubber": ("a rubber sheet", 0.5),
    "cushion_cork": ("a cork board", 2.0),
    "cushion_wood": ("a wooden board", 20.0),
}
CUSHION_INSERT_DEPTH_MM = 5.5
CUSHION_CONTACT_ANGLE_DEG = 21.5

OBJECTS: dict[str, TactileObject] = {
    "paper_cup": TactileObject("paper_cup", PAPER, contact_angle_deg=19.5),
    "bumpy_glass": TactileObject("bumpy_glass", GLASS_BUMPY, contact_angle_deg=20.5),
    "clear_plastic_cup": TactileObject("clear_plastic_cup", PET, contact_angle_deg=19.0),
    "stainless_cup": TactileObject("stainless_cup", STAINLESS, contact_angle_deg=20.0),
    "ceramic_mug": TactileObject("ceramic_mug", CERAMIC, contact_angle_deg=21.0),
    "warm_ceramic_mug": TactileObject(
        "warm_ceramic_mug", CERAMIC, temperature_c=45.0, contact_angle_deg=21.0
    ),
    "wooden_block": TactileObject("wooden_block", WOOD, contact_angle_deg=20.0),
    "foam_sponge": TactileObject("foam_sponge", FOAM, contact_angle_deg=18.0),
    "rubber_ball": TactileObject("rubber_ball", RUBBER, contact_angle_deg=19.0),
    "aluminium_can": TactileObject("aluminium_can", ALUMINIUM, contact_angle_deg=19.5),
    "cork_board": TactileObject("cork_board", CORK, contact_angle_deg=20.0),
    "pet_cup": TactileObject("pet_cup", PET, contact_angle_deg=20.0),
    "pet_cup_stiff": TactileObject("pet_cup_stiff", PET_STIFF, contact_angle_deg=20.0),
    "pet_cup_waxed": TactileObject("pet_cup_waxed", PET_WAXED, contact_angle_deg=20.0),
    "pet_cup_water": TactileObject("pet_cup_water", PET_ON_WATER, contact_angle_deg=20.0),
    "cushion_plain": TactileObject(
        "cushion_plain", CUSHION_FOAM, contact_angle_deg=CUSHION_CONTACT_ANGLE_DEG
    ),
    **{
        name: TactileObject(
            name,
            replace(
                CUSHION_FOAM,
                name=f"upholstery foam over {insert}",
                insert_depth_mm=CUSHION_INSERT_DEPTH_MM,
                insert_stiffness_n_per_mm=stiffness,
            ),
            contact_angle_deg=CUSHION_CONTACT_ANGLE_DEG,
        )
        for name, (insert, stiffness) in CUSHION_INSERTS.items()
    },
    **{
        f"texture_{round(1000 * pitch):d}um": TactileObject(
            f"texture_{round(1000 * pitch):d}um",
            replace(
                MICRO_TEXTURE,
                name=f"micro-texture, {1000 * pitch:.0f} µm pitch",
                texture_period_mm=pitch,
            ),
            contact_angle_deg=20.0,
        )
        for pitch in (0.02, 0.03, 0.045, 0.07)
    },
    # One glazed ceramic for all: the twins differ only in what the whole touch feels
    # (hardware.sim.electrodes.TWINS: fine texture period, contact width).
    **{
        name: TactileObject(name, replace(CERAMIC, name="glazed ceramic"), contact_angle_deg=20.0)
        for name in TWINS
    },
}
"""Preset objects; the first four are the paper's (Fig. 6a: O1..O4)."""

PAPER_CUPS: tuple[str, ...] = ("paper_cup", "bumpy_glass", "clear_plastic_cup", "stainless_cup")
"""The paper's four objects, in its order O1..O4."""

DEFAULT_TABLE: tuple[str, ...] = (*PAPER_CUPS, "ceramic_mug", "wooden_block", "foam_sponge")
"""What stands on a simulated turntable by default (slot 0 first): the paper's four cups in
slots 0-3, then three objects that differ from them in kind (a rigid glazed mug, a rough wooden
block, a soft open-cell foam sponge)."""


@dataclass(frozen=True)
class Table:
    """A set of objects for the simulated turntable: a named one, or one read from a file
    (:mod:`hardware.sim.table_file`).

    Attributes:
        name: Table name (``--table NAME``).
        slots: What stands on the turntable, slot 0 first (slots 0..n-1 are filled).
        description: What the table is for.
        action_std: Spread (std per action component) of a random collection design suited to
            the table: wide enough that random touches show what separates its objects, narrow
            enough that the planner's deepest presses stay within the servos' load limit.
    """

    name: str
    slots: tuple[TactileObject, ...]
    description: str = ""
    action_std: float = 1.0

    def __post_init__(self) -> None:
        if not self.slots:
            raise ConfigurationError(f"table {self.name!r}: no objects.")
        names = self.objects
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ConfigurationError(f"table {self.name!r}: objects {repeated} appear twice.")
        if not (math.isfinite(self.action_std) and self.action_std > 0):
            raise ConfigurationError(
                f"table {self.name!r}: action_std must be positive, received {self.action_std}."
            )

    @property
    def objects(self) -> tuple[str, ...]:
        """The objects' names, slot 0 first."""
        return tuple(item.name for item in self.slots)


def _presets(names: tuple[str, ...]) -> tuple[TactileObject, ...]:
    return tuple(OBJECTS[name] for name in names)


TABLES: dict[str, Table] = {
    table.name: table
    for table in (
        Table(
            "default",
            _presets(DEFAULT_TABLE),
            "The paper's four cups, a glazed mug, a wooden block and a foam sponge: objects that "
            "differ in kind (any touch tells them apart).",
        ),
        Table(
            "paper",
            _presets(PAPER_CUPS),
            "The paper's four cups (Fig. 6a: O1..O4).",
            # At 1, an active touch at the corner of the action box pressed deep enough into
            # the rigid cups to overload the simulated FFJ3 servo.
            action_std=0.75,
        ),
        Table(
            "lookalike_cups",
            _presets(("pet_cup", "pet_cup_stiff", "pet_cup_waxed", "pet_cup_water")),
            "One clear plastic cup and three look-alikes, each changed in one property: a "
            "thicker wall (stiffness), a wax film (friction, not heat), water behind the wall "
            "(heat, felt after ~3 s of contact).",
        ),
        Table(
            "cushions",
            _presets(("cushion_plain", "cushion_rubber", "cushion_cork", "cushion_wood")),
            "Four cushions with one foam cover: plain, or with a rubber sheet, a cork board or "
            "a wooden board 5.5 mm under the surface. Only a press deep enough to reach the "
            "insert tells them apart.",
            # About one random touch in ten then presses down to the inserts (docs/simulation.md).
            action_std=1.5,
        ),
        Table(
            "textures",
            _presets(("texture_20um", "texture_30um", "texture_45um", "texture_70um")),
            "One micro-textured steel plate at four pitches: the same material, relief and "
            "heat; only the vibration's frequency (sliding speed / pitch) differs.",
            action_std=0.75,  # rigid plates: deeper presses overload FFJ3 (docs/simulation.md)
        ),
        Table(
            "twins",
            _presets(tuple(TWINS)),
            "Four glazed ceramic objects, one material, felt through the whole-touch sensor "
            "(an electrode ring and a 1.6 kHz vibration, hardware/sim/electrodes.py): a fine "
            "or coarse texture, a broad or edge contact. Every channel has the same mean on "
            "all four; only the vibration's spectrum and the electrodes' spread differ.",
            action_std=0.75,  # rigid like the textures: deeper presses overload FFJ3
        ),
    )
}
"""Named tables of the simulated rig (``activetouch rig status --sim --table NAME``)."""

DEFAULT_TABLE_NAME = "default"


def get_table(table: str | Table) -> Table:
    """A named table, or ``table`` itself when it is one already (read from a file).

    Raises:
        ConfigurationError: Unknown name (the message lists the tables).
    """
    if isinstance(table, Table):
        return table
    try:
        return TABLES[table]
    except KeyError:
        raise ConfigurationError(f"unknown table {table!r}; tables: {', '.join(TABLES)}.") from None


def table_name(table: str | Table) -> str:
    """The name of a table given by name or as itself."""
    return table.name if isinstance(table, Table) else table


def design_std(table: str | Table, given: float | None = None) -> float:
    """The spread (std per action component) of a random collection design on a table.

    Args:
        table: Table name, or a table read from a file.
        given: The spread asked for; ``None`` takes the table's own :attr:`Table.action_std`.

    Raises:
        ConfigurationError: ``given`` is ``None`` and the table is unknown.
    """
    if given is not None:
        return given
    return get_table(table).action_std


def get_object(
    name: str, temperature_c: float | None = None, contact_angle_deg: float | None = None
) -> TactileObject:
    """A preset object by name, optionally at another temperature or contact angle.

    Raises:
        ConfigurationError: Unknown name (the message lists the presets).
    """
    try:
        preset = OBJECTS[name]
    except KeyError:
        raise ConfigurationError(
            f"unknown object {name!r}; presets: {', '.join(sorted(OBJECTS))}."
        ) from None
    if temperature_c is not None:
        preset = replace(preset, temperature_c=float(temperature_c))
    if contact_angle_deg is not None:
        preset = replace(preset, contact_angle_deg=float(contact_angle_deg))
    return preset
