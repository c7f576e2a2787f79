"""Sim2D: the 2D simulation library (thesis 6.7), with no Zenoh in it.

The engine process (services/engine/) serves one World over the network; the
Khepera emulator (services/bridge/simbody.py) uses a World as the physical
robot behind the serial protocol. Both import only this package.

- world.py: the World, a state and the parts that work on it:
  world_state.py (the WorldState: arena, obstacles, objects, lights, zones,
  agents and their per-agent state; EditError), and parts that each take the
  state: world_edits.py (the editor: live edits), world_actuators.py (what a
  command sets; one robot as common.controller.actuators.Actuators),
  world_tick.py (the ticker: the tick), gripper.py (below);
- bodies.py: how each kind of thing becomes pymunk bodies and joints;
- gripper.py: the gripper turret's rules (arm, fingers, grip, carry);
- sensing.py: the sensor components (IR proximity ring, ambient light, the
  gripper's barrier) and the suite that reads them all in one pass;
- kernels.py, chipmunk.py: the compiled per-tick kernels (numba), gathered
  from one module per job (packs.py, physics.py, noise.py, rays.py,
  sense_pass.py; discs.py and contacts.py for the discs drive; jitcache.py
  keeps their on-disk cache true, and shared by the machine's checkouts), and
  the chipmunk functions they call (chipmunk_calls.py); compiled.py, what the
  World calls: the same kernels compiled ahead of time where built (aot.py,
  aot_build.py: no numba in the process), numba's otherwise;
- specs.py, agents/: robot types as frozen specs (Khepera, e-puck);
- entities.py, geometry.py, collision.py: the things of a world and their shapes;
- maps.py: the map file format (load, save); wander.py: a built-in wander rule.
"""
