"""Bad scenarios stop with one line naming the key; the command line exits with 2."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from world_sim.core.scenario import ScenarioError, load, parse


@pytest.fixture
def doc(paper_scenario_path: str) -> dict[str, Any]:
    return yaml.safe_load(Path(paper_scenario_path).read_text())


def test_shipped_paper_scenario_has_the_papers_parameters(paper_scenario_path: str) -> None:
    s = load(paper_scenario_path)
    f = s.flock
    assert (f.d, f.r, f.epsilon, f.a, f.b, f.n_max, f.c1, f.c2, f.k, f.r0, f.n0, f.n1, f.height) == \
        (20.0, 24.0, 0.1, 5.0, 5.0, 80.0, 0.3, 0.6, 10.0, 0.95, 3, 10, 20.0)
    assert (s.rho, s.eta, s.dt, s.release_center) == (1.0, 3.5, 0.1, (-150.0, 50.0))
    assert [c.size for c in s.clusters] == [500] * 4


@pytest.mark.parametrize('edit, key', [
    (lambda d: d['flock'].pop('c1'), 'flock.c1'),
    (lambda d: d['flock'].__setitem__('k', -1.0), 'flock.k'),
    (lambda d: d['flock'].__setitem__('epsilon', math.nan), 'flock.epsilon'),
    (lambda d: d['flock'].__setitem__('d', 30.0), 'flock.d'),
    (lambda d: d['users'].__setitem__('clusters', []), 'users.clusters'),
    (lambda d: d.__setitem__('colour', 'red'), 'colour'),
    (lambda d: d['radio'].__setitem__('power', 2), 'radio.power'),
    (lambda d: d['users']['clusters'][1].__setitem__('spread', -3), 'users.clusters[1].spread'),
    (lambda d: d['policies'].__setitem__('edge_choice', 'random'), 'policies.edge_choice'),
    (lambda d: d.pop('seed'), 'seed'),
    (lambda d: d['radio'].__setitem__('eta', 0.0), 'radio.eta'),
    (lambda d: d['radio'].__setitem__('rho', -1.0), 'radio.rho'),
])
def test_bad_scenarios_name_the_key(doc: dict[str, Any], edit: Any, key: str) -> None:
    edit(doc)
    with pytest.raises(ScenarioError) as err:
        parse(doc)
    assert str(err.value).startswith(key + ':'), str(err.value)


def test_radio_power_and_exponent_are_optional_and_do_not_change_association(doc: dict[str, Any]) -> None:
    """Eq. 2's strongest signal is the nearest MAP for every rho, eta > 0, so both may be left out."""
    from uav_flock_tools.batch import BatchSimulator
    short = {'duration': 3.0, 'maps': 30}
    doc['radio'].pop('rho'), doc['radio'].pop('eta')
    default = parse(doc).with_overrides(**short)
    assert (default.rho, default.eta) == (1.0, 3.5)
    doc['radio'].update(rho=7.0, eta=2.0)
    other = parse(doc).with_overrides(**short)
    assert np.array_equal(BatchSimulator(default).run().metrics, BatchSimulator(other).run().metrics)


@pytest.mark.parametrize('override, key', [
    ({'seed': -5}, 'seed'), ({'maps': -3}, 'maps'), ({'maps': 2.5}, 'maps'), ({'duration': -5.0}, 'duration'),
    ({'duration': float('nan')}, 'duration'), ({'fail_at': -2.0}, 'failure.at'),
    ({'fail_fraction': -0.5}, 'failure.fraction'), ({'fail_fraction': 1.5}, 'failure.fraction'),
])
def test_overrides_are_checked_as_the_file_is(doc: dict[str, Any], override: dict[str, Any], key: str) -> None:
    """Node parameters and library callers override without the command line's argument types in front."""
    with pytest.raises(ScenarioError) as err:
        parse(doc).with_overrides(**override)
    assert str(err.value).startswith(key + ':'), str(err.value)


def test_command_line_reports_one_line_and_exit_2(doc: dict[str, Any], tmp_path: Path) -> None:
    doc['flock']['d'] = 25.0
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump(doc))
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--scenario', str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f'uav-flock: error: sim: {bad}: flock.d: must be below flock.r '
                                                '(24.0), got 25.0']
    assert 'Traceback' not in proc.stderr


@pytest.mark.parametrize('text, says', [
    ('name: x\nfoo: 1\n', 'foo: unknown key'),
    ('', 'the scenario file is empty'),
    ('name: x\n  seed: [1\n', 'not valid YAML at line 2, column 7'),
])
def test_a_bad_scenario_file_is_named_and_located(tmp_path: Path, text: str, says: str) -> None:
    bad = tmp_path / 'mine.yaml'
    bad.write_text(text)
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--scenario', str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert f'{bad}: {says}' in proc.stderr, proc.stderr


def test_options_are_never_abbreviated() -> None:
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--map', '40'],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and 'unrecognized arguments: --map 40' in proc.stderr, proc.stderr


def test_command_line_rejects_bad_options_in_one_line() -> None:
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--fail-fraction', '1.5'],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert '--fail-fraction' in proc.stderr
