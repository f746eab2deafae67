"""What the safety supervisor knows and may do: faults, actions, policies and their settings.

Pure data and geometry: no Vehicle, no clock. :class:`SafetyConfig` is built from a rig's
``safety:`` section (whose schema is generated from this module's declarations).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.settings import Field, from_settings, schema_of, setting

#: Every fault the supervisor knows, most severe first, with a one-line description.
FAULTS: dict[str, str] = {
    "crash": "crash detected (or the motors stopped without being asked)",
    "battery_critical": "battery below the critical voltage",
    "link_lost": "no telemetry from the drone",
    "geofence": "outside the geofence",
    "mocap_lost": "motion capture stale or dropped",
    "battery_low": "battery below the low voltage",
    "camera_stalled": "camera stopped delivering frames",
    "operator_interrupt": "operator interrupt (SIGINT/SIGTERM)",
    "leaf_exception": "an exception inside a leaf",
}

#: What a policy may do when it takes over.
ACTIONS: dict[str, str] = {
    "report": "report only (the mission decides)",
    "land": "land where it is",
    "hold_then_land": "hold position for hold_s (or until the fault clears), then land",
    "return_and_land": "fly back above the take-off point, then land",
    "return_inside_and_land": "stop, hold for hold_s, fly back inside the geofence, then land",
    "motors_off": "cut the motors and disarm",
}

#: Faults detected by observation every tick (the other two come from how the run ended).
OBSERVED = (
    "crash",
    "battery_critical",
    "link_lost",
    "geofence",
    "mocap_lost",
    "battery_low",
    "camera_stalled",
)
#: Faults that stay active once seen (a sagging battery recovers when the load drops).
LATCHED = ("crash", "battery_critical", "battery_low")


@dataclass(frozen=True)
class Policy:
    """What to do about one fault: ``action`` (see :data:`ACTIONS`) after ``grace_s``.

    ``grace_s`` is how long the mission tree keeps control after the fault is detected (it may
    react with ``FaultActive``/``IsSafe``, and a transient fault may clear). ``hold_s`` is the
    hold time of ``hold_then_land`` / ``return_inside_and_land``.
    """

    action: str = "land"
    grace_s: float = 0.0
    hold_s: float = 0.0


DEFAULT_POLICIES: dict[str, Policy] = {
    "crash": Policy("motors_off"),
    "battery_critical": Policy("land"),
    "link_lost": Policy("hold_then_land", 0.0, 1.0),
    "geofence": Policy("return_inside_and_land", 0.0, 0.5),
    "mocap_lost": Policy("hold_then_land", 1.0, 0.5),
    "battery_low": Policy("return_and_land", 2.0),
    "camera_stalled": Policy("report"),
    "operator_interrupt": Policy("land"),
    "leaf_exception": Policy("land"),
}


#: The rig's one-line description of each policy entry.
POLICY_DOCS: dict[str, str] = {
    "crash": "crash or motors stopped",
    "battery_critical": "battery critical",
    "link_lost": "no telemetry",
    "geofence": "geofence breach",
    "mocap_lost": "mocap stale or dropped",
    "battery_low": "battery low",
    "camera_stalled": "camera stalled",
    "operator_interrupt": "SIGINT / SIGTERM",
    "leaf_exception": "exception in a leaf",
}


@dataclass
class SafetyConfig:
    """The rig's ``safety:`` section; each setting is declared once, here (the rig schema
    is generated from these fields, :func:`safety_schema`)."""

    enabled: bool = setting(True, "check faults every tick (off: only land at the end)")
    land_speed_mps: float = setting(0.3, "descent speed of a supervisor landing", min=0.05)
    return_speed_mps: float = setting(0.5, "speed of return flights", min=0.05)
    max_recovery_s: float = setting(30.0, "recovery flight limit; then the motors are cut", min=1.0)
    battery_low_v: float = setting(3.3, "battery_low below this filtered voltage", min=0.0)
    battery_critical_v: float = setting(
        3.1, "battery_critical below this filtered voltage", min=0.0
    )
    geofence_enabled: bool = setting(True, "check the geofence box", key="geofence.enabled")
    geofence_min_m: tuple[float, float, float] = setting(
        (-1.5, -3.0, -0.5), "box corner x;y;z min (m)", key="geofence.min_m"
    )
    geofence_max_m: tuple[float, float, float] = setting(
        (9.2, 3.0, 2.5), "box corner x;y;z max (m)", key="geofence.max_m"
    )
    geofence_margin_m: float = setting(
        0.3, "return this far inside the box", min=0.0, key="geofence.margin_m"
    )
    policies: dict[str, Policy] = field(default_factory=lambda: dict(DEFAULT_POLICIES))

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SafetyConfig:
        """Build from validated rig data (``rig.data["safety"]``); missing keys keep defaults."""
        pol = dict(DEFAULT_POLICIES)
        for name, p in ((data or {}).get("policies") or {}).items():
            base = pol.get(name, Policy())
            pol[name] = Policy(
                p.get("action", base.action),
                float(p.get("grace_s", base.grace_s)),
                float(p.get("hold_s", base.hold_s)),
            )
        return from_settings(cls, data, policies=pol)

    def box_words(self) -> str:
        """The geofence box in words: ``x -1.5 to 9.2, y -3 to 3, z -0.5 to 2.5 m`` (what a
        geofence message says)."""
        lo, hi = self.geofence_min_m, self.geofence_max_m
        return ", ".join(f"{a} {lo[i]:g} to {hi[i]:g}" for i, a in enumerate("xyz")) + " m"

    def inside(self, p: tuple[float, float, float], margin_m: float = 0.0) -> bool:
        """True if ``p`` is inside the geofence box shrunk by ``margin_m``."""
        lo, hi = self.geofence_min_m, self.geofence_max_m
        return all(lo[i] + margin_m <= p[i] <= hi[i] - margin_m for i in range(3))

    def nearest_inside(self, p: tuple[float, float, float]) -> tuple[float, float, float]:
        """The point of the box shrunk by ``geofence_margin_m`` nearest to ``p``."""
        lo, hi, m = self.geofence_min_m, self.geofence_max_m, self.geofence_margin_m
        out = []
        for i in range(3):
            a, b = lo[i] + m, hi[i] - m
            if a > b:  # box thinner than twice the margin: its middle
                a = b = 0.5 * (lo[i] + hi[i])
            out.append(min(max(p[i], a), b))
        return (out[0], out[1], out[2])


def fmt_number(v: float) -> str:
    return f"{v:g}"


def describe_action(policy: Policy) -> str:
    """A short human description of what ``policy`` does."""
    a = policy.action
    if a == "hold_then_land":
        return f"hold up to {fmt_number(policy.hold_s)} s, then land"
    if a == "return_inside_and_land":
        return f"stop, hold {fmt_number(policy.hold_s)} s, fly back inside the geofence, land"
    return ACTIONS.get(a, a)


def safety_schema() -> Field:
    """The rig's ``safety:`` schema, generated from :class:`SafetyConfig` and
    :data:`DEFAULT_POLICIES` (so defaults are written once)."""
    spec = schema_of(SafetyConfig, "the safety supervisor (docs/safety.md)")
    spec.children["policies"] = Field(
        "map",
        children={
            name: Field(
                "map",
                doc=POLICY_DOCS[name],
                children={
                    "action": Field(
                        "choice", pol.action, "what the supervisor does", choices=tuple(ACTIONS)
                    ),
                    "grace_s": Field(
                        "float", pol.grace_s, "the tree keeps control this long first", min=0.0
                    ),
                    "hold_s": Field(
                        "float", pol.hold_s, "hold time before landing (hold actions)", min=0.0
                    ),
                },
            )
            for name, pol in DEFAULT_POLICIES.items()
        },
    )
    return spec
