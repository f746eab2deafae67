"""NearestPad: where to land at the end of a mission, when a drone may land on more than one pad.

A site can have pads at both ends of its aisles. A sweep over a rack face with an odd number
of levels ends at the face's far end; flying the aisle's length back to the take-off pad
(about 20 s on the site) is then dead time, which a pad at that end saves. ``NearestPad``
picks, from the take-off point (``home``) and the world pads named in ``pads``, the one the
drone reaches by the shortest way around the racks (the way ``FlyRoute`` flies), at the
take-off point's height. With no ``pads`` it is ``home``. In a fleet, each drone's landing
pads are its own (``landing_pads`` in the fleet file, checked so that no two drones share a
pad); battery changes stay on the take-off pad.
"""

from __future__ import annotations

from typing import Any

from bt_engine.node import FAILURE, SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import STRING, VEC3, input_port, output_port
from bt_engine.registry import register
from drivers.settings import ConfigError
from nodes.common import geofence_config, outside_geofence, vehicle_of
from nodes.energy import travel_m
from nodes.inventory import CATEGORY_INVENTORY, world_of


def pad_names(text: Any) -> list[str]:
    """Pad names from ``pads`` (``pad-5;pad-6``, commas or a list), blanks dropped."""
    if isinstance(text, (list, tuple)):
        items = [str(v) for v in text]
    else:
        items = str(text or "").replace(",", ";").split(";")
    return [s.strip() for s in items if s.strip()]


@register
class NearestPad(SyncActionNode):
    """``point``: the nearest (by the way around the racks) of ``home`` and the world pads
    in ``pads``, at ``home``'s height: where the drone lands at the end. FAILURE for a pad
    the world does not have."""

    bt_id = "NearestPad"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("home", VEC3, description="the take-off point, x;y;z in m"),
        input_port(
            "pads",
            STRING,
            "",
            "other world pads the drone may land on, e.g. pad-5;pad-6 (empty: home only)",
        ),
        output_port("point", VEC3, "where to land: above the chosen pad, x;y;z in m"),
        output_port("pad", STRING, "the chosen pad's name (home: the take-off point)"),
    )

    def preflight(self) -> list[Any]:
        """A pad name the rig's world does not have (written in the mission, or a mission
        input such as ``--set landing_pads=...``), before anything flies."""
        try:
            text = self.get_input("pads")
        except Exception:  # noqa: BLE001 - written in flight: the tick checks it
            return []
        try:
            world = world_of(self.ctx)
        except ConfigError as exc:
            return [("pads", f"the rig's world cannot be loaded: {exc}")]
        unknown = self._unknown(world, text)
        if unknown or world is None:
            return [("pads", why) for why in unknown]
        return self._outside(world, text)

    def _outside(self, world: Any, text: Any) -> list[tuple[str, str]]:
        """A pad the drone would land on outside the rig's geofence (it would breach it on
        the way down), as ``(port, message)``."""
        config = geofence_config(self)
        if config is None:
            return []
        z = 0.5 * (config.geofence_min_m[2] + config.geofence_max_m[2])  # x and y decide
        out = []
        for name in pad_names(text):
            x, y = world.pads()[name]
            out += outside_geofence(self, "pads", [(x, y, z)], f"pad '{name}' at x {x:g}, y {y:g}")
        return out

    def _unknown(self, world: Any, text: Any) -> list[str]:
        names = pad_names(text)
        if not names or world is None:
            return []
        known = world.pads()
        listed = ", ".join(known) or "none: the world has no pads"
        return [f"unknown pad '{n}': expected one of the world's pads ({listed})" for n in names
                if n not in known]  # fmt: skip

    def tick_impl(self) -> NodeStatus:
        world = world_of(self.ctx)
        bad = self._unknown(world, self.get_input("pads"))
        if bad:
            self.failure_reason = bad[0]
            return FAILURE
        home = tuple(float(v) for v in self.get_input("home"))
        here = vehicle_of(self).position
        best, best_m = "home", travel_m(self.ctx, here, home)
        point = home
        pads = world.pads()
        for name in pad_names(self.get_input("pads")):
            x, y = pads[name]
            candidate = (x, y, home[2])
            d = travel_m(self.ctx, here, candidate)
            if d < best_m - 1e-6:
                best, best_m, point = name, d, candidate
        self.set_output("point", point)
        self.set_output("pad", best)
        if best != "home":
            self.ctx.log(f"{self.describe()}: landing on {best}, {best_m:.1f} m away")
        return SUCCESS
