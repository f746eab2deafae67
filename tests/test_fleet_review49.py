"""Review 49 of the fleet file's checks: one Crazyflie under two spellings of its URI (the
fleet's check and the link lock), pads resolved in the world that is flown (``--set
world.path=``, the fleet file's ``set:``), a drone with both a pad and a start, an empty
fleet file, a drone setting what the drones share."""

from __future__ import annotations

import os

import pytest
from helpers import REPO

from bt_engine.cli import main
from drivers.crazyflie.link_lock import LinkInUse, LinkLock, link_identity, lock_path

MISSION = os.path.join(REPO, "missions", "inventory.xml")
AISLE_RIG = os.path.join(REPO, "rigs", "aisle.yaml")
CF_RIG = os.path.join(REPO, "rigs", "crazyflie-vicon.yaml")
AISLE_FLEET = os.path.join(REPO, "fleets", "aisle_2.yaml")


def _fleet(tmp_path, drones: str, rig: str = AISLE_RIG, extra: str = "") -> str:
    path = tmp_path / "fleet.yaml"
    path.write_text(f"name: t\nmission: {MISSION}\nrig: {rig}\n{extra}drones:\n{drones}")
    return str(path)


def _world(tmp_path, old: str, new: str) -> str:
    """worlds/aisle.yaml with ``old`` replaced by ``new`` (its pads moved or renamed)."""
    with open(os.path.join(REPO, "worlds", "aisle.yaml"), encoding="utf-8") as f:
        text = f.read()
    assert old in text
    path = tmp_path / "world.yaml"
    path.write_text(text.replace(old, new))
    return str(path)


# -- 1. one Crazyflie, two spellings of its URI --------------------------------------------


@pytest.mark.parametrize(
    "first, second",
    [
        ("radio://0/80/2M/E7E7E7E701", "radio://0/80/2M/e7e7e7e701"),  # the address's case
        ("radio://0/80/2M/E7E7E7E7E7", "radio://0/80/2M"),  # cflib's default address
        ("radio://0/80/2M/E7E7E7E701", "radio://1/80/2M/E7E7E7E701"),  # another dongle
        ("radio://0/80/2M/E7E7E7E701", "radio://0/80/1M/e7e7e7e701"),  # another data rate
        ("radio://0/80/2M/E7E701", "radio://0/80/2M/0000E7E701"),  # cflib pads with zeros
    ],
)
def test_two_spellings_of_one_crazyflie_are_refused_where_the_second_is(
    tmp_path, capsys, first, second
):
    drones = (
        f"  - {{name: a, start_m: [0, 0, 0], uri: {first}}}\n"
        f"  - {{name: b, start_m: [0, 2, 0], uri: {second}}}\n"
    )
    path = _fleet(tmp_path, drones, rig=CF_RIG)
    assert main(["fleet", path, "--check"]) == 2
    err = capsys.readouterr().err
    assert f"{path}:6:40: b and a both use the Crazyflie on radio channel 80, address " in err
    assert f"({second} and {first}; " in err, err
    assert "Traceback" not in err


def test_a_drone_on_the_rigs_default_uri_and_one_spelling_it_otherwise_are_refused(
    tmp_path, capsys
):
    drones = (
        "  - {name: a, start_m: [0, 0, 0], uri: radio://0/80/2M/e7e7e7e7e7}\n"
        "  - {name: b, start_m: [0, 2, 0]}\n"  # the rig's radio://0/80/2M/E7E7E7E7E7
    )
    path = _fleet(tmp_path, drones, rig=CF_RIG)
    assert main(["fleet", path, "--check"]) == 2
    err = capsys.readouterr().err
    assert (
        f"{path}:6:5: b and a both use the Crazyflie on radio channel 80, address E7E7E7E7E7" in err
    )
    assert "(radio://0/80/2M/E7E7E7E7E7 and radio://0/80/2M/e7e7e7e7e7; " in err, err


def test_the_same_address_on_another_channel_is_another_drone(tmp_path, capsys):
    drones = (
        "  - {name: a, start_m: [0, 0, 0], uri: radio://0/80/2M/E7E7E7E701}\n"
        "  - {name: b, start_m: [0, 2, 0], uri: radio://0/90/2M/e7e7e7e701}\n"
    )
    path = tmp_path / "fleet.yaml"  # a mission without places: no gallery to build
    square = os.path.join(REPO, "missions", "square.xml")
    path.write_text(f"name: t\nmission: {square}\nrig: {CF_RIG}\ndrones:\n{drones}")
    assert main(["fleet", str(path), "--check"]) == 0, capsys.readouterr().err


def test_the_link_identity_reads_radio_uris_as_cflib_does():
    one = "radio channel 80, address E7E7E7E701"
    for uri in (
        "radio://0/80/2M/E7E7E7E701",
        " radio://0/80/2M/e7e7e7e701 ",
        "radio://1/80/250K/E7E7E7E701?rate_limit=100",
        "radio://0/080/2M/E7E7E7E701/",  # channel 080
    ):
        assert link_identity(uri) == one, uri
    assert link_identity("radio://0/80") == "radio channel 80, address E7E7E7E7E7"
    assert link_identity("radio://0/80/2M/e701") == "radio channel 80, address 000000E701"
    assert link_identity("radio://0/80/2M/E7E7E7E702") != one
    assert link_identity("radio://0/81/2M/E7E7E7E701") != one
    assert link_identity("UDP://LocalHost:19850/X") == "udp://localhost:19850/X"
    assert link_identity("radio://0/80/2M/notahex") == "radio://0/80/2M/notahex"


def test_the_link_lock_is_one_per_crazyflie_however_its_uri_is_spelled():
    uri = "radio://0/79/2M/E7E7E7E7B9"  # a channel and address no test flies
    same = (
        "radio://0/79/2M/e7e7e7e7b9",
        "radio://1/79/1M/E7E7E7E7B9",
        " radio://0/79/2M/e7e7e7e7B9",
    )
    assert {lock_path(u) for u in same} == {lock_path(uri)}
    assert lock_path("radio://0/78/2M/E7E7E7E7B9") != lock_path(uri)  # another channel
    assert lock_path("radio://0/79/2M/E7E7E7E7BA") != lock_path(uri)  # another address
    assert lock_path("radio://0/80/2M") == lock_path("radio://0/80/2M/E7E7E7E7E7")
    held = LinkLock(uri).acquire()
    try:
        for other in same:
            with pytest.raises(LinkInUse) as info:
                LinkLock(other).acquire()
            msg = str(info.value)
            assert msg.startswith(f"{other}: in use by another btrun (pid {os.getpid()}, since ")
            assert f", on {uri})" in msg  # the holder's own spelling
        LinkLock("radio://0/78/2M/E7E7E7E7B9").acquire().release()  # another drone: free
    finally:
        held.release()
    LinkLock(same[0]).acquire().release()  # released: free again, under any spelling


# -- 2. the pads of the world that is flown ------------------------------------------------


def test_a_pad_missing_from_the_set_world_is_refused_at_the_fleet_files_line(tmp_path, capsys):
    world = _world(tmp_path, "name: pad-2,", "name: pad-9,")
    out = tmp_path / "run"
    for extra in (["--check"], ["--out", str(out), "-q"]):  # the check, and before a flight
        assert main(["fleet", AISLE_FLEET, "--set", f"world.path={world}", *extra]) == 2
        err = capsys.readouterr().err
        assert f"{AISLE_FLEET}:22:22: pad 'pad-2' is not a pad of the world (pad-1, pad-9)" in err
        assert not out.exists()


def test_the_fleet_files_own_world_setting_gives_the_pads(tmp_path, capsys):
    world = _world(tmp_path, "name: pad-2,", "name: pad-9,")
    drones = "  - {name: a, pad: pad-1}\n  - {name: b, pad: pad-2}\n"
    path = _fleet(tmp_path, drones, extra=f"set: {{world.path: {world}}}\n")
    assert main(["fleet", path, "--check"]) == 2
    assert f"{path}:7:20: pad 'pad-2' is not a pad of the world (pad-1, pad-9)" in (
        capsys.readouterr().err
    )


def test_the_drones_start_on_the_pads_of_the_set_world(tmp_path, capsys):
    # pad-2 moved next to pad-1 in the world flown: the starts are its, so they are too close
    world = _world(tmp_path, "position_m: [1.0, -2.8]", "position_m: [1.0, 2.6]")
    assert main(["fleet", AISLE_FLEET, "--check", "--set", f"world.path={world}"]) == 2
    err = capsys.readouterr().err
    assert f"{AISLE_FLEET}:22:22: cf2 starts 0.20 m from cf1" in err, err


# -- 3. a pad and a start ------------------------------------------------------------------


def test_a_drone_with_both_a_pad_and_a_start_is_refused(tmp_path, capsys):
    drones = "  - {name: a, pad: pad-1, start_m: [1.0, 0.0, 0.0]}\n  - {name: b, pad: pad-2}\n"
    path = _fleet(tmp_path, drones)
    assert main(["fleet", path, "--check"]) == 2
    err = capsys.readouterr().err
    assert (
        f"{path}:5:36: drone 'a' has both a pad ('pad-1') and start_m (1, 0, 0): expected one"
        in err
    ), err


# -- 4. an empty fleet file ----------------------------------------------------------------


@pytest.mark.parametrize("text", ["", "# just a comment\n"])
def test_an_empty_fleet_file_says_so(tmp_path, capsys, text):
    path = tmp_path / "fleet.yaml"
    path.write_text(text)
    assert main(["fleet", str(path), "--check"]) == 2
    err = capsys.readouterr().err
    assert f"{path}:1:1: the fleet file is empty: expected at least mission:" in err, err
    assert "None" not in err and "1 problem found" in err


def test_pads_only_the_set_world_has_are_flown_as_they_are_checked(tmp_path, capsys):
    """The flight read the fleet file without the command's --set: pads that only the
    --set world has passed --check, then were refused when flown."""
    world = _world(tmp_path, "name: pad-2,", "name: pad-9,")
    drones = "  - {name: a, pad: pad-1}\n  - {name: b, pad: pad-9}\n"
    path = _fleet(tmp_path, drones)
    assert main(["fleet", path, "--check", "--set", f"world.path={world}"]) == 0
    capsys.readouterr()
    taken = tmp_path / "taken"
    taken.write_text("a file where the run folder would go")
    # the flight reads the fleet as the check did: it gets as far as the run folder
    assert main(["fleet", path, "--set", f"world.path={world}", "--out", str(taken)]) == 2
    err = capsys.readouterr().err
    assert "pad-9" not in err and str(taken) in err, err


# -- 5. what the drones share, set for one drone ---------------------------------------------


def test_a_drones_own_world_clock_or_link_setting_is_refused_at_its_line(tmp_path, capsys):
    """A drone's own ``set: {world.path: ...}`` had been flown: its check took the fleet's
    world's pads, its flight another world."""
    site = os.path.join(REPO, "worlds", "site.yaml")
    drones = (
        f"  - {{name: a, pad: pad-1, set: {{world.path: {site}}}}}\n"
        "  - name: b\n    pad: pad-2\n    set:\n"
        "      rig.clock.mode: realtime\n      rig.link: crazyflie\n      bb.note: fine\n"
    )
    path = _fleet(tmp_path, drones)
    assert main(["fleet", path, "--check"]) == 2
    err = capsys.readouterr().err
    shared = "the drones of a fleet share one world, clock and link kind"
    assert f"{path}:5:" in err and f"world.path cannot be set for one drone ('a'): {shared}" in err
    assert f"{path}:9:23: rig.clock.mode cannot be set for one drone ('b')" in err, err
    assert f"{path}:10:17: rig.link cannot be set for one drone ('b')" in err, err
    assert "bb.note" not in err and "3 problems found" in err, err
