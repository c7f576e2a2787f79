"""How urgent each kind of message is on the wire: Zenoh's priority and congestion control.

Zenoh's default for a put is priority DATA and congestion control DROP: when
a link's queue is full the message is dropped. A context, a viewer and a
recorder all subscribe to their world's frames and samples, so on a busy
machine the router's queue to them fills with frames and a put at the same
priority is lost with them: a student's print that never reached the page was
seen so (tests/integration/test_qos.py makes it happen). Each priority has its
own queue on a link, and higher ones are sent first; so what people read and
what stops robots travel above the frames, and wait for room rather than
vanish (they are a few a second at most, so the wait is short).

Frames, samples and wheel commands keep the default or their own DROP on
purpose: a stale one is worth nothing once the next exists.
"""

from __future__ import annotations

from typing import Any

import zenoh

# Chat lines, controller output, request statuses and queue events, private mail and
# kick notices, grading's changes and scores, leases, revocations, audit lines: a
# person reads each one, or a run or a security check waits on it.
WORDS: dict[str, Any] = {
    "priority": zenoh.Priority.DATA_HIGH,
    "congestion_control": zenoh.CongestionControl.BLOCK,
}

# An emergency stop engaged or released: before anything else on the link.
STOP: dict[str, Any] = {
    "priority": zenoh.Priority.REAL_TIME,
    "congestion_control": zenoh.CongestionControl.BLOCK,
    "express": True,
}
