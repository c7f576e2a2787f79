"""Robots from parts: component types with typed schemas, robot files, the plugin registry.

No network (like common/sim2d/): the engine, the tools and the viewer share it.

- schema.py: a component type's parameters (Param) and calls (ApiCall), checked;
- components.py: the engine's own components (body, drive, IR ring, light ring,
  LEDs, gripper); sensors.py: batched sensors (floor, range finder, bumper);
- robotfile.py: a robot type as a TOML file, validated (file, line, field), compiled
  into the engine's AgentTypeSpec; shipped/: khepera.toml and epuck.toml;
- registry.py: built-ins + entry points (wart.components, wart.agents,
  wart.engines, wart.contexts) + a lab's robot directory, failures recorded;
- describe.py: what `wart robots describe` and docs/CONTROLLERS.md print.
"""
