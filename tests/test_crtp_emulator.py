"""The CRTP emulator answers the REAL cflib client over UDP on 127.0.0.1."""

from __future__ import annotations

import math
import random
import socket
import struct
import time

import pytest
from crtp_helpers import sitl_session, sync_cf
from helpers import wait_until

from drivers.sim.emulators.crtp.crtp import Packet, decode

pytestmark = pytest.mark.sitl  # every test runs the emulator on 127.0.0.1

LOG_NEEDED = [
    f"stateEstimate.{a}" for a in ("x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw")
]
LOG_NEEDED += ["stabilizer.roll", "stabilizer.pitch", "stabilizer.yaw", "pm.vbat"]
LOG_NEEDED += [f"{g}.{a}" for g in ("gyro", "acc") for a in "xyz"] + ["supervisor.info"]
PARAM_NEEDED = [
    "stabilizer.estimator",
    "stabilizer.controller",
    "locSrv.extPosStdDev",
    "locSrv.extQuatStdDev",
    "commander.enHighLevel",
]


def test_sync_crazyflie_connects_and_reads_tocs() -> None:
    with sitl_session() as s, sync_cf(s.uri) as scf:
        cf = scf.cf
        assert cf.platform.get_protocol_version() == 12
        for name in LOG_NEEDED:
            assert cf.log.toc.get_element_by_complete_name(name) is not None, name
        for name in PARAM_NEEDED:
            assert cf.param.toc.get_element_by_complete_name(name) is not None, name
        assert float(cf.param.get_value("locSrv.extPosStdDev")) == pytest_approx(0.01)
        assert s.emulator.stats.errors == 0


def pytest_approx(v: float):  # small local helper keeps the imports minimal
    import pytest

    return pytest.approx(v, rel=1e-5)


def test_log_blocks_follow_the_simulated_pose() -> None:
    from cflib.crazyflie.log import LogConfig

    with sitl_session() as s, sync_cf(s.uri) as scf:
        with s.emulator.lock:
            s.cf.drone.body.x, s.cf.drone.body.y = 0.7, -0.3
        conf = LogConfig("pose", period_in_ms=10)
        for v in ("x", "y", "z"):
            conf.add_variable(f"stateEstimate.{v}")
        conf.add_variable("supervisor.info")
        got: list[tuple[int, dict]] = []
        conf.data_received_cb.add_callback(lambda ts, d, _c: got.append((ts, d)))
        scf.cf.log.add_config(conf)
        conf.start()
        wait_until(lambda: len(got) >= 30, 5.0, "30 log blocks")
        conf.stop()
        ts, d = got[-1]
        assert abs(d["stateEstimate.x"] - 0.7) < 0.05 and abs(d["stateEstimate.y"] + 0.3) < 0.05
        assert d["supervisor.info"] & 1  # can be armed
        stamps = [t for t, _ in got]
        assert stamps == sorted(stamps)  # firmware ms, in the order the blocks were sent


def test_oversized_block_is_refused_with_e2big() -> None:
    with sitl_session() as s:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(1.0)
        try:
            sock.sendto(Packet(5, 1, bytes((5,))).encode(), ("127.0.0.1", s.emulator.port))
            assert decode(sock.recv(64)) == Packet(5, 1, bytes((5, 0, 0)))
            items = b"".join(bytes((7, i, 0)) for i in range(7))  # 7 floats = 28 bytes
            sock.sendto(
                Packet(5, 1, bytes((6, 1)) + items).encode(), ("127.0.0.1", s.emulator.port)
            )
            assert decode(sock.recv(64)) == Packet(5, 1, bytes((6, 1, 7)))
        finally:
            sock.close()


def test_parameter_writes_change_the_simulated_drone() -> None:
    with sitl_session() as s, sync_cf(s.uri) as scf:
        with s.emulator.lock:
            s.cf.drone.estimator.ex = 0.4
        scf.cf.param.set_value("posCtlPid.zKp", 3.25)
        scf.cf.param.set_value("kalman.resetEstimation", 1)
        scf.cf.param.set_value("stabilizer.estimator", 2)
        wait_until(lambda: s.cf.drone.params["pos_z_kp"] == 3.25, 5.0, "posCtlPid.zKp = 3.25")
        wait_until(lambda: s.cf.drone.estimator.ex == 0.0, 5.0, "the estimator reset")
        wait_until(
            lambda: s.emulator.param.values["stabilizer.estimator"] == 2,
            5.0,
            "stabilizer.estimator = 2",
        )


@pytest.mark.slow
def test_supervisor_arming_and_watchdog_stops_motors_after_2_s() -> None:
    with sitl_session() as s, sync_cf(s.uri) as scf:
        cf, fw = scf.cf, s.cf.drone.firmware
        cf.supervisor.send_arming_request(True)
        wait_until(lambda: fw.armed, 5.0, "the drone armed")
        assert cf.supervisor.read_bitfield() & 0b10  # is armed
        end = time.monotonic() + 0.6
        while time.monotonic() < end:  # climb at 0.5 m/s
            cf.commander.send_velocity_world_setpoint(0.0, 0.0, 0.5, 0.0)
            time.sleep(0.01)
        assert fw.motors_running and s.cf.drone.body.z > 0.05
        wait_until(lambda: not fw.motors_running, 10.0, "the watchdog to stop the motors", 0.01)
        # stopped by the watchdog: levelled first (0.5 s of silence), off after 2 s of
        # silence, counted on the emulated firmware's own clock
        with s.emulator.lock:
            silent_s = s.cf.t_s - fw.last_setpoint_s
        assert fw.watchdog_level and silent_s > s.cf.drone.params["setpoint_shutdown_timeout_s"]
        assert s.cf.drone.params["setpoint_shutdown_timeout_s"] == 2.0
        cf.supervisor.send_arming_request(False)
        wait_until(lambda: not fw.armed, 5.0, "the drone disarmed")


@pytest.mark.slow
def test_position_setpoints_and_extpose_reach_the_firmware() -> None:
    with sitl_session() as s, sync_cf(s.uri) as scf:
        cf = scf.cf
        cf.supervisor.send_arming_request(True)
        wait_until(lambda: s.cf.drone.firmware.armed, 5.0, "the drone armed")
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            b = s.cf.drone.body
            cf.extpos.send_extpose(b.x, b.y, b.z, 0.0, 0.0, 0.0, 1.0)
            cf.commander.send_position_setpoint(0.0, 0.0, 0.4, 30.0)
            time.sleep(0.01)
        assert s.cf.last_setpoint is not None and s.cf.last_setpoint[0] == "position"
        assert s.cf.last_setpoint[1][3] == pytest_approx(math.radians(30.0))
        assert s.cf.drone.body.z > 0.25
        assert s.cf.extpose_count > 100 and s.cf.last_extpose[6] == 1.0
        cf.commander.send_stop_setpoint()
        wait_until(lambda: not s.cf.drone.firmware.motors_running, 5.0, "the motors stopped")


def test_garbage_datagrams_never_crash_the_emulator() -> None:
    rng = random.Random(7)
    with sitl_session() as s:
        addr = ("127.0.0.1", s.emulator.port)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            junk = [b"", b"\xff" * 200, bytes(range(32))]
            junk += [
                bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) for _ in range(3000)
            ]
            for port in range(16):  # every port, every channel, truncated payloads
                for ch in range(4):
                    for n in range(0, 31, 3):
                        junk.append(
                            Packet(port, ch, bytes(rng.randrange(256) for _ in range(n))).encode()
                        )
            junk.append(
                Packet(7, 0, bytes((8,)) + struct.pack("<ffff", math.nan, 0, 0, 0)).encode()
            )
            for j in junk:
                sock.sendto(j, addr)
            wait_until(lambda: s.emulator.stats.malformed >= 2, 10.0, "malformed packets counted")
            assert s.emulator.running
            with s.emulator.lock:
                assert all(math.isfinite(v) for v in (s.cf.drone.body.x, s.cf.drone.body.z))
            sock.settimeout(0.5)

            def ping_echoed() -> bool:
                # under load the junk may still fill the emulator's socket buffer and drop a
                # ping: resend until one is echoed (replies to the junk may be queued too)
                sock.sendto(Packet(15, 0, b"ping").encode(), addr)
                try:
                    while True:
                        if decode(sock.recv(64)) == Packet(15, 0, b"ping"):
                            return True
                except TimeoutError:
                    return False

            wait_until(ping_echoed, 15.0, "the emulator to echo a ping after the junk", 0.0)
        finally:
            sock.close()
        with sync_cf(s.uri) as scf:  # and a real client still connects
            assert scf.cf.platform.get_protocol_version() == 12


def test_scan_probe_is_answered() -> None:
    with sitl_session() as s:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(1.0)
        try:
            sock.sendto(b"\xff", ("127.0.0.1", s.emulator.port))
            assert sock.recv(64)
        finally:
            sock.close()


def _fly(scf, s, seconds: float, each=None) -> None:
    """Forward the true pose as extpose at 100 Hz for ``seconds`` (calls ``each()`` too)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        b = s.cf.drone.body
        scf.cf.extpos.send_extpose(b.x, b.y, b.z, 0.0, 0.0, 0.0, 1.0)
        if each is not None:
            each()
        time.sleep(0.01)


@pytest.mark.slow
def test_high_level_commander_takes_off_goes_to_and_lands() -> None:
    from drivers.sim.emulators.crtp import high_level as hl

    with sitl_session() as s, sync_cf(s.uri) as scf:
        cf, fw, port = scf.cf, s.cf.drone.firmware, s.emulator.high_level
        cf.supervisor.send_arming_request(True)
        wait_until(lambda: fw.armed, 5.0, "the drone armed")
        hlc = cf.high_level_commander
        hlc.takeoff(0.5, 1.5)
        wait_until(lambda: port.state == hl.FLYING, 5.0, "the planner FLYING")
        _fly(scf, s, 2.0)
        b = s.cf.drone.body
        assert abs(b.z - 0.5) < 0.05 and fw.motors_running, b.z
        hlc.takeoff(1.0, 1.0)  # refused while flying (the planner is not idle)
        wait_until(lambda: port.refused == 1, 5.0, "the second take-off refused")
        hlc.go_to(0.4, -0.2, 0.6, math.radians(90.0), 2.0)  # cflib sends GO_TO_2
        _fly(scf, s, 3.0)
        assert port.commands.get(hl.CMD_GO_TO_2) == 1
        assert math.dist((b.x, b.y, b.z), (0.4, -0.2, 0.6)) < 0.06, (b.x, b.y, b.z)
        assert abs(math.degrees(math.remainder(b.yaw - math.radians(90.0), math.tau))) < 8.0
        hlc.land(0.0, 2.0)
        _fly(scf, s, 3.0)
        assert port.state == hl.IDLE and not fw.motors_running and b.on_ground
        assert not s.cf.drone.crashed
        # a low-level set-point pre-empts the planner; stop makes it idle again
        cf.commander.send_velocity_world_setpoint(0.0, 0.0, 0.0, 0.0)
        wait_until(lambda: port.state == hl.DISABLED, 5.0, "the planner DISABLED")
        hlc.stop()
        wait_until(lambda: port.state == hl.IDLE, 5.0, "the planner IDLE")


@pytest.mark.slow
def test_yaw_rate_sign_matches_the_firmware() -> None:
    """Velocity-world (type 8) yaw rate is counter-clockwise positive (firmware
    ``velocityDecoder``; cflib ``MotionCommander.start_turn_left`` sends +rate); the legacy
    type 1 is negated by the firmware (``legacyVelocityDecoder``)."""
    with sitl_session() as s, sync_cf(s.uri) as scf:
        cf, fw = scf.cf, s.cf.drone.firmware
        cf.supervisor.send_arming_request(True)
        wait_until(lambda: fw.armed, 5.0, "the drone armed")
        _fly(scf, s, 1.0, lambda: cf.commander.send_velocity_world_setpoint(0, 0, 0.4, 0))
        yaw0 = s.cf.drone.body.yaw
        _fly(scf, s, 1.0, lambda: cf.commander.send_velocity_world_setpoint(0, 0, 0, 45.0))
        turned = math.degrees(math.remainder(s.cf.drone.body.yaw - yaw0, math.tau))
        assert 25.0 < turned < 60.0, turned  # counter-clockwise, about 45 deg
        legacy = Packet(7, 0, bytes((1,)) + struct.pack("<ffff", 0, 0, 0, 45.0)).encode()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            yaw1 = s.cf.drone.body.yaw
            _fly(scf, s, 1.0, lambda: sock.sendto(legacy, ("127.0.0.1", s.emulator.port)))
        finally:
            sock.close()
        turned = math.degrees(math.remainder(s.cf.drone.body.yaw - yaw1, math.tau))
        assert -60.0 < turned < -25.0, turned  # clockwise
        cf.commander.send_stop_setpoint()
