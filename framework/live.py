"""Live feeds: what a running stage is doing, published for ``surgiplan view --live``.

A stage that runs for a while with something to watch (an ``execute`` stage
moving a device, a ``guide`` stage following a trainee) publishes samples on
its :attr:`StageContext.live <surgiplan.results.StageContext.live>` feed::

    context.live.publish("tip", {"t": 1.25, "tip": [x, y, z], "clearance": 0.004})
    context.live.publish("event", {"t": 1.3, "kind": "below_threshold", "message": "..."})

The default feed (:class:`LiveFeed`) drops everything, so publishing costs
nothing when nobody watches; ``surgiplan run --live`` (see
:mod:`surgiplan.outputs.report`) connects a feed that forwards to a viewer on
127.0.0.1. Publishing never blocks the stage: a feed that cannot keep up
drops samples, never delays the control loop.

Channels and payloads (JSON values, SI units):

* ``stage``: ``{"name", "kind", "plugin", "path_from"?, "recommended"?: [[x, y, z], ...]}`` when a stage starts;
* ``tip``: ``{"t", "tip": [x, y, z], "commanded"?: [x, y, z], "clearance"?, "deviation"?}``;
* ``event``: ``{"t", "kind", "message"}``;
* ``status``: ``{"status", "message"?}`` when the stage ends.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class LiveFeed:
    """A feed nobody watches: every publication is dropped."""

    #: whether anyone is watching (a stage may skip preparing payloads when not)
    active: bool = False

    def publish(self, channel: str, payload: Mapping[str, Any]) -> None:
        """Send ``payload`` on ``channel``; never blocks, never raises."""

    def close(self) -> None:
        pass
