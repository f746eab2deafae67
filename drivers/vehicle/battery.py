"""Single-cell LiPo figures shared by the real and the simulated links."""

from __future__ import annotations

import bisect

FULL_V = 4.2
LAND_BELOW_V = 3.2  # [cflib] (docs/references.md): land below about 3.2 V

# Open-circuit voltage against state of charge (approx., typical 1S LiPo), ascending.
OCV_CURVE: tuple[tuple[float, float], ...] = (
    (0.00, 3.00),
    (0.05, 3.45),
    (0.10, 3.60),
    (0.20, 3.70),
    (0.50, 3.80),
    (0.80, 3.95),
    (0.90, 4.05),
    (1.00, 4.20),
)


def ocv_from_soc(soc: float) -> float:
    """Open-circuit voltage (V) at state of charge ``soc`` (0..1), linear interpolation."""
    soc = min(1.0, max(0.0, soc))
    socs = [p[0] for p in OCV_CURVE]
    i = max(1, bisect.bisect_left(socs, soc))
    (s0, v0), (s1, v1) = OCV_CURVE[i - 1], OCV_CURVE[i]
    return v0 + (v1 - v0) * (soc - s0) / (s1 - s0)


def percent_from_voltage(voltage_v: float) -> float:
    """Charge estimate (0..100 %) from a measured cell voltage, by inverting the OCV curve.

    Under load the measured voltage sags, so the estimate reads low in flight (as on the
    real Crazyflie, which only reports ``pm.vbat``).
    """
    if voltage_v <= OCV_CURVE[0][1]:
        return 0.0
    if voltage_v >= OCV_CURVE[-1][1]:
        return 100.0
    for (s0, v0), (s1, v1) in zip(OCV_CURVE, OCV_CURVE[1:], strict=False):
        if v0 <= voltage_v <= v1:
            return 100.0 * (s0 + (s1 - s0) * (voltage_v - v0) / (v1 - v0))
    return 0.0
