"""Run the CRTP emulator alone: ``python -m drivers.sim.crtp_emulator --port 19850``.

cfclient or any cflib script can then connect to ``udp://127.0.0.1:19850`` (a cflib scan of
127.0.0.1 finds it too: ports 19850-19859). Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import sys
import time

from drivers.sim.sitl import LOOPBACK, SitlSession


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    ap = argparse.ArgumentParser(prog="python -m drivers.sim.crtp_emulator", description=__doc__)
    ap.add_argument("--host", default=LOOPBACK, help="bind address (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=19850, help="UDP port (cflib scans 19850-19859)")
    ap.add_argument("--rig", default=None, help="rig file for the simulated drone (default sim)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stats-every", type=float, default=0.0, help="print counters every N s")
    args = ap.parse_args(argv)
    from drivers.rig import load_rig

    sitl = SitlSession(load_rig(args.rig).data, args.seed, host=args.host, port=args.port)
    sitl.start()
    print(f"CRTP emulator serving {sitl.uri} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(args.stats_every or 3600)
            if args.stats_every:
                print(sitl.truth(), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        sitl.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
