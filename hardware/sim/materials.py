"""Materials and objects of the simulated tactile world.

Property values are order-of-magnitude figures for the materials named (thermal effusivity
e = sqrt(k ρ c) from handbook conductivities, densities and heat capacities; wall stiffness of a
thin cup is low, a thick glass or steel wall is effectively rigid against a fingertip pad of
~1 N/mm). They are meant to make the four cups of the paper differ the way the paper reports:
the stainless cup stands apart by its heat flux, the paper and clear plastic cups are close
(similar hardness), the bumpy glass vibrates.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from hardware.errors import ConfigurationError


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
            draws heat from a warm fingertip).
    """

    name: str
    stiffness_n_per_mm: float
    friction: float
    stick_slip: float
    roughness_um: float
    texture_period_mm: float
    effusivity: float

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
        ``temperature_c``, ``contact_angle_deg``.
        """
        m = self.material
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
}
"""Preset objects; the first four are the paper's (Fig. 6a: O1..O4)."""

PAPER_CUPS: tuple[str, ...] = ("paper_cup", "bumpy_glass", "clear_plastic_cup", "stainless_cup")
"""The paper's four objects, in its order O1..O4."""

DEFAULT_TABLE: tuple[str, ...] = (*PAPER_CUPS, "ceramic_mug", "wooden_block", "foam_sponge")
"""What stands on a simulated turntable by default (slot 0 first): the paper's four cups in
slots 0-3, then three objects that differ from them in kind (a rigid glazed mug, a rough wooden
block, a soft open-cell foam sponge)."""


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
