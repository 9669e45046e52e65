"""The X500 airframe (`vehicle: {model: x500}`): crazyflow's hb_x500 behind airframes.Airframe, flown by the real
command line in processes of their own (crazyflow needs SCIPY_ARRAY_API=1 from the start)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from world_sim.core import airframes, vehicle
from world_sim.core.records import read_csv, read_trajectory

pytestmark = pytest.mark.slow  # every test starts a process that builds crazyflow's worlds

NEEDS = 'the x500 extra (crazyflow), which `./uav-flock test` installs: ./uav-flock bootstrap --with x500'


def cli(*args: str, code: str = '', cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """The command line in a process of its own; `code` runs first in it (before the command is parsed)."""
    run = f'{code}\nimport sys\nfrom uav_flock_tools.cli import main\nsys.exit(main({list(args)!r}))'
    return subprocess.run([sys.executable, '-c', run], capture_output=True, text=True, timeout=600, cwd=cwd)


@pytest.fixture(scope='module')
def flown(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, subprocess.CompletedProcess[str]]:
    assert airframes.missing('x500') is None, NEEDS
    out = tmp_path_factory.mktemp('x500')
    args = ('sim', '--scenario', 'drift', '--vehicle', 'x500', '--maps', '24', '--duration', '8')
    first = cli(*args, '--out', str(out / 'a'), cwd=out)
    again = cli(*args, '--out', str(out / 'b'), cwd=out)
    assert first.returncode == 0 and again.returncode == 0, first.stderr[-2000:] + again.stderr[-2000:]
    return out / 'a', out / 'b', first


def test_sim_flies_the_x500_and_names_it_first(flown: tuple) -> None:
    a, _, proc = flown
    assert proc.stdout.splitlines()[0].startswith('vehicle: x500: 15 m/s, 4 m/s^2, lag 0.25 s'), proc.stdout
    assert 'least distance' in proc.stdout and 'Traceback' not in proc.stderr
    assert len(proc.stdout.splitlines()) == 4, 'the report alone on stdout: ' + proc.stdout
    assert not (a.parent / 'MUJOCO_LOG.TXT').exists(), 'MuJoCo\'s warnings leave no file where the run started'
    t = read_trajectory(a)
    assert np.all(np.abs(t['z'] - t['z'][0]) < 1.0), 'its altitude hold keeps the formation flat'
    m = read_csv(a / 'metrics.csv')
    assert np.nanmin(m['min_distance']) >= vehicle.MULTIROTOR.separation
    est = np.hypot(t['x_est'] - t['x'], t['y_est'] - t['y'])
    assert 0 < est.max() < 10, 'the GNSS error is the first-order multirotor\'s'


def test_an_x500_run_flies_again_to_the_bit(flown: tuple) -> None:
    a, b, _ = flown
    for name in ('metrics.csv', 'trajectory.csv'):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_a_step_response_of_the_x500_is_within_its_profile() -> None:
    """A command of a_max along x from hover: the airframe follows it with the lag its profile states (63 % of it
    within tau and a step), overshoots it by at most half while its controller catches up with the setpoints
    (docs/vehicle.md, "The X500"), then delivers it, and holds its height."""
    assert airframes.missing('x500') is None, NEEDS
    code = '''
import numpy as np
from world_sim.core import airframes, vehicle
from dataclasses import replace
v = replace(vehicle.by_name('x500'), wind=vehicle.Wind(0.0, 0.0, 0.0, 5.0), gnss=vehicle.Gnss(0.0, 60.0, 0.0))
f = airframes.start(v, 1, 0.1, np.random.default_rng(0))
q, p = f.release(np.array([[0.0, 0.0, 20.0]]), np.zeros((1, 3)), (0.0, 0.0), 40.0, np.random.default_rng(1))
out = []
for k in range(40):
    q2, p2 = f.step(np.arange(1), q, p, np.array([[v.a_max, 0.0, 0.0]]))
    out.append([(p2[0, 0] - p[0, 0]) / 0.1, p2[0, 0], q2[0, 2]])
    q, p = q2, p2
print(repr(out))
'''
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **airframes.environment('x500')})
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = np.array(eval(proc.stdout.strip().splitlines()[-1]))
    accel, speed, z = rows[:, 0], rows[:, 1], rows[:, 2]
    tau, a_max = vehicle.by_name('x500').tau, vehicle.by_name('x500').a_max
    first = int(np.argmax(accel >= 0.63 * a_max))
    assert accel[first] >= 0.63 * a_max and (first + 1) * 0.1 <= tau + 0.1 + 1e-9, accel[:6]
    assert accel.max() <= 1.5 * a_max, accel.max()
    assert abs(accel[10:30].mean() - a_max) < 0.1 * a_max, accel[10:30]
    assert np.all(np.abs(z - 20.0) < 0.5), z.min()


def test_a_scenario_naming_the_x500_without_crazyflow_is_one_line() -> None:
    proc = cli('sim', '--vehicle', 'x500', '--maps', '5', '--duration', '1',
               code="import world_sim.core.airframes.x500 as x; x.X500.NEEDS = 'crazyflow_is_not_here'")
    assert proc.returncode == 2 and proc.stdout == '', proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [
        'uav-flock: error: sim: vehicle x500 flies on crazyflow_is_not_here, which is not installed here: '
        './uav-flock bootstrap --with x500'], proc.stderr
