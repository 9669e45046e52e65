"""The bootstrap stops on bad ground with one line that says what is missing, and leaves no stamp behind,
so the next call starts the unfinished stage again. Runs a copy of the bootstrap in a scratch checkout."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ('bash', 'env', 'sha256sum', 'cut', 'cat', 'find', 'sort', 'xargs', 'rm', 'dirname', 'tail', 'grep')


@pytest.fixture
def scratch(tmp_path: Path) -> Path:
    """A checkout with the bootstrap and requirements but no .venv, and a bin/ holding only basic tools."""
    (tmp_path / 'tools').mkdir()
    shutil.copy(ROOT / 'tools' / 'bootstrap.sh', tmp_path / 'tools')
    shutil.copy(ROOT / 'uav-flock', tmp_path)
    shutil.copytree(ROOT / 'requirements', tmp_path / 'requirements')
    (tmp_path / 'ros2_ws').mkdir()
    (tmp_path / 'ros2_ws' / 'src').mkdir()
    bin_dir = tmp_path / 'bin'
    bin_dir.mkdir()
    for tool in TOOLS:
        found = shutil.which(tool)
        assert found, f'the test needs {tool} on PATH'
        (bin_dir / tool).symlink_to(found)
    return tmp_path


def bootstrap(root: Path, *command: str, **env: str) -> subprocess.CompletedProcess[str]:
    """tools/bootstrap.sh, or with command the ./uav-flock wrapper (which bootstraps first)."""
    base = {'PATH': str(root / 'bin'), 'HOME': os.environ.get('HOME', '/tmp')}
    base.update(env)
    argv = ['bash', str(root / 'uav-flock'), *command] if command else ['bash', str(root / 'tools' / 'bootstrap.sh')]
    return subprocess.run(argv, env=base, capture_output=True, text=True, timeout=300)


def one_error_line(proc: subprocess.CompletedProcess[str]) -> str:
    errors = [line for line in proc.stderr.splitlines() if line.startswith('uav-flock: error:')]
    assert proc.returncode != 0 and len(errors) == 1, proc.stderr
    assert 'Traceback' not in proc.stderr
    return errors[0]


def test_unsupported_python_is_named(scratch: Path) -> None:
    old = scratch / 'bin' / 'python3.9'  # answers the bootstrap's version probes as a Python 3.9 would
    old.write_text('#!/bin/bash\ncase "$2" in *platform*) echo 3.9.1 ;; *) exit 1 ;; esac\n')
    old.chmod(0o755)
    line = one_error_line(bootstrap(scratch, UAV_FLOCK_PYTHON=str(old)))
    assert '3.10-3.12' in line and 'UAV_FLOCK_PYTHON' in line


def test_missing_compiler_is_named(scratch: Path) -> None:
    line = one_error_line(bootstrap(scratch, UAV_FLOCK_PYTHON=sys.executable))
    assert 'no C compiler' in line and 'build-essential' in line
    assert not (scratch / '.venv').exists()


@pytest.mark.parametrize('through_wrapper', [False, True])
def test_failed_download_is_named_and_leaves_no_stamp(scratch: Path, through_wrapper: bool) -> None:
    """Also through ./uav-flock, as `make test` runs it: each stage says what it does, with the time so far."""
    for tool in ('cc', 'c++', 'cmake', 'make'):
        found = shutil.which(tool)
        assert found, f'the test needs {tool} on PATH'
        (scratch / 'bin' / tool).symlink_to(found)
    python = shutil.which('python3.11') or shutil.which('python3.12') or shutil.which('python3.10')
    assert python, 'the test needs a CPython 3.10-3.12 on PATH'
    proc = bootstrap(scratch, *(['test'] if through_wrapper else []), UAV_FLOCK_PYTHON=os.path.realpath(python),
                     PIP_INDEX_URL='http://127.0.0.1:9/simple',
                     PIP_EXTRA_INDEX_URL='', PIP_FIND_LINKS='', PIP_RETRIES='0', PIP_TIMEOUT='2',
                     PIP_CONFIG_FILE=os.devnull)
    line = one_error_line(proc)
    assert 'package installation failed' in line and 'PyPI' in line
    stages = [ln for ln in proc.stderr.splitlines() if ln.startswith('uav-flock: [set-up')]
    assert [ln.split('] ')[1].split(' ')[0] for ln in stages] == ['creating', 'installing'], proc.stderr
    assert (scratch / '.venv' / 'bin' / 'python').exists(), 'the venv stays, so the next call only installs'
    assert not (scratch / '.venv' / '.uav-flock-stamp').exists(), 'an unfinished stage must not be stamped'


def test_the_shell_puts_the_environment_before_what_the_users_rc_files_add(tmp_path: Path) -> None:
    """A ~/.bashrc that puts a pyenv-like shim first on PATH must not hide the venv's python."""
    shim = tmp_path / 'shim'
    shim.mkdir()
    (shim / 'python').write_text('#!/bin/sh\necho shim-python\nexit 1\n')
    (shim / 'python').chmod(0o755)
    (tmp_path / '.bashrc').write_text(f'export PATH="{shim}:$PATH"\n')
    env = {**os.environ, 'HOME': str(tmp_path)}
    proc = subprocess.run([str(ROOT / 'uav-flock'), 'shell'], input='python -c "import rclpy, sys; print(sys.executable)"\n'
                          'exit\n', env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert str(ROOT / '.venv') in proc.stdout and 'shim-python' not in proc.stdout, proc.stdout + proc.stderr
