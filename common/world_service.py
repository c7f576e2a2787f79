"""What every world serves, simulated (the Sim2D engine) or real (the Khepera bridge).

A controller cannot tell the two apart because both declare exactly this
interface, here, once (ARGoS's control interface, Enki's world): frames and
sensor batches out, commands and leases in, snapshot, edit and map queries.
"""

from __future__ import annotations

from typing import Any

import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import Message
from common.service import Service


class WorldService(Service):
    """Base of the engine's and the bridge's services; subclasses implement the handlers."""

    kind = AliveKind.WORLD
    _frame_pub: Any
    _batch_pub: Any

    def declare_world_interface(self) -> None:
        """Declare the world's keys (call from on_start, before the service's own threads)."""
        realm, name = self.realm, self.ident
        self._frame_pub = self.track(self.session.declare_publisher(keys.world_frame(realm, name)))
        self._batch_pub = self.track(
            self.session.declare_publisher(keys.world_sensors(realm, name))
        )
        self.subscribe(keys.agent_cmd_all(realm, name), self._on_command)
        self.subscribe(keys.agent_lease_all(realm, name), self._on_lease)
        self.serve(keys.world_snapshot(realm, name), self._on_snapshot)
        self.serve(keys.world_edit(realm, name), self._on_edit)
        self.serve(keys.world_map(realm, name), self._on_map)

    # -- what each world does with them

    def _on_command(self, sample: zenoh.Sample) -> None:
        raise NotImplementedError

    def _on_lease(self, sample: zenoh.Sample) -> None:
        raise NotImplementedError

    def _on_snapshot(self, query: zenoh.Query) -> Message:
        raise NotImplementedError

    def _on_edit(self, query: zenoh.Query) -> Message:
        raise NotImplementedError

    def _on_map(self, query: zenoh.Query) -> Message:
        raise NotImplementedError
