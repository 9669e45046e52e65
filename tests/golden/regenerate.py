"""Re-record the golden bag on purpose, after a change of the agents' behaviour that is meant.

    ./uav-flock exec python tests/golden/regenerate.py

tests/ros/test_bags.py replays every MAP of this bag against the current agent code; any difference in
a command fails. The run (scenario.yaml: 7 MAPs, 10 s, every mode, one scheduled failure) keeps the bag far below 2 MB.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
RUN_ARGS = ('--scenario', str(HERE / 'scenario.yaml'), '--fail-at', '6', '--fail-fraction', '0.15')


def main() -> int:
    with tempfile.TemporaryDirectory(prefix='uav-flock-golden-') as tmp:
        run = Path(tmp) / 'run'
        done = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'up', *RUN_ARGS, '--record',
                               '--out', str(run)], text=True)
        if done.returncode != 0:
            print('regenerate: the recorded run failed; the golden bag is unchanged', file=sys.stderr)
            return 1
        target = HERE / 'bag'
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(run / 'bag', target)
    size = sum(f.stat().st_size for f in target.iterdir())
    print(f'golden bag written to {target} ({size / 1e6:.2f} MB)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
