"""Write (or --check) each node's parameter file <package>/config/<executable>.yaml from its schema
dataclasses, so the files list exactly the declared parameters at their defaults.

    ./hexapod shell python tools/params_files.py            # rewrite the files
    ./hexapod shell python tools/params_files.py --check    # exit 1 naming the stale ones
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def nodes():
    from hexapod_driver.config import NODE as DRIVER
    from hexapod_locomotion.nodes.params import NODE as LOCOMOTION
    from hexapod_locomotion.nodes.params import TERRAIN_NODE
    from hexapod_model.param_schema import MODEL_NODE, ROBOT_STATE_NODE
    from hexapod_sim.node.params import NODE as SIM
    return [DRIVER, SIM, MODEL_NODE, ROBOT_STATE_NODE, LOCOMOTION, TERRAIN_NODE]


def config_path(node) -> Path:
    return REPO / node.package / 'config' / f'{node.executable}.yaml'


def main(argv=None) -> int:
    from hexapod_model.param_schema import params_yaml
    ap = argparse.ArgumentParser(prog='params_files', description=__doc__.splitlines()[0])
    ap.add_argument('--check', action='store_true', help='do not write; exit 1 if a file differs')
    args = ap.parse_args(argv)
    stale = []
    for node in nodes():
        path, text = config_path(node), params_yaml(node)
        if path.is_file() and path.read_text() == text:
            continue
        stale.append(path.relative_to(REPO))
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f'wrote {path.relative_to(REPO)}', file=sys.stderr)
    if args.check and stale:
        print('params_files: out of date (run ./hexapod shell python tools/params_files.py): '
              + ', '.join(map(str, stale)), file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
