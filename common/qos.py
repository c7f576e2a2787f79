"""How urgent each kind of message is on the wire: Zenoh's priority and congestion control.

Zenoh's default for a put is priority DATA and congestion control DROP: when
a link's queue is full the message is dropped. A viewer, and a context's
recorder while it records a slot, subscribe to their world's frames and samples,
so on a busy machine the router's queue to them fills with frames and a put at the same
priority is lost with them: a student's print that never reached the page was
seen so (tests/integration/test_qos.py makes it happen). Each priority has its
own queue on a link, and higher ones are sent first; so what people read and
what stops robots travel above the frames, and wait for room rather than
vanish (they are a few a second at most, so the wait is short).

Frames, samples and wheel commands keep the default or their own DROP on
purpose: a stale one is worth nothing once the next exists. Which key travels how
is the dataflow table's choice (common/dataflow.py, `Flow.urgency`).
"""

from __future__ import annotations

from functools import cache
from typing import Any

import zenoh

from common import dataflow
from common.dataflow import KeyBuilder, Urgency

_OPTIONS: dict[Urgency, dict[str, Any]] = {
    Urgency.FRAMES: {},
    # A person reads it, or a run or a security check waits on it.
    Urgency.WORDS: {
        "priority": zenoh.Priority.DATA_HIGH,
        "congestion_control": zenoh.CongestionControl.BLOCK,
    },
    # An emergency stop engaged or released: before anything else on the link.
    Urgency.STOP: {
        "priority": zenoh.Priority.REAL_TIME,
        "congestion_control": zenoh.CongestionControl.BLOCK,
        "express": True,
    },
}


@cache
def of(builder: KeyBuilder) -> dict[str, Any]:
    """The put (or publisher) options for keys built by ``builder``, from its flow's urgency.

    ``session.put(key, payload, **qos.of(keys.ctx_events))``: the choice lives in
    the dataflow table (common/dataflow.py), not at the call site.
    """
    return _OPTIONS[dataflow.urgency_of(builder)]
