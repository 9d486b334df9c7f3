"""The one energy scale of the command line: the scene's kappa, as the simulation uses it.

``E = -kappa Re f``: the correlation ``f`` is a volume (scene unit cubed) and kappa turns it
into an energy. Every command (evaluate, landscape, report, simulate) and the window report
E, F and T with the same kappa, the one the simulation resolves for the scene (its
``[simulation] kappa``, or the scale-free default from the moving part's size and mass), so
one pose gives one number everywhere. Masses are in kg, so a millimetre scene's energy is in
µJ, its force in mN and its torque in mN·mm (:class:`engine.params.QuantityUnits`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from engine.params import QuantityUnits
from engine.scene import Scene

if TYPE_CHECKING:
    from engine.runtime import SceneHandle


@dataclass(frozen=True)
class EnergyScale:
    """The kappa every reported energy is scaled by, and the units that follow from it."""

    kappa: float
    units: QuantityUnits
    source: str  # "scene" ([simulation] kappa) or "default" (scale-free)

    def describe(self) -> str:
        """One line for a report: the value, its unit and where it comes from."""
        where = ("the scene's [simulation] kappa" if self.source == "scene" else
                 "the scale-free default the simulation uses; set [simulation] kappa to fix it")
        return f"kappa = {self.kappa:.6g} {self.units.kappa} ({where})"

    def as_json(self) -> dict[str, object]:
        """The scale for a JSON result."""
        u = self.units
        return {"kappa": self.kappa, "kappa_source": self.source,
                "units": {"length": u.length, "energy": u.energy, "force": u.force,
                          "torque": u.torque, "kappa": u.kappa}}


def energy_scale(scene: Scene, handle: SceneHandle | None = None) -> EnergyScale:
    """The scene's kappa as its simulation resolves it.

    Loads the parts' meshes unless ``handle`` (the scene opened) is given.
    """
    from engine.runtime import open_scene
    from engine.sim import SceneModel

    units = QuantityUnits.of(scene.units)
    given = scene.config.simulation.kappa
    if given is not None:
        return EnergyScale(float(given), units, "scene")
    if handle is None:
        handle = open_scene(scene.path)
    kappa = SceneModel(handle).physics(handle.config.effects).kappa
    return EnergyScale(float(kappa), units, "default")
