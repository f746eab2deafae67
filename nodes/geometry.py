"""Geometry helpers for missions: points along a line (scan checkpoints)."""

from __future__ import annotations

from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import FLOAT, VEC3, input_port, output_port
from bt_engine.registry import register


@register
class LinePoint(SyncActionNode):
    """Write the point at ``fraction`` (0..1) of the way from ``start`` to ``end``.

    Used to split a scan line into segments so the drone passes checkpoints::

        LinePoint start={scan_start} end={scan_end} fraction=0.333 point={checkpoint_1}
    """

    bt_id = "LinePoint"
    category = "geometry"
    ports = (
        input_port("start", VEC3, description="first end of the line, x;y;z in m"),
        input_port("end", VEC3, description="other end of the line, x;y;z in m"),
        input_port("fraction", FLOAT, 0.5, "0 = start, 1 = end"),
        output_port("point", VEC3, "the point, x;y;z in m"),
    )

    def tick_impl(self) -> NodeStatus:
        a, b, f = self.get_input("start"), self.get_input("end"), self.get_input("fraction")
        self.set_output("point", tuple(a[i] + f * (b[i] - a[i]) for i in range(3)))
        return SUCCESS
