"""btrun's drone leaves, registered with the engine when this package is imported.

This package is btrun's plug-in (entry point ``btrun.plugins``): importing it registers the
flight actions and vehicle conditions, and it gives the CLI the rig loader (simulator or
real drone), the safety supervisor and the flight report writer.
"""

from nodes import conditions, flight, geometry, perception, safety  # noqa: F401  (registration)


def load_rig(path, overrides=None):
    """Load and validate a rig file (see :func:`drivers.rig.load_rig`)."""
    from drivers.rig import load_rig as _load

    return _load(path, overrides)


def make_supervisor(rig, platform, mission):
    """The safety supervisor hook of a run (see :mod:`drivers.safety`), or None."""
    if getattr(platform, "vehicle", None) is None:
        return None
    from drivers.safety import SafetySupervisor

    return SafetySupervisor.from_rig(rig, platform, mission)


def write_report(run_dir, trace, summary, mission):
    """Write the flight report of a run; return its path (None if there is nothing to plot)."""
    try:
        from nodes.report import write_report as _write
    except ImportError:  # pragma: no cover - report module not installed
        return None
    return _write(run_dir, trace, summary, mission)


def add_commands():
    """Subcommands this plug-in adds to ``btrun``: ``btrun sim serve crazyflie|aideck ...`` and
    ``btrun gallery ...`` (:mod:`nodes.gallery_cli`)."""
    import argparse

    def setup(p: argparse.ArgumentParser) -> None:
        sub = p.add_subparsers(dest="sim_command", metavar="SUBCOMMAND", required=True)
        serve = sub.add_parser(
            "serve",
            help="run a software Crazyflie (CRTP over UDP) or AI-deck (CPX over TCP) on "
            "loopback, for cfclient or the AI-deck viewers",
        )
        serve.add_argument("device", choices=("crazyflie", "aideck"))
        serve.add_argument(
            "args", nargs=argparse.REMAINDER, help="options of the emulator (--help)"
        )

    def run(args) -> int:
        if args.device == "crazyflie":
            from drivers.sim.crtp_emulator.__main__ import main as serve
        else:
            from drivers.sim.aideck_emulator import main as serve
        return int(serve(list(args.args)) or 0)

    from nodes import gallery_cli

    return {
        "sim": ("simulator tools (btrun sim serve crazyflie|aideck)", setup, run),
        "gallery": (
            "enrolled pallets: btrun gallery list|enrol|remove|export|evaluate|demo",
            gallery_cli.setup,
            gallery_cli.run,
        ),
    }
