"""The simulation: the moving part as a rigid body, stepped with the fields acting on it.

The package holds the rigid body, the geometric fields acting on it, the virtual coupling
to the input proxy, the coupled system stepped at a fixed time step, and building all of
it from a loaded scene.

Modules: :mod:`~engine.sim.body` (rigid body, state, integrator pieces),
:mod:`~engine.sim.fields` (Correlator, landscape and null fields),
:mod:`~engine.sim.coupling` (coupling wrench, haptic reaction, clamping),
:mod:`~engine.sim.simulation` (:class:`Simulation`), :mod:`~engine.sim.build` (mass
properties, size-scaled physics, :func:`build_simulation`), :mod:`~engine.sim.guard`
(proxy poses within reach, divergence detected and explained; docs/limits.md). The
mathematics is in docs/simulation.md.
"""

from engine.sim.body import BodyState, RigidBody, kinetic_energy
from engine.sim.build import (
    SceneModel,
    build_simulation,
    mass_properties,
    part_pivot,
    resolve_physics,
    rigid_body,
    rotational_stiffness,
)
from engine.sim.coupling import clamp_norm, coupling_energy, coupling_wrench, haptic_reaction
from engine.sim.fields import (
    CorrelatorField,
    GeometricField,
    LandscapeField,
    NullField,
    RotationCacheField,
    evaluator_name,
    field_correlator,
    field_for_effects,
)
from engine.sim.simulation import Simulation

__all__ = [
    "BodyState",
    "CorrelatorField",
    "GeometricField",
    "LandscapeField",
    "NullField",
    "RigidBody",
    "RotationCacheField",
    "evaluator_name",
    "field_correlator",
    "SceneModel",
    "Simulation",
    "build_simulation",
    "clamp_norm",
    "coupling_energy",
    "coupling_wrench",
    "field_for_effects",
    "haptic_reaction",
    "kinetic_energy",
    "mass_properties",
    "part_pivot",
    "resolve_physics",
    "rigid_body",
    "rotational_stiffness",
]
