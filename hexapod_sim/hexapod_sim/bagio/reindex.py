"""Rebuild bags a recording left unfinished (``rosbag2 reindex`` in ROS 2 terms).

    ./hexapod reindex BAG [BAG ...] [--force]

A recording cut off without closing its bag (power cut, the whole machine killed, a copy taken
while it was being written) leaves an MCAP file without its summary and footer: this project's
tools read it with one warning, other readers (``rosbags``, ``ros2 bag``) refuse it. ``reindex``
copies every readable message into one new, closed MCAP file and writes ``metadata.yaml`` from
what it holds (:func:`hexapod_sim.bagio.repair.reindex_bag`); a complete bag is left as it is
unless ``--force``. One line per bag; exit code 2 if a bag has nothing readable.
"""
from __future__ import annotations

import argparse
import sys

from hexapod_sim.bagio import BagError
from hexapod_sim.bagio.repair import reindex_bag


def main(args=None) -> int:
    ap = argparse.ArgumentParser(prog='reindex', description=__doc__.split('\n\n')[0])
    ap.add_argument('bags', nargs='+', metavar='BAG', help='rosbag2 directory to rebuild')
    ap.add_argument('--force', action='store_true', help='rebuild a bag even if it is complete')
    opts = ap.parse_args(sys.argv[1:] if args is None else args)
    rc = 0
    for bag in opts.bags:
        try:
            print(reindex_bag(bag, force=opts.force).line(), flush=True)
        except BagError as exc:
            print(f'reindex: error: {exc}', file=sys.stderr)
            rc = 2
        except OSError as exc:
            print(f'reindex: error: {bag}: {exc.strerror or exc}', file=sys.stderr)
            rc = 2
    return rc


if __name__ == '__main__':
    sys.exit(main())
