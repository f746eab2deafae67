"""Simulated 1S LiPo: charge drawn by the motors, voltage sag under load, injected sag,
swapped for a fresh one or charged on a pad (inventory missions)."""

from __future__ import annotations

from drivers.vehicle.battery import ocv_from_soc, percent_from_voltage


class SimBattery:
    """State of charge integrates the current; voltage = OCV(soc) - I*R - injected sag."""

    def __init__(self, params: dict) -> None:
        self.capacity_c = params["battery_capacity_mah"] * 3.6
        self.r_ohm = params["battery_internal_resistance_ohm"]
        self.idle_a = params["battery_idle_current_a"]
        self.coeff = params["battery_current_coeff"]
        self.soc = params["battery_initial_soc"]
        self.current_a = self.idle_a
        self.sag_v = 0.0  # injected extra drop (fault "battery_sag")
        self.charge_a = float(params.get("battery_charge_current_a", 0.5))
        self.charging = False
        self.swaps = 0
        self.voltage_v = ocv_from_soc(self.soc) - self.current_a * self.r_ohm

    def update(self, dt_s: float, thrust_n: float) -> None:
        """Draw current for ``dt_s`` at total motor thrust ``thrust_n`` (charging instead,
        while on a charging pad with the motors off)."""
        i = self.idle_a + self.coeff * max(thrust_n, 0.0) ** 1.5
        if self.charging and thrust_n <= 1e-6:
            i = self.idle_a - self.charge_a  # negative: charge flows in
        self.current_a = i
        self.soc = min(1.0, max(0.0, self.soc - i * dt_s / self.capacity_c))
        self.voltage_v = max(0.0, ocv_from_soc(self.soc) - i * self.r_ohm - self.sag_v)

    def swap(self, soc: float) -> None:
        """A fresh battery at state of charge ``soc`` (the injected sag goes with the old)."""
        self.soc = soc
        self.sag_v = 0.0
        self.swaps += 1
        self.voltage_v = ocv_from_soc(self.soc) - self.current_a * self.r_ohm

    @property
    def resting_voltage_v(self) -> float:
        """The open-circuit voltage at the present state of charge: what the cell would read
        with no current flowing."""
        return ocv_from_soc(self.soc)

    def report(self) -> dict[str, float | int]:
        """The ``battery`` section of ``summary.json`` (``sim``), at the end of the run.

        ``soc`` is the truth (0..1); ``voltage_v`` the terminal voltage then, low by
        ``current_a`` times the internal resistance while the motors draw current (just
        after a landing too); ``resting_voltage_v`` what it reads at rest; and
        ``percent_from_voltage`` is ``voltage_v`` read on the LiPo curve, as a voltage-based
        gauge shows it (the Crazyflie's own percentage is one): it reads far below ``soc``
        under load. docs/vehicle.md, "The battery in summary.json".
        """
        voltage_v = round(self.voltage_v, 3)  # the gauge reads the voltage shown beside it
        return {
            "soc": round(self.soc, 4),
            "voltage_v": voltage_v,
            "current_a": round(self.current_a, 3),
            "resting_voltage_v": round(self.resting_voltage_v, 3),
            "percent_from_voltage": round(percent_from_voltage(voltage_v), 1),
            "swaps": self.swaps,
        }
